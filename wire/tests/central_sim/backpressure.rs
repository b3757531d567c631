//! Back-pressure: floods into slow subscribers, queries waiting for a
//! handler, and modules held back while they handle or answer. Central
//! stops reading a module (`PauseRead`); the module's bytes then wait in
//! the network, and it writes no more once its socket buffer is full.
//!
//! Central handles a whole read before a pause takes effect, so how far
//! its queues pass the limit depends on the reads: these tests read 1 to
//! 128 bytes at a time (`support::cut`), at most two of their frames.

use courier_wire::ipc::central::{Config, DISPATCH_COST};
use courier_wire::ipc::frame::HEADER_SIZE;
use courier_wire::ipc::module::{Event, MsgLength};
use courier_wire::sim::Reads;

use crate::support::{define, pub_sub, Mod, Sim};

/// A module's socket buffer: about 1000 of these tests' 100-byte frames.
const SOCKET: usize = 100_000;

/// Counts rounds in which nothing reached the subscriber, so that a flood
/// that stalls fails instead of spinning.
#[derive(Default)]
struct Stall(usize);

impl Stall {
    fn round(&mut self, progress: bool, at: impl std::fmt::Debug) {
        self.0 = if progress { 0 } else { self.0 + 1 };
        assert!(self.0 < 1000, "nothing delivered in 1000 rounds, at {at:?}");
    }
}

/// 64 bytes of `[int:16]` data, the first int `i`.
fn numbered(i: i32) -> Vec<u8> {
    let mut body = vec![0u8; 64];
    body[..4].copy_from_slice(&i.to_le_bytes());
    body
}

/// The subscriber `s` handles up to `most` of the messages it was given,
/// which must be numbered `*next`, `*next + 1`, …, and acknowledges each.
fn handle_in_order(sim: &mut Sim, s: Mod, next: &mut i32, most: usize, stall: &mut Stall) {
    let before = *next;
    for (id, _, _, data) in sim.deliveries(s).into_iter().take(most) {
        assert_eq!(i32::from_le_bytes(data[..4].try_into().unwrap()), *next);
        *next += 1;
        sim.m(s).ack(id).unwrap();
    }
    stall.round(*next > before, *next);
}

/// A publisher floods 100 000 messages at a subscriber with capacity 1 that
/// acknowledges one message per round: central must pause reading from the
/// publisher (TCP back-pressure) so its queue stays under the limit, and
/// deliver everything in order.
#[test]
fn slow_subscriber_bounded_memory_nothing_lost() {
    let mut config = Config::default();
    config.max_queued_bytes = 256 << 10;
    let (mut sim, p, s) = pub_sub(config, ("flood", "slow"), "data", "[int:16]");
    const N: i32 = 100_000;
    let mut sent = 0;
    let mut next = 0;
    let mut stall = Stall::default();
    while next < N {
        // The publisher writes as fast as its socket lets it.
        while sent < N && sim.unread(p) < SOCKET {
            sim.m(p).publish("data", numbered(sent), -1).unwrap();
            sent += 1;
        }
        sim.pump();
        handle_in_order(&mut sim, s, &mut next, usize::MAX, &mut stall);
    }
    let st = sim.central().stats();
    println!(
        "100 000 messages, capacity 1: peak queued in central {} bytes (limit {}), dropped {}",
        st.peak_queued_bytes,
        256 << 10,
        st.dropped
    );
    assert_eq!(st.dropped, 0);
    assert!(
        st.peak_queued_bytes <= (256 << 10) + 1024,
        "peak {}",
        st.peak_queued_bytes
    );
    // the operator is told when central holds modules back, and for whom
    // the queue is (every module that sends more waits meanwhile)
    let held: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.contains("it stops reading the modules that send more"))
        .collect();
    // once: central held and released it over and over, a line at most
    // every 10 s (the whole run is shorter)
    assert_eq!(held.len(), 1, "{held:#?}");
    assert!(held.iter().all(|l| l.contains("slow from")), "{held:#?}");
    assert!(
        sim.logs
            .iter()
            .any(|l| l.contains("reading every module again")),
        "no line said it read again"
    );
}

/// Empty messages carry no data but do cost central their bookkeeping:
/// each counts [`DISPATCH_COST`] against the limit, so a flood of them to
/// a slow subscriber stops its publisher too instead of growing the
/// dispatch table without bound.
#[test]
fn a_flood_of_empty_messages_is_bounded_too() {
    const LIMIT: usize = 256 << 10;
    let mut config = Config::default();
    config.max_queued_bytes = LIMIT;
    let mut sim = Sim::new(config);
    // Reads shorter than a header complete at most one frame each: the
    // bound below counts dispatches, one per frame.
    sim.net.stream_faults.reads = Reads::Random(HEADER_SIZE);
    let p = sim.connect("flood");
    let s = sim.connect("slow");
    sim.m(p)
        .define_msg("tick", MsgLength::Variable, None)
        .unwrap();
    sim.m(s).subscribe("tick", "HND-tick").unwrap();
    sim.pump();
    const N: usize = 30_000;
    let (mut sent, mut got, mut most) = (0, 0, 0);
    let mut stall = Stall::default();
    while got < N {
        while sent < N && sim.unread(p) < SOCKET {
            sim.m(p).publish("tick", Vec::new(), -1).unwrap();
            sent += 1;
        }
        sim.pump();
        most = most.max(sim.central().stats().dispatches);
        let before = got;
        for (id, _, _, data) in sim.deliveries(s) {
            assert!(data.is_empty());
            got += 1;
            sim.m(s).ack(id).unwrap();
        }
        stall.round(got > before, got);
    }
    sim.pump();
    let st = sim.central().stats();
    println!(
        "{N} empty messages, capacity 1: at most {most} dispatches in central, peak queued {} (limit {LIMIT})",
        st.peak_queued_bytes
    );
    assert!(
        most <= LIMIT / DISPATCH_COST + 2,
        "{most} dispatches at once"
    );
    assert!(st.peak_queued_bytes <= LIMIT + DISPATCH_COST);
    assert_eq!((st.dropped, st.dispatches), (0, 0));
}

/// Queries for a message nobody handles wait for a handler (as in C),
/// but not without bound: past the limit the oldest are dropped, with a
/// rate-limited warning, and a handler that comes gets the newest, oldest
/// first.
#[test]
fn queries_waiting_for_a_handler_are_bounded_and_the_newest_kept() {
    const LIMIT: usize = 64 << 10;
    const N: i32 = 5_000;
    let mut config = Config::default();
    config.max_queued_bytes = LIMIT;
    let mut sim = Sim::new(config);
    let a = sim.connect("asker");
    define(&mut sim, a, "nobody", "[int:16]");
    define(&mut sim, a, "nobody_reply", "int");
    sim.pump();
    let before = sim.logs.len();
    for i in 0..N {
        sim.m(a).query("nobody", numbered(i), -1).unwrap();
        sim.pump();
    }
    let st = sim.central().stats();
    // As many as fit (64 bytes of data, the query's own bytes and the
    // bookkeeping each), no more.
    let kept = st.waiting_for_handler;
    let each = st.waiting_bytes / kept;
    assert!(
        each > 64 + DISPATCH_COST && each < 128 + DISPATCH_COST,
        "{each}"
    );
    assert!(
        st.waiting_bytes <= LIMIT && st.waiting_bytes + each > LIMIT,
        "{st:?}"
    );
    assert_eq!(st.dropped_waiting, N as u64 - kept as u64);
    let warnings: Vec<&String> = sim.logs[before..]
        .iter()
        .filter(|l| l.contains("dropped: more than 65536 bytes of queries wait for a handler"))
        .collect();
    assert!(
        (1..=10).contains(&warnings.len()),
        "a burst of warnings, not one per drop: {}",
        warnings.len()
    );
    assert!(
        warnings[0].starts_with("WARNING: Query nobody {") && warnings[0].contains("from asker"),
        "{}",
        warnings[0]
    );
    let b = sim.connect("server");
    sim.m(b).subscribe("nobody", "HND-nobody").unwrap();
    sim.pump();
    let mut next = N - kept as i32;
    while next < N {
        let d = sim.deliveries(b);
        assert_eq!(d.len(), 1, "capacity 1");
        assert_eq!(i32::from_le_bytes(d[0].3[..4].try_into().unwrap()), next);
        next += 1;
        sim.m(b)
            .respond(d[0].0, "nobody_reply", next.to_le_bytes())
            .unwrap();
        sim.pump();
    }
    let replies = sim
        .take_events(a)
        .iter()
        .filter(|e| matches!(e, Event::Reply { .. }))
        .count();
    assert_eq!(replies, kept);
    let st = sim.central().stats();
    assert_eq!(
        (st.waiting_for_handler, st.waiting_bytes, st.dispatches),
        (0, 0, 0)
    );
}

/// A module that publishes from inside a handler (the usual pipeline: it
/// handles a message and publishes what it made of it) is attending a
/// delivery the whole time. Central must still stop reading it when its
/// subscriber falls behind, or its queue grows without bound.
#[test]
fn a_module_publishing_inside_a_broadcast_handler_is_held_back_too() {
    const LIMIT: usize = 64 << 10;
    let mut config = Config::default();
    config.max_queued_bytes = LIMIT;
    let mut sim = Sim::new(config);
    let up = sim.connect("upstream");
    let m = sim.connect("pipeline");
    let s = sim.connect("slow");
    define(&mut sim, up, "go", "int");
    define(&mut sim, m, "data", "[int:16]");
    sim.m(m).subscribe("go", "HND-go").unwrap();
    sim.m(s).subscribe("data", "HND-data").unwrap();
    sim.pump();
    sim.m(up)
        .publish("go", 7i32.to_le_bytes().to_vec(), -1)
        .unwrap();
    sim.pump();
    let go = sim.deliveries(m);
    assert_eq!(go.len(), 1);
    // Inside its handler of "go", the pipeline module publishes 20 000
    // messages as fast as its socket lets it, then acknowledges "go".
    const N: i32 = 20_000;
    let (mut sent, mut next) = (0, 0);
    let mut acked = false;
    let mut stall = Stall::default();
    while next < N {
        // Its socket takes what fits; the handler blocks while it is full.
        while sent < N && sim.unread(m) < SOCKET {
            sim.m(m).publish("data", numbered(sent), -1).unwrap();
            sent += 1;
            if sent % 100 == 0 {
                sim.pump();
            }
        }
        // The handler returns once its last message is written.
        if sent == N && !acked && sim.unread(m) == 0 {
            sim.m(m).ack(go[0].0).unwrap();
            acked = true;
        }
        sim.pump();
        // The subscriber handles a few messages per turn.
        handle_in_order(&mut sim, s, &mut next, 5, &mut stall);
    }
    let st = sim.central().stats();
    assert_eq!((st.dropped, st.queued_bytes), (0, 0));
    assert!(
        st.peak_queued_bytes <= LIMIT + 1024,
        "peak {} bytes queued with a limit of {LIMIT}",
        st.peak_queued_bytes
    );
}

/// A module that publishes while it answers a query (its asker waits for
/// the reply) is held back too, when no queue can be stuck behind that
/// reply: the asker waits a little longer, and central's memory stays
/// bounded.
#[test]
fn a_module_publishing_inside_a_query_handler_is_held_back_too() {
    const LIMIT: usize = 64 << 10;
    const N: i32 = 20_000;
    let mut config = Config::default();
    config.max_queued_bytes = LIMIT;
    let mut sim = Sim::new(config);
    let a = sim.connect("asker");
    let h = sim.connect("server");
    let s = sim.connect("slow");
    define(&mut sim, a, "ask", "int");
    define(&mut sim, a, "ask_reply", "int");
    define(&mut sim, h, "data", "[int:16]");
    sim.m(h).subscribe("ask", "HND-ask").unwrap();
    sim.m(s).subscribe("data", "HND-data").unwrap();
    sim.pump();
    let q = sim.m(a).query("ask", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let ask = sim.deliveries(h);
    assert_eq!(ask.len(), 1);
    let (mut sent, mut next, mut replied, mut was_paused) = (0, 0, false, false);
    let mut stall = Stall::default();
    while next < N {
        while sent < N && sim.unread(h) < SOCKET {
            sim.m(h).publish("data", numbered(sent), -1).unwrap();
            sent += 1;
            if sent % 100 == 0 {
                sim.pump();
                was_paused |= sim.paused(h);
            }
        }
        if sent == N && !replied && sim.unread(h) == 0 {
            sim.m(h)
                .respond(ask[0].0, "ask_reply", 8i32.to_le_bytes())
                .unwrap();
            replied = true;
        }
        sim.pump();
        handle_in_order(&mut sim, s, &mut next, 5, &mut stall);
    }
    sim.pump();
    assert!(was_paused, "the answering module was never held back");
    assert!(sim
        .take_events(a)
        .iter()
        .any(|e| matches!(e, Event::Reply { query, .. } if *query == q)));
    let st = sim.central().stats();
    assert_eq!((st.dropped, st.queued_bytes, st.dispatches), (0, 0, 0));
    assert!(
        st.peak_queued_bytes <= LIMIT + 1024,
        "peak {} bytes queued with a limit of {LIMIT}",
        st.peak_queued_bytes
    );
}

/// The other side of that rule: when a message is queued for a module that
/// waits for an answer (here inside its handler, which holds its only
/// capacity slot), a module held back while it answers is read again, or
/// that queue would wait for a reply central does not read.
#[test]
fn a_held_back_answer_is_read_when_its_askers_queue_grows() {
    const LIMIT: usize = 16 << 10;
    let mut config = Config::default();
    config.max_queued_bytes = LIMIT;
    let mut sim = Sim::new(config);
    let up = sim.connect("upstream");
    let x = sim.connect("asker");
    let h = sim.connect("server");
    let s = sim.connect("slow");
    define(&mut sim, up, "go", "int");
    define(&mut sim, x, "ask", "int");
    define(&mut sim, x, "ask_reply", "int");
    define(&mut sim, h, "data", "[int:16]");
    sim.m(x).subscribe("go", "HND-go").unwrap();
    sim.m(h).subscribe("ask", "HND-ask").unwrap();
    sim.m(s).subscribe("data", "HND-data").unwrap();
    sim.pump();
    // The asker's handler of "go" queries the server and waits.
    sim.m(up)
        .publish("go", 1i32.to_le_bytes().to_vec(), -1)
        .unwrap();
    sim.pump();
    let go = sim.deliveries(x);
    let q = sim.m(x).query("ask", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let ask = sim.deliveries(h);
    assert_eq!((go.len(), ask.len()), (1, 1));
    // Answering, the server floods the slow module past the limit and is
    // held back (the asker has nothing queued yet).
    for i in 0..200i32 {
        sim.m(h).publish("data", numbered(i), -1).unwrap();
        sim.pump();
    }
    assert!(sim.paused(h), "the answering module was not held back");
    // Now something is queued for the asker, whose handler waits for the
    // server's reply: the server is read again.
    sim.m(up)
        .publish("go", 2i32.to_le_bytes().to_vec(), -1)
        .unwrap();
    sim.pump();
    assert!(
        !sim.paused(h),
        "the reply the asker's queue waits for is not read"
    );
    sim.m(h)
        .respond(ask[0].0, "ask_reply", 8i32.to_le_bytes())
        .unwrap();
    sim.pump();
    assert!(sim
        .take_events(x)
        .iter()
        .any(|e| matches!(e, Event::Reply { query, .. } if *query == q)));
    sim.m(x).ack(go[0].0).unwrap();
    sim.pump();
    let go2 = sim.deliveries(x);
    assert_eq!(go2.len(), 1);
    sim.m(x).ack(go2[0].0).unwrap();
    let mut got = 0;
    while got < 200 {
        sim.pump();
        let d = sim.deliveries(s);
        assert!(!d.is_empty(), "stuck after {got}");
        for (id, ..) in d {
            got += 1;
            sim.m(s).ack(id).unwrap();
        }
    }
    sim.pump();
    let st = sim.central().stats();
    assert_eq!((st.queued_bytes, st.dispatches), (0, 0));
}

/// A subscriber that stops reading keeps central's queues over the limit;
/// a module that connects meanwhile, subscribes and publishes elsewhere is
/// read all the same, since what it sends adds nothing to the queues
/// (audit 20: central stopped reading it after its first frame, and its
/// handshake timed out after 10 s for as long as the queues stayed full).
/// The publisher whose messages fill the queue is the one held back.
#[test]
fn a_stuck_subscriber_holds_back_its_publisher_not_modules_that_connect() {
    let mut config = Config::default();
    config.max_queued_bytes = 16 << 10;
    let (mut sim, p, stuck) = pub_sub(config, ("flood", "stuck"), "data", "[int:16]");
    // `stuck` takes nothing from now on
    let mut sent = 0;
    while !sim.paused(p) {
        assert!(sent < 10_000, "the publisher was never held back");
        sim.m(p).publish("data", numbered(sent), -1).unwrap();
        sent += 1;
        sim.pump();
    }
    assert!(sim.central().stats().queued_bytes > 16 << 10);
    // a newcomer connects (the handshake is several frames), defines,
    // subscribes and is served
    let late = sim.connect("late");
    define(&mut sim, late, "other", "int");
    sim.m(late).subscribe("other", "HND-other").unwrap();
    sim.pump();
    sim.m(late)
        .publish("other", 7i32.to_le_bytes().to_vec(), -1)
        .unwrap();
    sim.pump();

    let got = sim.deliveries(late);
    assert_eq!(got.len(), 1, "the newcomer's own message came back to it");
    assert!(!sim.paused(late));
    // (the newcomer's subscription sent central's notice to every module,
    // the publisher too, whose acknowledgement must be read: it was read
    // again) and the publisher is held back again at its next message
    sim.m(p).publish("data", numbered(sent), -1).unwrap();
    sim.pump();
    let q = sim.central().stats().queued_bytes;
    assert!(
        sim.paused(p),
        "the flood's publisher is held back ({q} bytes queued)"
    );
    let _ = stuck;
}
