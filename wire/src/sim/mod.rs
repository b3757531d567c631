//! A deterministic simulated network for sans-I/O protocol machines (cargo
//! feature `sim`): seeded randomness, simulated time, no sockets, no
//! sleeps; datagrams lost, duplicated and delayed (so reordered) as
//! [`Faults`] says. [`Participant`] and [`Domain`] are [`Node`]s; other
//! machines (XRCE sessions…) implement the trait.
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

use std::fmt::Debug;
use std::time::{Duration, Instant, SystemTime};

use crate::dds::Domain;
use crate::rtps::participant::{self, Datagram, Participant};
use crate::rtps::Locator;

/// A machine on the simulated network.
pub trait Node {
    /// Its addresses.
    type Addr: Clone + PartialEq + Debug;
    /// What it reports.
    type Event;
    /// Whether a datagram to `to` is for this node.
    fn owns(&self, to: &Self::Addr) -> bool;
    /// Whether it reads datagrams to `to` now; those it does not read wait
    /// in the network (as in an unread socket) until it does.
    fn reads(&self, _to: &Self::Addr) -> bool {
        true
    }
    /// The source address of what it sends.
    fn address(&self) -> Self::Addr;
    /// A datagram arrived.
    fn handle_datagram(&mut self, from: Self::Addr, bytes: &[u8], now: Instant);
    /// Time passed.
    fn handle_timeout(&mut self, now: Instant);
    /// When it needs [`Node::handle_timeout`].
    fn poll_timeout(&self) -> Option<Instant>;
    /// A datagram to send: destination and bytes.
    fn poll_transmit(&mut self) -> Option<(Self::Addr, Vec<u8>)>;
    /// An event.
    fn poll_event(&mut self) -> Option<Self::Event>;
}

/// What the network does to datagrams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Faults {
    /// Percent lost.
    pub loss: u32,
    /// Percent delivered twice.
    pub duplicate: u32,
    /// Each datagram takes 1 ms up to this long (more reorders more).
    pub max_delay: Duration,
}

impl Faults {
    /// A perfect network with 1 ms latency.
    pub fn none() -> Self {
        Faults {
            loss: 0,
            duplicate: 0,
            max_delay: Duration::from_millis(1),
        }
    }

    /// `loss` % loss and, when there is loss, 5 % duplicates and up to
    /// 20 ms of delay.
    pub fn lossy(loss: u32) -> Self {
        if loss == 0 {
            return Self::none();
        }
        Faults {
            loss,
            duplicate: 5,
            max_delay: Duration::from_millis(20),
        }
    }
}

/// A datagram on the network.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet<A> {
    /// Sender.
    pub from: A,
    /// Destination.
    pub to: A,
    /// Bytes.
    pub payload: Vec<u8>,
}

/// A node and what the network keeps for it.
pub struct Host<N: Node> {
    /// The machine.
    pub node: N,
    /// Its events so far (taken by [`Net::pump`]).
    pub events: Vec<N::Event>,
    /// A host that is down neither sends nor receives (a crashed process).
    pub up: bool,
}

/// The simulated network: nodes, datagrams in flight, the clock.
pub struct Net<N: Node> {
    /// The hosts, in the order added.
    pub hosts: Vec<Host<N>>,
    /// What the network does.
    pub faults: Faults,
    /// Every datagram sent while true is copied to [`Net::tap`].
    pub tapping: bool,
    /// The datagrams sent while [`Net::tapping`].
    pub tap: Vec<Packet<N::Addr>>,
    /// How far [`Net::step`] moves the clock.
    pub tick: Duration,
    seed: u64,
    queue: Vec<(Instant, u64, Packet<N::Addr>)>,
    serial: u64,
    t0: Instant,
    now: Instant,
    wall0: SystemTime,
}

impl<N: Node> Net<N> {
    /// An empty network; its clocks start now (the monotonic one at an
    /// arbitrary instant, the wall clock at 2023-11-14T22:13:20Z).
    pub fn new(seed: u64, faults: Faults) -> Self {
        let t0 = Instant::now();
        Net {
            hosts: Vec::new(),
            faults,
            tapping: false,
            tap: Vec::new(),
            tick: Duration::from_millis(1),
            seed: seed | 1,
            queue: Vec::new(),
            serial: 0,
            t0,
            now: t0,
            wall0: SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000),
        }
    }

    /// Adds a node; returns its index.
    pub fn add(&mut self, node: N) -> usize {
        self.hosts.push(Host {
            node,
            events: Vec::new(),
            up: true,
        });
        self.pump();
        self.hosts.len() - 1
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

    /// Puts a datagram on the network (faults apply).
    pub fn send(&mut self, p: Packet<N::Addr>) {
        if self.tapping {
            self.tap.push(p.clone());
        }
        if self.rand() % 100 < self.faults.loss {
            return;
        }
        let copies = if self.rand() % 100 < self.faults.duplicate {
            2
        } else {
            1
        };
        let max = u64::try_from(self.faults.max_delay.as_millis())
            .unwrap_or(u64::MAX)
            .max(1);
        for _ in 0..copies {
            let delay = 1 + u64::from(self.rand()) % max;
            self.serial += 1;
            self.queue.push((
                self.now + Duration::from_millis(delay),
                self.serial,
                p.clone(),
            ));
        }
    }

    /// Takes every up host's datagrams (onto the network) and events.
    pub fn pump(&mut self) {
        for i in 0..self.hosts.len() {
            while let Some((to, payload)) = self.hosts[i].node.poll_transmit() {
                if self.hosts[i].up {
                    let from = self.hosts[i].node.address();
                    self.send(Packet { from, to, payload });
                }
            }
            let h = &mut self.hosts[i];
            while let Some(e) = h.node.poll_event() {
                h.events.push(e);
            }
        }
    }

    /// Advances the clock by [`Net::tick`]: delivers what is due, fires
    /// timers, pumps.
    pub fn step(&mut self) {
        self.now += self.tick;
        let now = self.now;
        let mut due = Vec::new();
        let hosts = &self.hosts;
        self.queue.retain(|(t, serial, p)| {
            let read = hosts
                .iter()
                .all(|h| !h.up || !h.node.owns(&p.to) || h.node.reads(&p.to));
            if *t <= now && read {
                due.push((*t, *serial, p.clone()));
                false
            } else {
                true
            }
        });
        due.sort_by_key(|d| (d.0, d.1));
        for (_, _, p) in due {
            for h in self.hosts.iter_mut().filter(|h| h.up) {
                if h.node.owns(&p.to) {
                    h.node.handle_datagram(p.from.clone(), &p.payload, now);
                }
            }
        }
        for h in self.hosts.iter_mut().filter(|h| h.up) {
            if h.node.poll_timeout().is_some_and(|t| t <= now) {
                h.node.handle_timeout(now);
            }
        }
        self.pump();
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

    /// Whether host `i` reported an event like this.
    pub fn has(&self, i: usize, f: impl Fn(&N::Event) -> bool) -> bool {
        self.hosts[i].events.iter().any(f)
    }

    /// Takes host `i`'s events so far.
    pub fn take_events(&mut self, i: usize) -> Vec<N::Event> {
        std::mem::take(&mut self.hosts[i].events)
    }

    /// Datagrams in flight (or waiting to be read).
    pub fn in_flight(&self) -> usize {
        self.queue.len()
    }
}

fn owns(c: &participant::Config, to: &Locator) -> bool {
    c.metatraffic_unicast.contains(to) || c.default_unicast.contains(to)
}

fn address(c: &participant::Config) -> Locator {
    c.default_unicast
        .first()
        .copied()
        .unwrap_or(Locator::udpv4([127, 0, 0, 1], 0))
}

fn split(d: Datagram) -> (Locator, Vec<u8>) {
    (d.destination, d.payload)
}

impl Node for Participant {
    type Addr = Locator;
    type Event = participant::Event;
    fn owns(&self, to: &Locator) -> bool {
        owns(self.config(), to)
    }
    fn address(&self) -> Locator {
        address(self.config())
    }
    fn handle_datagram(&mut self, from: Locator, bytes: &[u8], now: Instant) {
        Participant::handle_datagram(self, from, bytes, now);
    }
    fn handle_timeout(&mut self, now: Instant) {
        Participant::handle_timeout(self, now);
    }
    fn poll_timeout(&self) -> Option<Instant> {
        Participant::poll_timeout(self)
    }
    fn poll_transmit(&mut self) -> Option<(Locator, Vec<u8>)> {
        Participant::poll_transmit(self).map(split)
    }
    fn poll_event(&mut self) -> Option<participant::Event> {
        Participant::poll_event(self)
    }
}

impl Node for Domain {
    type Addr = Locator;
    type Event = crate::dds::Event;
    fn owns(&self, to: &Locator) -> bool {
        owns(self.participant().config(), to)
    }
    /// User data waits while a keep-all reader is full
    /// ([`Domain::paused_reader`]); discovery is always read.
    fn reads(&self, to: &Locator) -> bool {
        self.paused_reader().is_none() || !self.participant().config().default_unicast.contains(to)
    }
    fn address(&self) -> Locator {
        address(self.participant().config())
    }
    fn handle_datagram(&mut self, from: Locator, bytes: &[u8], now: Instant) {
        Domain::handle_datagram(self, from, bytes, now);
    }
    fn handle_timeout(&mut self, now: Instant) {
        Domain::handle_timeout(self, now);
    }
    fn poll_timeout(&self) -> Option<Instant> {
        Domain::poll_timeout(self)
    }
    fn poll_transmit(&mut self) -> Option<(Locator, Vec<u8>)> {
        Domain::poll_transmit(self).map(split)
    }
    fn poll_event(&mut self) -> Option<crate::dds::Event> {
        Domain::poll_event(self)
    }
}
