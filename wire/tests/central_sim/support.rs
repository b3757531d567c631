//! The IPC network the central tests run on: central (host 0) and real
//! module machines on the shared simulated network (`courier_wire::sim`),
//! with what the tests look at — central's log and closes, the bytes it
//! wrote to each module, whom it paused — and ways to hold a module's
//! bytes back or slip raw frames in.

use std::time::{Duration, SystemTime};

use courier_wire::ipc::central::{Central, Config, ConnId};
use courier_wire::ipc::frame::Header;
use courier_wire::ipc::module::{Connection, DeliveryKind, Event, ModuleConfig};
use courier_wire::sim::{
    CentralNode, Faults, IpcEvent, IpcNode, ModuleNode, Net, Reads, StreamFaults, StreamId,
};

/// Central's address.
pub const CENTRAL: &str = "localhost:1381";

/// A module: its host on the network.
pub type Mod = usize;

/// Streams cut into segments of up to 200 bytes and read 1 to 128 bytes
/// at a time, every frame boundary anywhere in a read, with no delay:
/// time stands still, as central's time-dependent behaviour (rate-limited
/// warnings, `-t` log times) is not what most tests look at.
pub fn cut() -> StreamFaults {
    StreamFaults {
        max_segment: 200,
        min_delay: Duration::ZERO,
        max_delay: Duration::ZERO,
        reads: Reads::Random(128),
    }
}

pub struct Sim {
    pub net: Net<IpcNode>,
    /// Central's log so far.
    pub logs: Vec<String>,
    /// The connections central closed (its ends), and why.
    pub closes: Vec<(StreamId, String)>,
    next_port: i32,
}

impl Sim {
    pub fn new(config: Config) -> Sim {
        Sim::with(config, 1, cut(), None)
    }

    /// Central started at `wall` (what its `-t` log times show).
    pub fn new_at(config: Config, wall: SystemTime) -> Sim {
        Sim::with(config, 1, cut(), Some(wall))
    }

    pub fn with(config: Config, seed: u64, faults: StreamFaults, wall: Option<SystemTime>) -> Sim {
        let mut net = Net::new(seed, Faults::none());
        net.stream_faults = faults;
        net.tapping = true;
        if let Some(wall) = wall {
            net.set_wall(wall);
        }
        let central = CentralNode::new(config, CENTRAL, net.now(), net.wall());
        net.add(IpcNode::Central(central));
        let mut sim = Sim {
            net,
            logs: Vec::new(),
            closes: Vec::new(),
            next_port: 10_001,
        };
        sim.collect();
        sim
    }

    /// A module that starts connecting (nothing runs yet).
    pub fn add(&mut self, name: &str) -> Mod {
        let port = self.next_port;
        self.next_port += 1;
        self.add_at(name, port)
    }

    /// A module listening on `port` in direct mode.
    pub fn add_at(&mut self, name: &str, port: i32) -> Mod {
        let cfg = ModuleConfig::new(name, "localhost");
        let node = ModuleNode::new(cfg, CENTRAL, port, self.net.now());
        self.net.add(IpcNode::Module(node))
    }

    /// A module, connected.
    pub fn connect(&mut self, name: &str) -> Mod {
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

    pub fn m(&mut self, id: Mod) -> &mut Connection {
        match self.net.node(id) {
            IpcNode::Module(m) => &mut m.conn,
            IpcNode::Central(_) => panic!("host {id} is central"),
        }
    }

    pub fn node(&mut self) -> &mut CentralNode {
        match self.net.node(0) {
            IpcNode::Central(c) => c,
            IpcNode::Module(_) => panic!("host 0 is not central"),
        }
    }

    pub fn central(&mut self) -> &mut Central {
        &mut self.node().central
    }

    /// Runs the network until nothing moves.
    pub fn pump(&mut self) {
        assert!(
            self.net.run_until_quiet(Duration::from_secs(3600)),
            "the network never got quiet"
        );
        self.collect();
    }

    /// Moves central's log lines and closes to `logs` and `closes` (done
    /// by [`pump`](Self::pump); after `net.run_for`, call it).
    pub fn collect(&mut self) {
        for e in self.net.take_events(0) {
            match e {
                IpcEvent::Log(line) => self.logs.push(line),
                IpcEvent::Closed { stream, reason } => self.closes.push((stream, reason)),
                IpcEvent::Module(e) => panic!("central reported {e:?}"),
            }
        }
    }

    pub fn take_events(&mut self, id: Mod) -> Vec<Event> {
        self.net
            .take_events(id)
            .into_iter()
            .map(|e| match e {
                IpcEvent::Module(e) => e,
                other => panic!("module {id} reported {other:?}"),
            })
            .collect()
    }

    /// User deliveries received by `id`: (delivery, msg, kind, data); its
    /// other events stay.
    pub fn deliveries(&mut self, id: Mod) -> Vec<(u64, String, DeliveryKind, Vec<u8>)> {
        let mut out = Vec::new();
        let mut rest = Vec::new();
        for e in self.net.take_events(id) {
            match e {
                IpcEvent::Module(Event::Delivery {
                    delivery,
                    msg,
                    kind,
                    data,
                    ..
                }) => out.push((delivery, msg, kind, data)),
                other => rest.push(other),
            }
        }
        self.net.hosts[id].events = rest;
        out
    }

    /// Module `id`'s process dies.
    pub fn close(&mut self, id: Mod) {
        self.net.crash(id);
        self.pump();
    }

    /// Module `id`'s end of its connection to central.
    pub fn stream(&self, id: Mod) -> StreamId {
        match &self.net.hosts[id].node {
            IpcNode::Module(m) => m.central_stream().expect("connected to central"),
            IpcNode::Central(_) => panic!("host {id} is central"),
        }
    }

    /// Central's connection to module `id`.
    pub fn conn(&self, id: Mod) -> ConnId {
        ConnId(self.stream(id).peer().0)
    }

    /// Holds module `id`'s bytes back from central (`true`), or lets them go.
    pub fn hold(&mut self, id: Mod, held: bool) {
        let s = self.stream(id);
        self.net.hold(s, held);
    }

    /// Bytes module `id` wrote that central has not read (its socket).
    pub fn unread(&self, id: Mod) -> usize {
        self.net.unread(self.stream(id))
    }

    /// Whether central stopped reading module `id`.
    pub fn paused(&mut self, id: Mod) -> bool {
        let s = self.stream(id).peer();
        self.node().is_paused(s)
    }

    /// Central's writes to module `id`, in order.
    fn writes_to(&self, id: Mod) -> impl Iterator<Item = &Vec<u8>> {
        let s = self.stream(id).peer();
        self.net
            .stream_tap
            .iter()
            .filter(move |(w, _)| *w == s)
            .map(|(_, b)| b)
    }

    /// Every byte central wrote to module `id`.
    pub fn wire(&self, id: Mod) -> Vec<u8> {
        self.writes_to(id).flatten().copied().collect()
    }

    /// The size of every write central made to module `id`.
    pub fn writes(&self, id: Mod) -> Vec<usize> {
        self.writes_to(id).map(Vec::len).collect()
    }

    /// The headers of the frames central wrote, and to which module.
    pub fn sent(&self) -> Vec<(Mod, Header)> {
        self.net
            .stream_tap
            .iter()
            .filter(|(w, _)| self.net.owner(*w) == Some(0))
            .filter_map(|(w, b)| Some((self.net.owner(w.peer())?, Header::decode(b).ok()?)))
            .collect()
    }

    /// Frames central wrote as a header and a shared body.
    pub fn shared_bodies(&mut self) -> usize {
        self.node().shared_bodies
    }

    /// A connection of the test's own to central, from `peer`.
    pub fn raw(&mut self, peer: &str) -> StreamId {
        let s = self
            .net
            .connect_raw(peer.into(), &CENTRAL.into())
            .expect("central listens");
        self.collect();
        s
    }

    /// Bytes slipped into module `id`'s stream to central, behind what it
    /// wrote (as the C library would send them).
    pub fn inject(&mut self, id: Mod, bytes: &[u8]) {
        let s = self.stream(id);
        self.net.write(s, bytes);
    }
}

/// The default configuration without the handshake and frame stall
/// timeouts, as C's central runs: for tests that keep a connection unnamed
/// or a frame half sent (raw bytes of their own, a module held back) while
/// the network's clock jumps ahead to whatever is due next.
pub fn untimed() -> Config {
    let mut c = Config::default();
    c.handshake_timeout = None;
    c.frame_stall_timeout = None;
    c
}

pub fn define(sim: &mut Sim, id: Mod, msg: &str, fmt: &str) {
    sim.m(id)
        .define_msg(
            msg,
            courier_wire::ipc::module::MsgLength::Variable,
            Some(fmt),
        )
        .unwrap();
}

/// Two modules connected: the first (`names.0`) defines `msg` with format
/// `fmt`, the second subscribes it with handler `HND-<msg>`.
pub fn pub_sub(config: Config, names: (&str, &str), msg: &str, fmt: &str) -> (Sim, Mod, Mod) {
    let mut sim = Sim::new(config);
    let a = sim.connect(names.0);
    let b = sim.connect(names.1);
    define(&mut sim, a, msg, fmt);
    sim.m(b).subscribe(msg, &format!("HND-{msg}")).unwrap();
    sim.pump();
    (sim, a, b)
}
