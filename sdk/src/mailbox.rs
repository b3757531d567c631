//! The command mailbox every backend driver reads: one queue, in order,
//! with a bounded number of slots.
//!
//! A caller that can wait ([`Mailbox::send`]) takes a slot first, so a
//! driver that falls behind slows its callers down instead of letting the
//! queue grow. Two kinds of sender cannot wait and need no slot, because
//! something else bounds how many of their commands can be queued: code in
//! `Drop` (one close per handle) and commands that carry a budget of their
//! own (an RTPS write holds its share of the write budget, a direct link's
//! reader one read at a time): they [`Mailbox::post`]. Both kinds share
//! one queue, so a command posted after a `send` returned is read after it
//! (a write made without waiting, then a drop, arrive in that order).
//!
//! When the driver stops ([`Inbox::close`] or drop), callers waiting for a
//! slot and every later command fail at once with [`Closed`].

use std::sync::Arc;
use std::task::{Context, Poll};

use tokio::sync::{mpsc, OwnedSemaphorePermit, Semaphore};

/// Commands a driver lets its callers queue before they wait.
pub(crate) const CAPACITY: usize = 1024;

/// The driver has stopped: the command was not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Closed;

struct Letter<C> {
    cmd: C,
    /// Given back when the driver takes the command.
    _slot: Option<OwnedSemaphorePermit>,
}

/// The sending side (cheap to clone).
pub(crate) struct Mailbox<C> {
    tx: mpsc::UnboundedSender<Letter<C>>,
    slots: Arc<Semaphore>,
}

impl<C> Clone for Mailbox<C> {
    fn clone(&self) -> Self {
        Mailbox {
            tx: self.tx.clone(),
            slots: self.slots.clone(),
        }
    }
}

impl<C> std::fmt::Debug for Mailbox<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mailbox")
            .field("free_slots", &self.slots.available_permits())
            .field("closed", &self.tx.is_closed())
            .finish()
    }
}

/// A sender that does not keep the driver alive.
pub(crate) struct WeakMailbox<C> {
    tx: mpsc::WeakUnboundedSender<Letter<C>>,
    slots: Arc<Semaphore>,
}

impl<C> Clone for WeakMailbox<C> {
    fn clone(&self) -> Self {
        WeakMailbox {
            tx: self.tx.clone(),
            slots: self.slots.clone(),
        }
    }
}

impl<C> WeakMailbox<C> {
    /// The mailbox, while its driver still has a strong sender.
    pub(crate) fn upgrade(&self) -> Option<Mailbox<C>> {
        Some(Mailbox {
            tx: self.tx.upgrade()?,
            slots: self.slots.clone(),
        })
    }
}

/// The driver's side.
pub(crate) struct Inbox<C> {
    rx: mpsc::UnboundedReceiver<Letter<C>>,
    slots: Arc<Semaphore>,
}

/// A mailbox with `capacity` slots for waiting senders.
pub(crate) fn mailbox<C>(capacity: usize) -> (Mailbox<C>, Inbox<C>) {
    let (tx, rx) = mpsc::unbounded_channel();
    let slots = Arc::new(Semaphore::new(capacity.max(1)));
    (
        Mailbox {
            tx,
            slots: slots.clone(),
        },
        Inbox { rx, slots },
    )
}

impl<C> Mailbox<C> {
    /// Closes the driver's session: posts the close `make` builds and
    /// waits for its end. Posted, not sent: a close whose future is
    /// dropped while the mailbox is full still closes (one command per
    /// close call). Inside a `listen` callback of the driver (`callback`:
    /// its owner in [`in_callback`](crate::in_callback)) it does not wait:
    /// the driver waits for the callback, which would wait for ever.
    pub(crate) async fn close_session(
        &self,
        callback: usize,
        make: impl FnOnce(tokio::sync::oneshot::Sender<()>) -> C,
    ) {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let posted = self.post(make(tx)).is_ok();
        if crate::in_callback::inside(callback) {
            tracing::error!(
                "close() called inside a listen callback of its own session: it goes on once \
                 the callback returns (spawn the close to wait for it)"
            );
            return;
        }
        if posted {
            let _ = rx.await;
        }
    }

    /// Queues `cmd`, waiting for a free slot first.
    pub(crate) async fn send(&self, cmd: C) -> Result<(), Closed> {
        let slot = self
            .slots
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| Closed)?;
        self.tx
            .send(Letter {
                cmd,
                _slot: Some(slot),
            })
            .map_err(|_| Closed)
    }

    /// Queues `cmd` without a slot. Only for senders whose number of
    /// queued commands is bounded otherwise (see the [module docs](self)).
    pub(crate) fn post(&self, cmd: C) -> Result<(), Closed> {
        self.tx
            .send(Letter { cmd, _slot: None })
            .map_err(|_| Closed)
    }

    /// Waits until the driver has stopped.
    pub(crate) async fn closed(&self) {
        self.tx.closed().await
    }

    /// A sender that does not keep the driver alive.
    pub(crate) fn downgrade(&self) -> WeakMailbox<C> {
        WeakMailbox {
            tx: self.tx.downgrade(),
            slots: self.slots.clone(),
        }
    }
}

impl<C> Inbox<C> {
    /// The next command; `None` once every sender is gone or the inbox
    /// was closed and emptied.
    pub(crate) async fn recv(&mut self) -> Option<C> {
        self.rx.recv().await.map(|l| l.cmd)
    }

    /// [`Inbox::recv`] for a hand-written future.
    pub(crate) fn poll_recv(&mut self, cx: &mut Context<'_>) -> Poll<Option<C>> {
        self.rx.poll_recv(cx).map(|l| l.map(|l| l.cmd))
    }

    /// The next command if one is queued.
    pub(crate) fn try_recv(&mut self) -> Result<C, mpsc::error::TryRecvError> {
        self.rx.try_recv().map(|l| l.cmd)
    }

    /// Refuses every later command and wakes the senders waiting for a
    /// slot (they get [`Closed`]); what is queued can still be read.
    pub(crate) fn close(&mut self) {
        self.slots.close();
        self.rx.close();
    }
}

impl<C> Drop for Inbox<C> {
    fn drop(&mut self) {
        self.slots.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_full_mailbox_makes_senders_wait_and_posts_keep_their_order() {
        let (tx, mut rx) = mailbox::<u32>(2);
        tx.send(1).await.unwrap();
        tx.send(2).await.unwrap();
        // a third send waits for a slot...
        let waiting = {
            let tx = tx.clone();
            tokio::spawn(async move { tx.send(4).await })
        };
        tokio::task::yield_now().await;
        assert!(!waiting.is_finished());
        // ...while a post goes in behind what is queued
        tx.post(3).unwrap();
        assert_eq!(rx.recv().await, Some(1));
        let sent = tokio::time::timeout(Duration::from_secs(5), waiting).await;
        assert_eq!(sent.unwrap().unwrap(), Ok(()));
        let mut got = Vec::new();
        while let Ok(c) = rx.try_recv() {
            got.push(c);
        }
        assert_eq!(got, [2, 3, 4]);
    }

    #[tokio::test]
    async fn closing_the_inbox_fails_waiting_and_later_senders() {
        let (tx, mut rx) = mailbox::<u32>(1);
        tx.send(1).await.unwrap();
        let waiting = {
            let tx = tx.clone();
            tokio::spawn(async move { tx.send(2).await })
        };
        tokio::task::yield_now().await;
        rx.close();
        let sent = tokio::time::timeout(Duration::from_secs(5), waiting).await;
        assert_eq!(sent.unwrap().unwrap(), Err(Closed));
        assert_eq!(tx.post(3), Err(Closed));
        // what was queued before the close is still read
        assert_eq!(rx.recv().await, Some(1));
        assert_eq!(rx.recv().await, None);
    }

    #[tokio::test]
    async fn a_weak_sender_does_not_keep_the_driver_alive() {
        let (tx, mut rx) = mailbox::<u32>(1);
        let weak = tx.downgrade();
        assert!(weak.upgrade().is_some());
        drop(tx);
        assert!(weak.upgrade().is_none());
        assert_eq!(rx.recv().await, None);
    }
}
