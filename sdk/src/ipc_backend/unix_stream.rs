//! The IPC backend's UNIX-socket connections (to central's
//! `/tmp/x_ipc/<port>` and direct links): registered with tokio's reactor
//! for read readiness only, and for write readiness only while a write
//! waits for room.

use std::io::{self, IoSlice, Read};
use std::os::fd::OwnedFd;
use std::os::unix::net::UnixStream;
use std::pin::Pin;
use std::task::{ready, Context, Poll};

use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};

use crate::sys::net::{register, register_for_room};

/// A UNIX-socket connection registered with the reactor for read
/// readiness only, and for write readiness only while a write waits for
/// room.
///
/// Why: a UNIX socket tells its writer that there is room again each time
/// the peer reads what it was sent, so a socket registered for both (as
/// `tokio::net::UnixStream` is) wakes its session's thread once more per
/// message it sends — when the session is asleep waiting for the answer,
/// at the moment the peer is running. (TCP sockets report room only after
/// a write found none.) Measured on a module sending 4 B queries to
/// Courier's central over the UNIX socket (BENCHMARKS.md §4.1.2, medians):
/// context switches per round trip 1.79 → 1.02, the module's CPU per round
/// trip 32.4 → 26.9 µs. Central's own sockets are registered the same way
/// (`central::server`'s `Sock`).
pub(crate) struct Unix {
    fd: AsyncFd<UnixStream>,
    /// While a write waits for room: its registration
    /// ([`register_for_room`]).
    room: Option<AsyncFd<OwnedFd>>,
}

impl Unix {
    pub(crate) fn new(s: tokio::net::UnixStream) -> io::Result<Unix> {
        // non-blocking, as tokio left it
        let s = s.into_std()?;
        Ok(Unix {
            fd: register(s, Interest::READABLE)?,
            room: None,
        })
    }

    /// Runs `op` (a send) until it does not find the socket full, waiting
    /// for room in between.
    fn poll_send(
        &mut self,
        cx: &mut Context<'_>,
        op: impl Fn(socket2::SockRef<'_>) -> io::Result<usize>,
    ) -> Poll<io::Result<usize>> {
        loop {
            match op(socket2::SockRef::from(self.fd.get_ref())) {
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                done => {
                    self.room = None;
                    return Poll::Ready(done);
                }
            }
            let room = match &mut self.room {
                Some(r) => r,
                r @ None => r.insert(register_for_room(self.fd.get_ref())?),
            };
            ready!(room.poll_write_ready(cx))?.clear_ready();
        }
    }
}

/// Sends never raise `SIGPIPE`: a peer that went away is an error.
const SEND_FLAGS: libc::c_int = libc::MSG_NOSIGNAL;

impl AsyncRead for Unix {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut ready = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let room = unfilled.len();
            match ready.try_io(|s| (&mut s.get_ref()).read(unfilled)) {
                Ok(Ok(n)) => {
                    // A short read emptied the socket: wait for the next
                    // edge rather than read again to find nothing (as
                    // tokio's own streams do; an edge that came in between
                    // is not lost, readiness is cleared by its tick).
                    if n > 0 && n < room {
                        ready.clear_ready();
                    }
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                // readiness cleared; wait for the next
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for Unix {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.poll_send(cx, |s| s.send_with_flags(buf, SEND_FLAGS))
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.poll_send(cx, |s| s.send_vectored_with_flags(bufs, SEND_FLAGS))
    }

    fn is_write_vectored(&self) -> bool {
        true
    }

    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(self.fd.get_ref().shutdown(std::net::Shutdown::Write))
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use std::os::fd::{AsRawFd, RawFd};
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    const EPOLLIN: u32 = libc::EPOLLIN as u32;
    const EPOLLOUT: u32 = libc::EPOLLOUT as u32;

    /// The event masks this process's epoll instances hold for `fd`, read
    /// from `/proc/self/fdinfo` (`tfd: <fd> events: <hex mask> data: <key>`).
    /// An instance open under two descriptors (tokio's reactor is) is seen
    /// twice, so registrations are told apart by their key.
    fn epoll_masks(fd: RawFd) -> Vec<u32> {
        let mut seen = std::collections::HashSet::new();
        for e in std::fs::read_dir("/proc/self/fd").unwrap().flatten() {
            let is_epoll = std::fs::read_link(e.path())
                .is_ok_and(|l| l.to_string_lossy() == "anon_inode:[eventpoll]");
            let path = format!("/proc/self/fdinfo/{}", e.file_name().to_string_lossy());
            let Some(info) = is_epoll
                .then(|| std::fs::read_to_string(path).ok())
                .flatten()
            else {
                continue;
            };
            for l in info.lines() {
                let w: Vec<&str> = l.split_whitespace().collect();
                if let ["tfd:", tfd, "events:", mask, "data:", key, ..] = w[..] {
                    if tfd.parse() == Ok(fd) {
                        seen.insert((u32::from_str_radix(mask, 16).unwrap(), key.to_string()));
                    }
                }
            }
        }
        seen.into_iter().map(|(m, _)| m).collect()
    }

    #[tokio::test]
    async fn a_unix_stream_asks_for_write_readiness_only_while_a_write_waits() {
        // What this guards against, and proof that the probe sees it:
        // tokio's own stream asks for both.
        let (plain, _plain_peer) = tokio::net::UnixStream::pair().unwrap();
        let m = epoll_masks(plain.as_raw_fd());
        assert!(
            m.iter().any(|m| m & EPOLLOUT != 0),
            "tokio's UnixStream is registered with {m:x?}, without write readiness: \
             the probe is broken, or tokio changed and Unix may no longer be needed"
        );

        let (a, mut peer) = tokio::net::UnixStream::pair().unwrap();
        let mut ours = Unix::new(a).unwrap();
        let fd = ours.fd.get_ref().as_raw_fd();
        let m = epoll_masks(fd);
        assert_eq!(m.len(), 1, "one registration expected, found {m:x?}");
        assert!(
            m[0] & EPOLLIN != 0 && m[0] & EPOLLOUT == 0,
            "registered with {:x}",
            m[0]
        );

        // Fill the socket until a write waits.
        let chunk = vec![7u8; 64 * 1024];
        let mut sent = 0;
        loop {
            match tokio::time::timeout(Duration::from_millis(50), ours.write(&chunk)).await {
                Ok(n) => sent += n.unwrap(),
                Err(_) => break,
            }
            assert!(sent < 64 << 20, "the socket never filled");
        }
        let dup = ours
            .room
            .as_ref()
            .expect("a waiting write registers for room")
            .get_ref()
            .as_raw_fd();
        assert_ne!(dup, fd);
        let m = epoll_masks(dup);
        assert!(
            m.len() == 1 && m[0] & EPOLLOUT != 0,
            "the waiting write's registration: {m:x?}"
        );
        assert!(epoll_masks(fd).iter().all(|m| m & EPOLLOUT == 0));

        // The peer takes everything; the waiting write then goes through,
        // and the registration for room is gone.
        let reader = tokio::spawn(async move {
            let mut got = vec![0u8; sent + chunk.len()];
            peer.read_exact(&mut got).await.unwrap();
            assert!(got.iter().all(|&b| b == 7));
            peer
        });
        let chunk = vec![7u8; 64 * 1024];
        tokio::time::timeout(Duration::from_secs(10), ours.write_all(&chunk))
            .await
            .expect("the write waited on after the peer read")
            .unwrap();
        assert!(
            ours.room.is_none(),
            "the registration for room outlived the wait"
        );
        let mut peer = tokio::time::timeout(Duration::from_secs(10), reader)
            .await
            .unwrap()
            .unwrap();

        // Both ways, vectored, then the ends.
        let bufs = [IoSlice::new(b"head"), IoSlice::new(b"-body")];
        let n = ours.write_vectored(&bufs).await.unwrap();
        let mut got = vec![0u8; n];
        peer.read_exact(&mut got).await.unwrap();
        assert_eq!(&got, &b"head-body"[..n]);
        peer.write_all(b"answer").await.unwrap();
        let mut got = [0u8; 6];
        ours.read_exact(&mut got).await.unwrap();
        assert_eq!(&got, b"answer");
        ours.shutdown().await.unwrap();
        assert_eq!(
            peer.read(&mut got).await.unwrap(),
            0,
            "shutdown did not end the peer's reads"
        );
        drop(peer);
        assert_eq!(
            ours.read(&mut got).await.unwrap(),
            0,
            "the peer's close did not end our reads"
        );
        let e = ours.write(b"late").await.unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::BrokenPipe, "{e}");
    }
}
