//! A driver's answer to an open (a publication, subscription, service or
//! client), awaited so that giving up the wait leaves nothing open.
//!
//! A `timeout` or `select!` may drop an open's future at any point. If the
//! driver answers after that, its send fails and the driver closes what
//! it made (it knows nobody will hold it). If the answer was already sent
//! and sits unread in the channel, only this side can tell: dropping an
//! [`OpenAnswer`] closes the channel and closes the handle it finds there.
//! Left open, a subscription nobody reads fills its queue and holds every
//! other delivery to the session, and a service keeps its name for ever.

use tokio::sync::oneshot;

use crate::backend::{Backend, Handle};
use crate::mailbox::Mailbox;

/// Sends the open `make` builds to a driver and waits for its answer; what
/// the driver opened for a caller that stopped waiting is closed (through
/// `backend`); `gone` is the error when the driver is gone.
pub(crate) async fn ask_open<C, T: Copy, E>(
    cmd: &Mailbox<C>,
    backend: &dyn Backend,
    handle: fn(T) -> Handle,
    make: impl FnOnce(oneshot::Sender<Result<T, E>>) -> C,
    gone: fn() -> E,
) -> Result<T, E> {
    let (tx, rx) = oneshot::channel();
    cmd.send(make(tx)).await.map_err(|_| gone())?;
    let close = |h: Handle| backend.close_handle(h);
    OpenAnswer::new(rx, handle, &close)
        .get()
        .await
        .ok_or_else(gone)?
}

pub(crate) struct OpenAnswer<'a, T: Copy, E> {
    rx: Option<oneshot::Receiver<Result<T, E>>>,
    handle: fn(T) -> Handle,
    close: &'a (dyn Fn(Handle) + Send + Sync),
}

impl<'a, T: Copy, E> OpenAnswer<'a, T, E> {
    /// The answer on `rx`; `handle` names what it opens; `close` closes
    /// a handle (the backend's `close_handle`).
    pub(crate) fn new(
        rx: oneshot::Receiver<Result<T, E>>,
        handle: fn(T) -> Handle,
        close: &'a (dyn Fn(Handle) + Send + Sync),
    ) -> Self {
        OpenAnswer {
            rx: Some(rx),
            handle,
            close,
        }
    }

    /// The answer; `None` if the driver is gone.
    pub(crate) async fn get(mut self) -> Option<Result<T, E>> {
        let rx = self.rx.as_mut()?;
        let r = rx.await.ok();
        self.rx = None;
        r
    }
}

impl<T: Copy, E> Drop for OpenAnswer<'_, T, E> {
    fn drop(&mut self) {
        let Some(mut rx) = self.rx.take() else {
            return;
        };
        // no answer can come after this: one sent before is read here,
        // one sent after fails and the driver closes what it made
        rx.close();
        if let Ok(Ok(id)) = rx.try_recv() {
            (self.close)((self.handle)(id));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::SubId;
    use std::sync::Mutex;

    #[test]
    fn an_answer_left_unread_is_closed_and_one_read_is_not() {
        let closed = Mutex::new(Vec::new());
        let close = |h: Handle| closed.lock().unwrap().push(h);
        // answered, never read
        let (tx, rx) = oneshot::channel::<Result<SubId, ()>>();
        tx.send(Ok(SubId(7))).unwrap();
        drop(OpenAnswer::new(rx, Handle::Subscription, &close));
        assert_eq!(*closed.lock().unwrap(), [Handle::Subscription(SubId(7))]);
        // not answered yet: the driver's send fails after the drop
        let (tx, rx) = oneshot::channel::<Result<SubId, ()>>();
        drop(OpenAnswer::new(rx, Handle::Subscription, &close));
        assert!(tx.send(Ok(SubId(8))).is_err());
        // read: nothing to close
        let (tx, rx) = oneshot::channel::<Result<SubId, ()>>();
        tx.send(Ok(SubId(9))).unwrap();
        let got =
            futures::executor::block_on(OpenAnswer::new(rx, Handle::Subscription, &close).get());
        assert_eq!(got, Some(Ok(SubId(9))));
        assert_eq!(closed.lock().unwrap().len(), 1);
    }
}
