//! The central state machine driven by real module state machines
//! (`ipc::module::Connection`) over an in-memory network: no sockets, no
//! clocks, fully deterministic. Covers routing, capacity, priorities, queue
//! limits, notifications, direct mode, `-r`, back-pressure and hostile input.

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::{Instant, SystemTime};

use courier_wire::ipc::central::{
    Central, Config, ConnId, DispatchState, LogOptions, Output, Peer, DISPATCH_COST,
};
use courier_wire::ipc::frame::{ClassId, Header, MsgClass};
use courier_wire::ipc::module::{Connection, DeliveryKind, Event, ModuleConfig, MsgLength};

struct Module {
    conn: Connection,
    /// Frames the module wrote that central has not read (held while paused).
    outbox: VecDeque<Vec<u8>>,
    events: VecDeque<Event>,
    closed_by_central: bool,
}

struct Sim {
    central: Central,
    mods: HashMap<u64, Module>,
    paused: HashSet<u64>,
    logs: Vec<String>,
    closes: Vec<(u64, String)>,
    /// Headers of the frames central wrote, by module.
    sent: Vec<(u64, Header)>,
    /// The wall clock central is given.
    wall: SystemTime,
    now: Instant,
    /// Most bytes ever held in module outboxes while paused (TCP buffers).
    next: u64,
    /// Central reads a module's bytes this many at a time (a socket's
    /// reads), instead of one frame at a time.
    read_size: Option<usize>,
    /// Every byte central wrote, by module, in order.
    wire: HashMap<u64, Vec<u8>>,
    /// The size of every write central made, by module.
    writes: HashMap<u64, Vec<usize>>,
    /// Frames written as a header plus a shared body.
    shared_bodies: usize,
    /// Steps since central's invariants were last checked.
    unchecked: usize,
}

impl Sim {
    fn new(config: Config) -> Sim {
        Sim::new_at(config, SystemTime::now())
    }

    fn new_at(config: Config, wall: SystemTime) -> Sim {
        Sim {
            central: Central::new_at(config, wall),
            mods: HashMap::new(),
            paused: HashSet::new(),
            logs: Vec::new(),
            closes: Vec::new(),
            sent: Vec::new(),
            wall,
            now: Instant::now(),
            next: 1,
            read_size: None,
            wire: HashMap::new(),
            writes: HashMap::new(),
            shared_bodies: 0,
            unchecked: 0,
        }
    }

    fn add(&mut self, name: &str) -> u64 {
        let id = self.next;
        self.next += 1;
        self.central
            .connect(ConnId(id), Peer::Other(name.into()), self.wall);
        let conn = Connection::new(ModuleConfig::new(name, "localhost"), self.now);
        self.mods.insert(
            id,
            Module {
                conn,
                outbox: VecDeque::new(),
                events: VecDeque::new(),
                closed_by_central: false,
            },
        );
        id
    }

    fn connect(&mut self, name: &str) -> u64 {
        let id = self.add(name);
        self.pump();
        let ev = self.take_events(id);
        assert!(
            ev.iter().any(|e| matches!(e, Event::Connected)),
            "{name} did not connect: {ev:?}\nlog: {:#?}",
            self.logs
        );
        id
    }

    fn m(&mut self, id: u64) -> &mut Connection {
        &mut self.mods.get_mut(&id).unwrap().conn
    }

    /// Moves bytes until nothing moves.
    fn pump(&mut self) {
        loop {
            let mut moved = false;
            let ids: Vec<u64> = self.mods.keys().copied().collect();
            for id in ids {
                let m = self.mods.get_mut(&id).unwrap();
                while let Some(b) = m.conn.poll_transmit() {
                    m.outbox.push_back(b);
                }
                while let Some(e) = m.conn.poll_event() {
                    m.events.push_back(e);
                    moved = true;
                }
                // Processing a delivery may have queued a lookup.
                while let Some(b) = m.conn.poll_transmit() {
                    m.outbox.push_back(b);
                    moved = true;
                }
                while !self.paused.contains(&id) {
                    let Some(m) = self.mods.get_mut(&id) else {
                        break;
                    };
                    if m.closed_by_central {
                        break;
                    }
                    let Some(b) = m.outbox.pop_front() else {
                        break;
                    };
                    moved = true;
                    let step = self.read_size.unwrap_or(b.len()).max(1);
                    for piece in b.chunks(step) {
                        self.central.receive(ConnId(id), piece, self.wall);
                        self.drain();
                    }
                }
            }
            if self.drain() {
                moved = true;
            }
            if !moved {
                break;
            }
        }
    }

    /// Carries out central's outputs; true if anything reached a module.
    fn drain(&mut self) -> bool {
        let mut any = false;
        while let Some(o) = self.central.poll_output() {
            any = true;
            match o {
                o @ (Output::Transmit { .. } | Output::TransmitBody { .. }) => {
                    if matches!(o, Output::TransmitBody { .. }) {
                        self.shared_bodies += 1;
                    }
                    let (conn, bytes) = o.transmitted().unwrap();
                    self.wire
                        .entry(conn.0)
                        .or_default()
                        .extend_from_slice(&bytes);
                    self.writes.entry(conn.0).or_default().push(bytes.len());
                    if let Ok(h) = Header::decode(&bytes) {
                        self.sent.push((conn.0, h));
                    }
                    if let Some(m) = self.mods.get_mut(&conn.0) {
                        m.conn.receive(&bytes, self.now);
                    }
                }
                Output::Log { line, .. } => self.logs.push(line),
                Output::PauseRead { conn } => {
                    self.paused.insert(conn.0);
                }
                Output::ResumeRead { conn } => {
                    self.paused.remove(&conn.0);
                }
                Output::Close { conn, reason } => {
                    self.closes.push((conn.0, reason));
                    if let Some(m) = self.mods.get_mut(&conn.0) {
                        m.closed_by_central = true;
                        m.conn.handle_eof();
                    }
                    self.central.disconnect(conn, self.wall);
                }
                other => panic!("unexpected output {other:?}"),
            }
        }
        self.check();
        any
    }

    /// Central's tables must agree with each other after every step (every
    /// step ends in [`Sim::drain`]). The check walks every table, so its
    /// cost grows with the messages queued: with more than 8 of them it
    /// runs once every `dispatches / 8` steps, which keeps the floods
    /// below (hundreds of thousands of steps, a thousand messages queued)
    /// from taking minutes while a broken link is still caught within a
    /// few steps.
    fn check(&mut self) {
        self.unchecked += 1;
        if self.unchecked * 8 >= self.central.stats().dispatches {
            self.central.check_invariants();
            self.unchecked = 0;
        }
    }

    fn take_events(&mut self, id: u64) -> Vec<Event> {
        self.mods.get_mut(&id).unwrap().events.drain(..).collect()
    }

    /// User deliveries received by `id`: (delivery, msg, kind, data).
    fn deliveries(&mut self, id: u64) -> Vec<(u64, String, DeliveryKind, Vec<u8>)> {
        let m = self.mods.get_mut(&id).unwrap();
        let mut out = Vec::new();
        let mut rest = VecDeque::new();
        for e in m.events.drain(..) {
            match e {
                Event::Delivery {
                    delivery,
                    msg,
                    kind,
                    data,
                    ..
                } => out.push((delivery, msg, kind, data)),
                other => rest.push_back(other),
            }
        }
        m.events = rest;
        out
    }

    fn close(&mut self, id: u64) {
        self.mods.remove(&id);
        self.paused.remove(&id);
        self.central.disconnect(ConnId(id), self.wall);
        self.drain();
        self.pump();
    }
}

fn define(sim: &mut Sim, id: u64, msg: &str, fmt: &str) {
    sim.m(id)
        .define_msg(msg, MsgLength::Variable, Some(fmt))
        .unwrap();
}

/// Two modules connected: the first (`names.0`) defines `msg` with format
/// `fmt`, the second subscribes it with handler `HND-<msg>`.
fn pub_sub(config: Config, names: (&str, &str), msg: &str, fmt: &str) -> (Sim, u64, u64) {
    let mut sim = Sim::new(config);
    let a = sim.connect(names.0);
    let b = sim.connect(names.1);
    define(&mut sim, a, msg, fmt);
    sim.m(b).subscribe(msg, &format!("HND-{msg}")).unwrap();
    sim.pump();
    (sim, a, b)
}

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
        sim.central.stats().dispatches,
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
fn priorities_and_queue_limits(config: Config) -> Sim {
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
        sim.central.stats().dropped,
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
    let a = sim.add("a");
    sim.pump();
    assert!(sim
        .take_events(a)
        .iter()
        .any(|e| matches!(e, Event::DirectListenRequested)));
    sim.m(a).announce_direct_port(8123);
    sim.pump();
    assert!(sim
        .take_events(a)
        .iter()
        .any(|e| matches!(e, Event::Connected)));
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

#[test]
fn without_resend_unfinished_messages_are_cleared() {
    let (mut sim, a, b) = pub_sub(Config::default(), ("pub", "worker"), "job", "int");
    sim.m(a).publish("job", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    sim.close(b);
    assert_eq!(sim.central.stats().dispatches, 0);
}

#[test]
fn two_hundred_modules_connect_at_once() {
    let mut sim = Sim::new(Config::default());
    let ids: Vec<u64> = (0..200).map(|i| sim.add(&format!("m{i}"))).collect();
    sim.pump();
    for &id in &ids {
        assert!(sim
            .take_events(id)
            .iter()
            .any(|e| matches!(e, Event::Connected)));
    }
    assert_eq!(sim.central.module_names().len(), 200);
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
    let mut max_outbox = 0usize;
    while next < N {
        // The publisher writes as fast as its socket lets it.
        while sent < N && sim.mods[&p].outbox.len() < 1000 {
            let mut body = vec![0u8; 64];
            body[..4].copy_from_slice(&sent.to_le_bytes());
            sim.m(p).publish("data", body.clone(), -1).unwrap();
            sent += 1;
        }
        sim.pump();
        max_outbox = max_outbox.max(sim.mods[&p].outbox.len());
        for (id, _, _, data) in sim.deliveries(s) {
            assert_eq!(i32::from_le_bytes(data[..4].try_into().unwrap()), next);
            next += 1;
            sim.m(s).ack(id).unwrap();
        }
    }
    let st = sim.central.stats();
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
    let p = sim.connect("flood");
    let s = sim.connect("slow");
    sim.m(p)
        .define_msg("tick", MsgLength::Variable, None)
        .unwrap();
    sim.m(s).subscribe("tick", "HND-tick").unwrap();
    sim.pump();
    const N: usize = 30_000;
    let (mut sent, mut got, mut most) = (0, 0, 0);
    while got < N {
        while sent < N && sim.mods[&p].outbox.len() < 1000 {
            sim.m(p).publish("tick", Vec::new(), -1).unwrap();
            sent += 1;
        }
        sim.pump();
        most = most.max(sim.central.stats().dispatches);
        for (id, _, _, data) in sim.deliveries(s) {
            assert!(data.is_empty());
            got += 1;
            sim.m(s).ack(id).unwrap();
        }
    }
    sim.pump();
    let st = sim.central.stats();
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
        let mut body = vec![0u8; 64];
        body[..4].copy_from_slice(&i.to_le_bytes());
        sim.m(a).query("nobody", body, -1).unwrap();
        sim.pump();
    }
    let st = sim.central.stats();
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
    let st = sim.central.stats();
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
    while next < N {
        // Its socket takes what fits; the handler blocks while it is full.
        while sent < N && sim.mods[&m].outbox.len() < 1000 {
            let mut body = vec![0u8; 64];
            body[..4].copy_from_slice(&sent.to_le_bytes());
            sim.m(m).publish("data", body, -1).unwrap();
            sent += 1;
            if sent % 100 == 0 {
                sim.pump();
            }
        }
        // The handler returns once its last message is written.
        if sent == N && !acked && sim.mods[&m].outbox.is_empty() {
            sim.m(m).ack(go[0].0).unwrap();
            acked = true;
        }
        sim.pump();
        // The subscriber handles a few messages per turn.
        for (id, _, _, data) in sim.deliveries(s).into_iter().take(5) {
            assert_eq!(i32::from_le_bytes(data[..4].try_into().unwrap()), next);
            next += 1;
            sim.m(s).ack(id).unwrap();
        }
    }
    let st = sim.central.stats();
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
    while next < N {
        while sent < N && sim.mods[&h].outbox.len() < 1000 {
            let mut body = vec![0u8; 64];
            body[..4].copy_from_slice(&sent.to_le_bytes());
            sim.m(h).publish("data", body, -1).unwrap();
            sent += 1;
            if sent % 100 == 0 {
                sim.pump();
                was_paused |= sim.paused.contains(&h);
            }
        }
        if sent == N && !replied && sim.mods[&h].outbox.is_empty() {
            sim.m(h)
                .respond(ask[0].0, "ask_reply", 8i32.to_le_bytes())
                .unwrap();
            replied = true;
        }
        sim.pump();
        for (id, _, _, data) in sim.deliveries(s).into_iter().take(5) {
            assert_eq!(i32::from_le_bytes(data[..4].try_into().unwrap()), next);
            next += 1;
            sim.m(s).ack(id).unwrap();
        }
    }
    sim.pump();
    assert!(was_paused, "the answering module was never held back");
    assert!(sim
        .take_events(a)
        .iter()
        .any(|e| matches!(e, Event::Reply { query, .. } if *query == q)));
    let st = sim.central.stats();
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
        let mut body = vec![0u8; 64];
        body[..4].copy_from_slice(&i.to_le_bytes());
        sim.m(h).publish("data", body, -1).unwrap();
        sim.pump();
    }
    assert!(
        sim.paused.contains(&h),
        "the answering module was not held back"
    );
    // Now something is queued for the asker, whose handler waits for the
    // server's reply: the server is read again.
    sim.m(up)
        .publish("go", 2i32.to_le_bytes().to_vec(), -1)
        .unwrap();
    sim.pump();
    assert!(
        !sim.paused.contains(&h),
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
    let st = sim.central.stats();
    assert_eq!((st.queued_bytes, st.dispatches), (0, 0));
}

fn raw_frame(class: MsgClass, intent: i32, body: &[u8]) -> Vec<u8> {
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

fn hostile(bytes: &[u8]) -> (Vec<String>, Vec<String>) {
    let mut sim = Sim::new(Config::default());
    let ok = sim.connect("bystander");
    sim.central.connect(
        ConnId(99),
        Peer::Other("attacker".into()),
        SystemTime::now(),
    );
    sim.central.receive(ConnId(99), bytes, SystemTime::now());
    sim.central.check_invariants();
    let mut closes = Vec::new();
    let mut logs = Vec::new();
    while let Some(o) = sim.central.poll_output() {
        match o {
            Output::Close { reason, .. } => closes.push(reason),
            Output::Log { line, .. } => logs.push(line),
            _ => {}
        }
    }
    // Central is still fine for everyone else.
    define(&mut sim, ok, "still", "int");
    sim.pump();
    let op = sim.m(ok).is_module_connected("bystander").unwrap();
    sim.pump();
    assert!(sim.take_events(ok).contains(&Event::ModuleConnected {
        op,
        connected: true
    }));
    (closes, logs)
}

/// `-lx` turns logging off, not the report of a module that sends garbage:
/// the ERROR line still goes to the terminal (and, with `-L`, to the file).
#[test]
fn bad_input_is_reported_with_logging_off() {
    for file in [false, true] {
        let mut config = Config::default();
        config.terminal_log = LogOptions::parse("x", false).unwrap();
        if file {
            config.file_log = LogOptions::parse("m", true).unwrap();
        }
        let mut central = Central::new(config);
        let now = SystemTime::now();
        central.connect(ConnId(7), Peer::Other("attacker".into()), now);
        let mut f = raw_frame(MsgClass::Query, 5, &[]);
        f[4..8].copy_from_slice(&(-8i32).to_be_bytes());
        central.receive(ConnId(7), &f, now);
        central.check_invariants();
        let mut lines = Vec::new();
        while let Some(o) = central.poll_output() {
            if let Output::Log { target, line } = o {
                lines.push((target.terminal, target.file, line));
            }
        }
        // Only the ERROR line reaches the terminal.
        let shown: Vec<_> = lines.iter().filter(|l| l.0).collect();
        assert_eq!(shown.len(), 1, "{lines:?}");
        let (_, to_file, line) = shown[0];
        assert_eq!(*to_file, file, "{lines:?}");
        assert!(
            line.starts_with("ERROR: closing connection 7 (from attacker): ")
                && line.contains("negative length"),
            "{line}"
        );
    }
}

#[test]
fn hostile_frames_close_only_the_offender_with_a_log_line() {
    // Negative length.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[4..8].copy_from_slice(&(-8i32).to_be_bytes());
    let (c, l) = hostile(&f);
    assert!(c[0].contains("negative length"), "{c:?}");
    assert!(l.iter().any(|x| x.contains("negative length")));
    // Oversized.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[4..8].copy_from_slice(&i32::MAX.to_be_bytes());
    let (c, _) = hostile(&f);
    assert!(c[0].contains("exceeds the limit"), "{c:?}");
    // Not packed / bad byte order.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[17] = 4;
    assert!(hostile(&f).0[0].contains("not packed"));
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[16] = 0x77;
    assert!(hostile(&f).0[0].contains("byte-order"));
}

#[test]
fn truncated_internal_data_closes_with_the_reason() {
    // x_ipc_msgInfoMsg with a string length running off the end.
    let mut sim = Sim::new(Config::default());
    sim.central
        .connect(ConnId(7), Peer::Other("t".into()), SystemTime::now());
    let mut id = [0u8; 4];
    if let Some(Output::Transmit { bytes, .. }) = sim.central.poll_output() {
        id.copy_from_slice(&bytes);
    }
    let msg_info = i32::from_be_bytes(id);
    let mut body = 1000i32.to_le_bytes().to_vec();
    body.extend_from_slice(b"abc");
    let f = raw_frame(MsgClass::Query, msg_info, &body);
    sim.central.receive(ConnId(7), &f, SystemTime::now());
    let mut closes = Vec::new();
    while let Some(o) = sim.central.poll_output() {
        if let Output::Close { reason, .. } = o {
            closes.push(reason);
        }
    }
    assert_eq!(closes.len(), 1);
    assert!(closes[0].contains("count 1000"), "{closes:?}");
}

#[test]
fn unknown_ids_and_stray_acks_are_logged_not_fatal() {
    let (c, l) = hostile(&raw_frame(MsgClass::Broadcast, 123_456, &[]));
    assert!(c.is_empty());
    assert!(l.iter().any(|x| x.contains("unknown id 123456")), "{l:?}");
    let mut ack = raw_frame(MsgClass::Success, -1, &[]);
    ack[20..24].copy_from_slice(&42i32.to_be_bytes());
    let (c, l) = hostile(&ack);
    assert!(c.is_empty());
    assert!(l.iter().any(|x| x.contains("Success for unknown")), "{l:?}");
}

/// A module repeating a mistake in a loop (here 10 000 Successes for a
/// dispatch it was never given, and as many frames with an unknown id)
/// gets a burst of lines, then one a second, and a count of the rest, not
/// a line per frame; another module's lines are not affected.
#[test]
fn a_module_repeating_a_mistake_cannot_flood_the_log() {
    let mut central = Central::new(Config::default());
    let t0 = SystemTime::now();
    central.connect(ConnId(7), Peer::Other("looper".into()), t0);
    central.connect(ConnId(8), Peer::Other("other".into()), t0);
    let mut ack = raw_frame(MsgClass::Success, -1, &[]);
    ack[20..24].copy_from_slice(&42i32.to_be_bytes());
    let unknown = raw_frame(MsgClass::Broadcast, 123_456, &[]);
    let problems = |central: &mut Central| {
        let mut lines = Vec::new();
        while let Some(o) = central.poll_output() {
            match o {
                Output::Log { line, .. } => lines.push(line),
                Output::Close { reason, .. } => panic!("closed: {reason}"),
                _ => {}
            }
        }
        lines
    };
    problems(&mut central);
    for i in 0..10_000u32 {
        // 10 000 frames over 5 seconds.
        let now = t0 + std::time::Duration::from_micros(u64::from(i) * 500);
        central.receive(ConnId(7), if i % 2 == 0 { &ack } else { &unknown }, now);
        central.check_invariants();
    }
    let lines = problems(&mut central);
    // 10 at once, then one for each of the 4 further seconds.
    assert_eq!(lines.len(), 10 + 4 + 4, "{lines:#?}");
    let counts: Vec<u64> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("WARNING: "))
        .filter_map(|l| {
            l.split_once(" more problem line(s) about connection 7 (from looper) left out")
        })
        .map(|(n, _)| n.parse().unwrap())
        .collect();
    assert_eq!(counts.len(), 4, "{lines:#?}");
    // The other module is not silenced by the first one's budget.
    central.receive(ConnId(8), &ack, t0 + std::time::Duration::from_secs(5));
    let other = problems(&mut central);
    assert_eq!(other.len(), 1, "{other:?}");
    assert!(other[0].contains("from 8 (from other)"), "{other:?}");
    // Whatever was left out last is said when the module goes.
    let later = t0 + std::time::Duration::from_micros(4_999_900);
    for _ in 0..3 {
        central.receive(ConnId(7), &ack, later);
    }
    assert!(problems(&mut central).is_empty());
    central.disconnect(ConnId(7), later);
    let closing = problems(&mut central);
    let last = closing
        .iter()
        .find_map(|l| {
            l.strip_prefix("WARNING: ")?
                .strip_suffix(" more problem line(s) about connection 7 (from looper) left out")
        })
        .unwrap_or_else(|| panic!("no count when the module went: {closing:#?}"));
    let last: u64 = last.parse().unwrap();
    assert!(last >= 3);
    let printed = (lines.len() - counts.len()) as u64;
    assert_eq!(
        printed + counts.iter().sum::<u64>() + last,
        10_003,
        "every problem printed or counted"
    );
}

#[test]
fn disconnect_mid_frame_is_logged() {
    let mut sim = Sim::new(Config::default());
    sim.central
        .connect(ConnId(3), Peer::Other("t".into()), SystemTime::now());
    let f = raw_frame(MsgClass::Query, 5, &[1, 2, 3, 4]);
    sim.central.receive(ConnId(3), &f[..20], SystemTime::now());
    sim.central.check_invariants();
    sim.central.disconnect(ConnId(3), SystemTime::now());
    sim.central.check_invariants();
    let mut logs = Vec::new();
    while let Some(o) = sim.central.poll_output() {
        if let Output::Log { line, .. } = o {
            logs.push(line);
        }
    }
    assert!(
        logs.iter()
            .any(|l| l.contains("in the middle of a frame (20 byte(s)")),
        "{logs:?}"
    );
    assert_eq!(sim.central.stats().modules, 0);
}

#[test]
fn random_bytes_never_panic() {
    // A cheap deterministic fuzz: xorshift bytes, sometimes with a valid header prefix.
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    for round in 0..2000 {
        let mut central = Central::new(Config::default());
        central.connect(ConnId(1), Peer::Other("fuzz".into()), SystemTime::now());
        let n = (round % 200) + 1;
        let mut b = Vec::with_capacity(n);
        for _ in 0..n {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            b.push(x as u8);
        }
        if round % 2 == 0 && b.len() >= 28 {
            let body = (b.len() - 28) as i32;
            b[0..4].copy_from_slice(&0i32.to_be_bytes());
            b[4..8].copy_from_slice(&body.to_be_bytes());
            b[16..20].copy_from_slice(&ClassId::native(MsgClass::Query).0.to_be_bytes());
            let id = [182i32, 171, 173, 166, 164, 168, 162, 147, 144, 199, 195][round % 11];
            b[12..16].copy_from_slice(&id.to_be_bytes());
        }
        central.receive(ConnId(1), &b, SystemTime::now());
        while central.poll_output().is_some() {}
        central.check_invariants();
        central.disconnect(ConnId(1), SystemTime::now());
        while central.poll_output().is_some() {}
        central.check_invariants();
    }
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
    let id = sim.central.message_id("x_ipc_registerHandlerMsg").unwrap();
    let mut body = 0i32.to_le_bytes().to_vec();
    for s in ["m", "HND-m"] {
        body.extend_from_slice(&(s.len() as i32).to_le_bytes());
        body.extend_from_slice(s.as_bytes());
    }
    let f = raw_frame(MsgClass::Inform, id, &body);
    sim.central.receive(ConnId(a), &f, SystemTime::now());
    sim.drain();
    sim.m(a).publish("m", 2i32.to_le_bytes(), -1).unwrap();
    // Look at the delivery frame central writes.
    let now = SystemTime::now();
    while let Some(b) = sim.m(a).poll_transmit() {
        sim.central.receive(ConnId(a), &b, now);
    }
    let mut delivery = None;
    while let Some(o) = sim.central.poll_output() {
        if let Output::Transmit { bytes, .. } = o {
            let h = Header::decode(&bytes).unwrap();
            if h.class_id.class() == 15 && h.intent > 0 {
                delivery = Some((h, bytes));
            }
        }
    }
    let (h, bytes) = delivery.expect("a delivery");
    assert_eq!(h.intent, hid, "the first handler id is kept");
    assert_eq!(h.class_total, 5, "class data names the message again");
    assert_eq!(&bytes[28..33], b"\x01\x00\x00\x00m");
}

/// `x_ipc_registerHandlerMsg {0, msg, hnd}`, raw, as the C library sends
/// it when it subscribes a handler it subscribed before.
fn register_again(sim: &mut Sim, conn: u64, msg: &str, hnd: &str) {
    register_raw(sim, conn, 0, msg, hnd)
}

fn register_raw(sim: &mut Sim, conn: u64, hid: i32, msg: &str, hnd: &str) {
    handler_raw(sim, conn, "x_ipc_registerHandlerMsg", hid, msg, hnd)
}
fn handler_raw(sim: &mut Sim, conn: u64, internal: &str, hid: i32, msg: &str, hnd: &str) {
    let id = sim.central.message_id(internal).unwrap();
    let mut body = hid.to_le_bytes().to_vec();
    for s in [msg, hnd] {
        body.extend_from_slice(&(s.len() as i32).to_le_bytes());
        body.extend_from_slice(s.as_bytes());
    }
    let f = raw_frame(MsgClass::Inform, id, &body);
    sim.central.receive(ConnId(conn), &f, SystemTime::now());
    sim.drain();
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
    sim.sent.clear();
    sim.m(b).publish("m", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let intents: Vec<i32> = sim
        .sent
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
    let a = sim.add("a");
    sim.pump();
    sim.m(a).announce_direct_port(8123);
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

/// With `-t` every message line carries the time, central's own variable
/// broadcasts and the replies and completions of internal messages
/// included, as in the C central's log.
#[test]
fn timed_log_lines_all_carry_the_time() {
    let mut config = Config::default();
    config.terminal_log = courier_wire::ipc::central::LogOptions::parse("mt", false).unwrap();
    let wall = SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(3_723_450);
    let mut sim = Sim::new_at(config, wall);
    let a = sim.connect("a");
    let b = sim.connect("b");
    define(&mut sim, a, "m", "int");
    sim.m(b).subscribe("m", "HND-m").unwrap();
    sim.pump();
    sim.m(a).publish("m", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let message_lines: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| {
            ["Query", "Inform", "Broadcast", "  Reply", "  Done"]
                .iter()
                .any(|p| l.starts_with(p))
        })
        .collect();
    assert!(
        message_lines
            .iter()
            .any(|l| l.starts_with("Broadcast") && l.contains("V_watch_")),
        "{message_lines:#?}"
    );
    assert!(message_lines
        .iter()
        .any(|l| l.starts_with("  Done    x_ipc_registerHandlerMsg:")));
    assert!(message_lines
        .iter()
        .any(|l| l.starts_with("  Reply  x_ipc_msgInfoMsg:")));
    for l in message_lines {
        assert!(l.ends_with("  1:02:03.45"), "no time on {l:?}");
    }
}

/// Internal messages logged as the C central logs them when `i` is not
/// among the options: a module not named yet is `**NEWMOD**`, the connect
/// reply names it, replies carry their data (`x_ipc_waitMsg`'s `1`
/// included) and `x_ipc_CloseMsg` completes with a Done line.
/// With `-lmsrp` (no `i`) the C central logs registering its own
/// variables at start-up, and every internal message with its dispatch
/// id and its parent's: lines from the C central 3.9.1's terminal log
/// with module1 (`central -lmsrp`, routed, captured in session 20; the
/// host name is the machine's).
#[test]
fn internal_messages_carry_ids_and_parents_like_c() {
    let mut config = Config::default();
    config.terminal_log = LogOptions::parse("msrp", false).unwrap();
    let mut sim = Sim::new(config);
    sim.drain();
    let c_start = [
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_CENTRAL_TERMINAL_LOG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_CENTRAL_TERMINAL_LOG_VAR {0}:",
        "Inform    V_set_CENTRAL_FILE_LOG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_CENTRAL_FILE_LOG_VAR {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_X_IPC_TAPPED_MSG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_X_IPC_TAPPED_MSG_VAR {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_X_IPC_BROADCAST_MSG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_X_IPC_BROADCAST_MSG_VAR {0}:",
    ];
    assert_eq!(sim.logs, c_start);
    sim.logs.clear();
    sim.connect("module1");
    let c_connect = [
        "Query     x_ipc_msgInfoMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_msgInfoMsg {0}: X_IPC Server --> **NEWMOD**      {-1}",
        "Query     x_ipc_classInfoMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_classInfoMsg {0}: X_IPC Server --> **NEWMOD**      {-1}",
        "Query     x_ipc_newModuleConnectMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_newModuleConnectMsg {0}: X_IPC Server --> module1         {-1}",
        "Query     x_ipc_msgInfoMsg {0}:    module1 {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_msgInfoMsg {0}: X_IPC Server --> module1         {-1}",
        "Query     V_get_CENTRAL_TERMINAL_LOG_VAR {0}:    module1 {-1} --> X_IPC Server    (Sent)",
    ];
    for line in c_connect {
        assert!(
            sim.logs.iter().any(|l| l == line),
            "no {line:?} in {:#?}",
            sim.logs
        );
    }
    // Nothing of this reaches a log file: C opens it after start-up.
    let mut config = Config::default();
    config.file_log = LogOptions::parse("msrp", true).unwrap();
    let mut central = Central::new(config);
    assert_eq!(central.poll_output(), None);
}

#[test]
fn internal_messages_are_logged_like_c() {
    let mut config = Config::default();
    config.terminal_log = courier_wire::ipc::central::LogOptions::parse("md", false).unwrap();
    let mut sim = Sim::new(config);
    let a = sim.connect("a");
    let logs = std::mem::take(&mut sim.logs);
    let at = |p: &str| {
        logs.iter()
            .position(|l| l.starts_with(p))
            .unwrap_or_else(|| panic!("no line {p:?} in {logs:#?}"))
    };
    assert!(logs[at("Query     x_ipc_msgInfoMsg:")].contains(" **NEWMOD** --> X_IPC Server"));
    assert!(logs[at("  Reply  x_ipc_newModuleConnectMsg:")].contains("X_IPC Server --> a "));
    let info = at("  Reply  x_ipc_msgInfoMsg:");
    assert!(logs[info + 1].starts_with("    *{"), "{}", logs[info + 1]);
    let wait = at("  Reply    x_ipc_waitMsg:");
    assert_eq!(logs[wait + 1], "    1");
    // A subscription changes the broadcast list: central's own V_set
    // around the broadcast to the list's watchers.
    define(&mut sim, a, "m", "int");
    sim.m(a).subscribe("m", "HND-m").unwrap();
    sim.pump();
    let logs = std::mem::take(&mut sim.logs);
    let at = |p: &str| {
        logs.iter()
            .position(|l| l.starts_with(p))
            .unwrap_or_else(|| panic!("no line {p:?} in {logs:#?}"))
    };
    let set =
        at("Inform    V_set_X_IPC_BROADCAST_MSG_VAR: X_IPC Server --> X_IPC Server    (Sent)");
    assert!(logs[set + 1].starts_with("    {"), "{}", logs[set + 1]);
    let watch = at("Broadcast V_watch_X_IPC_BROADCAST_MSG_VAR: X_IPC Server --> a");
    let done = at("  Done    V_set_X_IPC_BROADCAST_MSG_VAR:");
    assert!(set < watch && watch < done, "{logs:#?}");
    sim.m(a).close().unwrap();
    sim.pump();
    assert!(
        sim.logs
            .iter()
            .any(|l| l.starts_with("  Done     x_ipc_CloseMsg:")),
        "{:#?}",
        sim.logs
    );
}

#[test]
fn log_options_parse_like_c() {
    use courier_wire::ipc::central::LogOptions;
    let o = LogOptions::parse("MSD", false).unwrap();
    assert!(o.messages && o.status && o.data && !o.time);
    assert!(
        !LogOptions::parse("mxs", false).unwrap().any(),
        "any x turns the log off"
    );
    let f = LogOptions::parse("mF", true).unwrap();
    assert!(f.messages && f.no_flush);
    let e = LogOptions::parse("mq", false).unwrap_err().to_string();
    assert!(e.contains("unknown logging option 'q' in -l"), "{e}");
    assert!(
        LogOptions::parse("F", false).is_err(),
        "F is for the file log only"
    );
}

/// The console's options reach central through `reconfigure`.
#[test]
fn reconfiguring_changes_what_is_logged() {
    let (mut sim, a, _) = pub_sub(Config::default(), ("a", "b"), "foo", "int");
    let publish = |sim: &mut Sim| {
        let before = sim.logs.len();
        sim.m(a).publish("foo", 1i32.to_le_bytes(), -1).unwrap();
        sim.pump();
        sim.logs[before..]
            .iter()
            .filter(|l| l.contains(" foo"))
            .count()
    };
    assert!(publish(&mut sim) > 0, "logged with -lmsi");
    // The console's `-Ifoo`.
    sim.central.reconfigure(|c| c.ignore.push("foo".into()));
    assert_eq!(publish(&mut sim), 0, "ignored");
    assert!(sim.central.config().ignore.contains(&"foo".to_string()));
    // `-lmd -Lx` and no `-I`: logged again, and no file log.
    sim.central.reconfigure(|c| {
        c.ignore.clear();
        c.terminal_log = LogOptions::parse("md", false).unwrap();
        c.file_log = LogOptions::parse("x", true).unwrap();
    });
    assert!(!sim.central.config().file_log.any());
    assert!(publish(&mut sim) > 0, "logged again");
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
    let mut sim = Sim::new(Config::default());
    let a = sim.connect("a");
    define(&mut sim, a, "pong", "int");
    sim.pump();
    let b = sim.add("b");
    // Move b's frames one at a time until the next one subscribes the watch.
    let watch = b"V_watch_X_IPC_BROADCAST_MSG_VAR";
    for step in 0.. {
        assert!(step < 100, "b never subscribed the watch");
        sim.drain();
        let m = sim.mods.get_mut(&b).unwrap();
        loop {
            while let Some(x) = m.conn.poll_transmit() {
                m.outbox.push_back(x);
            }
            let Some(e) = m.conn.poll_event() else { break };
            m.events.push_back(e);
        }
        let next = m.outbox.front().cloned().unwrap_or_default();
        if next.windows(watch.len()).any(|w| w == watch) {
            break;
        }
        if let Some(x) = m.outbox.pop_front() {
            sim.central.receive(ConnId(b), &x, SystemTime::now());
            sim.drain();
        }
    }
    // Now a subscribes: the list changes while b is between read and watch.
    sim.m(a).subscribe("pong", "HND-pong").unwrap();
    sim.paused.insert(b);
    sim.pump();
    sim.paused.remove(&b);
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

// ----- cut-through (Config::cut_through) --------------------------------------

/// A module that asks a large query and one that answers it, with central
/// reading 4 KiB at a time: returns the sim and both modules' ids.
fn large_query_pair(cut_through: Option<usize>) -> (Sim, u64, u64) {
    let mut config = Config::default();
    config.cut_through = cut_through;
    let mut sim = Sim::new(config);
    sim.read_size = Some(4096);
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

/// The frames module `id` has written, as one byte string.
fn written(sim: &mut Sim, id: u64) -> Vec<u8> {
    std::iter::from_fn(|| sim.m(id).poll_transmit())
        .flatten()
        .collect()
}

/// `a` asks a 100 kB query (`blob(100_000, seed)`) of which central has
/// read the first `upto` bytes; returns the rest of its bytes.
fn half_sent_query(sim: &mut Sim, a: u64, seed: u8, upto: usize) -> Vec<u8> {
    sim.m(a).query("ask", blob(100_000, seed), -1).unwrap();
    let frame = written(sim, a);
    sim.central.receive(ConnId(a), &frame[..upto], sim.wall);
    sim.drain();
    frame[upto..].to_vec()
}

/// `{int, <ubyte:1>}` data holding `payload`.
fn blob_of(payload: &[u8]) -> Vec<u8> {
    let mut v = (payload.len() as i32).to_le_bytes().to_vec();
    v.extend_from_slice(payload);
    v
}

/// The one delivery `id` has received: its id and data.
fn only_delivery(sim: &mut Sim, id: u64) -> (u64, Vec<u8>) {
    let mut d = sim.deliveries(id);
    assert_eq!(d.len(), 1, "{d:?}");
    let (delivery, _, _, data) = d.remove(0);
    (delivery, data)
}

/// `rest` waits in `id`'s socket, ahead of anything it writes later, and
/// central does not read it until `id` leaves `sim.paused`.
fn hold_rest(sim: &mut Sim, id: u64, rest: &[u8]) {
    sim.mods
        .get_mut(&id)
        .unwrap()
        .outbox
        .push_front(rest.to_vec());
    sim.paused.insert(id);
}

/// The largest single write central made to `id` since write number `from`.
fn largest_write(sim: &Sim, id: u64, from: usize) -> usize {
    sim.writes[&id][from..].iter().copied().max().unwrap_or(0)
}

fn blob(n: usize, seed: u8) -> Vec<u8> {
    let mut v = (n as i32).to_le_bytes().to_vec();
    v.extend((0..n).map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed)));
    v
}

/// Runs `rounds` large queries and returns every byte central wrote to each
/// of the two modules, and the replies' data.
fn large_queries(cut_through: Option<usize>, rounds: usize) -> (Vec<u8>, Vec<u8>, Sim) {
    let (mut sim, a, b) = large_query_pair(cut_through);
    let start_a = sim.wire.get(&a).map_or(0, Vec::len);
    let start_b = sim.wire.get(&b).map_or(0, Vec::len);
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
        sim.central.stats().dispatches,
        0,
        "every dispatch completed"
    );
    let wa = sim.wire[&a][start_a..].to_vec();
    let wb = sim.wire[&b][start_b..].to_vec();
    (wa, wb, sim)
}

#[test]
fn cut_through_sends_the_same_bytes_as_store_and_forward() {
    let (a_whole, b_whole, whole) = large_queries(None, 3);
    let (a_cut, b_cut, cut) = large_queries(Some(64 << 10), 3);
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
        cut.writes[&b]
    );
    assert!(
        largest_write(&cut, a, 0) <= 4096 + 64,
        "{:?}",
        cut.writes[&a]
    );
    assert_eq!(
        cut.central.stats().frames_in,
        whole.central.stats().frames_in
    );
}

#[test]
fn cut_through_forwards_before_the_last_byte_arrives() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    sim.m(a).query("ask", blob(100_000, 1), -1).unwrap();
    let frame = written(&mut sim, a);
    let before = sim.wire[&b].len();
    // All but the last byte: the answerer already has all but the last byte
    // (the header is central's own; the module knows the message's name).
    sim.central
        .receive(ConnId(a), &frame[..frame.len() - 1], sim.wall);
    sim.drain();
    assert_eq!(sim.wire[&b].len() - before, frame.len() - 1);
    assert!(sim.deliveries(b).is_empty(), "not complete yet");
    sim.central
        .receive(ConnId(a), &frame[frame.len() - 1..], sim.wall);
    sim.drain();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(100_000, 1));
}

#[test]
fn cut_through_holds_other_frames_until_the_relayed_one_is_complete() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    let rest = half_sent_query(&mut sim, a, 2, 50_000);
    // The rest is in the asker's socket, not yet read.
    hold_rest(&mut sim, a, &rest);
    // The answerer asks central something while the query is half through:
    // central's answer must not land inside the query's bytes.
    let op = sim.m(b).is_module_connected("asker").unwrap();
    let before = sim.wire[&b].len();
    sim.pump();
    assert_eq!(
        sim.wire[&b].len(),
        before,
        "the answer waits for the query's end"
    );
    assert!(sim.take_events(b).is_empty());
    sim.paused.remove(&a);
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
    let (delivery, body) = only_delivery(&mut sim, b);
    assert_eq!(body.len(), 100_004);
    assert!(body[body.len() - 1000..].iter().all(|&x| x == 0));
    // Its answer goes nowhere, and central is fine for everyone else.
    sim.m(b).respond(delivery, "answer", blob(10, 0)).unwrap();
    sim.pump();
    assert_eq!(sim.central.stats().dispatches, 0);
    let e = sim.connect("after");
    define(&mut sim, e, "ask", "{int, <ubyte:1>}");
    sim.m(e).query("ask", blob(70_000, 4), -1).unwrap();
    sim.pump();
    assert_eq!(only_delivery(&mut sim, b).1, blob(70_000, 4));
}

#[test]
fn cut_through_receiver_dying_midway_leaves_the_sender_in_step() {
    let (mut sim, a, b) = large_query_pair(Some(64 << 10));
    let b2 = sim.connect("answerer2");
    let rest = half_sent_query(&mut sim, a, 5, 30_000);
    hold_rest(&mut sim, a, &rest);
    sim.close(b);
    sim.paused.remove(&a);
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
    let writes = sim.writes[&b].len();
    sim.m(a).query("ask", blob(100_000, 8), -1).unwrap();
    sim.pump();
    assert_eq!(
        sim.writes[&b].len(),
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
    config.terminal_log = courier_wire::ipc::central::LogOptions::parse("md", false).unwrap();
    let mut sim = Sim::new(config);
    sim.read_size = Some(4096);
    let a = sim.connect("asker");
    let b = sim.connect("answerer");
    define(&mut sim, a, "ask", "{int, <ubyte:1>}");
    sim.m(b).subscribe("ask", "HND-ask").unwrap();
    sim.pump();
    let writes = sim.writes[&b].len();
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
    let ask = sim.central.message_id("ask").expect("ask is registered");
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
        let hostile = ConnId(1000 + round);
        sim.central
            .connect(hostile, Peer::Other("hostile".into()), sim.wall);
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
        let mut at = 0;
        while at < sent {
            let k = (1 + rnd(700) as usize).min(sent - at);
            sim.central.receive(hostile, &bytes[at..at + k], sim.wall);
            sim.drain();
            at += k;
        }
        sim.central.disconnect(hostile, sim.wall);
        sim.drain();
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
        sim.closes.iter().all(|(c, _)| *c >= 1000),
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
    let ask = sim.central.message_id("ask").expect("ask is registered");
    let mut body = 5i32.to_le_bytes().to_vec();
    body.extend_from_slice(&3i32.to_le_bytes()); // a count that disagrees
    body.extend_from_slice(&[1, 2, 3]);
    let rogue = ConnId(500);
    sim.central
        .connect(rogue, Peer::Other("rogue".into()), sim.wall);
    sim.central
        .receive(rogue, &raw_frame(MsgClass::Broadcast, ask, &body), sim.wall);
    sim.drain();
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
        sim.central.stats().dispatches,
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
    let start = sim.wire[&b].len();
    let sizes = [10, 70_000, 3, 20_000, 5];
    for (i, n) in sizes.iter().enumerate() {
        sim.m(a).publish("m", blob(*n, i as u8), -1).unwrap();
    }
    let stream = written(&mut sim, a);
    for piece in stream.chunks(read) {
        sim.central.receive(ConnId(a), piece, sim.wall);
        sim.drain();
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
    (got, sim.wire[&b][start..].to_vec(), sim.shared_bodies)
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
    let (_, _, whole) = large_queries(None, 3);
    // Three 100 kB queries and three 200 kB replies.
    assert_eq!(whole.shared_bodies, 6);
    let (_, _, cut) = large_queries(Some(64 << 10), 3);
    assert_eq!(cut.shared_bodies, 0, "relayed frames pass in pieces");
}

// ----- send-ahead ------------------------------------------------------------

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
fn frames(sim: &Sim, id: u64) -> (Vec<Vec<u8>>, Vec<Vec<u8>>) {
    use courier_wire::ipc::frame::HEADER_SIZE;
    let mut bytes = &sim.wire[&id][4..];
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
fn ticks(config: Config, n: i32) -> (Sim, u64, u64) {
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
fn handle_in_order(sim: &mut Sim, id: u64) -> (Vec<i32>, usize) {
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
        assert_eq!(sim.central.stats().dispatches, 0);
        assert_eq!(sim.central.stats().queued_bytes, 0);
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
        sim.sent
            .iter()
            .filter(|(to, h)| *to == b && h.intent > 0 && h.class_id.class() == 15)
            .map(|x| x.1)
            .collect()
    };
    let before = to_sub(&sim).len();
    // Central does not hear from the subscriber (its lookup is delayed).
    sim.paused.insert(b);
    for i in 0..3i32 {
        sim.m(a).publish("tick", i.to_le_bytes(), -1).unwrap();
    }
    sim.pump();
    let sent = to_sub(&sim);
    assert_eq!(sent.len() - before, 1, "only the first delivery: {sent:?}");
    assert!(sent.last().unwrap().class_total > 0, "it carries the name");
    // The lookup arrives: the other two go ahead, without the name.
    sim.paused.remove(&b);
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
    let sub = sim.central.modules();
    let sub = sub.iter().find(|m| m.conn == ConnId(b)).unwrap();
    assert_eq!(sub.name.as_deref(), Some("sub"));
    assert_eq!((sub.capacity, sub.active, sub.pending), (1, 1, 4));
    let states: Vec<DispatchState> = sim.central.dispatches().iter().map(|d| d.state).collect();
    let count = |s: DispatchState| states.iter().filter(|x| **x == s).count();
    assert_eq!(count(DispatchState::SentAhead), 2, "{states:?}");
    assert_eq!(count(DispatchState::Active), 1, "{states:?}");
    // Two are written; the other two are held in central and only they
    // count as queued bytes (each message is 12 bytes of data here, and
    // its bookkeeping).
    assert_eq!(sim.central.stats().queued_bytes, 2 * (12 + DISPATCH_COST));
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
    assert_eq!(sim.central.stats().dispatches, 0);
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
    assert_eq!(sim.central.stats().dispatches, 0);
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
            assert_eq!(sim.central.stats().dispatches, 0);
            assert_eq!(sim.central.stats().queued_bytes, 0);
            continue;
        }
        let b2 = sim.connect("sub");
        sim.m(b2).subscribe("tick", "HND-tick").unwrap();
        sim.pump();
        assert_eq!(handle_in_order(&mut sim, b2).0, vec![0, 1, 2, 3]);
        assert_eq!(sim.central.stats().dispatches, 0);
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
    assert_eq!(sim.central.stats().dispatches, 0);
    assert_eq!(sim.central.stats().queued_bytes, 0);
    assert!(
        sim.logs
            .iter()
            .any(|l| l.starts_with("Deleted pending tick")),
        "the one still queued in central is deleted, as in C: {:#?}",
        sim.logs
    );
}
