//! The links to an agent: UDP (one message per datagram), TCP (2-byte
//! little-endian length before each message, prefix and message written
//! in one call, `TCP_NODELAY` on) and serial (HDLC-like framing with
//! CRC-16/ARC; this client is address 1, the agent 0).
//!
//! [`Link::recv`] is cancellation safe: the bytes a read took are kept in
//! the deframer, so the driver can `select!` on it.

use std::fs::File;
use std::io::{self, Read, Write};
use std::net::SocketAddr;

use courier_wire::xrce::serial::{self, SerialDecoder};
use courier_wire::xrce::tcp::{self, TcpDeframer};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpStream, UdpSocket};

use super::options::XrceTransport;

/// The serial address of this client and of the agent.
pub(crate) const SERIAL_CLIENT_ADDR: u8 = 1;
pub(crate) const SERIAL_AGENT_ADDR: u8 = 0;

/// An open link to the agent.
pub(crate) enum Link {
    Udp {
        socket: UdpSocket,
        /// An ICMP "port unreachable" came back since the agent last sent
        /// anything: nothing listens at its address (loopback reports it
        /// at once).
        refused: bool,
    },
    Tcp {
        stream: TcpStream,
        deframer: TcpDeframer,
        out: Vec<u8>,
    },
    Serial {
        fd: AsyncFd<File>,
        decoder: SerialDecoder,
        out: Vec<u8>,
    },
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Link::Udp { .. } => "Link::Udp",
            Link::Tcp { .. } => "Link::Tcp",
            Link::Serial { .. } => "Link::Serial",
        })
    }
}

async fn resolve(addr: &str) -> io::Result<SocketAddr> {
    tokio::net::lookup_host(addr)
        .await?
        .next()
        .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, format!("{addr}: no address")))
}

impl Link {
    /// Opens the link `t` names; `mtu` bounds what a frame may carry.
    pub(crate) async fn open(t: &XrceTransport, mtu: usize) -> io::Result<Link> {
        match t {
            XrceTransport::Udp(addr) => {
                let to = resolve(addr).await?;
                let any: SocketAddr = if to.is_ipv4() {
                    "0.0.0.0:0".parse().expect("literal")
                } else {
                    "[::]:0".parse().expect("literal")
                };
                let s = UdpSocket::bind(any).await?;
                s.connect(to).await?;
                Ok(Link::Udp {
                    socket: s,
                    refused: false,
                })
            }
            XrceTransport::Tcp(addr) => {
                let to = resolve(addr).await?;
                let stream = TcpStream::connect(to).await?;
                stream.set_nodelay(true)?;
                Ok(Link::Tcp {
                    stream,
                    deframer: TcpDeframer::with_max_len(usize::from(u16::MAX)),
                    out: Vec::with_capacity(mtu + tcp::PREFIX_SIZE),
                })
            }
            XrceTransport::Serial { path, baud } => {
                let file = crate::sys::tty::open_raw(path, *baud)?;
                Ok(Link::Serial {
                    fd: crate::sys::net::register(
                        file,
                        tokio::io::Interest::READABLE | tokio::io::Interest::WRITABLE,
                    )?,
                    decoder: SerialDecoder::with_max_payload(mtu.max(serial::DEFAULT_MAX_PAYLOAD)),
                    out: Vec::with_capacity(2 * mtu + 8),
                })
            }
        }
    }

    /// Whether losing the link loses the connection (TCP), so that it has
    /// to be opened again; a datagram socket or a tty stays usable.
    pub(crate) fn is_stream(&self) -> bool {
        matches!(self, Link::Tcp { .. })
    }

    /// A stream link part way through a record (see
    /// [`TcpDeframer::mid_record`]).
    pub(crate) fn mid_record(&self) -> bool {
        matches!(self, Link::Tcp { deframer, .. } if deframer.mid_record())
    }

    /// Whether the agent's address reported that nothing listens there
    /// (UDP's ICMP "port unreachable") since it last sent anything.
    pub(crate) fn unreachable(&self) -> bool {
        matches!(self, Link::Udp { refused: true, .. })
    }

    /// Sends one XRCE message.
    pub(crate) async fn send(&mut self, msg: &[u8]) -> io::Result<()> {
        match self {
            Link::Udp { socket, refused } => match socket.send(msg).await {
                Ok(_) => Ok(()),
                // nobody listens (yet): the machine's retries cover it
                Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                    *refused = true;
                    Ok(())
                }
                Err(e) => Err(e),
            },
            Link::Tcp { stream, out, .. } => {
                out.clear();
                tcp::encode(msg, out)
                    .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
                // prefix and message in one write
                stream.write_all(out).await
            }
            Link::Serial { fd, out, .. } => {
                out.clear();
                serial::encode(SERIAL_CLIENT_ADDR, SERIAL_AGENT_ADDR, msg, out)
                    .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
                let mut at = 0;
                while at < out.len() {
                    let mut guard = fd.writable().await?;
                    match guard.try_io(|f| f.get_ref().write(&out[at..])) {
                        Ok(Ok(n)) => at += n,
                        Ok(Err(e)) => return Err(e),
                        Err(_would_block) => continue,
                    }
                }
                Ok(())
            }
        }
    }

    /// The next XRCE message from the agent.
    pub(crate) async fn recv(&mut self, buf: &mut [u8]) -> io::Result<Vec<u8>> {
        match self {
            Link::Udp { socket, refused } => loop {
                match socket.recv(buf).await {
                    Ok(n) => {
                        *refused = false;
                        return Ok(buf[..n].to_vec());
                    }
                    // an ICMP "port unreachable" for an earlier datagram
                    Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => *refused = true,
                    Err(e) => return Err(e),
                }
            },
            Link::Tcp {
                stream, deframer, ..
            } => loop {
                match deframer.next_frame() {
                    Some(Ok(frame)) => return Ok(frame),
                    Some(Err(e)) => tracing::warn!("XRCE over TCP: {e}"),
                    None => {
                        let n = stream.read(buf).await?;
                        if n == 0 {
                            return Err(io::Error::new(
                                io::ErrorKind::UnexpectedEof,
                                "the agent closed the TCP connection",
                            ));
                        }
                        deframer.push(&buf[..n]);
                    }
                }
            },
            Link::Serial { fd, decoder, .. } => loop {
                match decoder.next_frame() {
                    Some(Ok(f)) if f.dst == SERIAL_CLIENT_ADDR => return Ok(f.payload),
                    Some(Ok(_)) => {}
                    Some(Err(e)) => tracing::debug!("XRCE serial line: {e}"),
                    None => {
                        let mut guard = fd.readable().await?;
                        match guard.try_io(|f| f.get_ref().read(buf)) {
                            Ok(Ok(0)) => {
                                // a pseudo-terminal without its other side
                                guard.clear_ready();
                                tokio::time::sleep(std::time::Duration::from_millis(20)).await;
                            }
                            Ok(Ok(n)) => decoder.push(&buf[..n]),
                            Ok(Err(e)) if e.raw_os_error() == Some(libc::EIO) => {
                                tokio::time::sleep(std::time::Duration::from_millis(20)).await;
                            }
                            Ok(Err(e)) => return Err(e),
                            Err(_would_block) => {}
                        }
                    }
                }
            },
        }
    }
}
