//! The receive thread (`receive_thread=true`).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant;

use super::driver::Shared;
use super::net;

/// A thread that blocks in `recvmmsg` on the user-data socket and handles
/// what arrives right there: the participant under the [`Shared`] lock,
/// then the callbacks of immediate subscriptions, which can answer at
/// once ([`Publisher::try_publish`](crate::Publisher::try_publish)). This
/// is how ORTE, Cyclone DDS (listeners) and ddsperf receive; it saves the
/// wake-up of a task in a tokio runtime per datagram.
pub(super) struct ReceiveThread {
    /// `None` once joined.
    pub(super) handle: Option<std::thread::JoinHandle<()>>,
    /// Where a datagram wakes the thread to stop.
    pub(super) addr: SocketAddr,
    pub(super) shared: Arc<Shared>,
}

impl ReceiveThread {
    pub(super) fn start(
        shared: Arc<Shared>,
        sock: std::net::UdpSocket,
        name: &str,
    ) -> std::io::Result<Self> {
        sock.set_nonblocking(false)?;
        let addr = sock.local_addr()?;
        let s = shared.clone();
        let handle = std::thread::Builder::new()
            .name(format!("rtps-rx {name}"))
            .spawn(move || receive_loop(&s, &sock))?;
        Ok(ReceiveThread {
            handle: Some(handle),
            addr,
            shared,
        })
    }

    /// Tells the thread to stop, wherever it waits.
    pub(super) fn signal(&self) {
        use std::sync::atomic::Ordering;
        self.shared.closing.store(true, Ordering::SeqCst);
        self.shared.stopping.notify_waiters();
        // a datagram to its own socket wakes the blocking receive
        let woken =
            std::net::UdpSocket::bind((self.addr.ip(), 0)).and_then(|s| s.send_to(&[], self.addr));
        if let Err(e) = woken {
            tracing::warn!("cannot wake the RTPS receive thread ({e}); it ends with the process");
        }
    }

    /// Stops the thread and waits for it.
    pub(super) async fn stop(mut self) {
        self.signal();
        if let Some(h) = self.handle.take() {
            let _ = tokio::task::spawn_blocking(move || h.join()).await;
        }
    }
}

impl Drop for ReceiveThread {
    /// Without [`ReceiveThread::stop`] (the runtime went away with the
    /// driver task): the thread still ends, unwaited.
    fn drop(&mut self) {
        if self.handle.is_some() {
            self.signal();
        }
    }
}

fn receive_loop(shared: &Shared, sock: &std::net::UdpSocket) {
    use std::sync::atomic::Ordering;
    let mut batch = net::RecvBatch::new();
    let mut immediate = Vec::new();
    let mut wakes = Vec::new();
    loop {
        // an error (ICMP port unreachable and the like) reads nothing
        let n = net::recv_batch_blocking(sock, &mut batch).unwrap_or_default();
        if shared.closing.load(Ordering::SeqCst) {
            return;
        }
        let now = Instant::now();
        let (full, paused) = {
            let mut c = shared.lock();
            c.st.wakes = Some(std::mem::take(&mut wakes));
            c.receive(&batch, n, now);
            std::mem::swap(&mut immediate, &mut c.st.immediate);
            // with callbacks to run, what this produced (acknowledgements)
            // goes out after them, packed with their answers
            let full = immediate.is_empty() && c.flush(now).is_err();
            if immediate.is_empty() {
                c.rearm();
            }
            wakes = c.st.wakes.take().unwrap_or_default();
            (full, c.st.full_queue())
        };
        // a woken Subscriber's task (often on this CPU) runs once per batch,
        // and does not find the lock held
        for w in wakes.drain(..) {
            w.wake();
        }
        let full = full || shared.run_callbacks(&mut immediate).is_err();
        if full {
            // the driver waits for room and sends the rest
            shared.attention.notify_one();
        }
        let mut paused = paused;
        while let Some(q) = paused {
            // a Stream subscriber has not caught up: stop reading until it
            // has (the socket buffer, then the writer, hold the rest)
            let stopping = shared.stopping.notified();
            let mut stopping = std::pin::pin!(stopping);
            stopping.as_mut().enable(); // from here on no stop is missed
            if shared.closing.load(Ordering::SeqCst) {
                return;
            }
            // no runtime needed: both are woken by whoever acts
            futures::executor::block_on(async {
                tokio::select! {
                    _ = q.space() => {}
                    _ = stopping => {}
                }
            });
            paused = shared.lock().st.full_queue();
        }
    }
}
