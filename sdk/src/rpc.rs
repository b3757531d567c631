//! Queries and serving: [`Query`], [`Request`], [`Requests`] and their raw forms.

use crate::error::{OpenError, PublishError, QueryError};
use crate::qos::TypeInfo;
use crate::reply::Responder;
use crate::session::{decode, encode_rpc, Encoding, Owned, Session};
use crate::subscriber::RecvError;
use crate::topics::Definition;
use courier_wire::{ipc, IpcMessage};
use futures::Stream;
use std::marker::PhantomData;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::sync::mpsc;

/// A reply as a backend returns it: reply message name, bytes, byte order.
pub type RawReply = (String, Vec<u8>, ipc::ByteOrder);

/// A request delivered to a server, with the way to answer it.
pub struct RawRequest {
    /// Query message name.
    pub msg: String,
    /// The request bytes.
    pub data: Vec<u8>,
    /// Byte order of `data`.
    pub order: ipc::ByteOrder,
    /// IPC: the query message's format as central holds it (expanded),
    /// which a typed server checks its request type against
    /// ([`RecvError::FormatMismatch`]); `None` elsewhere.
    pub format: Option<std::sync::Arc<str>>,
    /// Sends the reply (reply message name, bytes); may be called later and
    /// from any task (IPC_delayResponse). Dropping it unanswered declines
    /// the request.
    pub respond: Responder,
}

impl std::fmt::Debug for RawRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawRequest")
            .field("msg", &self.msg)
            .field("data", &self.data.len())
            .finish_non_exhaustive()
    }
}

/// A query that could not start: opening what it needs failed.
pub(crate) fn open_failed(msg: &str, e: OpenError) -> QueryError {
    match e {
        OpenError::Disconnected(_) => QueryError::Disconnected(msg.to_string()),
        source => QueryError::Open {
            msg: msg.to_string(),
            source,
        },
    }
}

/// A query being built; `.await` it.
#[derive(Debug)]
#[must_use = "a query does nothing until awaited"]
pub struct Query<'a, Resp> {
    pub(crate) session: &'a Session,
    pub(crate) msg: &'a str,
    pub(crate) req: TypeInfo,
    /// The request, encoded (or why it cannot be sent).
    pub(crate) data: Result<Vec<u8>, PublishError>,
    pub(crate) timeout: Duration,
    /// The query message's type check, as [`Publish`]'s.
    pub(crate) check: Result<Option<Definition>, OpenError>,
    /// Its first use's bindings, let go if it is dropped unsettled.
    pub(crate) _first: Option<crate::topics::Unsettled<'a>>,
    pub(crate) _t: PhantomData<fn() -> Resp>,
}

impl<'a, Resp: IpcMessage + 'a> Query<'a, Resp> {
    /// Bounds the wait for the reply (10 s unless given; `Duration::MAX`
    /// waits as long as it takes).
    ///
    /// A query that times out, or whose future is dropped, is not taken
    /// back: the request was sent, and a server may still get it and act
    /// on it later (on IPC central holds it for a server that is slow,
    /// stopped or not there yet, as C's central does; on DDS a reliable
    /// request reader still receives it). A late reply is dropped. Where
    /// acting late is wrong (a command to move), put a deadline or a
    /// sequence number in the request and have the server check it.
    pub fn timeout(mut self, d: Duration) -> Self {
        self.timeout = d;
        self
    }

    async fn run(self) -> Result<Resp, QueryError> {
        let refused = |e: OpenError| open_failed(self.msg, e);
        let data = self.data.map_err(|source| {
            self.session.topics.settle(&[self.msg], false);
            QueryError::Refused {
                msg: self.msg.to_string(),
                source,
            }
        })?;
        if let Some(def) = self.check.map_err(refused)? {
            let r = self.session.define_shared(self.msg, def).await;
            self.session.settled(&[self.msg], r).map_err(refused)?;
        }
        let r = self
            .session
            .client(self.msg, &self.req, &TypeInfo::of::<Resp>())
            .await;
        let client = self.session.settled(&[self.msg], r).map_err(refused)?;
        let (reply, data, order) = self
            .session
            .backend
            .query(client, data, self.timeout)
            .await?;
        if self.session.enc() == Encoding::Ipc {
            let ty = std::any::type_name::<Resp>();
            let fits = crate::format_check::verdict::<Resp>;
            if let Err((central, detail)) = self
                .session
                .central_formats
                .check(self.session, &reply, ty, fits)
                .await
            {
                return Err(QueryError::Decode {
                    msg: self.msg.to_string(),
                    reply: reply.clone(),
                    ty,
                    detail: format!(
                        "{reply} is sent as {central} (central's format), which does not fit: {detail}"
                    ),
                });
            }
        }
        decode::<Resp>(self.session.enc(), &data, order).map_err(|detail| QueryError::Decode {
            msg: self.msg.to_string(),
            reply,
            ty: std::any::type_name::<Resp>(),
            detail,
        })
    }
}

impl<'a, Resp: IpcMessage + 'a> std::future::IntoFuture for Query<'a, Resp> {
    type Output = Result<Resp, QueryError>;
    type IntoFuture = Pin<Box<dyn std::future::Future<Output = Self::Output> + Send + 'a>>;

    fn into_future(self) -> Self::IntoFuture {
        let home = &self.session.home;
        Box::pin(home.run(self.run()))
    }
}

/// A request to a [`Session::serve`] server.
pub struct Request<Req, Resp> {
    /// The request.
    pub value: Req,
    reply_msg: String,
    enc: Encoding,
    respond: Option<Responder>,
    _t: PhantomData<fn(Resp)>,
}

impl<Req: std::fmt::Debug, Resp> std::fmt::Debug for Request<Req, Resp> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Request")
            .field("value", &self.value)
            .finish_non_exhaustive()
    }
}

impl<Req, Resp: IpcMessage> Request<Req, Resp> {
    /// Answers the request (now or later, from any task); resolves once
    /// the reply is sent, or with why it could not be.
    ///
    /// A `Request` dropped without a reply is declined: the server keeps
    /// receiving (on IPC, central frees the module's capacity slot), and
    /// the asker gets no reply and runs into its timeout.
    ///
    /// IPC: a request counts against the session's capacity until it is
    /// answered (C's central), and the capacity is 1 by default: while one
    /// reply is delayed, central delivers the session nothing else — no
    /// other request, no subscribed message. A server that answers later
    /// or from other tasks raises it with
    /// `session.ipc()?.set_capacity(n)` to have up to `n` requests (and
    /// messages) in hand at once.
    pub async fn reply(mut self, resp: &Resp) -> Result<(), PublishError> {
        let r = self.respond.take().ok_or(PublishError::AlreadyAnswered)?;
        // refused: the responder, dropped, declines the request
        let data = encode_rpc(self.enc, &self.reply_msg, resp)?;
        r.reply(&self.reply_msg, data).await
    }
}

/// Raw requests of [`Session::serve_raw`]; dropping it stops serving.
#[derive(Debug)]
#[must_use = "dropping it stops serving"]
pub struct RawRequests {
    pub(crate) rx: mpsc::Receiver<RawRequest>,
    pub(crate) _handle: Owned,
}

impl RawRequests {
    /// The next request; `None` once the connection has ended.
    pub async fn recv(&mut self) -> Option<RawRequest> {
        self.rx.recv().await
    }
}

impl Stream for RawRequests {
    type Item = RawRequest;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<RawRequest>> {
        self.rx.poll_recv(cx)
    }
}

/// The stream of requests of [`Session::serve`].
#[must_use = "dropping it stops serving"]
pub struct Requests<Req, Resp> {
    pub(crate) rx: mpsc::Receiver<RawRequest>,
    /// Stops serving when dropped.
    pub(crate) _handle: Owned,
    /// The end (`Err(Disconnected)`) was yielded.
    pub(crate) ended: bool,
    /// Whether the session was closed by its user (the stream then ends
    /// without `Err(Disconnected)`).
    pub(crate) end: std::sync::Arc<crate::session_end::SessionEnd>,
    pub(crate) reply_msg: String,
    pub(crate) enc: Encoding,
    /// IPC: central's format of the query message against `Req`.
    pub(crate) check: crate::format_check::FormatCheck,
    pub(crate) _t: PhantomData<fn() -> (Req, Resp)>,
}

impl<Req: IpcMessage, Resp: IpcMessage> Requests<Req, Resp> {
    /// The next request, waiting for it; `None` at the end of the stream
    /// (see [How streams end](crate#rules)). The `Stream`'s `next()`
    /// without importing `futures::StreamExt`.
    pub async fn recv(&mut self) -> Option<Result<Request<Req, Resp>, RecvError>> {
        futures::StreamExt::next(self).await
    }
}

impl<Req: IpcMessage, Resp: IpcMessage> Stream for Requests<Req, Resp> {
    type Item = Result<Request<Req, Resp>, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.rx.poll_recv(cx) {
            Poll::Ready(Some(r)) => {
                // IPC: a request whose format does not fit `Req` would
                // read as wrong values; declined (its responder dropped)
                if let (Encoding::Ipc, Some(theirs)) = (self.enc, &r.format) {
                    if let Err(e) = self.check.check::<Req>(&r.msg, theirs) {
                        return Poll::Ready(Some(Err(e)));
                    }
                }
                let v = decode::<Req>(self.enc, &r.data, r.order);
                Poll::Ready(Some(match v {
                    Ok(value) => Ok(Request {
                        value,
                        reply_msg: self.reply_msg.clone(),
                        enc: self.enc,
                        respond: Some(r.respond),
                        _t: PhantomData,
                    }),
                    Err(e) => Err(RecvError::Decode {
                        msg: r.msg,
                        ty: std::any::type_name::<Req>(),
                        detail: e,
                    }),
                }))
            }
            // the backend closed the channel: the session is gone (lost,
            // unless its user closed it)
            Poll::Ready(None) if !self.ended && !self.end.ended() => {
                self.ended = true;
                Poll::Ready(Some(Err(RecvError::Disconnected)))
            }
            Poll::Ready(None) => Poll::Ready(None),
            Poll::Pending => Poll::Pending,
        }
    }
}

// (by hand: a derive would want `Req: Debug, Resp: Debug`)
impl<Req, Resp> std::fmt::Debug for Requests<Req, Resp> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Requests")
            .field("reply_msg", &self.reply_msg)
            .field("request", &std::any::type_name::<Req>())
            .field("reply", &std::any::type_name::<Resp>())
            .finish_non_exhaustive()
    }
}
