//! In-process links to an embedded central: a pair of bounded byte pipes in
//! place of a socket, for a module that runs in the process hosting
//! central (see [`CentralHandle::session`](super::CentralHandle::session)).
//!
//! The bytes are exactly those a socket would carry, so central and the
//! module run the unchanged protocol; what goes away is the loopback: no
//! system call per frame, and on a current-thread runtime no thread wake-up
//! either, only a task poll.

use std::collections::VecDeque;
use std::io::{self, IoSlice};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Bytes a pipe holds before its writer has to wait: like a socket buffer,
/// it bounds what a module that stops reading can cost.
pub(crate) const PIPE_CAPACITY: usize = 256 * 1024;

/// One direction: a bounded FIFO of bytes with one reader and one writer.
struct Pipe {
    state: Mutex<PipeState>,
}

struct PipeState {
    buf: VecDeque<u8>,
    cap: usize,
    reader: Option<Waker>,
    writer: Option<Waker>,
    /// The read end is gone: writes fail with `BrokenPipe`.
    read_closed: bool,
    /// The write end is gone or shut down: reads end (0) once drained.
    write_closed: bool,
}

impl Pipe {
    fn new(cap: usize) -> Arc<Pipe> {
        Arc::new(Pipe {
            state: Mutex::new(PipeState {
                buf: VecDeque::new(),
                cap,
                reader: None,
                writer: None,
                read_closed: false,
                write_closed: false,
            }),
        })
    }

    fn lock(&self) -> MutexGuard<'_, PipeState> {
        // Nothing here can panic while holding the lock; a poisoned lock
        // would still hold consistent bytes.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Copies what fits; `WouldBlock` when full, `BrokenPipe` when the
    /// reader is gone. Wakes the reader when bytes were added.
    fn try_write(&self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        self.write_with(bufs, None)
    }

    fn poll_write(&self, cx: &mut Context<'_>, bufs: &[IoSlice<'_>]) -> Poll<io::Result<usize>> {
        match self.write_with(bufs, Some(cx.waker())) {
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Poll::Pending,
            r => Poll::Ready(r),
        }
    }

    /// The write, under one lock; when full, `waker` (if any) is woken
    /// once there is room.
    fn write_with(&self, bufs: &[IoSlice<'_>], waker: Option<&Waker>) -> io::Result<usize> {
        let mut s = self.lock();
        if s.read_closed {
            return Err(io::ErrorKind::BrokenPipe.into());
        }
        if s.write_closed {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "write after shutdown",
            ));
        }
        if bufs.iter().all(|b| b.is_empty()) {
            return Ok(0);
        }
        let room = s.cap - s.buf.len();
        if room == 0 {
            if let Some(w) = waker {
                s.writer = Some(w.clone());
            }
            return Err(io::ErrorKind::WouldBlock.into());
        }
        let mut n = 0;
        for b in bufs {
            let k = b.len().min(room - n);
            s.buf.extend(&b[..k]);
            n += k;
            if n == room {
                break;
            }
        }
        let reader = s.reader.take();
        drop(s);
        if let Some(w) = reader {
            w.wake();
        }
        Ok(n)
    }

    /// Ready when there is room or the reader is gone (a write then fails).
    fn poll_writable(&self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let mut s = self.lock();
        if s.read_closed || s.buf.len() < s.cap {
            return Poll::Ready(Ok(()));
        }
        s.writer = Some(cx.waker().clone());
        Poll::Pending
    }

    fn poll_read(&self, cx: &mut Context<'_>, out: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let mut s = self.lock();
        if s.buf.is_empty() {
            if s.write_closed || out.remaining() == 0 {
                return Poll::Ready(Ok(()));
            }
            s.reader = Some(cx.waker().clone());
            return Poll::Pending;
        }
        let k = out.remaining().min(s.buf.len());
        let (a, b) = s.buf.as_slices();
        let from_a = k.min(a.len());
        out.put_slice(&a[..from_a]);
        out.put_slice(&b[..k - from_a]);
        s.buf.drain(..k);
        let writer = s.writer.take();
        drop(s);
        if let Some(w) = writer {
            w.wake();
        }
        Poll::Ready(Ok(()))
    }

    /// Ready when there are bytes or the writer is gone (a read then ends).
    fn poll_readable(&self, cx: &mut Context<'_>) -> Poll<()> {
        let mut s = self.lock();
        if !s.buf.is_empty() || s.write_closed {
            return Poll::Ready(());
        }
        s.reader = Some(cx.waker().clone());
        Poll::Pending
    }

    fn close_read(&self) {
        let mut s = self.lock();
        s.read_closed = true;
        s.buf = VecDeque::new();
        let w = s.writer.take();
        drop(s);
        if let Some(w) = w {
            w.wake();
        }
    }

    fn close_write(&self) {
        let mut s = self.lock();
        s.write_closed = true;
        let r = s.reader.take();
        drop(s);
        if let Some(r) = r {
            r.wake();
        }
    }
}

/// The module's end of an in-process link to central: a byte stream like a
/// connected socket (`AsyncRead + AsyncWrite`). Dropping it is a
/// disconnect; [`shutdown`](tokio::io::AsyncWriteExt::shutdown) closes the
/// direction towards central (central reads end of stream).
pub struct InProcessStream {
    rx: Arc<Pipe>,
    tx: Arc<Pipe>,
}

impl std::fmt::Debug for InProcessStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("InProcessStream").finish_non_exhaustive()
    }
}

impl AsyncRead for InProcessStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        self.rx.poll_read(cx, buf)
    }
}

impl AsyncWrite for InProcessStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.tx.poll_write(cx, &[IoSlice::new(buf)])
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.tx.poll_write(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        true
    }

    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.tx.close_write();
        Poll::Ready(Ok(()))
    }
}

impl Drop for InProcessStream {
    fn drop(&mut self) {
        self.rx.close_read();
        self.tx.close_write();
    }
}

/// Central's read end (what the module wrote).
pub(crate) struct ServerReader(Arc<Pipe>);

impl ServerReader {
    /// Ready when there are bytes to read or the module's end is closed;
    /// otherwise `cx` is woken when that happens.
    pub(crate) fn poll_readable(&mut self, cx: &mut Context<'_>) -> Poll<()> {
        self.0.poll_readable(cx)
    }

    /// Appends what is there now to `buf`, up to its capacity: 0 at the end
    /// of the stream, `WouldBlock` if nothing is there.
    pub(crate) fn try_read_spare(&mut self, buf: &mut Vec<u8>) -> io::Result<usize> {
        let mut s = self.0.lock();
        if s.buf.is_empty() {
            return if s.write_closed {
                Ok(0)
            } else {
                Err(io::ErrorKind::WouldBlock.into())
            };
        }
        let k = (buf.capacity() - buf.len()).min(s.buf.len());
        buf.extend(s.buf.drain(..k));
        let writer = s.writer.take();
        drop(s);
        if let Some(w) = writer {
            w.wake();
        }
        Ok(k)
    }

    /// Waits for bytes, then reads them (0: end of stream).
    #[cfg(test)]
    pub(crate) async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            std::future::poll_fn(|cx| self.poll_readable(cx)).await;
            let mut v = Vec::with_capacity(buf.len());
            match self.try_read_spare(&mut v) {
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => continue,
                Err(e) => return Err(e),
                Ok(n) => {
                    buf[..n].copy_from_slice(&v);
                    return Ok(n);
                }
            }
        }
    }
}

impl Drop for ServerReader {
    fn drop(&mut self) {
        self.0.close_read();
    }
}

/// Central's write end (towards the module).
pub(crate) struct ServerWriter(Arc<Pipe>);

impl ServerWriter {
    pub(crate) fn try_write_vectored(&self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        self.0.try_write(bufs)
    }

    pub(crate) async fn writable(&self) -> io::Result<()> {
        std::future::poll_fn(|cx| self.0.poll_writable(cx)).await
    }
}

impl Drop for ServerWriter {
    fn drop(&mut self) {
        self.0.close_write();
    }
}

/// Central's end of a link, before it is split.
pub(crate) struct ServerEnd {
    pub(crate) reader: ServerReader,
    pub(crate) writer: ServerWriter,
}

impl std::fmt::Debug for ServerEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServerEnd").finish_non_exhaustive()
    }
}

/// A connected pair: the module's stream and central's end.
pub(crate) fn link(cap: usize) -> (InProcessStream, ServerEnd) {
    let up = Pipe::new(cap); // module → central
    let down = Pipe::new(cap); // central → module
    (
        InProcessStream {
            rx: down.clone(),
            tx: up.clone(),
        },
        ServerEnd {
            reader: ServerReader(up),
            writer: ServerWriter(down),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[tokio::test]
    async fn bytes_cross_in_order_both_ways() {
        let (mut m, mut c) = link(16);
        m.write_all(b"hello central").await.unwrap();
        let mut b = [0u8; 64];
        let n = c.reader.read(&mut b).await.unwrap();
        assert_eq!(&b[..n], b"hello central");
        let n = c
            .writer
            .try_write_vectored(&[IoSlice::new(b"hi "), IoSlice::new(b"module")])
            .unwrap();
        assert_eq!(n, 9);
        let mut got = [0u8; 9];
        m.read_exact(&mut got).await.unwrap();
        assert_eq!(&got, b"hi module");
    }

    #[tokio::test]
    async fn a_full_pipe_pushes_back_and_resumes_when_read() {
        let (mut m, mut c) = link(8);
        assert_eq!(
            c.writer
                .try_write_vectored(&[IoSlice::new(&[1; 12])])
                .unwrap(),
            8
        );
        let e = c
            .writer
            .try_write_vectored(&[IoSlice::new(&[2])])
            .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::WouldBlock);
        let mut b = [0u8; 5];
        m.read_exact(&mut b).await.unwrap();
        tokio::time::timeout(std::time::Duration::from_secs(5), c.writer.writable())
            .await
            .expect("room after a read")
            .unwrap();
        assert_eq!(
            c.writer
                .try_write_vectored(&[IoSlice::new(&[3; 9])])
                .unwrap(),
            5
        );

        // The module's writes wait for central to read.
        let big = vec![9u8; 20];
        let w = tokio::spawn(async move {
            m.write_all(&big).await.unwrap();
            m
        });
        let mut got = Vec::new();
        while got.len() < 20 {
            let mut b = [0u8; 3];
            let n = c.reader.read(&mut b).await.unwrap();
            got.extend_from_slice(&b[..n]);
        }
        assert_eq!(got, vec![9u8; 20]);
        w.await.unwrap();
    }

    #[tokio::test]
    async fn dropping_either_end_is_seen_by_the_other() {
        let (m, mut c) = link(8);
        drop(m);
        let mut b = [0u8; 4];
        assert_eq!(c.reader.read(&mut b).await.unwrap(), 0, "end of stream");
        let e = c
            .writer
            .try_write_vectored(&[IoSlice::new(b"x")])
            .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::BrokenPipe);
        assert!(
            c.writer.writable().await.is_ok(),
            "ready, so the writer sees the error"
        );

        let (mut m, c) = link(8);
        c.writer
            .try_write_vectored(&[IoSlice::new(b"last")])
            .unwrap();
        drop(c);
        let mut rest = Vec::new();
        m.read_to_end(&mut rest).await.unwrap();
        assert_eq!(
            rest, b"last",
            "what was written before the close is still read"
        );
        let e = m.write_all(b"x").await.unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::BrokenPipe);
    }
}
