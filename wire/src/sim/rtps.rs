//! The RTPS participant and the DDS domain as datagram nodes.

use std::time::Instant;

use super::Node;
use crate::dds::Domain;
use crate::rtps::participant::{self, Datagram, Participant};
use crate::rtps::Locator;

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
