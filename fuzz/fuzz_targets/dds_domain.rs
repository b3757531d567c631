//! Fuzzes `courier_wire::dds::Domain` with commands and datagrams: two
//! domains exchange what they send (or the fuzzer's own bytes) while
//! endpoints, services, clients and patterns come and go, writes (plain and
//! confirmed; samples, disposes and unregisters of a few instances),
//! queries and replies are made and time passes. Writers and readers offer
//! and request every liveliness kind with finite and infinite leases;
//! writers and the participant assert their liveliness, participant
//! messages (PMD) of the fuzzer's own are injected from the other domain,
//! and time jumps far enough to lapse leases and participants. Nothing may
//! panic, and each writer's LIVELINESS_LOST total counts up by one.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::dds::{Domain, Event, ReaderId, RequestId, ServiceConfig, ServiceId, WriterId};
use std::collections::HashMap;

use courier_wire::rtps::discovery::{
    Duration as RtpsDuration, EndpointQos, History, LivelinessKind, Reliability,
};
use courier_wire::rtps::participant::{guid_prefix, Change, Config, EndpointConfig, KeyHash};
use courier_wire::rtps::{Data, EntityId, Locator, SequenceNumber, Submessage};
use libfuzzer_sys::fuzz_target;

const TOPICS: [&str; 3] = ["a", "b", "rq/sRequest"];
const TYPES: [&str; 2] = ["T", "U"];

fn qos(b: u8, writer: bool) -> EndpointQos {
    let mut q = if writer {
        EndpointQos::writer_default()
    } else {
        EndpointQos::reader_default()
    };
    if b & 1 == 1 {
        q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    }
    if b & 2 == 2 {
        q.history = History::KeepAll;
    }
    q.exclusive_ownership = b & 4 == 4;
    q.ownership_strength = i32::from(b >> 5);
    if b & 8 == 8 {
        q.deadline = RtpsDuration::from_std(Duration::from_millis(50));
        q.time_based_filter = RtpsDuration::from_std(Duration::from_millis(20));
    }
    if b & 16 == 16 {
        q.lifespan = RtpsDuration::from_std(Duration::from_millis(30));
    }
    q
}

/// Liveliness by a byte of its own: the kind (`l % 4`, 3 = automatic) and a
/// lease (`l >> 2 & 7`): infinite, zero (taken as infinite), or 10 ms to
/// 60 s.
fn liveliness(l: u8) -> (LivelinessKind, RtpsDuration) {
    let kind = match l % 4 {
        1 => LivelinessKind::ManualByParticipant,
        2 => LivelinessKind::ManualByTopic,
        _ => LivelinessKind::Automatic,
    };
    let ms = [0, 0, 10, 50, 200, 1000, 5000, 60_000][usize::from(l >> 2 & 7)];
    let lease = match l >> 2 & 7 {
        0 => RtpsDuration::INFINITE,
        1 => RtpsDuration::ZERO,
        _ => RtpsDuration::from_std(Duration::from_millis(ms)),
    };
    (kind, lease)
}

#[derive(Default)]
struct Side {
    writers: Vec<WriterId>,
    readers: Vec<ReaderId>,
    services: Vec<ServiceId>,
    requests: Vec<(ServiceId, RequestId)>,
    clients: Vec<courier_wire::dds::ClientId>,
    patterns: Vec<courier_wire::dds::PatternId>,
    /// Sequence numbers of the injected participant messages.
    pmd_sn: i64,
    /// LIVELINESS_LOST totals so far, by writer.
    lost: HashMap<WriterId, u64>,
}

fuzz_target!(|data: &[u8]| {
    let t0 = Instant::now();
    let mk = |i: u8| {
        let cfg = Config::udpv4(0, u32::from(i), guid_prefix([i + 1; 10]), [127, 0, 0, 1])
            .unwrap()
            .with_unicast_peers(&[[127, 0, 0, 1]], 2);
        Domain::new(cfg, t0, SystemTime::UNIX_EPOCH)
    };
    let mut ds = [mk(0), mk(1)];
    let mut sides = [Side::default(), Side::default()];
    let mut now = t0;
    let mut it = data.iter().copied();
    let svc = ServiceConfig::new("s", "T", "T");
    while let (Some(op), Some(arg)) = (it.next(), it.next()) {
        let i = usize::from(op >> 7);
        let (d, s) = (&mut ds[i], &mut sides[i]);
        let pick = |n: usize| usize::from(arg) % n.max(1);
        match op & 0x0f {
            0 => {
                let mut q = qos(arg, true);
                q.liveliness = liveliness(it.next().unwrap_or(0));
                let cfg = EndpointConfig::writer(TOPICS[pick(3)], TYPES[usize::from(arg >> 7)])
                    .keyed(arg & 8 == 8)
                    .qos(q);
                s.writers.extend(d.create_writer(cfg, now).ok());
            }
            1 => {
                let mut q = qos(arg, false);
                q.liveliness = liveliness(it.next().unwrap_or(0));
                let cfg = EndpointConfig::reader(TOPICS[pick(3)], TYPES[usize::from(arg >> 7)])
                    .keyed(arg & 8 == 8)
                    .qos(q);
                s.readers.extend(d.create_reader(cfg, now).ok());
            }
            2 if !s.writers.is_empty() => {
                let w = s.writers[pick(s.writers.len())];
                let len = usize::from(it.next().unwrap_or(0));
                let body: Vec<u8> = it.by_ref().take(len).collect();
                // a few instances; alive, disposed or unregistered
                let key = KeyHash([arg >> 4; 16]);
                let change = match (arg >> 1) & 3 {
                    2 => Change::dispose(&[], key),
                    3 => Change::unregister(&[], key),
                    _ => Change::alive_owned(body).with_key_hash(key),
                };
                if arg & 1 == 1 {
                    let _ = d.write_confirmed(w, change, Duration::from_millis(100), now);
                } else if d.has_room(w, change.data.len()) {
                    let _ = d.write(w, change, now);
                }
            }
            3 if !s.writers.is_empty() => {
                let w = s.writers.swap_remove(pick(s.writers.len()));
                d.delete_writer(w, now);
            }
            4 if !s.readers.is_empty() => {
                let r = s.readers.swap_remove(pick(s.readers.len()));
                d.delete_reader(r, now);
            }
            5 if !s.readers.is_empty() => {
                d.set_reader_full(s.readers[pick(s.readers.len())], arg & 1 == 1);
            }
            6 => s.services.extend(d.create_service(&svc, now).ok()),
            7 => s.clients.extend(d.create_client(&svc, now).ok()),
            8 if !s.clients.is_empty() => {
                let c = s.clients[pick(s.clients.len())];
                let _ = d.query(c, vec![0, 1, 0, 0, arg], Duration::from_millis(200), now);
            }
            9 if !s.requests.is_empty() => {
                let (sv, rq) = s.requests.swap_remove(pick(s.requests.len()));
                let _ = d.reply(sv, rq, vec![0, 1, 0, 0, arg], now);
            }
            10 if !s.services.is_empty() => {
                let sv = s.services.swap_remove(pick(s.services.len()));
                d.delete_service(sv, now);
            }
            11 if !s.clients.is_empty() => {
                let c = s.clients.swap_remove(pick(s.clients.len()));
                d.delete_client(c, now);
            }
            12 => {
                let p = d.create_pattern(["*", "a", "[ab]"][pick(3)], "*", qos(arg, false), now);
                s.patterns.push(p);
            }
            13 if !s.patterns.is_empty() => {
                let p = s.patterns.swap_remove(pick(s.patterns.len()));
                d.delete_pattern(p, now);
            }
            14 => {
                let len = usize::from(arg);
                let body: Vec<u8> = it.by_ref().take(len).collect();
                d.handle_datagram(Locator::udpv4([127, 0, 0, 1], 7411), &body, now);
            }
            // 15, and the ops above that found nothing to act on: by
            // `op >> 4 & 7`, liveliness or time
            _ => match op >> 4 & 7 {
                3 => {
                    // a participant message (PMD) from the other domain's
                    // participant (known to this one once SPDP went across)
                    // or one of the fuzzer's, with a payload of the fuzzer's
                    // encapsulation, prefix, kind and tail
                    let other = ds[1 - i].participant().guid_prefix();
                    let (d, s) = (&mut ds[i], &mut sides[i]);
                    let sender = if arg & 1 == 0 { other.0 } else { [arg; 12] };
                    let mut payload = vec![0, [1, 0, 3, 2][usize::from(arg >> 1 & 3)], 0, 0];
                    payload.extend_from_slice(if arg & 8 == 0 { &sender } else { &[9; 12] });
                    payload.extend_from_slice(&[0, 0, 0, [2, 1, 0, arg][usize::from(arg >> 4 & 3)]]);
                    let len = usize::from(it.next().unwrap_or(0) % 32);
                    payload.extend(it.by_ref().take(len));
                    s.pmd_sn += 1;
                    let sn = if arg & 0x40 == 0 { s.pmd_sn } else { i64::from(arg >> 7) + 1 };
                    let mut b = b"RTPS\x02\x05\x01\x10".to_vec();
                    b.extend_from_slice(&sender);
                    Submessage::Data(Data {
                        reader_id: if arg & 0x80 == 0 { EntityId::P2P_MESSAGE_READER } else { EntityId::UNKNOWN },
                        writer_id: EntityId::P2P_MESSAGE_WRITER,
                        writer_sn: SequenceNumber(sn),
                        inline_qos: None,
                        payload: Some(&payload),
                        key: false,
                        non_standard: false,
                    })
                    .write(&mut b, true);
                    d.handle_datagram(Locator::udpv4([127, 0, 0, 1], 7410), &b, now);
                }
                4 if !s.writers.is_empty() => {
                    let _ = d.assert_liveliness(s.writers[pick(s.writers.len())], now);
                }
                5 => d.assert_participant_liveliness(now),
                // long silences: leases of up to 60 s lapse, and SPDP's
                6 => now += Duration::from_millis(100 * u64::from(arg)),
                7 => now += Duration::from_secs(u64::from(arg)),
                _ => now += Duration::from_millis(u64::from(arg)),
            },
        }
        // the network: what each sends reaches the other; timers fire
        for k in 0..2 {
            if ds[k].poll_timeout().is_some_and(|t| t <= now) {
                ds[k].handle_timeout(now);
            }
            while let Some(out) = ds[k].poll_transmit() {
                ds[1 - k].handle_datagram(Locator::udpv4([127, 0, 0, 1], 7411), &out.payload, now);
            }
            while let Some(e) = ds[k].poll_event() {
                match e {
                    Event::Request { service, request, .. } => {
                        sides[k].requests.push((service, request));
                    }
                    Event::LivelinessLost { writer, total } => {
                        let prev = sides[k].lost.insert(writer, total).unwrap_or(0);
                        assert_eq!(total, prev + 1, "LIVELINESS_LOST totals of {writer:?}");
                    }
                    Event::LivelinessChanged { alive, alive_count, .. } => {
                        assert!(!alive || alive_count > 0, "alive with an alive count of 0");
                    }
                    _ => {}
                }
            }
        }
    }
});
