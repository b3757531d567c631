//! Fuzzes the XRCE message decoder: any datagram either fails with an
//! error or decodes; a decoded message re-encodes to exactly the input
//! (padding and trailing bytes are kept), and every FRAGMENT body also
//! decodes, or fails, without panicking as a reassembled submessage.
#![no_main]

use courier_wire::xrce::{Message, Payload};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(m) = Message::decode(data) else { return };
    let out = m.to_vec().expect("a decoded message encodes");
    assert_eq!(out, data, "re-encoding changed the bytes");
    let again = Message::decode(&out).expect("re-encoded message must decode");
    assert_eq!(again, m, "re-encoding changed the message");
    for s in &m.submessages {
        if let Payload::Fragment(body) = &s.payload {
            let _ = Message::reassembled(&m.header, body);
        }
    }
});
