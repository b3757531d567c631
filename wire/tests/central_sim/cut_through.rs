//! Cut-through (`Config::cut_through`): a large message forwarded while it
//! still arrives; and large messages kept in the buffer they arrived in.
//! Central reads 4 KiB at a time here, unless a test says otherwise.

use courier_wire::ipc::central::{Config, LogOptions};
use courier_wire::ipc::frame::{ClassId, Header, MsgClass};
use courier_wire::ipc::module::{DeliveryKind, Event};
use courier_wire::sim::{Reads, StreamFaults};

use crate::routing::raw_frame;
use crate::support::{define, pub_sub, Mod, Sim};

/// Writes travel whole, without delay, and are read 4 KiB at a time.
fn reads_of_4k() -> StreamFaults {
    StreamFaults {
        reads: Reads::Chunks(4096),
        ..StreamFaults::none()
    }
}

/// A module that asks a large query and one that answers it, with central
/// reading 4 KiB at a time: returns the sim and both modules. (No frame
/// stall timeout: the tests hold frames half sent while the network's clock
/// jumps ahead; `a_stalled_cut_through_sender_is_closed` has it.)
fn large_query_pair(cut_through: Option<usize>) -> (Sim, Mod, Mod) {
    large_query_pair_with(cut_through, None)
}

fn large_query_pair_with(
    cut_through: Option<usize>,
    stall: Option<std::time::Duration>,
) -> (Sim, Mod, Mod) {
    let mut config = Config::default();
    config.cut_through = cut_through;
    config.frame_stall_timeout = stall;
    let mut sim = Sim::with(config, 1, reads_of_4k(), None);
    let a = sim.connect("asker");
    let b = sim.connect("answerer");
    define(&mut sim, a, "ask", "{int, <ubyte:1>}");
    define(&mut sim, a, "answer", "{int, <ubyte:1>}");
    sim.m(b).subscribe("ask", "HND-ask").unwrap();
    sim.pump();
    // Both learn the messages' ids, so later frames go out at once.
    sim.m(a).query("ask", blob(1, 0), -1).unwrap();
    sim.pump();
    let d = sim.deliveries(b);
    sim.m(b).respond(d[0].0, "answer", blob(1, 0)).unwrap();
    sim.pump();
    sim.take_events(a);
    sim.take_events(b); // the answerer's Replied
    (sim, a, b)
}

/// The frames module `id` has written and not yet handed to the network,
/// as one byte string: taken from the machine, for the test to send.
fn written(sim: &mut Sim, id: Mod) -> Vec<u8> {
    std::iter::from_fn(|| sim.m(id).poll_transmit())
        .flatten()
        .collect()
}

/// `a` asks a 100 kB query (`blob(100_000, seed)`) of which central has
/// read the first `upto` bytes; the rest waits in the network, and so does
/// whatever `a` writes next, until `sim.hold(a, false)`.
fn half_sent_query(sim: &mut Sim, a: Mod, seed: u8, upto: usize) {
    sim.hold(a, true);
    sim.m(a).query("ask", blob(100_000, seed), -1).unwrap();
    sim.pump();
    let s = sim.stream(a);
    assert_eq!(sim.net.push(s, upto), upto);
}

/// `{int, <ubyte:1>}` data holding `payload`.
fn blob_of(payload: &[u8]) -> Vec<u8> {
    let mut v = (payload.len() as i32).to_le_bytes().to_vec();
    v.extend_from_slice(payload);
    v
}

/// `b` got the 100 kB query whose sender went half way, completed with
/// zeros; it answers it.
fn answer_the_zero_completed_query(sim: &mut Sim, b: Mod) {
    let (delivery, body) = only_delivery(sim, b);
    assert_eq!(body.len(), 100_004);
    assert!(body[body.len() - 1000..].iter().all(|&x| x == 0));
    sim.m(b).respond(delivery, "answer", blob(10, 0)).unwrap();
    sim.pump();
}

/// The one delivery `id` has received: its id and data.
fn only_delivery(sim: &mut Sim, id: Mod) -> (u64, Vec<u8>) {
    let mut d = sim.deliveries(id);
    assert_eq!(d.len(), 1, "{d:?}");
    let (delivery, _, _, data) = d.remove(0);
    (delivery, data)
}

/// The largest single write central made to `id` since write number `from`.
fn largest_write(sim: &Sim, id: Mod, from: usize) -> usize {
    sim.writes(id)[from..].iter().copied().max().unwrap_or(0)
}

pub fn blob(n: usize, seed: u8) -> Vec<u8> {
    let mut v = (n as i32).to_le_bytes().to_vec();
    v.extend((0..n).map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed)));
    v
}

/// Runs `rounds` large queries and returns every byte central wrote to each
/// of the two modules (the asker, host 1, and the answerer, host 2), and
/// the sim.
fn large_queries(cut_through: Option<usize>, rounds: usize) -> (Vec<u8>, Vec<u8>, Sim) {
    let (mut sim, a, b) = large_query_pair(cut_through);
    assert_eq!((a, b), (1, 2));
    let start_a = sim.wire(a).len();
    let start_b = sim.wire(b).len();
    for r in 0..rounds {
        let q = sim.m(a).query("ask", blob(100_000, r as u8), -1).unwrap();
        sim.pump();
        let (delivery, data) = only_delivery(&mut sim, b);
        assert_eq!(data, blob(100_000, r as u8), "the query arrives whole");
        sim.m(b)
            .respond(delivery, "answer", blob(200_000, 100 + r as u8))
            .unwrap();
        sim.pump();
        let ev = sim.take_events(a);
        assert!(
            ev.iter()
                .any(|e| matches!(e, Event::Reply { query, data, .. }
                if *query == q && data.ends_with(&blob(200_000, 100 + r as u8)[4..]))),
            "round {r}: {ev:?}"
        );
    }
    assert_eq!(
        sim.central().stats().dispatches,
        0,
        "every dispatch completed"
    );
    let wa = sim.wire(a)[start_a..].to_vec();
    let wb = sim.wire(b)[start_b..].to_vec();
    (wa, wb, sim)
}

#[test]
fn cut_through_sends_the_same_bytes_as_store_and_forward() {
    let (a_whole, b_whole, mut whole) = large_queries(None, 3);
    let (a_cut, b_cut, mut cut) = large_queries(Some(64 << 10), 3);
    assert_eq!(a_cut, a_whole, "the asker's byte stream");
    assert_eq!(b_cut, b_whole, "the answerer's byte stream");
    // ... in pieces as they arrived (4 KiB reads), where store-and-forward
    // writes each frame whole.
    let (a, b) = (1, 2);
    assert!(largest_write(&whole, b, 0) > 100_000);
    assert!(largest_write(&whole, a, 0) > 200_000);
    assert!(
        largest_write(&cut, b, 0) <= 4096 + 64,
        "{:?}",
        cut.writes(b)
    );
    assert!(
        largest_write(&cut, a, 0) <= 4096 + 64,
        "{:?}",
        cut.writes(a)
    );
    assert_eq!(
        cut.central().stats().frames_in,
        whole.central().stats().frames_in
    );
}

#[test]
fn cut_through_forwards_before_the_last_byte_arrives() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    sim.hold(a, true);
    sim.m(a).query("ask", blob(100_000, 1), -1).unwrap();
    sim.pump();
    let s = sim.stream(a);
    let frame = sim.net.unread(s);
    let before = sim.wire(b).len();
    // All but the last byte: the answerer already has all but the last byte
    // (the header is central's own; the module knows the message's name).
    assert_eq!(sim.net.push(s, frame - 1), frame - 1);
    sim.pump();
    assert_eq!(sim.wire(b).len() - before, frame - 1);
    assert!(sim.deliveries(b).is_empty(), "not complete yet");
    sim.hold(a, false);
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(100_000, 1));
}

#[test]
fn cut_through_holds_other_frames_until_the_relayed_one_is_complete() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    // The rest is in the asker's socket, not yet read.
    half_sent_query(&mut sim, a, 2, 50_000);
    // The answerer asks central something while the query is half through:
    // central's answer must not land inside the query's bytes.
    let op = sim.m(b).is_module_connected("asker").unwrap();
    let before = sim.wire(b).len();
    sim.pump();
    assert_eq!(
        sim.wire(b).len(),
        before,
        "the answer waits for the query's end"
    );
    assert!(sim.take_events(b).is_empty());
    sim.hold(a, false);
    sim.pump();
    let ev = sim.take_events(b);
    let q = ev
        .iter()
        .position(|e| matches!(e, Event::Delivery { data, .. } if *data == blob(100_000, 2)));
    let answer = ev.iter().position(|e| {
        *e == Event::ModuleConnected {
            op,
            connected: true,
        }
    });
    assert!(q.is_some() && answer.is_some(), "{ev:?}");
}

#[test]
fn cut_through_sender_dying_midway_completes_the_frame_with_zeros() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    // The asker dies with the rest of its query unsent.
    half_sent_query(&mut sim, a, 3, 30_000);
    sim.close(a);
    assert!(
        sim.logs
            .iter()
            .any(|l| l.contains("ended in the middle of ask")
                && l.contains("bytes forwarded); the rest went to")
                && l.contains("answerer")),
        "{:#?}",
        sim.logs
    );
    // The answerer's stream stays whole: one delivery, its tail zeros.
    // Its answer goes nowhere, and central is fine for everyone else.
    answer_the_zero_completed_query(&mut sim, b);
    assert_eq!(sim.central().stats().dispatches, 0);
    let e = sim.connect("after");
    define(&mut sim, e, "ask", "{int, <ubyte:1>}");
    sim.m(e).query("ask", blob(70_000, 4), -1).unwrap();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(70_000, 4));
}

/// A sender that stops in the middle of a relayed frame held its
/// receiver's other deliveries for as long as it kept the connection: it is
/// closed after `frame_stall_timeout` without a byte, and the receiver gets
/// the frame completed with zeros, then what waited for it.
#[test]
fn a_stalled_cut_through_sender_is_closed() {
    let stall = std::time::Duration::from_secs(30);
    let (mut sim, a, b) = large_query_pair_with(Some(64 << 10), Some(stall));
    let other = sim.connect("other");
    define(&mut sim, other, "ask", "{int, <ubyte:1>}");
    sim.pump();
    let start = sim.net.now();
    half_sent_query(&mut sim, a, 3, 30_000);
    // still within the timeout: a few more bytes keep it alive
    sim.net.run_for(stall / 2);
    let s = sim.stream(a);
    assert_eq!(sim.net.push(s, 10_000), 10_000);
    sim.net
        .run_for(stall / 2 + std::time::Duration::from_secs(5));
    sim.collect();
    assert!(sim.closes.is_empty(), "{:?}", sim.closes);
    // another module's query for b waits behind the relayed frame
    sim.m(other).query("ask", blob(10, 9), -1).unwrap();
    sim.pump();
    assert!(
        sim.net.now() - start >= stall + stall / 2,
        "closed too early"
    );
    let reasons: Vec<&str> = sim.closes.iter().map(|(_, why)| why.as_str()).collect();
    assert_eq!(
        reasons,
        ["its message (forwarded as it came) of 100012 bytes stopped arriving (39972 received, none in 30 s)"],
        "{:#?}",
        sim.logs
    );
    assert!(
        sim.logs
            .iter()
            .any(|l| l.starts_with("WARNING: closing connection")
                && l.contains("(asker")
                && l.contains("stopped arriving")),
        "{:#?}",
        sim.logs
    );
    // b: the stalled frame completed with zeros, then the other query
    answer_the_zero_completed_query(&mut sim, b);
    assert_eq!(only_delivery(&mut sim, b).1, blob(10, 9));
    sim.central().check_invariants();
}

#[test]
fn cut_through_receiver_dying_midway_leaves_the_sender_in_step() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    let b2 = sim.connect("answerer2");
    half_sent_query(&mut sim, a, 5, 30_000);
    sim.close(b);
    sim.hold(a, false);
    sim.pump();
    // The sender's next frame is read as a frame, not as the rest of the body.
    sim.m(b2).subscribe("ask", "HND-ask").unwrap();
    sim.pump();
    sim.m(a).query("ask", blob(80_000, 6), -1).unwrap();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b2).1, blob(80_000, 6));
    assert!(sim.closes.is_empty(), "{:?}", sim.closes);
}

#[test]
fn cut_through_waits_for_a_busy_receiver_and_skips_small_frames() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    // Busy: the first query is being handled, the second must wait whole.
    sim.m(a).query("ask", blob(100, 7), -1).unwrap();
    sim.pump();
    let first = sim.deliveries(b);
    assert_eq!(first.len(), 1);
    let writes = sim.writes(b).len();
    sim.m(a).query("ask", blob(100_000, 8), -1).unwrap();
    sim.pump();
    assert_eq!(
        sim.writes(b).len(),
        writes,
        "nothing forwarded to a busy handler"
    );
    sim.m(b).respond(first[0].0, "answer", blob(1, 0)).unwrap();
    sim.pump();
    assert!(
        largest_write(&sim, b, writes) > 100_000,
        "stored, then sent in one piece"
    );
    assert_eq!(only_delivery(&mut sim, b).1, blob(100_000, 8));
}

#[test]
fn cut_through_is_off_with_data_logging() {
    let mut config = Config::default();
    config.cut_through = Some(1024);
    config.terminal_log = LogOptions::parse("md", false).unwrap();
    let mut sim = Sim::with(config, 1, reads_of_4k(), None);
    let a = sim.connect("asker");
    let b = sim.connect("answerer");
    define(&mut sim, a, "ask", "{int, <ubyte:1>}");
    sim.m(b).subscribe("ask", "HND-ask").unwrap();
    sim.pump();
    let writes = sim.writes(b).len();
    sim.m(a).query("ask", blob(50_000, 9), -1).unwrap();
    sim.pump();
    assert!(
        largest_write(&sim, b, writes) > 50_000,
        "the whole message, logged, then sent"
    );
    assert!(
        sim.logs.iter().any(|l| l.contains("ask")),
        "{:#?}",
        sim.logs
    );
    assert_eq!(sim.deliveries(b)[0].3, blob(50_000, 9));
}

/// Hostile senders against a cut-through central: frames aimed at a real
/// handler with random classes, lengths, dispatch refs and bodies, read in
/// random pieces, the sender vanishing at random points. Central must not
/// panic, and the handler's stream must stay whole: it keeps parsing,
/// stays connected, and can finish every delivery it is given.
#[test]
fn cut_through_survives_hostile_senders() {
    let (mut sim, a, b) = large_query_pair(Some(16));
    sim.net.stream_faults.reads = Reads::Random(700);
    let ask = sim.central().message_id("ask").expect("ask is registered");
    let mut x: u64 = 0x2545_f491_4f6c_dd1d;
    let mut rnd = move |n: u64| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x % n
    };
    const HEADER: usize = 28;
    let mut relayed = 0;
    for round in 0..300u64 {
        let hostile = sim.raw("hostile");
        let class = [3u16, 6, 11, 15, 12, 7][rnd(6) as usize];
        let class_total = rnd(9) as usize;
        // A body the handler can read (as the asker's module marshals
        // it), of random bytes: what is tested is the stream, not the content.
        let n = rnd(6000) as usize;
        let payload: Vec<u8> = (0..n).map(|_| rnd(256) as u8).collect();
        sim.m(a).publish("ask", blob_of(&payload), -1).unwrap();
        let real = written(&mut sim, a);
        let real_h = Header::decode(&real).unwrap();
        let body = real[HEADER + real_h.class_total as usize..].to_vec();
        let h = Header {
            class_total: class_total as i32,
            msg_total: body.len() as i32,
            parent_ref: -1,
            intent: if rnd(4) == 0 { rnd(300) as i32 } else { ask },
            class_id: ClassId((ClassId::native(MsgClass::Unknown).0 & 0xffff_0000) | class as u32),
            dispatch_ref: rnd(8) as i32 - 1,
            msg_ref: 1,
        };
        let mut bytes = h.encode().to_vec();
        bytes.extend((0..class_total).map(|_| rnd(256) as u8));
        bytes.extend_from_slice(&body);
        // Sometimes the sender dies before the end (after the body's count:
        // zeros then complete an array, which the format can still read).
        let sent = if rnd(3) == 0 {
            let from = HEADER + class_total + 8;
            from + rnd((bytes.len() - from) as u64) as usize
        } else {
            bytes.len()
        };
        sim.net.write(hostile, &bytes[..sent]);
        sim.net.close(hostile);
        sim.pump();
        // The handler finishes what it was given, whatever its content.
        for (delivery, _, kind, _) in sim.deliveries(b) {
            match kind {
                DeliveryKind::Query => sim.m(b).respond(delivery, "answer", blob(1, 0)).unwrap(),
                DeliveryKind::Broadcast => sim.m(b).ack(delivery).unwrap(),
            }
        }
        sim.pump();
        if !sim.m(b).is_connected() {
            let ev = sim.take_events(b);
            panic!("round {round}: {:#?} {ev:?}", sim.logs);
        }
        relayed += sim
            .logs
            .iter()
            .filter(|l| l.contains("as zero bytes"))
            .count();
        sim.logs.clear();
    }
    assert!(
        relayed > 10,
        "senders died in the middle of relays: {relayed}"
    );
    // And still serves real traffic, whole.
    sim.m(a).query("ask", blob(100_000, 42), -1).unwrap();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(100_000, 42));
    // Central closed only hostile connections (bad class data and the like).
    assert!(
        sim.closes
            .iter()
            .all(|(c, _)| sim.net.owner(c.peer()).is_none()),
        "{:?}",
        sim.closes
    );
}

/// A message whose variable-length wrapper disagrees with itself is
/// dropped by the receiving module, which tells central it is done and
/// stays connected; what comes next is delivered as usual.
#[test]
fn a_malformed_body_costs_the_receiver_one_message_not_its_connection() {
    let (mut sim, a, b) = large_query_pair(None);
    let ask = sim.central().message_id("ask").expect("ask is registered");
    let mut body = 5i32.to_le_bytes().to_vec();
    body.extend_from_slice(&3i32.to_le_bytes()); // a count that disagrees
    body.extend_from_slice(&[1, 2, 3]);
    let rogue = sim.raw("rogue");
    sim.net
        .write(rogue, &raw_frame(MsgClass::Broadcast, ask, &body));
    sim.pump();
    let ev = sim.take_events(b);
    assert!(
        ev.iter().any(|e| matches!(e,
            Event::Undeliverable { msg, kind: DeliveryKind::Broadcast, error, .. }
                if msg == "ask" && error.to_string().contains("disagrees"))),
        "{ev:?}"
    );
    assert!(sim.m(b).is_connected());
    assert_eq!(
        sim.central().stats().dispatches,
        0,
        "the Success freed central"
    );
    sim.m(a).query("ask", blob(10, 1), -1).unwrap();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(10, 1));
}

// ----- large messages kept in the buffer they arrived in ----------------------

/// Five broadcasts, two of them large, written back to back by one module
/// and read by central in pieces of `read`: what the subscriber receives,
/// every byte central wrote to it, and how many frames went out with a
/// shared body.
fn mixed_sizes_read_in(read: usize) -> (Vec<Vec<u8>>, Vec<u8>, usize) {
    let (mut sim, a, b) = pub_sub(Config::default(), ("pub", "sub"), "m", "{int, <ubyte:1>}");
    let start = sim.wire(b).len();
    let sizes = [10, 70_000, 3, 20_000, 5];
    sim.net.stream_faults = StreamFaults {
        reads: Reads::Chunks(read),
        ..StreamFaults::none()
    };
    for (i, n) in sizes.iter().enumerate() {
        sim.m(a).publish("m", blob(*n, i as u8), -1).unwrap();
    }
    let mut got = Vec::new();
    while got.len() < sizes.len() {
        sim.pump();
        let d = sim.deliveries(b);
        assert!(!d.is_empty(), "read {read}: stalled after {}", got.len());
        for (id, _, _, data) in d {
            sim.m(b).ack(id).unwrap();
            got.push(data);
        }
    }
    for (i, (data, n)) in got.iter().zip(sizes).enumerate() {
        assert_eq!(*data, blob(n, i as u8), "read {read}: message {i}");
    }
    let wire = sim.wire(b)[start..].to_vec();
    (got, wire, sim.shared_bodies())
}

#[test]
fn large_messages_go_out_in_the_buffer_they_arrived_in_whatever_the_reads() {
    let (data, wire, shared) = mixed_sizes_read_in(usize::MAX);
    // The two messages of 16 KiB or more.
    assert_eq!(shared, 2);
    for read in [1, 7, 4096, 16 << 10, 20_031, 70_030, 70_100, 100_000] {
        let (d, w, s) = mixed_sizes_read_in(read);
        assert_eq!(d, data, "read {read}");
        assert_eq!(w, wire, "read {read}: central's bytes to the subscriber");
        assert_eq!(s, 2, "read {read}");
    }
}

#[test]
fn store_and_forward_shares_large_queries_and_replies_and_cut_through_copies_none() {
    let (_, _, mut whole) = large_queries(None, 3);
    // Three 100 kB queries and three 200 kB replies.
    assert_eq!(whole.shared_bodies(), 6);
    let (_, _, mut cut) = large_queries(Some(64 << 10), 3);
    assert_eq!(cut.shared_bodies(), 0, "relayed frames pass in pieces");
}
