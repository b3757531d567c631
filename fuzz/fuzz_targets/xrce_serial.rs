//! Fuzzes the XRCE serial (HDLC-like) frame decoder: the input is cut into
//! pieces at the sizes its first byte picks; frames and errors are the same
//! as when the whole stream arrives at once, and every good frame
//! re-encodes to a frame that decodes to it again.
#![no_main]

use courier_wire::xrce::serial::{self, SerialDecoder, SerialError, SerialFrame};
use libfuzzer_sys::fuzz_target;

fn frames(data: &[u8], step: usize) -> Vec<Result<SerialFrame, SerialError>> {
    let mut d = SerialDecoder::with_max_payload(600);
    let mut out = Vec::new();
    for chunk in data.chunks(step) {
        d.push(chunk);
        while let Some(f) = d.next_frame() {
            out.push(f);
        }
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&step, data)) = data.split_first() else { return };
    let split = frames(data, usize::from(step % 16) + 1);
    assert_eq!(split, frames(data, data.len().max(1)));
    for f in split.into_iter().flatten() {
        let mut wire = Vec::new();
        serial::encode(f.src, f.dst, &f.payload, &mut wire).expect("payload fits");
        let mut d = SerialDecoder::with_max_payload(600);
        d.push(&wire);
        assert_eq!(d.next_frame(), Some(Ok(f)));
    }
});
