//! A deterministic simulated network for sans-I/O protocol machines (cargo
//! feature `sim`): seeded randomness, simulated time, no sockets, no
//! sleeps. Two kinds of link, on one network and one clock:
//!
//! - **datagrams** (UDP-like, [`Packet`]): lost,
//!   duplicated and delayed (so reordered) as [`Faults`] says;
//! - **streams** (TCP-like, [`StreamOp`]): reliable and ordered, with
//!   connect, accept and close (EOF), but cut and joined arbitrarily as
//!   [`StreamFaults`] says — a write may arrive in pieces, at different
//!   times, and several writes may arrive as one read — so framing is
//!   exercised; a node that stops reading ([`Node::reads_stream`]) leaves
//!   the bytes in the network, as an unread socket does.
//!
//! # One trait, two halves
//! A machine is a [`Node`]. The trait has a datagram half
//! ([`Node::owns`], [`Node::handle_datagram`], [`Node::poll_transmit`])
//! and a stream half ([`Node::listens`], [`Node::handle_accept`],
//! [`Node::handle_connect`], [`Node::handle_stream`], [`Node::handle_eof`],
//! [`Node::poll_stream`]); every method of either half has a do-nothing
//! default, so a node implements the half its links need — or both, as
//! an XRCE agent serving UDP and TCP clients does. That is why this is one
//! trait and one [`Net`] rather than a second `StreamNode` trait and
//! network: a node using both kinds would otherwise need two networks
//! with two clocks, and stream-only and datagram-only nodes could not
//! meet. Nodes of different types (a central and its modules, an agent
//! and its clients) share a network as the variants of one enum
//! ([`IpcNode`] is the IPC one).
//!
//! [`Participant`](crate::rtps::participant::Participant) and
//! [`Domain`](crate::dds::Domain) are datagram nodes; the IPC
//! [`CentralNode`] and [`ModuleNode`] are stream nodes.
//!
//! # Driving it
//! [`Net::step`] moves the clock by [`Net::tick`] and delivers what is
//! due; [`Net::run_until`] steps until a condition holds.
//! [`Net::run_until_quiet`] instead jumps from one arrival to the next
//! until nothing that will be read is in flight — the way to run
//! machines without timers (the IPC ones) to the end of an exchange.
//! A test can also take part itself: [`Net::connect_raw`] and
//! [`Net::listen_raw`] give it stream ends of its own to write scripted or
//! hostile bytes on, and [`Net::hold`] / [`Net::push`] control exactly
//! what a node has read.
//!
//! ```
//! use std::time::Duration;
//! use courier_wire::rtps::participant::{guid_prefix, Config, Event, Participant};
//! use courier_wire::sim::{Faults, Net};
//!
//! let mut net: Net<Participant> = Net::new(7, Faults::lossy(20));
//! for i in 0..2u32 {
//!     let cfg = Config::udpv4(0, i, guid_prefix([i as u8 + 1; 10]), [127, 0, 0, 1])
//!         .unwrap()
//!         .with_unicast_peers(&[[127, 0, 0, 1]], 3);
//!     net.add(Participant::new(cfg, net.now(), net.wall()));
//! }
//! assert!(net.run_until(Duration::from_secs(5), |n| {
//!     n.has(0, |e| matches!(e, Event::ParticipantFound(_)))
//! }));
//! ```
//!
//! A central and a module over streams cut into pieces of at most 7 bytes:
//!
//! ```
//! use std::time::Duration;
//! use courier_wire::ipc::central::Config;
//! use courier_wire::ipc::module::{Event, ModuleConfig};
//! use courier_wire::sim::{CentralNode, Faults, IpcEvent, IpcNode, ModuleNode, Net, StreamFaults};
//!
//! let mut net: Net<IpcNode> = Net::new(3, Faults::none());
//! net.stream_faults = StreamFaults::rough(7);
//! let central = CentralNode::new(Config::default(), "central:1381", net.now(), net.wall());
//! net.add(IpcNode::Central(central));
//! let cfg = ModuleConfig::new("m1", "localhost");
//! let m = net.add(IpcNode::Module(ModuleNode::new(cfg, "central:1381", 10_001, net.now())));
//! assert!(net.run_until_quiet(Duration::from_secs(10)));
//! assert!(net.has(m, |e| matches!(e, IpcEvent::Module(Event::Connected))));
//! ```

mod datagram;
mod ipc;
mod rtps;
mod stream;

use std::fmt::Debug;
use std::time::{Duration, Instant, SystemTime};

pub use self::datagram::{Faults, Packet};
pub use self::ipc::{CentralNode, IpcEvent, IpcNode, ModuleNode};
pub use self::stream::{Reads, StreamFaults, StreamId, StreamOp};

/// A machine on the simulated network. Every method but
/// [`address`](Node::address) and [`poll_event`](Node::poll_event) has a
/// default that does nothing: a node overrides the half (datagrams,
/// streams) its links use.
pub trait Node {
    /// Its addresses.
    type Addr: Clone + PartialEq + Debug;
    /// What it reports.
    type Event;
    /// Its address: the source of its datagrams, and what a node it
    /// connects to sees as the connection's peer.
    fn address(&self) -> Self::Addr;
    /// Time passed.
    fn handle_timeout(&mut self, _now: Instant) {}
    /// When it needs [`Node::handle_timeout`].
    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
    /// An event.
    fn poll_event(&mut self) -> Option<Self::Event>;

    // ----- datagrams ------------------------------------------------------

    /// Whether a datagram to `to` is for this node.
    fn owns(&self, _to: &Self::Addr) -> bool {
        false
    }
    /// Whether it reads datagrams to `to` now; those it does not read wait
    /// in the network (as in an unread socket) until it does.
    fn reads(&self, _to: &Self::Addr) -> bool {
        true
    }
    /// A datagram arrived.
    fn handle_datagram(&mut self, _from: Self::Addr, _bytes: &[u8], _now: Instant) {}
    /// A datagram to send: destination and bytes.
    fn poll_transmit(&mut self) -> Option<(Self::Addr, Vec<u8>)> {
        None
    }

    // ----- streams --------------------------------------------------------

    /// Whether it accepts stream connections to `at` (it listens there).
    fn listens(&self, _at: &Self::Addr) -> bool {
        false
    }
    /// A connection to one of its listening addresses was accepted:
    /// `stream` is its end, `from` the connecting node's address.
    fn handle_accept(&mut self, _stream: StreamId, _from: Self::Addr, _now: Instant) {}
    /// The connection it asked for with [`StreamOp::Connect`] `token` is
    /// up (`Some`, its end) or was refused (`None`: nobody listens there).
    fn handle_connect(&mut self, _token: u64, _stream: Option<StreamId>, _now: Instant) {}
    /// Bytes arrived on `stream`: the next piece of what the peer wrote,
    /// cut anywhere and possibly several writes together.
    fn handle_stream(&mut self, _stream: StreamId, _bytes: &[u8], _now: Instant) {}
    /// The peer closed `stream` (or its process died): every byte it
    /// wrote has been handed over; nothing more will come.
    fn handle_eof(&mut self, _stream: StreamId, _now: Instant) {}
    /// Whether it reads `stream` now; bytes it does not read wait in the
    /// network until it does (back-pressure).
    fn reads_stream(&self, _stream: StreamId) -> bool {
        true
    }
    /// A stream operation: connect, write or close.
    fn poll_stream(&mut self) -> Option<StreamOp<Self::Addr>> {
        None
    }
}

/// A node and what the network keeps for it.
pub struct Host<N: Node> {
    /// The machine.
    pub node: N,
    /// Its events so far (taken by [`Net::pump`]).
    pub events: Vec<N::Event>,
    /// A host that is down neither sends nor receives (a crashed process;
    /// [`Net::crash`] also resets its connections).
    pub up: bool,
    /// A frozen host runs nothing (a stopped process, `SIGSTOP`): no
    /// timer fires, and what is sent to it waits in the network, as in
    /// its sockets' buffers, to be read first when it is thawed
    /// ([`Net::freeze`], [`Net::thaw`]).
    pub frozen: bool,
}

impl<N: Node> Host<N> {
    /// Up and not frozen: it reads and its timers fire.
    pub fn runs(&self) -> bool {
        self.up && !self.frozen
    }
}

/// The simulated network: nodes, datagrams and stream bytes in flight,
/// the clock.
pub struct Net<N: Node> {
    /// The hosts, in the order added.
    pub hosts: Vec<Host<N>>,
    /// What the network does to datagrams.
    pub faults: Faults,
    /// What the network does to stream bytes.
    pub stream_faults: StreamFaults,
    /// Every datagram and stream write made while true is copied to
    /// [`Net::tap`] or [`Net::stream_tap`].
    pub tapping: bool,
    /// The datagrams sent while [`Net::tapping`].
    pub tap: Vec<Packet<N::Addr>>,
    /// The stream writes made while [`Net::tapping`]: the writer's end
    /// and the bytes, one entry per write.
    pub stream_tap: Vec<(StreamId, Vec<u8>)>,
    /// How far [`Net::step`] moves the clock.
    pub tick: Duration,
    seed: u64,
    datagrams: datagram::Queue<N::Addr>,
    streams: stream::Links<N::Addr>,
    t0: Instant,
    now: Instant,
    wall0: SystemTime,
}

impl<N: Node> Net<N> {
    /// An empty network; its clocks start now (the monotonic one at an
    /// arbitrary instant, the wall clock at 2023-11-14T22:13:20Z). Streams
    /// start perfect ([`StreamFaults::none`]).
    pub fn new(seed: u64, faults: Faults) -> Self {
        let t0 = Instant::now();
        Net {
            hosts: Vec::new(),
            faults,
            stream_faults: StreamFaults::none(),
            tapping: false,
            tap: Vec::new(),
            stream_tap: Vec::new(),
            tick: Duration::from_millis(1),
            seed: seed | 1,
            datagrams: datagram::Queue::default(),
            streams: stream::Links::default(),
            t0,
            now: t0,
            wall0: SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000),
        }
    }

    /// Sets the wall clock: [`Net::wall`] is `wall` now.
    pub fn set_wall(&mut self, wall: SystemTime) {
        self.wall0 = wall.checked_sub(self.now - self.t0).unwrap_or(wall);
    }

    /// Adds a node; returns its index.
    pub fn add(&mut self, node: N) -> usize {
        self.hosts.push(Host {
            node,
            events: Vec::new(),
            up: true,
            frozen: false,
        });
        self.pump();
        self.hosts.len() - 1
    }

    /// Stops host `i`'s process (`SIGSTOP`): see [`Host::frozen`].
    pub fn freeze(&mut self, i: usize) {
        self.hosts[i].frozen = true;
    }

    /// Resumes host `i`'s process (`SIGCONT`): at the next step it reads
    /// what waited for it before its overdue timers fire, as a resumed
    /// process finds its sockets readable and its timers late.
    pub fn thaw(&mut self, i: usize) {
        self.hosts[i].frozen = false;
    }

    /// Node `i`.
    pub fn node(&mut self, i: usize) -> &mut N {
        &mut self.hosts[i].node
    }

    /// The simulated time.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// The simulated wall clock at [`Net::now`].
    pub fn wall(&self) -> SystemTime {
        self.wall0 + (self.now - self.t0)
    }

    /// Time since the network was made.
    pub fn elapsed(&self) -> Duration {
        self.now - self.t0
    }

    /// The next pseudo-random number (xorshift).
    pub fn rand(&mut self) -> u32 {
        self.seed ^= self.seed << 13;
        self.seed ^= self.seed >> 7;
        self.seed ^= self.seed << 17;
        (self.seed >> 32) as u32
    }

    /// A pseudo-random duration in `min..=max`, in whole milliseconds
    /// (`min` when `max <= min`).
    fn delay(&mut self, min: Duration, max: Duration) -> Duration {
        let span = u64::try_from(max.saturating_sub(min).as_millis()).unwrap_or(u64::MAX);
        if span == 0 {
            return min;
        }
        min + Duration::from_millis(u64::from(self.rand()) % (span.saturating_add(1)))
    }

    /// Takes every up host's datagrams and stream operations (onto the
    /// network) and events.
    pub fn pump(&mut self) {
        for i in 0..self.hosts.len() {
            self.pump_host(i);
        }
    }

    /// Takes host `i`'s output until it has none; whether it had any.
    fn pump_host(&mut self, i: usize) -> bool {
        let mut any = false;
        loop {
            let mut moved = false;
            while let Some((to, payload)) = self.hosts[i].node.poll_transmit() {
                moved = true;
                if self.hosts[i].up {
                    let from = self.hosts[i].node.address();
                    self.send(Packet { from, to, payload });
                }
            }
            while let Some(op) = self.hosts[i].node.poll_stream() {
                moved = true;
                if self.hosts[i].up {
                    self.apply(i, op);
                }
            }
            let h = &mut self.hosts[i];
            while let Some(e) = h.node.poll_event() {
                moved = true;
                h.events.push(e);
            }
            if !moved {
                return any;
            }
            any = true;
        }
    }

    /// Advances the clock by [`Net::tick`]: delivers what is due, fires
    /// timers, pumps.
    pub fn step(&mut self) {
        self.now += self.tick;
        self.deliver_datagrams();
        self.connect_due();
        self.deliver_streams();
        self.fire_timers();
        self.pump();
    }

    /// Fires the timers that are due; whether any was.
    fn fire_timers(&mut self) -> bool {
        let now = self.now;
        let mut any = false;
        for h in self.hosts.iter_mut().filter(|h| h.runs()) {
            if h.node.poll_timeout().is_some_and(|t| t <= now) {
                h.node.handle_timeout(now);
                any = true;
            }
        }
        any
    }

    /// Steps until `done` or `limit` passed; whether `done` held.
    pub fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&Self) -> bool) -> bool {
        let end = self.now + limit;
        while self.now < end {
            if done(self) {
                return true;
            }
            self.step();
        }
        done(self)
    }

    /// Steps for `d`.
    pub fn run_for(&mut self, d: Duration) {
        self.run_until(d, |_| false);
    }

    /// Runs until the network is quiet — nothing in flight that a node
    /// will read, no connection being set up, no timer due — moving the
    /// clock from one arrival (or timer) to the next rather than tick by
    /// tick, and handing over everything due at one instant before the
    /// clock moves. Bytes a node does not read ([`Node::reads_stream`],
    /// [`Net::hold`]) do not keep it running. Whether it got quiet within
    /// `limit`: nodes with periodic timers never do (use
    /// [`Net::run_until`] for them).
    pub fn run_until_quiet(&mut self, limit: Duration) -> bool {
        let end = self.now + limit;
        loop {
            loop {
                let mut moved = self.pump_all();
                moved |= self.deliver_datagrams();
                moved |= self.connect_due();
                moved |= self.deliver_streams();
                moved |= self.fire_timers();
                if !moved {
                    break;
                }
            }
            let Some(next) = self.next_due() else {
                return true;
            };
            if next > end {
                self.now = end;
                return false;
            }
            // Something due now that was not handed over (a timer that
            // does not move on) lets time pass rather than spin.
            self.now = if next > self.now {
                next
            } else {
                self.now + self.tick
            };
        }
    }

    /// [`Net::pump`], and whether anything moved.
    fn pump_all(&mut self) -> bool {
        let mut any = false;
        for i in 0..self.hosts.len() {
            any |= self.pump_host(i);
        }
        any
    }

    /// When the next thing that will be handed over is due.
    fn next_due(&self) -> Option<Instant> {
        let timers = self
            .hosts
            .iter()
            .filter(|h| h.runs())
            .filter_map(|h| h.node.poll_timeout());
        [self.next_datagram(), self.next_stream()]
            .into_iter()
            .flatten()
            .chain(timers)
            .min()
    }

    /// Whether host `i` reported an event like this.
    pub fn has(&self, i: usize, f: impl Fn(&N::Event) -> bool) -> bool {
        self.hosts[i].events.iter().any(f)
    }

    /// Takes host `i`'s events so far.
    pub fn take_events(&mut self, i: usize) -> Vec<N::Event> {
        std::mem::take(&mut self.hosts[i].events)
    }
}
