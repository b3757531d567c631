//! Datagram links (UDP-like): each datagram is lost, duplicated or
//! delayed on its own, so datagrams arrive out of order.

use std::time::{Duration, Instant};

use super::{Net, Node};

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

/// Datagrams in flight: when each is due, and a serial number that keeps
/// the order of those due at the same instant.
pub(super) struct Queue<A> {
    queue: Vec<(Instant, u64, Packet<A>)>,
    serial: u64,
}

impl<A> Default for Queue<A> {
    fn default() -> Self {
        Queue {
            queue: Vec::new(),
            serial: 0,
        }
    }
}

impl<N: Node> Net<N> {
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
            self.datagrams.serial += 1;
            let serial = self.datagrams.serial;
            self.datagrams
                .queue
                .push((self.now + Duration::from_millis(delay), serial, p.clone()));
        }
    }

    /// Datagrams in flight (or waiting to be read).
    pub fn in_flight(&self) -> usize {
        self.datagrams.queue.len()
    }

    /// Whether a datagram to `to` would be read now: no up host that owns
    /// the address holds it back (or is frozen).
    fn readable(&self, to: &N::Addr) -> bool {
        self.hosts
            .iter()
            .all(|h| !h.up || !h.node.owns(to) || (!h.frozen && h.node.reads(to)))
    }

    /// Hands the datagrams that are due to their hosts; whether any was due.
    pub(super) fn deliver_datagrams(&mut self) -> bool {
        let now = self.now;
        let queue = std::mem::take(&mut self.datagrams.queue);
        let (mut due, rest): (Vec<_>, Vec<_>) = queue
            .into_iter()
            .partition(|(t, _, p)| *t <= now && self.readable(&p.to));
        self.datagrams.queue = rest;
        due.sort_by_key(|d| (d.0, d.1));
        let any = !due.is_empty();
        for (_, _, p) in due {
            for h in self.hosts.iter_mut().filter(|h| h.up) {
                if h.node.owns(&p.to) {
                    h.node.handle_datagram(p.from.clone(), &p.payload, now);
                }
            }
        }
        any
    }

    /// When the next datagram that will be read is due.
    pub(super) fn next_datagram(&self) -> Option<Instant> {
        self.datagrams
            .queue
            .iter()
            .filter(|(_, _, p)| self.readable(&p.to))
            .map(|d| d.0)
            .min()
    }
}
