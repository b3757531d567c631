//! The eProsima captures as the replay tests read them: each message of a
//! capture with its number, time, direction, client port and bytes
//! (`tests/fixtures/xrce/<capture>.hex` and `times/<capture>.times`).

use std::collections::BTreeMap;
use std::path::PathBuf;

use courier_wire::xrce::{Message, Payload};

pub fn fixture(name: &str) -> String {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/xrce")
        .join(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

pub struct Rec {
    pub n: u32,
    pub t: f64,
    pub c2a: bool,
    pub port: u16,
    pub bytes: Vec<u8>,
}

pub fn records(capture: &str) -> Vec<Rec> {
    let times: BTreeMap<u32, f64> = fixture(&format!("times/{capture}.times"))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let (a, b) = l.split_once(' ').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    fixture(&format!("{capture}.hex"))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let n = f[0].parse().unwrap();
            Rec {
                n,
                t: times[&n],
                c2a: f[2] == "C->A",
                port: f[3].parse().unwrap(),
                bytes: (0..f[4].len())
                    .step_by(2)
                    .map(|i| u8::from_str_radix(&f[4][i..i + 2], 16).unwrap())
                    .collect(),
            }
        })
        .collect()
}

/// ACKNACK and HEARTBEAT messages.
pub fn is_stream_control(m: &[u8]) -> bool {
    Message::decode(m)
        .unwrap()
        .submessages
        .iter()
        .all(|s| matches!(s.payload, Payload::AckNack(_) | Payload::Heartbeat(_)))
}
