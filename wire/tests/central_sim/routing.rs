//! Routing through central: publish/subscribe and query/response,
//! capacity, priorities and queue limits, notifications, direct mode's
//! bookkeeping, `-r`, and handlers subscribed again.

use std::time::Duration;

use courier_wire::ipc::central::{Config, DISPATCH_COST};
use courier_wire::ipc::frame::{ClassId, Header, MsgClass};
use courier_wire::ipc::module::{DeliveryKind, Event};
use courier_wire::sim::{IpcNode, Net};

use crate::support::{cut, define, pub_sub, Mod, Sim};

#[test]
fn publish_subscribe_and_query_through_central() {
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("pub");
    let b = sim.connect("sub");
    define(&mut sim, a, "msg", "int");
    define(&mut sim, a, "ask", "int");
    define(&mut sim, a, "answer", "int");
    sim.m(b).subscribe("msg", "HND-msg1").unwrap();
    sim.m(b).subscribe("ask", "HND-ask1").unwrap();
    sim.pump();
    sim.m(a).publish("msg", 7i32.to_le_bytes(), -1).unwrap();
    let q = sim.m(a).query("ask", 20i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let d = sim.deliveries(b);
    assert_eq!(d.len(), 1, "capacity 1: the query waits for the ack: {d:?}");
    assert_eq!(
        (d[0].1.as_str(), d[0].3.clone()),
        ("msg", 7i32.to_le_bytes().to_vec())
    );
    sim.m(b).ack(d[0].0).unwrap();
    sim.pump();
    let d = sim.deliveries(b);
    assert_eq!(d.len(), 1);
    assert_eq!(d[0].2, DeliveryKind::Query);
    sim.m(b)
        .respond(d[0].0, "answer", 40i32.to_le_bytes())
        .unwrap();
    sim.pump();
    let ev = sim.take_events(a);
    assert!(
        // (The module unwraps the body only once it has looked up the reply
        // message; either way the value is the last 4 bytes.)
        ev.iter()
            .any(|e| matches!(e, Event::Reply { query, reply_msg, data, .. }
            if *query == q && reply_msg == "answer" && data.ends_with(&40i32.to_le_bytes()))),
        "{ev:?}"
    );
    assert_eq!(
        sim.central().stats().dispatches,
        0,
        "every dispatch completed"
    );
}

#[test]
fn capacity_priority_and_queue_limits() {
    let sim = priorities_and_queue_limits(Config::default());
    assert!(
        sim.logs.iter().any(|l| l.contains("PENDING LIMIT")),
        "{:#?}",
        sim.logs
    );
}

/// A capacity-1 subscriber with a priority on one message and a queue
/// limit of 2 on another: the high-priority one overtakes, the limit drops
/// the three oldest, and the subscriber never holds more than one.
pub fn priorities_and_queue_limits(config: Config) -> Sim {
    let mut sim = Sim::new(config);
    let a = sim.connect("pub");
    let b = sim.connect("sub");
    define(&mut sim, a, "low", "int");
    define(&mut sim, a, "high", "int");
    define(&mut sim, a, "limited", "int");
    for m in ["low", "high", "limited"] {
        sim.m(b).subscribe(m, &format!("HND-{m}")).unwrap();
    }
    sim.m(b).set_priority("high", 10).unwrap();
    sim.m(b).set_queue_length("limited", 2).unwrap();
    sim.pump();
    // First one occupies the only slot; the rest queue in central.
    for i in 0..3i32 {
        sim.m(a).publish("low", i.to_le_bytes(), -1).unwrap();
    }
    for i in 0..5i32 {
        sim.m(a)
            .publish("limited", (100 + i).to_le_bytes(), -1)
            .unwrap();
    }
    sim.m(a).publish("high", 999i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let mut got = Vec::new();
    loop {
        let d = sim.deliveries(b);
        if d.is_empty() {
            break;
        }
        assert_eq!(d.len(), 1, "never more than capacity outstanding");
        got.push((
            d[0].1.clone(),
            i32::from_le_bytes(d[0].3[..4].try_into().unwrap()),
        ));
        sim.m(b).ack(d[0].0).unwrap();
        sim.pump();
    }
    let expect: Vec<(String, i32)> = [
        ("low", 0),
        ("high", 999),
        ("low", 1),
        ("low", 2),
        ("limited", 103),
        ("limited", 104),
    ]
    .iter()
    .map(|(m, v)| (m.to_string(), *v))
    .collect();
    assert_eq!(got, expect);
    assert_eq!(
        sim.central().stats().dropped,
        3,
        "limit 2 dropped the three oldest"
    );
    sim
}

#[test]
fn larger_capacity_allows_concurrent_deliveries() {
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("pub");
    let b = sim.connect("sub");
    define(&mut sim, a, "m", "int");
    sim.m(b).subscribe("m", "HND-m").unwrap();
    sim.m(b).set_capacity(3).unwrap();
    sim.pump();
    for i in 0..5i32 {
        sim.m(a).publish("m", i.to_le_bytes(), -1).unwrap();
    }
    sim.pump();
    assert_eq!(sim.deliveries(b).len(), 3);
}

#[test]
fn query_before_any_handler_waits_for_one() {
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("asker");
    define(&mut sim, a, "late", "int");
    define(&mut sim, a, "late_reply", "int");
    let q = sim.m(a).query("late", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let b = sim.connect("server");
    sim.m(b).subscribe("late", "HND-late").unwrap();
    sim.pump();
    let d = sim.deliveries(b);
    assert_eq!(d.len(), 1, "the waiting query reaches the new handler");
    sim.m(b)
        .respond(d[0].0, "late_reply", 2i32.to_le_bytes())
        .unwrap();
    sim.pump();
    assert!(sim
        .take_events(a)
        .iter()
        .any(|e| matches!(e, Event::Reply { query, .. } if *query == q)));
}

#[test]
fn connect_disconnect_and_handler_change_notifications() {
    let mut sim = Sim::new(Config::default());
    let w = sim.connect("watcher");
    define(&mut sim, w, "topic", "int");
    sim.m(w).subscribe_connect().unwrap();
    sim.m(w).subscribe_disconnect().unwrap();
    sim.m(w).subscribe_handler_change("topic").unwrap();
    sim.pump();
    sim.take_events(w);
    let x = sim.connect("other");
    sim.m(x).subscribe("topic", "HND-topic").unwrap();
    sim.pump();
    let ev = sim.take_events(w);
    assert!(ev.contains(&Event::ModuleConnect("other".into())), "{ev:?}");
    assert!(
        ev.iter()
            .any(|e| matches!(e, Event::HandlerChange { msg, count: 1 } if msg == "topic")),
        "{ev:?}"
    );
    let op = sim.m(w).is_module_connected("other").unwrap();
    let n = sim.m(w).num_handlers("topic").unwrap();
    sim.pump();
    let ev = sim.take_events(w);
    assert!(
        ev.contains(&Event::ModuleConnected {
            op,
            connected: true
        }),
        "{ev:?}"
    );
    assert!(
        ev.contains(&Event::NumHandlers { op: n, count: 1 }),
        "{ev:?}"
    );
    sim.close(x);
    let ev = sim.take_events(w);
    assert!(
        ev.contains(&Event::ModuleDisconnect("other".into())),
        "{ev:?}"
    );
    assert!(
        ev.iter()
            .any(|e| matches!(e, Event::HandlerChange { msg, count: 0 } if msg == "topic")),
        "{ev:?}"
    );
    let op = sim.m(w).is_module_connected("other").unwrap();
    sim.pump();
    assert!(sim.take_events(w).contains(&Event::ModuleConnected {
        op,
        connected: false
    }));
}

#[test]
fn direct_mode_negates_ids_and_lists_listeners() {
    let mut config = Config::default();
    config.direct = true;
    let mut sim = Sim::new(config);
    // The module's shell opens its listener on 8123 when asked and
    // announces it (`announce_direct_port`).
    let a = sim.add_at("a", 8123);
    sim.pump();
    let ev = sim.take_events(a);
    assert!(ev.iter().any(|e| matches!(e, Event::DirectListenRequested)));
    assert!(ev.iter().any(|e| matches!(e, Event::Connected)));
    define(&mut sim, a, "d", "int");
    sim.m(a).subscribe("d", "HND-d").unwrap();
    sim.pump();
    assert!(sim.m(a).msg_info("d").is_none_or(|i| i.id < 0));
    let op = sim.m(a).num_handlers("d").unwrap();
    sim.pump();
    assert!(sim
        .take_events(a)
        .contains(&Event::NumHandlers { op, count: 1 }));
    assert!(sim
        .logs
        .iter()
        .any(|l| l == "Direct Connection Established For: a at 8123"));
}

#[test]
fn resend_on_reconnect_redelivers_unfinished_messages() {
    let mut config = Config::default();
    config.resend_on_reconnect = true;
    let (mut sim, a, b) = pub_sub(config, ("pub", "worker"), "job", "int");
    sim.m(a).publish("job", 1i32.to_le_bytes(), -1).unwrap();
    sim.m(a).publish("job", 2i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    assert_eq!(sim.deliveries(b).len(), 1);
    // The worker crashes without acknowledging, then comes back.
    sim.close(b);
    let b2 = sim.connect("worker");
    sim.m(b2).subscribe("job", "HND-job").unwrap();
    sim.pump();
    let mut vals = Vec::new();
    loop {
        let d = sim.deliveries(b2);
        if d.is_empty() {
            break;
        }
        for (id, _, _, data) in d {
            vals.push(i32::from_le_bytes(data[..4].try_into().unwrap()));
            sim.m(b2).ack(id).unwrap();
        }
        sim.pump();
    }
    assert_eq!(vals, vec![1, 2]);
    assert!(sim.logs.iter().any(|l| l.starts_with("Resending job")));
}

/// Workers named after their process id die one after another with work
/// unfinished; none comes back under its name. What `-r` keeps for them
/// stays within `max_queued_bytes`, the oldest dropped first, and a worker
/// that does come back gets what is still kept for it.
#[test]
fn resend_keeps_within_max_queued_bytes_when_names_never_return() {
    const BODY: usize = 1000;
    const WORKERS: usize = 40;
    let mut config = Config::default();
    config.resend_on_reconnect = true;
    // room for about ten kept messages
    config.max_queued_bytes = 10 * (BODY + DISPATCH_COST);
    let (mut sim, a, first) = pub_sub(config, ("pub", "worker-0"), "job", "string");
    let mut worker = first;
    for i in 0..WORKERS {
        sim.m(a).publish("job", vec![b'x'; BODY], -1).unwrap();
        sim.pump();
        assert_eq!(sim.deliveries(worker).len(), 1, "worker-{i} got its job");
        sim.close(worker);
        worker = sim.connect(&format!("worker-{}", i + 1));
        // subscribing under a new name resends nothing
        sim.m(worker).subscribe("job", "HND-job").unwrap();
        sim.pump();
    }
    let st = sim.central().stats();
    assert!(
        st.kept_bytes <= 10 * (BODY + DISPATCH_COST) && st.kept_for_resend >= 9,
        "{st:?}"
    );
    assert_eq!(
        st.dropped_kept as usize,
        WORKERS - st.kept_for_resend,
        "{st:?}"
    );
    let warned: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.contains("kept to resend to worker-"))
        .collect();
    assert_eq!(warned.len(), WORKERS - st.kept_for_resend, "{warned:#?}");
    assert!(
        warned[0].contains("WARNING: 1 message(s) kept to resend to worker-0 dropped"),
        "{}",
        warned[0]
    );
    // The last worker to die comes back: its job is resent; the first
    // one's was dropped.
    let back = sim.connect(&format!("worker-{}", WORKERS - 1));
    sim.m(back).subscribe("job", "HND-job").unwrap();
    sim.pump();
    assert_eq!(sim.deliveries(back).len(), 1);
    let old = sim.connect("worker-0");
    sim.m(old).subscribe("job", "HND-job").unwrap();
    sim.pump();
    assert!(sim.deliveries(old).is_empty());
    assert_eq!(
        sim.central().stats().kept_for_resend,
        st.kept_for_resend - 1
    );
}

#[test]
fn without_resend_unfinished_messages_are_cleared() {
    let (mut sim, a, b) = pub_sub(Config::default(), ("pub", "worker"), "job", "int");
    sim.m(a).publish("job", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    sim.close(b);
    assert_eq!(sim.central().stats().dispatches, 0);
}

#[test]
fn two_hundred_modules_connect_at_once() {
    let mut sim = Sim::new(Config::default());
    let ids: Vec<Mod> = (0..200).map(|i| sim.add(&format!("m{i}"))).collect();
    sim.pump();
    for &id in &ids {
        assert!(sim
            .take_events(id)
            .iter()
            .any(|e| matches!(e, Event::Connected)));
    }
    assert_eq!(sim.central().module_names().len(), 200);
    define(&mut sim, ids[0], "all", "int");
    for &id in &ids {
        sim.m(id).subscribe("all", "HND-all").unwrap();
    }
    sim.pump();
    // Settle the broadcast-list updates every subscription caused.
    sim.m(ids[0])
        .publish("all", 5i32.to_le_bytes(), -1)
        .unwrap();
    sim.pump();
    let mut n = 0;
    for &id in &ids {
        n += sim.deliveries(id).iter().filter(|d| d.1 == "all").count();
    }
    assert_eq!(n, 200);
}

pub fn raw_frame(class: MsgClass, intent: i32, body: &[u8]) -> Vec<u8> {
    let h = Header {
        class_total: 0,
        msg_total: body.len() as i32,
        parent_ref: -1,
        intent,
        class_id: ClassId::native(class),
        dispatch_ref: -1,
        msg_ref: 1,
    };
    let mut v = h.encode().to_vec();
    v.extend_from_slice(body);
    v
}

/// A C module subscribing the same handler again (new client data) sends
/// `registerHandler` with id 0: central keeps the first id and names the
/// message again on the next delivery (ipcTest1 crashed when it did not).
#[test]
fn resubscribing_a_handler_keeps_its_id_and_renames_the_message() {
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("a");
    define(&mut sim, a, "m", "int");
    let hid = sim.m(a).subscribe("m", "HND-m").unwrap();
    sim.pump();
    sim.m(a).publish("m", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let d = sim.deliveries(a);
    sim.m(a).ack(d[0].0).unwrap();
    sim.pump();
    // The raw re-registration, as the C library sends it.
    register_again(&mut sim, a, "m", "HND-m");
    let written = sim.net.stream_tap.len();
    sim.m(a).publish("m", 2i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    // Look at the delivery frame central writes.
    let central = sim.stream(a).peer();
    let delivery = sim.net.stream_tap[written..]
        .iter()
        .filter(|(w, _)| *w == central)
        .filter_map(|(_, bytes)| Some((Header::decode(bytes).ok()?, bytes)))
        .find(|(h, _)| h.class_id.class() == 15 && h.intent > 0);
    let (h, bytes) = delivery.expect("a delivery");
    assert_eq!(h.intent, hid, "the first handler id is kept");
    assert_eq!(h.class_total, 5, "class data names the message again");
    assert_eq!(&bytes[28..33], b"\x01\x00\x00\x00m");
}

/// `x_ipc_registerHandlerMsg {0, msg, hnd}`, raw, as the C library sends
/// it when it subscribes a handler it subscribed before.
pub fn register_again(sim: &mut Sim, id: Mod, msg: &str, hnd: &str) {
    register_raw(sim, id, 0, msg, hnd)
}

pub fn register_raw(sim: &mut Sim, id: Mod, hid: i32, msg: &str, hnd: &str) {
    handler_raw(sim, id, "x_ipc_registerHandlerMsg", hid, msg, hnd)
}

/// An internal handler message, raw, in module `id`'s stream to central.
fn handler_raw(sim: &mut Sim, id: Mod, internal: &str, hid: i32, msg: &str, hnd: &str) {
    let intent = sim.central().message_id(internal).unwrap();
    let mut body = hid.to_le_bytes().to_vec();
    for s in [msg, hnd] {
        body.extend_from_slice(&(s.len() as i32).to_le_bytes());
        body.extend_from_slice(s.as_bytes());
    }
    let f = raw_frame(MsgClass::Inform, intent, &body);
    sim.inject(id, &f);
    sim.pump();
}

/// Subscribe, unsubscribe, subscribe again: the C library sends id 0 the
/// second time and dispatches on the id of the first registration, as the
/// C central (which keeps the handler's record) delivers. Delivering with
/// intent 0 made the C module crash (SIGSEGV in its dispatch), found by
/// running the C library's own programs against this central.
#[test]
fn a_handler_subscribed_again_after_an_unsubscribe_keeps_its_first_id() {
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("a");
    let b = sim.connect("b");
    define(&mut sim, a, "m", "int");
    let hid = sim.m(a).subscribe("m", "HND-m").unwrap();
    sim.pump();
    sim.m(a).unsubscribe("m", "HND-m").unwrap();
    sim.pump();
    register_again(&mut sim, a, "m", "HND-m");
    sim.pump();
    // Courier's module state machine, subscribing the same handler again,
    // uses the first id too (and so works with either central).
    assert_eq!(sim.m(a).subscribe("m", "HND-m").unwrap(), hid);
    sim.pump();
    let before = sim.sent().len();
    sim.m(b).publish("m", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let intents: Vec<i32> = sim.sent()[before..]
        .iter()
        .filter(|(to, h)| *to == a && h.class_id.class() == 15 && h.intent >= 0)
        .map(|(_, h)| h.intent)
        .collect();
    assert_eq!(intents, vec![hid], "one delivery, to the first id");
    assert_eq!(sim.deliveries(a).len(), 1, "the module dispatched it");
}

/// A module unsubscribing a handler under another message's name (C's
/// library never does; a hostile or broken module may) leaves the
/// handler where it is: central finds no such handler of that message,
/// as the C central does, and its tables keep agreeing.
#[test]
fn unsubscribing_a_handler_under_another_message_changes_nothing() {
    // `a` handles m (as HND-m).
    let (mut sim, b, a) = pub_sub(Config::default(), ("b", "a"), "m", "int");
    define(&mut sim, b, "other", "int");
    handler_raw(
        &mut sim,
        a,
        "x_ipc_deregisterHandlerMsg",
        0,
        "other",
        "HND-m",
    );
    sim.pump();
    let warning = "unsubscribed handler HND-m from other, but it handles m";
    let warned = sim.logs.iter().any(|l| l.contains(warning));
    assert!(warned, "{:#?}", sim.logs);
    sim.m(b).publish("m", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    assert_eq!(sim.deliveries(a).len(), 1, "still subscribed");
}

/// Direct mode: the handler lists central broadcasts (`V_watch_<msg>`)
/// carry the first id after an unsubscribe and subscribe, and a handler
/// subscribed again while still subscribed has the list announced again,
/// as the C central does (`registerHandlerHnd` → `updateDirectHandlers`).
#[test]
fn direct_handler_lists_keep_the_first_id_and_are_announced_again() {
    let mut config = Config::default();
    config.direct = true;
    config.terminal_log = courier_wire::ipc::central::LogOptions::parse("md", false).unwrap();
    let mut sim = Sim::new(config);
    let a = sim.add_at("a", 8123);
    sim.pump();
    define(&mut sim, a, "d", "int");
    let hid = sim.m(a).subscribe("d", "HND-d").unwrap();
    sim.pump();
    // Follow the handler list, as a C module does before its first
    // direct send of d.
    register_raw(&mut sim, a, 500, "V_watch_d", "V_watch_d");
    sim.pump();
    // The data line logged after each broadcast of the list.
    let lists = |sim: &mut Sim| -> Vec<String> {
        let logs = std::mem::take(&mut sim.logs);
        logs.iter()
            .zip(logs.iter().skip(1))
            .filter(|(l, _)| l.starts_with("Broadcast") && l.contains(" V_watch_d: "))
            .map(|(_, data)| data.clone())
            .collect()
    };
    lists(&mut sim);
    let first = format!("{{{hid}, 0, 0, 8123, ");

    register_again(&mut sim, a, "d", "HND-d");
    sim.pump();
    let again = lists(&mut sim);
    assert_eq!(again.len(), 1, "announced again: {again:#?}");
    assert!(again[0].contains(&first), "{}", again[0]);

    sim.m(a).unsubscribe("d", "HND-d").unwrap();
    sim.pump();
    register_again(&mut sim, a, "d", "HND-d");
    sim.pump();
    let after = lists(&mut sim);
    let last = after.last().expect("a list after subscribing again");
    assert!(last.contains(&first), "{last}");
    assert!(!last.contains("{0, 0, 0,"), "{last}");
}

/// The race of a C module's start (ipc.md §4): it reads
/// `X_IPC_BROADCAST_MSG_VAR` with `V_get_…`, then subscribes
/// `V_watch_…`. A subscription made by another module between the two
/// changes the list after the read and before the watch, and the C central
/// tells the new module nothing: it then drops every publication of that
/// message for good (seen as a hung `prtt`, 2 runs in 20, against the C
/// central). Courier's central sends the watcher the current value when it
/// changed since that module read it.
#[test]
fn a_subscription_between_a_modules_var_read_and_its_watch_is_not_missed() {
    use courier_wire::ipc::frame::HEADER_SIZE;
    // b is held unnamed while the clock jumps ahead.
    let mut sim = Sim::new(crate::support::untimed());
    let a = sim.connect("a");
    define(&mut sim, a, "pong", "int");
    sim.pump();
    // b connects over a 1 ms network, and is held back from the moment it
    // is connected, before it has written anything.
    sim.net.stream_faults.min_delay = Duration::from_millis(1);
    sim.net.stream_faults.max_delay = Duration::from_millis(1);
    let b = sim.add("b");
    let connected = |n: &Net<IpcNode>| matches!(&n.hosts[b].node, IpcNode::Module(m) if m.central_stream().is_some());
    assert!(sim.net.run_until(Duration::from_secs(1), connected));
    sim.hold(b, true);
    sim.net.stream_faults = cut();
    // Hand b's frames to central one at a time until the next one
    // subscribes the watch.
    let watch = b"V_watch_X_IPC_BROADCAST_MSG_VAR";
    let stream = sim.stream(b);
    for step in 0.. {
        assert!(step < 100, "b never subscribed the watch");
        sim.pump();
        let pending = sim.net.pending(stream);
        let Ok(h) = Header::decode(&pending) else {
            continue;
        };
        let len = HEADER_SIZE + (h.class_total + h.msg_total) as usize;
        let next = &pending[..len.min(pending.len())];
        if next.windows(watch.len()).any(|w| w == watch) {
            break;
        }
        assert_eq!(sim.net.push(stream, len), len);
    }
    // Now a subscribes: the list changes while b is between read and watch.
    sim.m(a).subscribe("pong", "HND-pong").unwrap();
    sim.pump();
    sim.hold(b, false);
    sim.pump();
    assert!(sim
        .take_events(b)
        .iter()
        .any(|e| matches!(e, Event::Connected)));
    sim.m(b).publish("pong", 5i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let ev = sim.take_events(b);
    assert!(
        !ev.iter().any(|e| matches!(e, Event::PublishDropped { .. })),
        "b thinks nobody subscribes pong: {ev:?}"
    );
    let d = sim.deliveries(a);
    assert_eq!(d.len(), 1, "{d:?}");
    assert_eq!(d[0].3, 5i32.to_le_bytes());
}
