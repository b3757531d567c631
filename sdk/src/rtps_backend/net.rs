//! Sockets for an RTPS participant: interface selection, participant index
//! probing, multicast membership, buffer sizes.

use std::io;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};

use courier_wire::rtps::participant::{PortMapping, SPDP_MULTICAST_ADDRESS};
use socket2::{Domain, Protocol, Socket, Type};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// A participant's UDP socket, registered with tokio for reading only.
///
/// A socket registered for writability too is woken by the kernel (an
/// `EPOLLOUT` callback, then an event for tokio to process) every time a
/// sent datagram's buffer is freed, which on loopback is every send. Sends
/// go straight to the nonblocking socket instead; only a full send buffer
/// waits for room, through [`wait_writable`].
pub(crate) type UdpSocket = AsyncFd<std::net::UdpSocket>;

use super::options::RtpsOptions;

pub(crate) use crate::sys::net::interfaces;
use crate::sys::net::{register, register_for_room};

/// The IPv4 address RTPS options select: the named interface's
/// (`interface=lo`), a literal address, or by default the first up,
/// multicast-capable, non-loopback interface's, else 127.0.0.1. For
/// programs that open sockets of their own next to Courier's (the XRCE
/// agent).
pub fn interface_address(o: &RtpsOptions) -> Result<Ipv4Addr, String> {
    let ifs = interfaces().map_err(|e| format!("cannot list network interfaces: {e}"))?;
    match &o.interface {
        Some(name) => {
            if let Ok(a) = name.parse::<Ipv4Addr>() {
                if ifs.iter().any(|i| i.addr == a) {
                    return Ok(a);
                }
                return Err(format!("no interface has the address {a}"));
            }
            ifs.iter()
                .find(|i| &i.name == name)
                .map(|i| i.addr)
                .ok_or_else(|| {
                    let names: Vec<&str> = ifs.iter().map(|i| i.name.as_str()).collect();
                    format!(
                        "no IPv4 interface named {name:?} (there are: {})",
                        names.join(", ")
                    )
                })
        }
        None => Ok(ifs
            .iter()
            .find(|i| i.up && !i.loopback && i.multicast)
            .map(|i| i.addr)
            .unwrap_or(Ipv4Addr::LOCALHOST)),
    }
}

/// Receive buffer asked for when none is configured.
pub(crate) const DEFAULT_RECV_BUFFER: usize = 1 << 20;

fn udp(bind: SocketAddrV4, reuse: bool, o: &RtpsOptions) -> io::Result<Socket> {
    let s = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))?;
    if reuse {
        s.set_reuse_address(true)?;
        s.set_reuse_port(true)?;
    }
    // like Cyclone DDS: ask for 1 MiB unless told otherwise (the kernel caps
    // it at net.core.rmem_max); the default ~208 KiB loses a 200 KiB sample
    // sent as one burst of fragments
    s.set_recv_buffer_size(o.recv_buffer.unwrap_or(DEFAULT_RECV_BUFFER))?;
    if let Some(n) = o.send_buffer {
        s.set_send_buffer_size(n)?;
    }
    s.set_nonblocking(true)?;
    s.bind(&SocketAddr::V4(bind).into())?;
    Ok(s)
}

fn tokio_socket(s: Socket) -> io::Result<UdpSocket> {
    register_readable(s.into())
}

/// Registers a socket with tokio for reading (only).
pub(crate) fn register_readable(s: std::net::UdpSocket) -> io::Result<UdpSocket> {
    register(s, Interest::READABLE)
}

/// Waits until `sock` can take another datagram. The socket is registered
/// for reading only, so it is registered for room for as long as the wait
/// lasts ([`register_for_room`]; rare: a UDP send buffer is full only while
/// a NIC's queue is).
pub(crate) async fn wait_writable(sock: &std::net::UdpSocket) -> io::Result<()> {
    let _ready = register_for_room(sock)?.writable().await?;
    Ok(())
}

/// The sockets of one participant.
#[derive(Debug)]
pub(crate) struct Sockets {
    pub(crate) index: u32,
    /// SPDP/SEDP unicast (7410 + 2i).
    pub(crate) meta: UdpSocket,
    /// User data unicast (7411 + 2i); also the sending socket. Not
    /// registered with tokio yet: read by the driver
    /// ([`register_readable`]) or by a receive thread of its own.
    pub(crate) user: std::net::UdpSocket,
    /// SPDP multicast (7400), when multicast is on.
    pub(crate) meta_mc: Option<UdpSocket>,
    /// User data multicast (7401), when multicast is on.
    pub(crate) user_mc: Option<UdpSocket>,
}

/// Binds the unicast pair at the first free participant index (or the
/// fixed one), and the multicast sockets when asked.
pub(crate) fn open(o: &RtpsOptions, address: Ipv4Addr) -> Result<Sockets, String> {
    let m = PortMapping::STANDARD;
    let indices: Vec<u32> = match o.participant_index {
        Some(i) => vec![i],
        None => (0..=o.max_participant_index).collect(),
    };
    let mut last_err = String::from("no participant index to try");
    let mut found = None;
    for i in indices {
        let (Some(mp), Some(up)) = (
            m.metatraffic_unicast(o.domain, i),
            m.user_unicast(o.domain, i),
        ) else {
            last_err = format!("participant index {i} has no port in domain {}", o.domain);
            break;
        };
        let meta = match udp(SocketAddrV4::new(address, mp), false, o) {
            Ok(s) => s,
            Err(e) => {
                last_err = format!("{address}:{mp}: {e}");
                continue;
            }
        };
        match udp(SocketAddrV4::new(address, up), false, o) {
            Ok(user) => {
                found = Some((i, meta, user));
                break;
            }
            Err(e) => last_err = format!("{address}:{up}: {e}"),
        }
    }
    let (index, meta, user) = found.ok_or_else(|| {
        format!(
            "no free participant index in domain {} on {address} ({last_err})",
            o.domain
        )
    })?;
    let mut meta_mc = None;
    let mut user_mc = None;
    if o.multicast {
        let group = Ipv4Addr::from(SPDP_MULTICAST_ADDRESS);
        let mk = |port: u16| -> io::Result<Socket> {
            let s = udp(SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, port), true, o)?;
            s.join_multicast_v4(&group, &address)?;
            s.set_multicast_loop_v4(true)?;
            Ok(s)
        };
        let (sp, dp) = (
            m.spdp_multicast(o.domain).ok_or("no SPDP multicast port")?,
            m.user_multicast(o.domain).ok_or("no user multicast port")?,
        );
        meta_mc = Some(mk(sp).map_err(|e| format!("multicast {group}:{sp} on {address}: {e}"))?);
        user_mc = Some(mk(dp).map_err(|e| format!("multicast {group}:{dp} on {address}: {e}"))?);
        user.set_multicast_if_v4(&address)
            .map_err(|e| format!("IP_MULTICAST_IF {address}: {e}"))?;
        user.set_multicast_loop_v4(true)
            .map_err(|e| format!("IP_MULTICAST_LOOP: {e}"))?;
    }
    let t = |s: Socket| tokio_socket(s).map_err(|e| format!("socket: {e}"));
    Ok(Sockets {
        index,
        meta: t(meta)?,
        user: user.into(),
        meta_mc: meta_mc.map(t).transpose()?,
        user_mc: user_mc.map(t).transpose()?,
    })
}

/// Largest UDP datagram received.
pub(crate) const MAX_DATAGRAM: usize = 65_536;

/// Datagrams taken from a socket per system call at most.
pub(crate) const RECV_SLOTS: usize = 8;

/// Buffers for receiving up to [`RECV_SLOTS`] datagrams with one system
/// call (`recvmmsg` on Linux).
pub(crate) struct RecvBatch {
    bufs: Vec<Vec<u8>>,
    lens: [usize; RECV_SLOTS],
    from: [SocketAddr; RECV_SLOTS],
    n: usize,
}

impl RecvBatch {
    pub(crate) fn new() -> Self {
        RecvBatch {
            bufs: (0..RECV_SLOTS).map(|_| vec![0; MAX_DATAGRAM]).collect(),
            lens: [0; RECV_SLOTS],
            from: [SocketAddr::from(([0, 0, 0, 0], 0)); RECV_SLOTS],
            n: 0,
        }
    }

    /// Datagram `i` of the last [`recv_batch`] and its sender.
    pub(crate) fn get(&self, i: usize) -> (&[u8], SocketAddr) {
        (&self.bufs[i][..self.lens[i]], self.from[i])
    }
}

/// Takes the datagrams waiting on `sock`, up to [`RECV_SLOTS`], without
/// blocking; `Ok(0)` when none was waiting. When fewer than a full batch
/// were waiting the socket's readiness is cleared at once (the queue was
/// seen empty), so that a lone datagram costs one receive call, not a
/// second one that answers `EAGAIN`.
#[cfg(target_os = "linux")]
pub(crate) fn recv_batch(sock: &UdpSocket, b: &mut RecvBatch) -> io::Result<usize> {
    b.n = 0;
    let r = sock.try_io(Interest::READABLE, |s| {
        let n = recvmmsg(s, b, libc::MSG_DONTWAIT)?;
        if n < RECV_SLOTS {
            // the queue was empty after these: let tokio wait for the next
            // arrival (edge-triggered; a datagram that came meanwhile has
            // already made a newer readiness event, which this does not clear)
            Err(io::ErrorKind::WouldBlock.into())
        } else {
            Ok(())
        }
    });
    match r {
        Ok(()) => Ok(b.n),
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(b.n),
        Err(e) => Err(e),
    }
}

/// Takes the datagrams waiting on `sock`, up to [`RECV_SLOTS`], without
/// blocking and without tokio (whose readiness it leaves alone): for a
/// session closing after its runtime shut down.
#[cfg(target_os = "linux")]
pub(crate) fn recv_batch_now(sock: &std::net::UdpSocket, b: &mut RecvBatch) -> io::Result<usize> {
    b.n = 0;
    match recvmmsg(sock, b, libc::MSG_DONTWAIT) {
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(0),
        r => r,
    }
}

/// Waits for at least one datagram on a blocking socket, then takes what
/// else is waiting, up to [`RECV_SLOTS`] (one `recvmmsg` with
/// `MSG_WAITFORONE`).
#[cfg(target_os = "linux")]
pub(crate) fn recv_batch_blocking(
    sock: &std::net::UdpSocket,
    b: &mut RecvBatch,
) -> io::Result<usize> {
    b.n = 0;
    loop {
        match recvmmsg(sock, b, libc::MSG_WAITFORONE) {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            r => return r,
        }
    }
}

/// One `recvmmsg` into `b`'s buffers; sets `b.n`.
#[cfg(target_os = "linux")]
fn recvmmsg(
    sock: &std::net::UdpSocket,
    b: &mut RecvBatch,
    flags: libc::c_int,
) -> io::Result<usize> {
    let n = crate::sys::net::recvmmsg(sock, &mut b.bufs, &mut b.lens, &mut b.from, flags)?;
    b.n = n;
    Ok(n)
}

/// Takes the datagrams waiting on `sock`, up to [`RECV_SLOTS`], without
/// blocking (one `recvfrom` each); `Ok(0)` when none was waiting.
#[cfg(not(target_os = "linux"))]
pub(crate) fn recv_batch(sock: &UdpSocket, b: &mut RecvBatch) -> io::Result<usize> {
    fill(b, |buf| {
        sock.try_io(Interest::READABLE, |s| s.recv_from(buf))
    })
}

/// Takes the datagrams waiting on `sock` (non-blocking, as the
/// participant's sockets are), up to [`RECV_SLOTS`], without tokio.
#[cfg(not(target_os = "linux"))]
pub(crate) fn recv_batch_now(sock: &std::net::UdpSocket, b: &mut RecvBatch) -> io::Result<usize> {
    fill(b, |buf| sock.recv_from(buf))
}

/// Fills `b` with what `recv` takes, one datagram a call, until it would
/// block or the batch is full.
#[cfg(not(target_os = "linux"))]
fn fill(
    b: &mut RecvBatch,
    mut recv: impl FnMut(&mut [u8]) -> io::Result<(usize, SocketAddr)>,
) -> io::Result<usize> {
    b.n = 0;
    while b.n < RECV_SLOTS {
        match recv(&mut b.bufs[b.n]) {
            Ok((len, from)) => {
                b.lens[b.n] = len;
                b.from[b.n] = from;
                b.n += 1;
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
            Err(e) if b.n == 0 => return Err(e),
            Err(_) => break,
        }
    }
    Ok(b.n)
}

/// Waits for one datagram on a blocking socket.
#[cfg(not(target_os = "linux"))]
pub(crate) fn recv_batch_blocking(
    sock: &std::net::UdpSocket,
    b: &mut RecvBatch,
) -> io::Result<usize> {
    let (len, from) = sock.recv_from(&mut b.bufs[0])?;
    b.lens[0] = len;
    b.from[0] = from;
    b.n = 1;
    Ok(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn bound() -> UdpSocket {
        let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        s.set_nonblocking(true).unwrap();
        register(s, Interest::READABLE).unwrap()
    }

    /// A socket registered for reading only can still wait for room to
    /// send (through a registered duplicate), again and again.
    #[tokio::test]
    async fn a_read_only_socket_waits_for_room_to_send() {
        let s = bound();
        for _ in 0..3 {
            tokio::time::timeout(Duration::from_secs(5), wait_writable(s.get_ref()))
                .await
                .expect("an empty send buffer has room")
                .unwrap();
        }
    }

    /// Datagrams sent past tokio arrive through the read-only registration:
    /// a batch read takes them, and once the queue is seen empty the
    /// socket waits for the next one.
    #[tokio::test]
    async fn datagrams_arrive_through_the_read_only_registration() {
        let rx = bound();
        let tx = bound();
        let to = rx.get_ref().local_addr().unwrap();
        let mut b = RecvBatch::new();
        for round in 0..3u8 {
            for i in 0..3u8 {
                tx.get_ref().send_to(&[round, i], to).unwrap();
            }
            let mut got = Vec::new();
            while got.len() < 3 {
                tokio::time::timeout(Duration::from_secs(5), async {
                    let _ready = rx.readable().await.unwrap();
                })
                .await
                .expect("readable");
                let n = recv_batch(&rx, &mut b).unwrap();
                got.extend((0..n).map(|k| b.get(k).0.to_vec()));
            }
            assert_eq!(got, vec![vec![round, 0], vec![round, 1], vec![round, 2]]);
            assert_eq!(recv_batch(&rx, &mut b).unwrap(), 0, "nothing left");
        }
    }
}
