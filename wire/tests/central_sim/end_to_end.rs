//! Central and several module machines end to end on a rough network —
//! writes cut into segments of up to 40 bytes, each 0 to 3 ms late, read
//! 1 to 40 bytes at a time — over many seeds: publish/subscribe,
//! query/response, a goodbye, crashes; and direct mode, where modules
//! connect to each other's listeners through the network. Each module's
//! application acknowledges what it is given and answers queries with
//! the square of the value asked.

use std::collections::BTreeMap;
use std::time::Duration;

use courier_wire::ipc::central::Config;
use courier_wire::ipc::module::{DeliveryKind, Error, Event, ModuleConfig, MsgLength, OpId};
use courier_wire::sim::{CentralNode, Faults, IpcEvent, IpcNode, ModuleNode, Net, StreamFaults};

use crate::support::CENTRAL;

const SEEDS: u64 = 12;

/// What the applications saw.
#[derive(Debug, Default, PartialEq)]
struct Seen {
    /// Broadcasts handled: (module, message, value), in order.
    got: Vec<(usize, String, i32)>,
    /// Replies to queries: (module, query, value).
    replies: Vec<(usize, OpId, i32)>,
    /// Every other module event.
    other: Vec<(usize, Event)>,
    /// Central's log.
    log: Vec<String>,
}

impl Seen {
    fn values(&self, module: usize, msg: &str) -> Vec<i32> {
        self.got
            .iter()
            .filter(|(m, n, _)| *m == module && n == msg)
            .map(|x| x.2)
            .collect()
    }
}

fn value(data: &[u8]) -> i32 {
    i32::from_le_bytes(data[data.len() - 4..].try_into().unwrap())
}

fn m(net: &mut Net<IpcNode>, i: usize) -> &mut courier_wire::ipc::module::Connection {
    &mut net.node(i).module().expect("a module").conn
}

/// A network with central (host 0, `config`) and the modules `names`
/// (hosts 1…), connected.
fn world(seed: u64, config: Config, names: &[&str]) -> Net<IpcNode> {
    let mut net = Net::new(seed, Faults::none());
    net.stream_faults = StreamFaults::rough(40);
    net.tapping = true;
    let central = CentralNode::new(config, CENTRAL, net.now(), net.wall());
    net.add(IpcNode::Central(central));
    for (i, name) in names.iter().enumerate() {
        let cfg = ModuleConfig::new(*name, "localhost");
        let node = ModuleNode::new(cfg, CENTRAL, 20_000 + i as i32, net.now());
        net.add(IpcNode::Module(node));
    }
    assert!(net.run_until_quiet(Duration::from_secs(60)));
    for i in 1..net.hosts.len() {
        assert!(
            net.has(i, |e| *e == IpcEvent::Module(Event::Connected)),
            "seed {seed}: {} did not connect",
            names[i - 1]
        );
        net.take_events(i);
    }
    net
}

/// Runs the network, with every application handling what it is given,
/// until nothing moves.
fn run(net: &mut Net<IpcNode>, seen: &mut Seen) {
    loop {
        assert!(net.run_until_quiet(Duration::from_secs(60)));
        let mut acted = false;
        for i in 1..net.hosts.len() {
            for e in net.take_events(i) {
                let IpcEvent::Module(e) = e else {
                    panic!("module {i} reported {e:?}");
                };
                match e {
                    Event::Delivery {
                        delivery,
                        msg,
                        kind,
                        data,
                        ..
                    } => {
                        acted = true;
                        let v = value(&data);
                        match kind {
                            DeliveryKind::Broadcast => {
                                seen.got.push((i, msg, v));
                                // (What arrived while a goodbye waited for
                                // its lookup is reported, and cannot be
                                // acknowledged once the goodbye is out.)
                                match m(net, i).ack(delivery) {
                                    Ok(()) | Err(Error::Closed) => {}
                                    Err(e) => panic!("module {i}: {e}"),
                                }
                            }
                            DeliveryKind::Query => {
                                let reply = format!("{msg}_reply");
                                m(net, i)
                                    .respond(delivery, &reply, (v * v).to_le_bytes())
                                    .unwrap();
                            }
                        }
                    }
                    Event::Reply { query, data, .. } => seen.replies.push((i, query, value(&data))),
                    other => seen.other.push((i, other)),
                }
            }
        }
        for e in net.take_events(0) {
            match e {
                IpcEvent::Log(line) => seen.log.push(line),
                IpcEvent::Closed { .. } => {}
                IpcEvent::Module(e) => panic!("central reported {e:?}"),
            }
        }
        if !acted {
            return;
        }
    }
}

fn define(net: &mut Net<IpcNode>, i: usize, msg: &str) {
    m(net, i)
        .define_msg(msg, MsgLength::Variable, Some("int"))
        .unwrap();
}

const SENSOR: usize = 1;
const LOGGER: usize = 2;
const MONITOR: usize = 3;
const SERVER: usize = 4;
const CLIENT: usize = 5;

/// One seed of the routed scenario: a sensor publishes to a logger and a
/// monitor while a client queries a server; the monitor says goodbye, the
/// sensor dies while publishing, the client dies with a query out.
fn routed(seed: u64) -> Seen {
    let names = ["sensor", "logger", "monitor", "server", "client"];
    let mut net = world(seed, Config::default(), &names);
    let mut seen = Seen::default();
    define(&mut net, SENSOR, "reading");
    define(&mut net, SERVER, "square");
    define(&mut net, SERVER, "square_reply");
    for i in [LOGGER, MONITOR] {
        m(&mut net, i).subscribe("reading", "HND-reading").unwrap();
    }
    m(&mut net, LOGGER).subscribe_disconnect().unwrap();
    m(&mut net, SERVER)
        .subscribe("square", "HND-square")
        .unwrap();
    run(&mut net, &mut seen);

    // Publishes and queries at once.
    let mut asked = BTreeMap::new();
    for v in 0..50i32 {
        m(&mut net, SENSOR)
            .publish("reading", v.to_le_bytes(), -1)
            .unwrap();
        if v < 20 {
            let q = m(&mut net, CLIENT)
                .query("square", v.to_le_bytes(), -1)
                .unwrap();
            asked.insert(q, v);
        }
        if v % 7 == 0 {
            run(&mut net, &mut seen);
        }
    }
    run(&mut net, &mut seen);
    for i in [LOGGER, MONITOR] {
        assert_eq!(
            seen.values(i, "reading"),
            (0..50).collect::<Vec<_>>(),
            "seed {seed}: module {i}"
        );
    }
    let replies: BTreeMap<OpId, i32> = seen
        .replies
        .iter()
        .filter(|r| r.0 == CLIENT)
        .map(|r| (r.1, r.2))
        .collect();
    let squares: BTreeMap<OpId, i32> = asked.iter().map(|(q, v)| (*q, v * v)).collect();
    assert_eq!(
        replies, squares,
        "seed {seed}: one reply per query, its own"
    );

    // The monitor says goodbye; the sensor dies in the middle of a burst;
    // the client dies with a query out.
    m(&mut net, MONITOR).close().unwrap();
    for v in 50..60i32 {
        m(&mut net, SENSOR)
            .publish("reading", v.to_le_bytes(), -1)
            .unwrap();
    }
    m(&mut net, CLIENT)
        .query("square", 99i32.to_le_bytes(), -1)
        .unwrap();
    // Both die 0 to 5 ms later, after more or less of it got out.
    net.pump();
    for _ in 0..seed % 6 {
        net.step();
    }
    net.crash(SENSOR);
    net.crash(CLIENT);
    run(&mut net, &mut seen);
    // What the sensor got out before it died, in order, once; the monitor
    // may have been given some of it before its goodbye was out.
    for i in [LOGGER, MONITOR] {
        let got = seen.values(i, "reading");
        let n = got.len();
        assert!((50..=60).contains(&n), "seed {seed}: module {i} got {n}");
        assert_eq!(got, (0..n as i32).collect::<Vec<_>>(), "seed {seed}: {i}");
    }
    for gone in ["monitor", "sensor", "client"] {
        assert!(
            seen.other
                .contains(&(LOGGER, Event::ModuleDisconnect(gone.into()))),
            "seed {seed}: no disconnect of {gone}: {:?}",
            seen.other
        );
    }
    let central = &mut net.node(0).central().unwrap().central;
    let mut names = central.module_names();
    names.sort();
    assert_eq!(names, ["logger", "server"], "seed {seed}");
    assert_eq!(central.stats().dispatches, 0, "seed {seed}: all finished");
    seen
}

#[test]
fn modules_publish_query_and_disconnect_through_central_over_many_seeds() {
    for seed in 1..=SEEDS {
        routed(seed);
    }
}

#[test]
fn a_seed_replays_exactly() {
    let (a, b) = (routed(5), routed(5));
    assert_eq!(a, b);
    assert_ne!(a.log, routed(6).log, "another seed, another interleaving");
}

/// Direct mode (`central -c`): the publisher looks the receivers up in
/// central, connects to their listeners through the network, and sends
/// them the message itself; central routes none of it. A query goes the
/// same way, and its reply comes back on the link.
#[test]
fn direct_mode_modules_talk_over_their_own_links() {
    for seed in 1..=SEEDS {
        let mut config = Config::default();
        config.direct = true;
        let names = ["pub", "sub1", "sub2"];
        let mut net = world(seed, config, &names);
        let mut seen = Seen::default();
        define(&mut net, 1, "dmsg");
        define(&mut net, 2, "dask");
        define(&mut net, 2, "dask_reply");
        for i in [2, 3] {
            m(&mut net, i).subscribe("dmsg", "HND-dmsg").unwrap();
        }
        m(&mut net, 2).subscribe("dask", "HND-dask").unwrap();
        run(&mut net, &mut seen);
        let frames_in = net.node(0).central().unwrap().central.stats().frames_in;
        for v in 0..30i32 {
            m(&mut net, 1).publish("dmsg", v.to_le_bytes(), -1).unwrap();
        }
        let q = m(&mut net, 1)
            .query("dask", 12i32.to_le_bytes(), -1)
            .unwrap();
        run(&mut net, &mut seen);
        for i in [2, 3] {
            assert_eq!(
                seen.values(i, "dmsg"),
                (0..30).collect::<Vec<_>>(),
                "seed {seed}: module {i}"
            );
        }
        assert!(
            seen.replies.contains(&(1, q, 144)),
            "seed {seed}: {:?}",
            seen.replies
        );
        // The publisher's links: streams it wrote on whose other end is a
        // subscriber, not central.
        let to_subscribers = net
            .stream_tap
            .iter()
            .filter(|(w, _)| net.owner(*w) == Some(1))
            .filter(|(w, _)| matches!(net.owner(w.peer()), Some(2 | 3)))
            .count();
        assert!(
            to_subscribers >= 30,
            "seed {seed}: {to_subscribers} writes on links"
        );
        // Central saw the lookups and the link bookkeeping, not 30
        // messages and their acknowledgements.
        let more = net.node(0).central().unwrap().central.stats().frames_in - frames_in;
        assert!(more < 30, "seed {seed}: central read {more} frames");
        assert!(
            !seen
                .log
                .iter()
                .any(|l| l.contains("dmsg") && l.starts_with("Broadcast")),
            "seed {seed}"
        );
    }
}
