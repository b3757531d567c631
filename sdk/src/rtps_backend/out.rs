//! The sending side, and where datagrams may go.

use std::collections::VecDeque;
use std::io::IoSlice;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};

use courier_wire::rtps::participant::Transmission;
use courier_wire::rtps::Locator;
use smallvec::SmallVec;

use crate::sys::net::{sendmmsg, SEND_SLOTS};

/// The sending side: the user-data unicast socket (every datagram goes
/// out from it), the rules on where datagrams may go, and the datagrams
/// queued to go out together.
pub(super) struct Out {
    sock: std::net::UdpSocket,
    loopback_only: bool,
    multicast: bool,
    /// Datagrams for one `sendmmsg`, in order, with their addresses; the
    /// first of them found the send buffer full when [`Out::send`] said
    /// `Err(Full)`.
    queued: VecDeque<(SocketAddrV4, Transmission)>,
    /// Datagrams not sent because of the loopback/multicast rules.
    pub(super) refused: u64,
    pub(super) send_errors: u64,
}

/// The send buffer is full: send the rest once the socket is writable.
pub(super) struct Full;

impl Out {
    pub(super) fn new(sock: std::net::UdpSocket, loopback_only: bool, multicast: bool) -> Self {
        Out {
            sock,
            loopback_only,
            multicast,
            queued: VecDeque::new(),
            refused: 0,
            send_errors: 0,
        }
    }

    fn allowed(&self, to: SocketAddr) -> Option<SocketAddrV4> {
        match to {
            SocketAddr::V4(a) => {
                let ip: Ipv4Addr = *a.ip();
                let ok = if ip.is_multicast() {
                    self.multicast && !self.loopback_only
                } else {
                    !self.loopback_only || ip.is_loopback()
                };
                ok.then_some(a)
            }
            SocketAddr::V6(_) => None,
        }
    }

    /// Whether [`Out::queue`] takes another datagram before a
    /// [`Out::send`] (one system call's worth).
    pub(super) fn has_room(&self) -> bool {
        self.queued.len() < SEND_SLOTS
    }

    /// Whether datagrams wait to be sent.
    pub(super) fn is_empty(&self) -> bool {
        self.queued.is_empty()
    }

    /// Queues a datagram for the next [`Out::send`], unless the rules
    /// refuse its destination.
    pub(super) fn queue(&mut self, t: Transmission) {
        match t.destination().socket_addr().and_then(|a| self.allowed(a)) {
            Some(to) => self.queued.push_back((to, t)),
            None => self.refused += 1,
        }
    }

    /// Drops the first queued datagram (it cannot be sent; reliable
    /// writers repair).
    pub(super) fn drop_first(&mut self) {
        if self.queued.pop_front().is_some() {
            self.send_errors += 1;
        }
    }

    /// Sends the queued datagrams without waiting (the socket may be in
    /// blocking mode for a receive thread: every send says
    /// `MSG_DONTWAIT`), all of them with one `sendmmsg` as a rule: on one
    /// CPU a reader woken by a sample's first datagram then finds the
    /// whole sample. Large sample data goes from the writer's history to
    /// the kernel without a copy (each datagram gathered from its
    /// [`Transmission::parts`]). `Err(Full)` when the send buffer is full,
    /// the rest still queued: call again once the socket is writable.
    pub(super) fn send(&mut self) -> Result<(), Full> {
        while !self.queued.is_empty() {
            match self.send_some() {
                Ok(n) => {
                    self.queued.drain(..n.min(self.queued.len()));
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Err(Full),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(_) => self.drop_first(),
            }
        }
        Ok(())
    }

    /// One `sendmmsg` of the first queued datagrams: how many went.
    fn send_some(&self) -> std::io::Result<usize> {
        // a few parts per datagram (2 per shared piece + 1), kept off the
        // heap for the usual batch
        let mut parts: SmallVec<[IoSlice<'_>; 4 * SEND_SLOTS]> = SmallVec::new();
        let mut ends: SmallVec<[usize; SEND_SLOTS]> = SmallVec::new();
        for (_, t) in self.queued.iter().take(SEND_SLOTS) {
            parts.extend(t.parts().map(IoSlice::new));
            ends.push(parts.len());
        }
        let mut from = 0;
        let msgs: SmallVec<[(SocketAddrV4, &[IoSlice<'_>]); SEND_SLOTS]> = self
            .queued
            .iter()
            .zip(&ends)
            .map(|((to, _), &end)| {
                let m = (*to, &parts[from..end]);
                from = end;
                m
            })
            .collect();
        sendmmsg(&self.sock, &msgs, DONTWAIT)
    }
}

#[cfg(unix)]
pub(super) const DONTWAIT: libc::c_int = libc::MSG_DONTWAIT;
#[cfg(not(unix))]
pub(super) const DONTWAIT: std::ffi::c_int = 0;

pub(super) fn locator_of(a: SocketAddr) -> Locator {
    match a {
        SocketAddr::V4(v) => Locator::udpv4(v.ip().octets(), v.port()),
        SocketAddr::V6(v) => Locator {
            kind: Locator::KIND_UDPV6,
            port: u32::from(v.port()),
            address: v.ip().octets(),
        },
    }
}
