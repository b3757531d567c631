//! Fuzzes the RTPS message parser: any datagram either fails with an error
//! or parses; a parsed message re-encodes to bytes that parse to the same
//! message, and parameter lists, SPDP/SEDP data and disposals in DATA
//! submessages parse without panicking.
#![no_main]

use courier_wire::rtps::discovery::{payload_params, Disposal, EndpointData, ParticipantData};
use courier_wire::rtps::{Message, ParameterList, Submessage};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(m) = Message::parse(data) else { return };
    for s in &m.submessages {
        if let Submessage::Data(d) = s {
            if let Some(p) = d.payload {
                if p.len() >= 4 {
                    let _ = ParameterList::parse(&p[4..], p[1] & 1 == 1);
                }
                if let Ok(list) = payload_params(p) {
                    let _ = ParticipantData::from_params(&list);
                    let _ = EndpointData::from_params(&list, true);
                }
            }
            let _ = Disposal::from_data(d.inline_qos, true, d.payload, d.key);
        }
    }
    let out = m.to_vec();
    let again = Message::parse(&out).expect("re-encoded message must parse");
    assert_eq!(again, m, "re-encoding changed the message");
});
