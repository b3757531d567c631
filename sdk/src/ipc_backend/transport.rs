//! The byte streams a session talks IPC over: TCP (with quick
//! acknowledgements for bulk reads) or the UNIX socket `/tmp/x_ipc/<port>`
//! ([`Unix`]: woken only for what it reads), and vectored writes that keep every
//! byte across partial writes.

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};

use super::unix_stream::Unix;

use super::{is_local_name, local_host_name};

/// A byte stream to central: what a connected socket offers.
pub trait IpcStream: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> IpcStream for T {}

/// A TCP connection of the IPC backend: `TCP_NODELAY`, and what it reads
/// is acknowledged at once every [`QUICK_ACK_EVERY`] bytes
/// (`TCP_QUICKACK`).
///
/// Why the acknowledgement: the C library (central and modules alike) sets
/// 16 KiB socket buffers on its TCP connections, so a C peer sending a large
/// message has at most ~32 KiB unacknowledged before it must wait for an
/// ACK. Our receive buffer is the system's (autotuned, large), so reading
/// that data never opens the window "significantly", and once this side
/// has sent anything (a Success, a reply) Linux treats the connection as
/// interactive and delays the ACK by its 40 ms minimum: each ~32 KiB of a
/// large message from a C peer cost 40 ms (a stream of 64 KiB messages
/// from the C central ran at 23 msg/s, a 1 MiB query took 660 ms).
///
/// Small messages do not need it (the ACK rides on the answer), and an ACK
/// of its own for each of them would cost a packet per message, hence the
/// byte count: a peer can only be stalled with at least its send buffer
/// unacknowledged, and Linux's smallest is 4608 bytes.
pub(super) struct Tcp {
    s: tokio::net::TcpStream,
    /// Bytes read since the last `TCP_QUICKACK`.
    unacked: usize,
}

/// See [`Tcp`].
pub(super) const QUICK_ACK_EVERY: usize = 4096;

impl Tcp {
    pub(super) fn new(s: tokio::net::TcpStream) -> std::io::Result<Tcp> {
        s.set_nodelay(true)?;
        Ok(Tcp { s, unacked: 0 })
    }
}

impl AsyncRead for Tcp {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = std::pin::Pin::new(&mut self.s).poll_read(cx, buf);
        if let std::task::Poll::Ready(Ok(())) = r {
            self.unacked += buf.filled().len() - before;
            if self.unacked >= QUICK_ACK_EVERY {
                self.unacked = 0;
                quick_ack(&self.s);
            }
        }
        r
    }
}

#[cfg(any(target_os = "linux", target_os = "android"))]
pub(super) fn quick_ack(s: &tokio::net::TcpStream) {
    // Best effort: failing costs only the delay this avoids.
    let _ = socket2::SockRef::from(s).set_tcp_quickack(true);
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
pub(super) fn quick_ack(_: &tokio::net::TcpStream) {}

impl AsyncWrite for Tcp {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.s).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.s).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.s.is_write_vectored()
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.s).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.s).poll_shutdown(cx)
    }
}

/// Central's host name did not resolve (or resolved to no address): the
/// error [`open`] wraps in an `io::Error`, so that connecting gives up at
/// once instead of retrying what no retry mends ([`is_unresolved`]).
#[derive(Debug)]
pub(super) struct Unresolved(String);

impl std::fmt::Display for Unresolved {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Unresolved {}

/// Whether `e` says that central's host name does not resolve.
pub(super) fn is_unresolved(e: &std::io::Error) -> bool {
    e.get_ref().is_some_and(|i| i.is::<Unresolved>())
}

pub(super) async fn open(host: &str, port: u16) -> std::io::Result<Box<dyn IpcStream>> {
    if is_local_name(host, &local_host_name()) {
        if let Ok(s) = tokio::net::UnixStream::connect(format!("/tmp/x_ipc/{port}")).await {
            return Ok(Box::new(Unix::new(s)?));
        }
    }
    // Resolve first, apart from connecting: a name that does not resolve
    // is told from a central that does not answer (yet).
    let unresolved = |kind, why: String| {
        std::io::Error::new(kind, Unresolved(format!("cannot resolve {host:?}: {why}")))
    };
    let addrs: Vec<std::net::SocketAddr> = tokio::net::lookup_host((host, port))
        .await
        .map_err(|e| unresolved(e.kind(), e.to_string()))?
        .collect();
    let mut last = None;
    for a in addrs {
        match tokio::net::TcpStream::connect(a).await {
            Ok(s) => return Ok(Box::new(Tcp::new(s)?)),
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| unresolved(std::io::ErrorKind::NotFound, "no address".into())))
}

/// Writes `bufs` one after the other, with as few system calls as the
/// socket takes (a large message's header and data go out together).
pub(super) async fn write_all_vectored<W: AsyncWrite + Unpin + ?Sized>(
    w: &mut W,
    bufs: &[Vec<u8>],
) -> std::io::Result<()> {
    /// Slices per call: well under any system's `IOV_MAX`.
    const MAX_SLICES: usize = 64;
    let (mut i, mut off) = (0, 0);
    while i < bufs.len() {
        let slices: Vec<std::io::IoSlice<'_>> = std::iter::once(&bufs[i][off..])
            .chain(bufs[i + 1..].iter().map(|b| &b[..]))
            .take(MAX_SLICES)
            .map(std::io::IoSlice::new)
            .collect();
        let mut n = w.write_vectored(&slices).await?;
        if n == 0 && slices.iter().any(|s| !s.is_empty()) {
            return Err(std::io::ErrorKind::WriteZero.into());
        }
        while i < bufs.len() && off + n >= bufs[i].len() {
            n -= bufs[i].len() - off;
            i += 1;
            off = 0;
        }
        off += n;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncReadExt;

    /// Takes at most `step` bytes per write, vectored.
    struct Trickle {
        got: Vec<u8>,
        step: usize,
        calls: usize,
    }

    impl AsyncWrite for Trickle {
        fn poll_write(
            self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
            buf: &[u8],
        ) -> std::task::Poll<std::io::Result<usize>> {
            self.poll_write_vectored(cx, &[std::io::IoSlice::new(buf)])
        }

        fn poll_write_vectored(
            mut self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
            bufs: &[std::io::IoSlice<'_>],
        ) -> std::task::Poll<std::io::Result<usize>> {
            self.calls += 1;
            let mut n = 0;
            for b in bufs {
                let k = b.len().min(self.step - n);
                self.got.extend_from_slice(&b[..k]);
                n += k;
                if n == self.step {
                    break;
                }
            }
            std::task::Poll::Ready(Ok(n))
        }

        fn is_write_vectored(&self) -> bool {
            true
        }

        fn poll_flush(
            self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::task::Poll::Ready(Ok(()))
        }

        fn poll_shutdown(
            self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::task::Poll::Ready(Ok(()))
        }
    }

    #[tokio::test]
    pub(super) async fn vectored_writes_keep_every_byte_in_order_across_partial_writes() {
        let bufs: Vec<Vec<u8>> = [0usize, 28, 0, 1, 70_000, 3, 0]
            .iter()
            .enumerate()
            .map(|(i, &n)| (0..n).map(|k| (k * 7 + i) as u8).collect())
            .collect();
        let whole = bufs.concat();
        for step in [1, 5, 28, 29, 4096, 1 << 20] {
            let mut w = Trickle {
                got: Vec::new(),
                step,
                calls: 0,
            };
            write_all_vectored(&mut w, &bufs).await.unwrap();
            assert_eq!(w.got, whole, "step {step}");
            if step == 1 << 20 {
                assert_eq!(w.calls, 1, "one call when the socket takes it all");
            }
        }
        let many: Vec<Vec<u8>> = (0..200u8).map(|i| vec![i; 3]).collect();
        let mut w = Trickle {
            got: Vec::new(),
            step: 1 << 20,
            calls: 0,
        };
        write_all_vectored(&mut w, &many).await.unwrap();
        assert_eq!(w.got, many.concat());
        assert_eq!(w.calls, 4, "64 slices per call");
    }

    /// Whether the kernel would acknowledge at once (`TCP_QUICKACK` read
    /// back: not in its "interactive" delayed-ACK mode).
    #[cfg(target_os = "linux")]
    fn acks_at_once(s: &tokio::net::TcpStream) -> bool {
        socket2::SockRef::from(s).tcp_quickack().unwrap()
    }

    /// Drives `ours` (read through `read`) into Linux's interactive mode
    /// with a few small exchanges, then has the peer send `big` bytes and
    /// reads them; returns whether `ours` acknowledges at once afterwards,
    /// and whether it did after the small exchanges.
    #[cfg(target_os = "linux")]
    pub(super) async fn after_exchanges<S: AsyncRead + AsyncWrite + Unpin>(
        ours: &mut S,
        peer: &mut tokio::net::TcpStream,
        big: usize,
        probe: impl Fn(&S) -> bool,
    ) -> (bool, bool) {
        let mut buf = vec![0u8; 64 * 1024];
        for _ in 0..5 {
            peer.write_all(&[1; 48]).await.unwrap();
            ours.read_exact(&mut buf[..48]).await.unwrap();
            ours.write_all(&[2; 28]).await.unwrap();
            peer.read_exact(&mut buf[..28]).await.unwrap();
        }
        let small = probe(ours);
        peer.write_all(&vec![3; big]).await.unwrap();
        ours.read_exact(&mut buf[..big]).await.unwrap();
        (small, probe(ours))
    }

    /// The C library's 16 KiB send buffers stall on our delayed ACKs (see
    /// [`Tcp`]); the exchange below puts a plain socket in the mode that
    /// delays them, so that the check on `Tcp` cannot pass vacuously.
    #[cfg(target_os = "linux")]
    #[tokio::test]
    pub(super) async fn tcp_reads_of_bulk_data_are_acknowledged_at_once() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        let pair = || async {
            let s = tokio::net::TcpStream::connect(addr).await.unwrap();
            let (peer, _) = l.accept().await.unwrap();
            peer.set_nodelay(true).unwrap();
            (s, peer)
        };
        // The kernel leaves the delayed-ACK mode by itself when its 40 ms
        // timer fires; a test thread descheduled that long on a loaded
        // machine would see that, so a few attempts are allowed.
        for _ in 0..5 {
            let (plain, mut peer) = pair().await;
            plain.set_nodelay(true).unwrap();
            let mut plain = plain;
            let (_, plain_after) = after_exchanges(&mut plain, &mut peer, 8192, acks_at_once).await;

            let (s, mut peer) = pair().await;
            let mut ours = Tcp::new(s).unwrap();
            let (small, after) =
                after_exchanges(&mut ours, &mut peer, 8192, |t: &Tcp| acks_at_once(&t.s)).await;
            if plain_after || small {
                continue;
            }
            assert!(after, "bulk data read through Tcp left the ACK delayed");
            return;
        }
        panic!(
            "the exchange never left a plain socket (or Tcp after small messages) in \
             delayed-ACK mode: this test would check nothing"
        );
    }
}
