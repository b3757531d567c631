//! The sending side, and where datagrams may go.

use std::io::IoSlice;
use std::net::{Ipv4Addr, SocketAddr};

use courier_wire::rtps::participant::Transmission;
use courier_wire::rtps::Locator;
use smallvec::SmallVec;

/// The sending side: the user-data unicast socket (every datagram goes
/// out from it) and the rules on where datagrams may go.
pub(super) struct Out {
    pub(super) sock: std::net::UdpSocket,
    pub(super) loopback_only: bool,
    pub(super) multicast: bool,
    /// Datagrams not sent because of the loopback/multicast rules.
    pub(super) refused: u64,
    pub(super) send_errors: u64,
}

/// A datagram that found the socket's send buffer full.
pub(super) struct Full;

impl Out {
    fn allowed(&self, to: SocketAddr) -> bool {
        match to {
            SocketAddr::V4(a) => {
                let ip: Ipv4Addr = *a.ip();
                if ip.is_multicast() {
                    self.multicast && !self.loopback_only
                } else {
                    !self.loopback_only || ip.is_loopback()
                }
            }
            SocketAddr::V6(_) => false,
        }
    }

    /// Sends one message without waiting (the socket may be in blocking
    /// mode for a receive thread: every send says `MSG_DONTWAIT`); large
    /// sample data goes from the writer's history to the kernel without a
    /// copy, with one vectored `sendmsg`. `Err(Full)` when the send buffer
    /// is full: send it again once the socket is writable.
    pub(super) fn try_send(&mut self, t: &Transmission) -> Result<(), Full> {
        let Some(addr) = t.destination().socket_addr().filter(|a| self.allowed(*a)) else {
            self.refused += 1;
            return Ok(());
        };
        // a few parts (2 per shared piece + 1), kept off the heap
        let parts: SmallVec<[IoSlice<'_>; 8]> = t.parts().map(IoSlice::new).collect();
        let to = socket2::SockAddr::from(addr);
        let sock = socket2::SockRef::from(&self.sock);
        let sent = match &parts[..] {
            [] => return Ok(()),
            [one] => sock.send_to_with_flags(one, &to, DONTWAIT),
            _ => sock.send_to_vectored_with_flags(&parts, &to, DONTWAIT),
        };
        match sent {
            Ok(_) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Err(Full),
            Err(_) => {
                self.send_errors += 1;
                Ok(())
            }
        }
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
