//! The driver task: sockets, timers and commands around the [`State`].

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot};

use super::cmd::{disconnected, Cmd, Done};
use super::net::{self, UdpSocket};
use super::out::{locator_of, Full, Out};
use super::receive::ReceiveThread;
use super::state::State;
use crate::busy_poll::BusyPoll;
use crate::driver_timer;
use crate::session::SampleQueue;

/// The socket has data. The driver is its only reader, so it waits in the
/// socket's one read-waker slot (`poll_read_ready`), not in the list of
/// waiters that `readable()` joins and leaves on every turn.
async fn recv_ready(s: &UdpSocket) -> std::io::Result<()> {
    // the guard is dropped without clearing: `recv_batch` clears readiness
    // when it finds the queue empty
    std::future::poll_fn(|cx| s.poll_read_ready(cx).map_ok(drop)).await
}

async fn recv_ready_opt(s: &Option<UdpSocket>) -> std::io::Result<()> {
    match s {
        Some(s) => recv_ready(s).await,
        None => std::future::pending().await,
    }
}

enum Wake {
    Cmd(Option<Cmd>),
    /// Socket `i` (meta, user, meta multicast, user multicast) has data.
    Readable(usize),
    Space,
    Timer,
    /// Someone else changed the core: a send found the socket full, or a
    /// close was found among the commands.
    Attention,
}

/// What the driver task, a receive thread and `try_publish` share: the
/// participant and everything around it, one at a time.
pub(super) struct Shared {
    pub(super) core: Mutex<Core>,
    /// The driver should look at the core (see [`Wake::Attention`]).
    pub(super) attention: tokio::sync::Notify,
    /// The receive thread stops (set before it is woken).
    pub(super) closing: std::sync::atomic::AtomicBool,
    /// Wakes the receive thread where it waits for room in a queue.
    pub(super) stopping: tokio::sync::Notify,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Shared")
    }
}

impl Shared {
    pub(super) fn lock(&self) -> std::sync::MutexGuard<'_, Core> {
        // a panic while locked leaves the state as consistent as any
        // protocol error would: go on
        self.core.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(super) fn id(&self) -> usize {
        std::ptr::from_ref(self) as usize
    }

    /// Hands the samples of immediate-delivery subscriptions to their
    /// callbacks, holding no lock, then sends what the callbacks wrote;
    /// leaves `queues` empty (its allocation is passed around, not
    /// renewed per datagram). `Err(Full)` when that found the send buffer
    /// full.
    pub(super) fn run_callbacks(&self, queues: &mut Vec<Arc<SampleQueue>>) -> Result<(), Full> {
        let mut full = false;
        while !queues.is_empty() {
            // (their writes are sent when they are done: see try_publish)
            crate::in_callback::running(self.id(), || {
                for q in queues.iter() {
                    q.run_handler();
                }
            });
            queues.clear();
            let now = Instant::now();
            let mut c = self.lock();
            // a full socket does not hold up callbacks: what they write
            // waits in the participant for the driver
            full |= c.flush(now).is_err();
            c.rearm();
            std::mem::swap(queues, &mut c.st.immediate);
        }
        if full {
            Err(Full)
        } else {
            Ok(())
        }
    }
}

pub(super) struct Core {
    pub(super) st: State,
    pub(super) out: Out,
    pub(super) cmd: crate::mailbox::Inbox<Cmd>,
    /// The driver's deadlines (see [`driver_timer`]).
    pub(super) timer: driver_timer::DriverTimer,
    /// A close taken from the commands by someone other than the driver
    /// (`None` inside: every sender was dropped).
    pub(super) close: Option<Option<oneshot::Sender<()>>>,
}

impl Core {
    /// Hands received samples and events to the application and sends
    /// what the participant has to send, until the socket is full: the
    /// datagrams a turn produced go out together, a `sendmmsg` for every
    /// [`SEND_SLOTS`](crate::sys::net::SEND_SLOTS) of them.
    pub(super) fn flush(&mut self, now: Instant) -> Result<(), Full> {
        self.st.pump(now);
        loop {
            while self.out.has_room() {
                match self.st.d.poll_transmission() {
                    Some(t) => self.out.queue(t),
                    None => break,
                }
            }
            if self.out.is_empty() {
                return Ok(());
            }
            self.out.send()?;
        }
    }

    /// What the last turn produced goes out, then what is due at `now`
    /// (timers) if there was room for the first.
    pub(super) fn turn(&mut self, now: Instant) -> Result<(), Full> {
        self.flush(now)?;
        if self.st.next_wakeup() <= now {
            self.st.tick(now);
            return self.flush(now);
        }
        Ok(())
    }

    /// Arms the timer for the next deadline, if that moved earlier.
    pub(super) fn rearm(&mut self) {
        self.timer.set(self.st.next_wakeup());
    }

    /// Takes the commands already queued, in order (so that a write made
    /// without waiting comes after the `publish().await`s before it).
    pub(super) fn take_commands(&mut self, now: Instant) {
        while self.close.is_none() {
            match self.cmd.try_recv() {
                Ok(Cmd::Close { reply }) => self.close = Some(Some(reply)),
                Ok(c) => self.st.command(c, now),
                Err(mpsc::error::TryRecvError::Empty) => return,
                Err(mpsc::error::TryRecvError::Disconnected) => self.close = Some(None),
            }
        }
    }

    /// Hands the first `n` datagrams of `batch` to the participant, and
    /// what they deliver to the subscriptions; sample buffers the
    /// application has given back are reused first.
    pub(super) fn receive(&mut self, batch: &net::RecvBatch, n: usize, now: Instant) {
        let st = &mut self.st;
        st.returns.take(|b| st.d.recycle(b));
        for k in 0..n {
            let (bytes, from) = batch.get(k);
            self.st.d.handle_datagram(locator_of(from), bytes, now);
            // deliver as we go so that back-pressure is seen
            self.st.pump(now);
        }
    }
}

pub(super) struct Driver {
    /// Busy polling after activity, when configured.
    pub(super) spin: Option<BusyPoll>,
    pub(super) shared: Arc<Shared>,
    pub(super) meta: UdpSocket,
    /// User data, when the driver reads it (no receive thread).
    pub(super) user: Option<UdpSocket>,
    pub(super) meta_mc: Option<UdpSocket>,
    pub(super) user_mc: Option<UdpSocket>,
    pub(super) batch: net::RecvBatch,
    /// A duplicate of the sending socket, to wait for room.
    pub(super) send_sock: std::net::UdpSocket,
    pub(super) receiver: Option<ReceiveThread>,
    /// Immediate subscriptions with samples for their callbacks.
    pub(super) immediate: Vec<Arc<SampleQueue>>,
    /// [`Driver::close`] has run.
    pub(super) finished: bool,
}

impl Drop for Driver {
    /// The driver task dropped unfinished: its runtime was shut down
    /// before the session closed (the application returned from `main`
    /// right after dropping its last handle, or without closing). The
    /// writes it was told are queued are written and acknowledged, within
    /// the linger a close has, blocking ([`linger`](super::linger)); then
    /// it ends as a close does, so that handles that live on fail instead
    /// of waiting for ever (the mailbox lives in [`Shared`], which they
    /// hold).
    fn drop(&mut self) {
        if !self.finished {
            if !self.linger_blocking() {
                warn_unacknowledged();
            }
            let now = Instant::now();
            self.say_goodbye(now);
            self.finish(now);
        }
    }
}

/// A command that came while the session closes: a write fails, anything
/// else is dropped (its caller learns that the session is gone).
fn refuse(c: Cmd) {
    if let Cmd::Write { done, .. } = c {
        done.send(Err(disconnected()));
    }
}

/// How long a closing session waits for its readers to acknowledge what
/// its writers hold (Cyclone DDS's `WriterLingerDuration` is 1 s).
pub(super) const CLOSE_LINGER: Duration = Duration::from_secs(1);

fn warn_unacknowledged() {
    tracing::warn!(
        "DDS session closes with samples its readers have not acknowledged \
         (after a linger of {} ms); they may be lost",
        CLOSE_LINGER.as_millis()
    );
}

/// A close under way: until when it waits, and who waits for it.
struct Linger {
    until: Instant,
    replies: Vec<oneshot::Sender<()>>,
}

impl Driver {
    pub(super) async fn run(mut self) {
        // one clock reading per turn, taken when the driver wakes
        let mut now = Instant::now();
        let shared = self.shared.clone();
        let mut linger: Option<Linger> = None;
        // every sender is gone: the mailbox is not polled again
        let mut orphaned = false;
        loop {
            // what the last turn produced goes out first; then what is due
            let (paused, flushed, close, quiet) = {
                let mut c = shared.lock();
                let flushed = c.turn(now);
                c.rearm();
                // samples the flush delivered, from this session's own
                // writers: their callbacks run now, not at the next wake
                if self.immediate.is_empty() {
                    std::mem::swap(&mut self.immediate, &mut c.st.immediate);
                }
                let quiet = linger.is_some() && flushed.is_ok() && c.st.quiet();
                (c.st.full_queue(), flushed, c.close.take(), quiet)
            };
            if !self.immediate.is_empty() {
                // (it flushes what they write; a full send buffer is seen
                // by the next turn's flush)
                let _ = shared.run_callbacks(&mut self.immediate);
            }
            if let Some(reply) = close {
                self.begin_close(&mut linger, reply, now);
                continue;
            }
            if let Some(l) = linger.take_if(|l| quiet || now >= l.until) {
                if !quiet {
                    warn_unacknowledged();
                }
                self.close(Instant::now()).await;
                for r in l.replies {
                    let _ = r.send(());
                }
                return;
            }
            if flushed.is_err() {
                if net::wait_writable(&self.send_sock).await.is_err() {
                    // cannot wait: drop the datagram (reliable writers repair)
                    shared.lock().out.drop_first();
                }
                now = Instant::now();
                continue;
            }
            let until = linger.as_ref().map(|l| l.until);
            let wake = tokio::select! {
                biased;
                c = std::future::poll_fn(|cx| shared.lock().cmd.poll_recv(cx)), if !orphaned => Wake::Cmd(c),
                _ = async { if let Some(t) = until { tokio::time::sleep_until(t.into()).await } }, if until.is_some() => Wake::Timer,
                _ = recv_ready(&self.meta) => Wake::Readable(0),
                _ = recv_ready_opt(&self.user), if paused.is_none() => Wake::Readable(1),
                _ = recv_ready_opt(&self.meta_mc) => Wake::Readable(2),
                _ = recv_ready_opt(&self.user_mc), if paused.is_none() => Wake::Readable(3),
                _ = async { if let Some(q) = &paused { q.space().await } }, if paused.is_some() => Wake::Space,
                _ = std::future::poll_fn(|cx| shared.lock().timer.poll_fired(cx)) => Wake::Timer,
                _ = shared.attention.notified() => Wake::Attention,
            };
            now = Instant::now();
            if let (Some(s), Wake::Cmd(_) | Wake::Readable(_)) = (&self.spin, &wake) {
                s.activity();
            }
            match wake {
                Wake::Cmd(None) => {
                    orphaned = true;
                    self.begin_close(&mut linger, None, now);
                }
                Wake::Cmd(Some(Cmd::Close { reply })) => {
                    self.begin_close(&mut linger, Some(reply), now);
                }
                // closing: nothing new is taken
                Wake::Cmd(Some(c)) if linger.is_some() => refuse(c),
                Wake::Cmd(Some(c)) => {
                    let mut core = shared.lock();
                    core.st.command(c, now);
                    // take every command already queued before flushing
                    core.take_commands(now);
                    std::mem::swap(&mut self.immediate, &mut core.st.immediate);
                }
                Wake::Readable(i) => self.drain(i, now),
                Wake::Space | Wake::Timer | Wake::Attention => {}
            }
            if !self.immediate.is_empty() {
                // a full send buffer is seen by the next turn's flush
                let _ = shared.run_callbacks(&mut self.immediate);
            }
        }
    }

    /// Reads what is waiting on socket `i`, a batch per system call, up
    /// to a limit (so that commands and timers are not starved); takes the
    /// immediate-delivery subscriptions that got samples.
    pub(super) fn drain(&mut self, i: usize, now: Instant) {
        let mut c = self.shared.lock();
        let sock = match i {
            0 => Some(&self.meta),
            1 => self.user.as_ref(),
            2 => self.meta_mc.as_ref(),
            _ => self.user_mc.as_ref(),
        };
        if let Some(sock) = sock {
            for _ in 0..8 {
                if i % 2 == 1 && c.st.full_queue().is_some() {
                    break;
                }
                let n = match net::recv_batch(sock, &mut self.batch) {
                    Ok(n) => n,
                    // ICMP port unreachable and the like: reported once, nothing to do
                    Err(_) => continue,
                };
                c.receive(&self.batch, n, now);
                if n < net::RECV_SLOTS {
                    break; // the socket was emptied
                }
            }
        }
        std::mem::swap(&mut self.immediate, &mut c.st.immediate);
    }

    /// A close was asked for (or every handle is gone): the first starts
    /// the linger, later ones wait for the same end.
    fn begin_close(
        &mut self,
        linger: &mut Option<Linger>,
        reply: Option<oneshot::Sender<()>>,
        now: Instant,
    ) {
        let l = linger.get_or_insert_with(|| {
            self.shared.lock().st.begin_close(now);
            Linger {
                until: now + CLOSE_LINGER,
                replies: Vec::new(),
            }
        });
        l.replies.extend(reply);
    }

    pub(super) async fn close(&mut self, now: Instant) {
        if let Some(r) = self.receiver.take() {
            r.stop().await;
        }
        if self.say_goodbye(now) {
            // the goodbyes, once there is room (a bounded wait)
            let room = net::wait_writable(&self.send_sock);
            if let Ok(Ok(())) = tokio::time::timeout(Duration::from_millis(100), room).await {
                let _ = self.shared.lock().flush(now);
            }
        }
        self.finish(now);
    }

    /// Disposes what the publications leave and says goodbye; true if the
    /// send buffer was full.
    fn say_goodbye(&mut self, now: Instant) -> bool {
        let mut c = self.shared.lock();
        // the instances its publications leave, disposed (best effort:
        // the participant leaves with them)
        c.st.dispose_all_live(now);
        c.st.d.close(now);
        c.flush(now).is_err()
    }

    /// Ends everything the application holds: streams end, waiting calls
    /// fail, later commands fail at once.
    fn finish(&mut self, now: Instant) {
        self.finished = true;
        let mut c = self.shared.lock();
        c.st.pump(now);
        c.st.fail_all();
        // later commands fail at once (an `ask` gets its reply dropped),
        // and so do writes that do not wait; those whose publishers went
        // on are counted in one line
        c.cmd.close();
        let mut lost = 0u64;
        while let Ok(cmd) = c.cmd.try_recv() {
            match cmd {
                Cmd::Write {
                    done: Done::Queued(_),
                    ..
                } => lost += 1,
                Cmd::Write { done, .. } => done.send(Err(disconnected())),
                _ => {}
            }
        }
        if lost > 0 {
            tracing::warn!(
                "{lost} queued write(s) were not sent: the DDS session closed before they \
                 were taken"
            );
        }
        c.close = Some(None);
        let queues = c.st.take_handler_queues();
        drop(c);
        for q in queues {
            q.run_handler();
        }
    }
}
