//! The end its user asked for: [`Session::close`](crate::Session::close)
//! ends every timer made from the session (waking those that wait), and
//! its subscription and request streams then end with `None` rather than
//! `Err(RecvError::Disconnected)`, which is kept for a connection lost.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;
use std::task::{Context, Waker};

/// Shared by every clone of a session and the handles made from it.
#[derive(Debug, Default)]
pub(crate) struct SessionEnd {
    ended: AtomicBool,
    next_id: AtomicU64,
    /// The wakers of the timers waiting for their next tick, by timer.
    waiting: Mutex<HashMap<u64, Waker>>,
}

impl SessionEnd {
    /// The session was closed: every timer (and those made later) ends.
    pub(crate) fn end(&self) {
        self.ended.store(true, Ordering::Release);
        let waiting = std::mem::take(&mut *self.waiting.lock().unwrap_or_else(|e| e.into_inner()));
        for w in waiting.into_values() {
            w.wake();
        }
    }

    /// Whether `close()` was called on the session (or a clone of it).
    pub(crate) fn ended(&self) -> bool {
        self.ended.load(Ordering::Acquire)
    }

    /// An id for a waiter of [`wait`](Self::wait).
    pub(crate) fn next_id(&self) -> u64 {
        self.next_id.fetch_add(1, Ordering::Relaxed)
    }

    /// Keeps `cx`'s waker for waiter `id` to be woken by [`end`](Self::end);
    /// `false` (nothing kept) if the session has ended already.
    pub(crate) fn wait(&self, id: u64, cx: &Context<'_>) -> bool {
        let mut waiting = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
        // (checked again under the lock: `end` takes the wakers after
        // setting the flag)
        if self.ended() {
            return false;
        }
        match waiting.get_mut(&id) {
            Some(w) if w.will_wake(cx.waker()) => {}
            _ => {
                waiting.insert(id, cx.waker().clone());
            }
        }
        true
    }

    #[cfg(test)]
    pub(crate) fn nobody_waits(&self) -> bool {
        self.waiting.lock().unwrap().is_empty()
    }

    /// Runs `f`, a `listen` callback of this session, marked as such on
    /// this thread (see [`in_own_callback`](Self::in_own_callback)).
    pub(crate) fn in_callback<R>(&self, f: impl FnOnce() -> R) -> R {
        crate::in_callback::running(self as *const Self as usize, f)
    }

    /// Whether this thread is running a `listen` callback of this session
    /// (where waiting for the session's close could wait for ever).
    pub(crate) fn in_own_callback(&self) -> bool {
        crate::in_callback::inside(self as *const Self as usize)
    }

    /// Waiter `id` is gone.
    pub(crate) fn forget(&self, id: u64) {
        self.waiting
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&id);
    }
}
