//! Fuzzes `Participant::handle_datagram`: a participant with a keyed
//! reliable writer and reader, and writers and readers of every liveliness
//! kind with finite leases (so it sends automatic participant messages
//! and takes the PMDs and liveliness HEARTBEATs of remote writers), takes
//! any sequence of datagrams (each behind an RTPS header from a fixed
//! remote participant, or raw), between steps of time (some long enough
//! for every lease to lapse), asserts its own liveliness, and never
//! panics; what it sends parses.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::rtps::discovery::{
    Duration as RtpsDuration, EndpointQos, History, LivelinessKind, Reliability,
};
use courier_wire::rtps::participant::{guid_prefix, Config, EndpointConfig, Participant};
use courier_wire::rtps::{Locator, Message};
use libfuzzer_sys::fuzz_target;

fn lively(kind: LivelinessKind, ms: u64, writer: bool) -> EndpointQos {
    let mut q = if writer {
        EndpointQos::writer_default()
    } else {
        EndpointQos::reader_default()
    };
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.liveliness = (kind, RtpsDuration::from_std(Duration::from_millis(ms)));
    q
}

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
    let plain = p
        .create_writer(EndpointConfig::writer("Fuzz", "T").keyed(true), t0)
        .unwrap();
    // liveliness: one writer of each kind (the automatic one sets the
    // participant-message period), readers requesting each kind
    use LivelinessKind::{Automatic, ManualByParticipant, ManualByTopic};
    let live = |p: &mut Participant, kind, ms| {
        let w = EndpointConfig::writer("Live", "T").qos(lively(kind, ms, true));
        p.create_writer(w, t0).unwrap()
    };
    let by_topic = live(&mut p, ManualByTopic, 200);
    let by_participant = live(&mut p, ManualByParticipant, 1000);
    live(&mut p, Automatic, 150);
    for (kind, ms) in [(ManualByTopic, 300), (ManualByParticipant, 2000), (Automatic, 500)] {
        let r = EndpointConfig::reader("Live", "T").qos(lively(kind, ms, false));
        p.create_reader(r, t0).unwrap();
    }
    let writers = [plain, by_topic, by_participant];
    let mut now = t0;
    let mut rest = data;
    // [flags][len][bytes…]…: flag bit 0 puts an RTPS header from a remote
    // participant in front, bits 1..7 advance time by that many 10 ms (up
    // to 119; 120..127 by 10 to 80 s). An empty raw datagram is also an
    // assertion of liveliness, by the same bits: none, the participant's,
    // or one of the writers'.
    while let [flags, len, tail @ ..] = rest {
        let n = usize::from(*len).min(tail.len());
        let (body, next) = tail.split_at(n);
        rest = next;
        let steps = u64::from(flags >> 1);
        now += if steps < 120 {
            Duration::from_millis(10 * steps)
        } else {
            Duration::from_secs(10 * (steps - 119))
        };
        let mut d = Vec::new();
        if flags & 1 == 1 {
            d.extend_from_slice(b"RTPS\x02\x03\x01\x0f");
            d.extend_from_slice(&[2; 12]);
        }
        d.extend_from_slice(body);
        p.handle_datagram(Locator::udpv4([127, 0, 0, 1], 7411), &d, now);
        if d.is_empty() {
            match steps % 5 {
                1 => p.assert_liveliness(now),
                k @ 2..=4 => drop(p.assert_writer_liveliness(writers[usize::from(k as u8 - 2)], now)),
                _ => {}
            }
        }
        if p.poll_timeout().is_some_and(|t| t <= now) {
            p.handle_timeout(now);
        }
        while let Some(out) = p.poll_transmit() {
            Message::parse(&out.payload).expect("what a participant sends parses");
        }
        while p.poll_event().is_some() {}
    }
});
