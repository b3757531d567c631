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
/// dropped unanswered, it declines the request.
pub struct Responder(Option<Box<dyn Reply>>);

impl std::fmt::Debug for Responder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
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
        Responder(Some(Box::new(reply)))
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
        match self.0.take() {
            Some(r) => r.reply(reply_msg, data),
            // `reply` takes `self`, and only it and drop empty it
            None => Box::pin(std::future::ready(Err(PublishError::AlreadyAnswered))),
        }
    }
}

impl Drop for Responder {
    fn drop(&mut self) {
        if let Some(r) = self.0.take() {
            r.decline();
        }
    }
}
