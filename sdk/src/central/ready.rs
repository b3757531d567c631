//! Which connections may have bytes to read, for the task that runs the
//! state machine and reads every connection itself.
//!
//! Each connection gets a [`Waker`] ([`ReadyList::waker`]) that the core
//! task passes when it polls the connection for read readiness. When the
//! I/O driver (or an in-process link) finds bytes, it calls that waker,
//! which puts the connection's id on the list and wakes the core task:
//! one task wake-up per burst of readiness, where a reader task per
//! connection cost a wake-up of the reader, a channel send to the core,
//! and a second wake-up of the reader for its go-ahead, per message.

use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Wake, Waker};

use courier_wire::ipc::central::ConnId;

/// Connections to poll for reading, and the core task's waker.
#[derive(Default)]
pub(super) struct ReadyList {
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    ids: Vec<ConnId>,
    core: Option<Waker>,
}

impl ReadyList {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        // Nothing panics while holding it; the list stays consistent.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The waker to poll `conn`'s read half with.
    pub(super) fn waker(self: &Arc<Self>, conn: ConnId) -> Waker {
        Waker::from(Arc::new(ConnWake {
            conn,
            list: self.clone(),
        }))
    }

    /// Puts `conn` on the list (and wakes the core task if it waits).
    pub(super) fn push(&self, conn: ConnId) {
        let mut inner = self.lock();
        inner.ids.push(conn);
        let core = inner.core.take();
        drop(inner);
        if let Some(w) = core {
            w.wake();
        }
    }

    /// Ready once some connection is on the list: moves the list into
    /// `into` (emptied first, so its allocation is reused).
    pub(super) fn poll_take(&self, cx: &mut Context<'_>, into: &mut Vec<ConnId>) -> Poll<()> {
        let mut inner = self.lock();
        if inner.ids.is_empty() {
            if !inner.core.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
                inner.core = Some(cx.waker().clone());
            }
            return Poll::Pending;
        }
        into.clear();
        std::mem::swap(&mut inner.ids, into);
        Poll::Ready(())
    }
}

/// A connection's read waker.
struct ConnWake {
    conn: ConnId,
    list: Arc<ReadyList>,
}

impl Wake for ConnWake {
    fn wake(self: Arc<Self>) {
        self.list.push(self.conn);
    }

    fn wake_by_ref(self: &Arc<Self>) {
        self.list.push(self.conn);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wakers_list_their_connections_and_wake_the_core() {
        struct Count(std::sync::atomic::AtomicUsize);
        impl Wake for Count {
            fn wake(self: Arc<Self>) {
                self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
        }
        let count = Arc::new(Count(0.into()));
        let core = Waker::from(count.clone());
        let mut cx = Context::from_waker(&core);
        let list = Arc::new(ReadyList::default());
        let mut got = vec![ConnId(99)];
        assert!(list.poll_take(&mut cx, &mut got).is_pending());
        list.waker(ConnId(5)).wake_by_ref();
        list.waker(ConnId(6)).wake();
        assert_eq!(count.0.load(std::sync::atomic::Ordering::Relaxed), 1);
        assert!(list.poll_take(&mut cx, &mut got).is_ready());
        assert_eq!(got, [ConnId(5), ConnId(6)]);
        assert!(list.poll_take(&mut cx, &mut got).is_pending());
    }
}
