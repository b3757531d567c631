//! Fuzzes `Participant::handle_datagram`: a participant with a keyed
//! reliable writer and reader takes any sequence of datagrams (each behind
//! an RTPS header from a fixed remote participant, or raw), between steps
//! of time, and never panics; what it sends parses.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History, Reliability};
use courier_wire::rtps::participant::{guid_prefix, Config, EndpointConfig, Participant};
use courier_wire::rtps::{Locator, Message};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let t0 = Instant::now();
    let cfg = Config::udpv4(0, 0, guid_prefix([1; 10]), [127, 0, 0, 1])
        .unwrap()
        .with_unicast_peers(&[[127, 0, 0, 1]], 2);
    let mut p = Participant::new(cfg, t0, SystemTime::UNIX_EPOCH);
    let mut q = EndpointQos::reader_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepAll;
    p.create_reader(EndpointConfig::reader("Fuzz", "T").keyed(true).qos(q.clone()), t0)
        .unwrap();
    p.create_writer(EndpointConfig::writer("Fuzz", "T").keyed(true), t0)
        .unwrap();
    let mut now = t0;
    let mut rest = data;
    // [flags][len][bytes…]…: flag bit 0 puts an RTPS header from a remote
    // participant in front, bits 1..7 advance time by that many 10 ms
    while let [flags, len, tail @ ..] = rest {
        let n = usize::from(*len).min(tail.len());
        let (body, next) = tail.split_at(n);
        rest = next;
        now += Duration::from_millis(10 * u64::from(flags >> 1));
        let mut d = Vec::new();
        if flags & 1 == 1 {
            d.extend_from_slice(b"RTPS\x02\x03\x01\x0f");
            d.extend_from_slice(&[2; 12]);
        }
        d.extend_from_slice(body);
        p.handle_datagram(Locator::udpv4([127, 0, 0, 1], 7411), &d, now);
        if p.poll_timeout().is_some_and(|t| t <= now) {
            p.handle_timeout(now);
        }
        while let Some(out) = p.poll_transmit() {
            Message::parse(&out.payload).expect("what a participant sends parses");
        }
        while p.poll_event().is_some() {}
    }
});
