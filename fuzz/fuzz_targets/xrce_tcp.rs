//! Fuzzes the XRCE TCP deframer: the input is cut into pieces at the sizes
//! its first byte picks; every record found is the same as when the whole
//! stream arrives at once, and its bytes go to the message decoder.
#![no_main]

use courier_wire::xrce::{tcp::TcpDeframer, Message};
use libfuzzer_sys::fuzz_target;

fn frames(data: &[u8], step: usize) -> Vec<Result<Vec<u8>, String>> {
    let mut d = TcpDeframer::with_max_len(600);
    let mut out = Vec::new();
    for chunk in data.chunks(step) {
        d.push(chunk);
        while let Some(f) = d.next_frame() {
            out.push(f.map_err(|e| e.to_string()));
        }
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&step, data)) = data.split_first() else { return };
    let split = frames(data, usize::from(step % 16) + 1);
    assert_eq!(split, frames(data, data.len().max(1)));
    for f in split.into_iter().flatten() {
        let _ = Message::decode(&f);
    }
});
