//! The event hub every backend driver shares: one sender, any number of
//! listeners, each with a bounded queue of its own.
//!
//! A listener that does not keep up never holds up the driver or the
//! other listeners, and never makes the session's memory grow: when its
//! queue is full the oldest event is dropped and counted, and the listener
//! can see how many it lost ([`Listener::lost`]). Dropping a listener
//! unregisters it at once; closing the hub ends every listener's stream
//! after the events already queued.

use std::collections::VecDeque;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};

use futures::Stream;

/// Events queued per listener before the oldest are dropped.
pub const DEFAULT_CAPACITY: usize = 1024;

struct Slot<T> {
    queue: VecDeque<T>,
    lost: u64,
    waker: Option<Waker>,
}

struct Inner<T> {
    slots: Vec<Arc<Mutex<Slot<T>>>>,
    closed: bool,
    capacity: usize,
}

/// The sending side, owned by a driver (cheap to clone).
pub struct Hub<T> {
    inner: Arc<Mutex<Inner<T>>>,
}

impl<T> Clone for Hub<T> {
    fn clone(&self) -> Self {
        Hub {
            inner: self.inner.clone(),
        }
    }
}

impl<T> std::fmt::Debug for Hub<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let inner = lock(&self.inner);
        f.debug_struct("Hub")
            .field("listeners", &inner.slots.len())
            .field("closed", &inner.closed)
            .finish()
    }
}

fn lock<X>(m: &Mutex<X>) -> MutexGuard<'_, X> {
    // every critical section leaves the state whole
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl<T: Clone> Hub<T> {
    /// A hub whose listeners queue up to `capacity` events each.
    pub fn new(capacity: usize) -> Self {
        Hub {
            inner: Arc::new(Mutex::new(Inner {
                slots: Vec::new(),
                closed: false,
                capacity: capacity.max(1),
            })),
        }
    }

    /// A new listener; it sees the events sent from now on. On a closed
    /// hub its stream ends at once.
    pub fn listen(&self) -> Listener<T> {
        let slot = Arc::new(Mutex::new(Slot {
            queue: VecDeque::new(),
            lost: 0,
            waker: None,
        }));
        let mut inner = lock(&self.inner);
        if !inner.closed {
            inner.slots.push(slot.clone());
        }
        Listener {
            slot,
            hub: Arc::downgrade(&self.inner),
        }
    }

    /// Whether anybody listens (a driver may skip building events then).
    pub fn has_listeners(&self) -> bool {
        !lock(&self.inner).slots.is_empty()
    }

    /// Queues `event` for every listener, dropping (and counting) the
    /// oldest of a full queue.
    pub fn send(&self, event: T) {
        let inner = lock(&self.inner);
        let cap = inner.capacity;
        for slot in &inner.slots {
            let mut s = lock(slot);
            if s.queue.len() >= cap {
                s.queue.pop_front();
                s.lost += 1;
            }
            s.queue.push_back(event.clone());
            if let Some(w) = s.waker.take() {
                w.wake();
            }
        }
    }

    /// Ends every listener's stream once it has taken what is queued; later
    /// listeners end at once.
    pub fn close(&self) {
        let mut inner = lock(&self.inner);
        inner.closed = true;
        for slot in inner.slots.drain(..) {
            if let Some(w) = lock(&slot).waker.take() {
                w.wake();
            }
        }
    }
}

/// One listener's stream of events.
pub struct Listener<T> {
    slot: Arc<Mutex<Slot<T>>>,
    hub: std::sync::Weak<Mutex<Inner<T>>>,
}

impl<T> std::fmt::Debug for Listener<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = lock(&self.slot);
        f.debug_struct("Listener")
            .field("queued", &s.queue.len())
            .field("lost", &s.lost)
            .finish()
    }
}

impl<T> Listener<T> {
    /// Events dropped so far because this listener's queue was full.
    pub fn lost(&self) -> u64 {
        lock(&self.slot).lost
    }

    fn registered(&self) -> bool {
        self.hub
            .upgrade()
            .is_some_and(|h| lock(&h).slots.iter().any(|s| Arc::ptr_eq(s, &self.slot)))
    }
}

impl<T> Stream for Listener<T> {
    type Item = T;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<T>> {
        {
            let mut s = lock(&self.slot);
            if let Some(e) = s.queue.pop_front() {
                return Poll::Ready(Some(e));
            }
            s.waker = Some(cx.waker().clone());
        }
        // checked after the waker is in place: a close in between wakes it
        if self.registered() {
            Poll::Pending
        } else {
            // the hub closed (or is gone): take what raced in, then end
            Poll::Ready(lock(&self.slot).queue.pop_front())
        }
    }
}

impl<T> Drop for Listener<T> {
    fn drop(&mut self) {
        if let Some(h) = self.hub.upgrade() {
            lock(&h).slots.retain(|s| !Arc::ptr_eq(s, &self.slot));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futures::StreamExt;

    fn now<T>(l: &mut Listener<T>) -> Poll<Option<T>> {
        let waker = futures::task::noop_waker();
        l.poll_next_unpin(&mut Context::from_waker(&waker))
    }

    #[test]
    fn every_listener_gets_every_event_in_order() {
        let hub = Hub::new(8);
        let mut a = hub.listen();
        let mut b = hub.listen();
        hub.send(1);
        hub.send(2);
        assert_eq!(now(&mut a), Poll::Ready(Some(1)));
        assert_eq!(now(&mut a), Poll::Ready(Some(2)));
        assert_eq!(now(&mut a), Poll::Pending);
        assert_eq!(now(&mut b), Poll::Ready(Some(1)));
        assert_eq!(a.lost() + b.lost(), 0);
    }

    #[test]
    fn a_slow_listener_loses_the_oldest_and_counts_them_alone() {
        let hub = Hub::new(3);
        let mut slow = hub.listen();
        let mut fast = hub.listen();
        for i in 0..10 {
            hub.send(i);
            assert_eq!(now(&mut fast), Poll::Ready(Some(i)));
        }
        assert_eq!(slow.lost(), 7);
        assert_eq!(fast.lost(), 0);
        let got: Vec<i32> = std::iter::from_fn(|| match now(&mut slow) {
            Poll::Ready(Some(v)) => Some(v),
            _ => None,
        })
        .collect();
        assert_eq!(got, [7, 8, 9], "the newest kept");
    }

    #[test]
    fn a_dropped_listener_is_gone_at_once_and_close_ends_the_others() {
        let hub = Hub::new(4);
        let a = hub.listen();
        let mut b = hub.listen();
        assert!(hub.has_listeners());
        drop(a);
        assert_eq!(lock(&hub.inner).slots.len(), 1);
        hub.send(5);
        hub.close();
        assert_eq!(now(&mut b), Poll::Ready(Some(5)), "queued before close");
        assert_eq!(now(&mut b), Poll::Ready(None));
        let mut late = hub.listen();
        assert_eq!(now(&mut late), Poll::Ready(None));
        assert!(!hub.has_listeners());
    }

    #[tokio::test]
    async fn a_waiting_listener_is_woken_by_send_and_by_close() {
        let hub = Hub::<u8>::new(4);
        let mut l = hub.listen();
        let h = hub.clone();
        let t = tokio::spawn(async move {
            let first = l.next().await;
            let end = l.next().await;
            (first, end)
        });
        tokio::task::yield_now().await;
        h.send(9);
        tokio::task::yield_now().await;
        h.close();
        let (first, end) = tokio::time::timeout(std::time::Duration::from_secs(5), t)
            .await
            .unwrap()
            .unwrap();
        assert_eq!((first, end), (Some(9), None));
    }
}
