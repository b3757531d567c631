//! How a server answers one request: [`Responder`], given to it with each
//! [`RawRequest`](crate::RawRequest) by the backend.
//!
//! A request is answered once or declined: dropping the `Responder` (with
//! the `Request` that holds it) without answering declines it, so that the
//! backend can free what the request holds (IPC: the module's capacity slot
//! in central, without which the module would receive nothing more).

use std::future::Future;
use std::pin::Pin;

use crate::error::PublishError;

/// The future of an answer: resolves once the reply is sent, or with why
/// it could not be (the reply message is unknown to central, say).
pub type ReplyFuture = Pin<Box<dyn Future<Output = Result<(), PublishError>> + Send>>;

/// A backend's side of one request.
pub trait Reply: Send {
    /// Sends the reply `data` as message `reply_msg` (IPC's reply message
    /// name; DDS backends send it on the service's reply topic).
    fn reply(self: Box<Self>, reply_msg: &str, data: Vec<u8>) -> ReplyFuture;
    /// The request will not be answered.
    fn decline(self: Box<Self>);
}

/// Answers one request, now or later, from any task (IPC_delayResponse);
/// dropped unanswered, it declines the request. `Send` and `Sync`: a
/// request can be held across an `.await` in a spawned task (the lock is
/// only for `Sync`; answering takes the responder by value).
pub struct Responder(std::sync::Mutex<Option<Box<dyn Reply>>>);

impl Responder {
    /// The reply machinery, taken out (by value or in `drop`: no contention).
    fn take(&mut self) -> Option<Box<dyn Reply>> {
        self.0.get_mut().unwrap_or_else(|e| e.into_inner()).take()
    }
}

impl std::fmt::Debug for Responder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let unanswered = self.0.lock().map_or(true, |g| g.is_some());
        f.write_str(if unanswered {
            "Responder(unanswered)"
        } else {
            "Responder(answered)"
        })
    }
}

/// A [`Reply`] from a function; declining does nothing.
struct FnReply<F>(F);

impl<F> Reply for FnReply<F>
where
    F: FnOnce(&str, Vec<u8>) -> Result<(), PublishError> + Send,
{
    fn reply(self: Box<Self>, reply_msg: &str, data: Vec<u8>) -> ReplyFuture {
        Box::pin(std::future::ready((self.0)(reply_msg, data)))
    }

    fn decline(self: Box<Self>) {}
}

impl Responder {
    /// A responder backed by `reply`.
    pub fn new(reply: impl Reply + 'static) -> Self {
        Responder(std::sync::Mutex::new(Some(Box::new(reply))))
    }

    /// A responder that answers by calling `f` at once and has nothing to
    /// free when declined.
    pub fn from_fn(
        f: impl FnOnce(&str, Vec<u8>) -> Result<(), PublishError> + Send + 'static,
    ) -> Self {
        Responder::new(FnReply(f))
    }

    /// Sends the reply; the future resolves once it is sent or failed.
    pub fn reply(mut self, reply_msg: &str, data: Vec<u8>) -> ReplyFuture {
        match self.take() {
            Some(r) => r.reply(reply_msg, data),
            // `reply` takes `self`, and only it and drop empty it
            None => Box::pin(std::future::ready(Err(PublishError::AlreadyAnswered))),
        }
    }
}

impl Drop for Responder {
    fn drop(&mut self) {
        if let Some(r) = self.take() {
            r.decline();
        }
    }
}

#[cfg(test)]
mod tests {
    /// A request held across an `.await` keeps a spawned task's future
    /// `Send`: `Request` is `Sync` (it was not: a `&Request` in an async
    /// handler made the future `!Send`).
    #[test]
    fn requests_are_send_and_sync() {
        fn send_sync<T: Send + Sync>() {}
        send_sync::<super::Responder>();
        send_sync::<crate::Request<i32, i32>>();
        send_sync::<crate::RawRequest>();
        send_sync::<crate::RawSample>();
    }
}
