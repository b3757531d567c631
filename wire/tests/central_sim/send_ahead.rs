//! Send-ahead (`Config::send_ahead`): messages written to a module before
//! it finished the one it handles, without changing what it receives,
//! what central logs, or what counts as pending.

use std::collections::VecDeque;

use courier_wire::ipc::central::{Config, DispatchState, DISPATCH_COST};
use courier_wire::ipc::frame::Header;
use courier_wire::ipc::module::DeliveryKind;

use crate::routing::priorities_and_queue_limits;
use crate::support::{define, pub_sub, Mod, Sim};

/// Send-ahead of `n` to the module named `sub`.
fn ahead_config(n: usize) -> Config {
    let mut c = Config::default();
    c.send_ahead = [("sub".to_string(), n)].into();
    c
}

fn value(data: &[u8]) -> i32 {
    i32::from_le_bytes(data[data.len() - 4..].try_into().unwrap())
}

/// The frames central wrote to `id`: (deliveries, everything else), each
/// in order, after the 4-byte greeting.
fn frames(sim: &Sim, id: Mod) -> (Vec<Vec<u8>>, Vec<Vec<u8>>) {
    use courier_wire::ipc::frame::HEADER_SIZE;
    let wire = sim.wire(id);
    let mut bytes = &wire[4..];
    let (mut deliveries, mut rest) = (Vec::new(), Vec::new());
    while !bytes.is_empty() {
        let h = Header::decode(bytes).unwrap();
        let len = HEADER_SIZE + (h.class_total + h.msg_total) as usize;
        let f = bytes[..len].to_vec();
        if h.intent > 0 {
            deliveries.push(f);
        } else {
            rest.push(f);
        }
        bytes = &bytes[len..];
    }
    (deliveries, rest)
}

/// A publisher sends `n` broadcasts to a capacity-1 subscriber that handles
/// them one at a time (acknowledging the oldest it holds, as a C module's
/// handler returns). Returns what the subscriber handled, in order, the
/// most deliveries it ever held unacknowledged, and the simulation.
fn one_at_a_time(config: Config, n: i32) -> (Vec<i32>, usize, Sim) {
    let (mut sim, _, b) = ticks(config, n);
    let (handled, most) = handle_in_order(&mut sim, b);
    (handled, most, sim)
}

/// `pub` publishes the ints `0..n` on `tick`, which `sub` (capacity 1)
/// subscribed to. Returns the simulation and the two modules.
fn ticks(config: Config, n: i32) -> (Sim, Mod, Mod) {
    let (mut sim, a, b) = pub_sub(config, ("pub", "sub"), "tick", "int");
    for i in 0..n {
        sim.m(a).publish("tick", i.to_le_bytes(), -1).unwrap();
    }
    sim.pump();
    (sim, a, b)
}

/// `id` handles what it receives one at a time, oldest first, acknowledging
/// each (as a C module's handler returns), until nothing more comes.
/// Returns the values handled and the most deliveries it ever held.
fn handle_in_order(sim: &mut Sim, id: Mod) -> (Vec<i32>, usize) {
    let mut held: VecDeque<(u64, i32)> = VecDeque::new();
    let mut handled = Vec::new();
    let mut most = 0;
    loop {
        held.extend(sim.deliveries(id).into_iter().map(|d| (d.0, value(&d.3))));
        most = most.max(held.len());
        let Some((delivery, v)) = held.pop_front() else {
            break;
        };
        handled.push(v);
        sim.m(id).ack(delivery).unwrap();
        sim.pump();
    }
    (handled, most)
}

#[test]
fn send_ahead_changes_when_a_module_receives_not_what_it_receives_or_what_central_logs() {
    let (plain, plain_most, mut plain_sim) = one_at_a_time(Config::default(), 20);
    let (ahead, ahead_most, mut ahead_sim) = one_at_a_time(ahead_config(2), 20);
    assert_eq!(plain, (0..20).collect::<Vec<_>>());
    assert_eq!(ahead, plain);
    assert_eq!(plain_most, 1, "without send-ahead, one message at a time");
    assert_eq!(
        ahead_most, 3,
        "with send-ahead 2, the one being handled and the next two"
    );
    // Byte for byte the same frames to the subscriber, in the same order
    // among deliveries and among the rest (only how the two interleave
    // differs), and the same log, line for line. Nothing goes ahead of a
    // handler's first delivery and its lookup, so no frame carries class
    // data it would not carry in C.
    let (a, p) = (frames(&ahead_sim, 2), frames(&plain_sim, 2));
    assert_eq!(a.0.len(), 21, "20 ticks and the broadcast-list watch");
    assert_eq!(a, p);
    for (i, (x, y)) in ahead_sim.logs.iter().zip(&plain_sim.logs).enumerate() {
        assert_eq!(x, y, "log line {i}");
    }
    assert_eq!(ahead_sim.logs.len(), plain_sim.logs.len());
    assert!(
        ahead_sim
            .logs
            .iter()
            .any(|l| l.contains("Resource sub") && l.contains("(Sent)")),
        "{:#?}",
        ahead_sim.logs
    );
    for sim in [&mut plain_sim, &mut ahead_sim] {
        assert_eq!(sim.central().stats().dispatches, 0);
        assert_eq!(sim.central().stats().queued_bytes, 0);
    }
}

#[test]
fn only_the_modules_named_get_messages_ahead() {
    let mut sim = Sim::new(ahead_config(2));
    let a = sim.connect("pub");
    let b = sim.connect("sub");
    let c = sim.connect("other");
    define(&mut sim, a, "tick", "int");
    for m in [b, c] {
        sim.m(m).subscribe("tick", "HND-tick").unwrap();
    }
    sim.pump();
    for i in 0..5i32 {
        sim.m(a).publish("tick", i.to_le_bytes(), -1).unwrap();
    }
    sim.pump();
    assert_eq!(sim.deliveries(b).len(), 3, "sub: one handled, two ahead");
    assert_eq!(sim.deliveries(c).len(), 1, "other: one at a time, as in C");
}

/// A C module handles queued messages while it waits for the reply to its
/// first lookup of a handler; a delivery without the message name then
/// fails its sanity check and is lost. So nothing goes ahead until the
/// module has looked the handler up.
#[test]
fn nothing_goes_ahead_of_a_handlers_first_lookup() {
    let (mut sim, a, b) = pub_sub(ahead_config(4), ("pub", "sub"), "tick", "int");
    let to_sub = |sim: &Sim| -> Vec<Header> {
        sim.sent()
            .iter()
            .filter(|(to, h)| *to == b && h.intent > 0 && h.class_id.class() == 15)
            .map(|x| x.1)
            .collect()
    };
    let before = to_sub(&sim).len();
    // Central does not hear from the subscriber (its lookup is delayed).
    sim.hold(b, true);
    for i in 0..3i32 {
        sim.m(a).publish("tick", i.to_le_bytes(), -1).unwrap();
    }
    sim.pump();
    let sent = to_sub(&sim);
    assert_eq!(sent.len() - before, 1, "only the first delivery: {sent:?}");
    assert!(sent.last().unwrap().class_total > 0, "it carries the name");
    // The lookup arrives: the other two go ahead, without the name.
    sim.hold(b, false);
    sim.pump();
    let sent = to_sub(&sim);
    assert_eq!(sent.len() - before, 3);
    assert!(sent[before + 1..].iter().all(|h| h.class_total == 0));
}

#[test]
fn messages_sent_ahead_still_count_as_pending() {
    let (mut sim, _, b) = ticks(ahead_config(2), 5);
    assert_eq!(sim.deliveries(b).len(), 3, "one handled, two ahead");
    // (the console's `status`/`display` text over this data is the
    // shell's: courier::central's console tests)
    let conn = sim.conn(b);
    let sub = sim.central().modules();
    let sub = sub.iter().find(|m| m.conn == conn).unwrap();
    assert_eq!(sub.name.as_deref(), Some("sub"));
    assert_eq!((sub.capacity, sub.active, sub.pending), (1, 1, 4));
    let states: Vec<DispatchState> = sim.central().dispatches().iter().map(|d| d.state).collect();
    let count = |s: DispatchState| states.iter().filter(|x| **x == s).count();
    assert_eq!(count(DispatchState::SentAhead), 2, "{states:?}");
    assert_eq!(count(DispatchState::Active), 1, "{states:?}");
    // Two are written; the other two are held in central and only they
    // count as queued bytes (each message is 12 bytes of data here, and
    // its bookkeeping).
    assert_eq!(sim.central().stats().queued_bytes, 2 * (12 + DISPATCH_COST));
}

#[test]
fn nothing_is_sent_ahead_where_priorities_or_queue_limits_decide() {
    // C's order and drops, one message at a time.
    priorities_and_queue_limits(ahead_config(8));
}

#[test]
fn a_query_is_not_sent_ahead_nor_anything_behind_it() {
    let mut sim = Sim::new(ahead_config(4));
    let a = sim.connect("pub");
    let b = sim.connect("sub");
    define(&mut sim, a, "tick", "int");
    define(&mut sim, a, "ask", "int");
    define(&mut sim, a, "answer", "int");
    sim.m(b).subscribe("tick", "HND-tick").unwrap();
    sim.m(b).subscribe("ask", "HND-ask").unwrap();
    sim.pump();
    sim.m(a).publish("tick", 1i32.to_le_bytes(), -1).unwrap();
    sim.m(a).query("ask", 2i32.to_le_bytes(), -1).unwrap();
    sim.m(a).publish("tick", 3i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let d = sim.deliveries(b);
    assert_eq!(d.len(), 1, "the query heads the queue: {d:?}");
    sim.m(b).ack(d[0].0).unwrap();
    sim.pump();
    // The query takes the slot; the broadcast behind it may now go ahead.
    let d = sim.deliveries(b);
    assert_eq!(
        d.iter().map(|x| (x.2, value(&x.3))).collect::<Vec<_>>(),
        vec![(DeliveryKind::Query, 2), (DeliveryKind::Broadcast, 3)]
    );
    sim.m(b)
        .respond(d[0].0, "answer", 4i32.to_le_bytes())
        .unwrap();
    sim.m(b).ack(d[1].0).unwrap();
    sim.pump();
    assert_eq!(sim.central().stats().dispatches, 0);
}

#[test]
fn a_message_sent_ahead_may_be_finished_first() {
    let (mut sim, _, b) = ticks(ahead_config(1), 3);
    let d = sim.deliveries(b);
    assert_eq!(d.iter().map(|x| value(&x.3)).collect::<Vec<_>>(), [0, 1]);
    // A module handling concurrently acknowledges the later one first.
    sim.m(b).ack(d[1].0).unwrap();
    sim.pump();
    assert!(
        !sim.logs.iter().any(|l| l.contains("WARNING")),
        "{:#?}",
        sim.logs
    );
    // It was logged as sent before it was done; the first one still holds
    // the slot and the last one goes ahead.
    let sent = sim.logs.iter().filter(|l| l.contains("(Sent)")).count();
    assert_eq!(sent, 2, "{:#?}", sim.logs);
    assert!(sim.logs.last().unwrap().contains("Done"), "{:#?}", sim.logs);
    let d2 = sim.deliveries(b);
    assert_eq!(d2.iter().map(|x| value(&x.3)).collect::<Vec<_>>(), [2]);
    sim.m(b).ack(d[0].0).unwrap();
    sim.m(b).ack(d2[0].0).unwrap();
    sim.pump();
    assert_eq!(sim.central().stats().dispatches, 0);
    assert!(
        !sim.logs.iter().any(|l| l.contains("WARNING")),
        "{:#?}",
        sim.logs
    );
}

#[test]
fn messages_sent_ahead_are_resent_after_a_crash_or_cleared() {
    for resend in [true, false] {
        let mut config = ahead_config(2);
        config.resend_on_reconnect = resend;
        let (mut sim, _, b) = ticks(config, 4);
        assert_eq!(sim.deliveries(b).len(), 3);
        // The subscriber crashes holding one message and two sent ahead.
        sim.close(b);
        if !resend {
            assert_eq!(sim.central().stats().dispatches, 0);
            assert_eq!(sim.central().stats().queued_bytes, 0);
            continue;
        }
        let b2 = sim.connect("sub");
        sim.m(b2).subscribe("tick", "HND-tick").unwrap();
        sim.pump();
        assert_eq!(handle_in_order(&mut sim, b2).0, vec![0, 1, 2, 3]);
        assert_eq!(sim.central().stats().dispatches, 0);
    }
}

/// A module that unsubscribes while messages for that handler are ahead
/// gets them anyway, drops them and acknowledges them: nothing is left
/// behind in central.
#[test]
fn messages_ahead_of_an_unsubscribe_are_dropped_by_the_module() {
    let (mut sim, _, b) = ticks(ahead_config(2), 4);
    let d = sim.deliveries(b);
    assert_eq!(d.len(), 3, "one handled, two ahead");
    // The handler unsubscribes, then returns.
    sim.m(b).unsubscribe("tick", "HND-tick").unwrap();
    sim.pump();
    for (id, ..) in &d {
        sim.m(b).ack(*id).unwrap();
    }
    sim.pump();
    assert!(sim.deliveries(b).is_empty());
    assert_eq!(sim.central().stats().dispatches, 0);
    assert_eq!(sim.central().stats().queued_bytes, 0);
    assert!(
        sim.logs
            .iter()
            .any(|l| l.starts_with("Deleted pending tick (1 message): its handler ")),
        "the one still queued in central is deleted, as in C: {:#?}",
        sim.logs
    );
}

/// A send-ahead configured past `MAX_SEND_AHEAD` is taken as that: a
/// module gives up a central that sends more than its capacity and that
/// many before its acknowledgements (`ipc::module::MAX_SENT_AHEAD`).
#[test]
fn send_ahead_is_at_most_its_maximum() {
    use courier_wire::ipc::central::MAX_SEND_AHEAD;
    let n = MAX_SEND_AHEAD as i32 + 10;
    let (mut sim, _, b) = ticks(ahead_config(MAX_SEND_AHEAD + 500), n);
    assert_eq!(
        sim.deliveries(b).len(),
        1 + MAX_SEND_AHEAD,
        "one handled, the most ahead"
    );
    assert!(sim.m(b).is_connected());
}
