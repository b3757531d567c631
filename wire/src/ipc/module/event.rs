//! What the module state machine tells its shell: [`Event`]s, and the
//! handles (operations, deliveries) they refer to.

#[cfg(doc)]
use super::Connection;
use super::{Error, LinkId};
use crate::ipc::ByteOrder;

/// Handle of an API operation (publish, query, …), unique per connection.
pub type OpId = u64;
/// Handle of a delivery awaiting [`Connection::ack`] or [`Connection::respond`].
pub type DeliveryId = u64;

/// Class of a delivery.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeliveryKind {
    /// A published message (needs [`Connection::ack`]).
    Broadcast,
    /// A query (needs [`Connection::respond`]).
    Query,
}

/// Something the shell must know about.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Event {
    /// Central answered `newModuleConnect` with `direct = 1`: open a listener
    /// and call [`Connection::announce_direct_port`].
    DirectListenRequested,
    /// The handshake is complete (`IPC_connect` returned).
    Connected,
    /// A message for one of our handlers.
    Delivery {
        /// Handle for [`Connection::ack`] / [`Connection::respond`].
        delivery: DeliveryId,
        /// Our handler id (the frame's intent).
        handler: i32,
        /// Message name.
        msg: String,
        /// Broadcast or query.
        kind: DeliveryKind,
        /// Central's dispatch id.
        dispatch_ref: i32,
        /// Parent ref of the frame.
        parent_ref: i32,
        /// Byte order of `data`.
        order: ByteOrder,
        /// User bytes, unwrapped from the message format.
        data: Vec<u8>,
    },
    /// Reply to a [`Connection::query`].
    Reply {
        /// The query's handle.
        query: OpId,
        /// Reply message name (class data).
        reply_msg: String,
        /// Byte order of `data`.
        order: ByteOrder,
        /// User bytes, unwrapped according to the reply message's format
        /// when it is known to this module, else the raw body.
        data: Vec<u8>,
    },
    /// A publish was executed and sent to central.
    Published {
        /// The publish's handle.
        op: OpId,
    },
    /// A publish was dropped because no module subscribes the message
    /// (C's `x_ipcBroadcast` does this silently).
    PublishDropped {
        /// The publish's handle.
        op: OpId,
        /// Message name.
        msg: String,
    },
    /// A message for one of our handlers whose body does not hold together
    /// (its variable-length wrapper disagrees with itself). It was not
    /// delivered; central was told it is done (a Success), so the sender of
    /// a query gets no reply. The connection is unharmed: one bad sender
    /// must not cut a module off from everyone else.
    Undeliverable {
        /// Our handler id.
        handler: i32,
        /// Message name.
        msg: String,
        /// Published or queried.
        kind: DeliveryKind,
        /// What was wrong with it.
        error: Error,
    },
    /// The reply to query delivery `delivery` ([`Connection::respond`]) is
    /// sent.
    Replied {
        /// The query delivery answered.
        delivery: DeliveryId,
    },
    /// The reply to query delivery `delivery` could not be sent (its reply
    /// message is unknown to central). The query was declined instead (see
    /// [`Connection::decline`]): the module's capacity in central is free
    /// again, and the asker gets no reply.
    ReplyFailed {
        /// The query delivery.
        delivery: DeliveryId,
        /// Why.
        error: Error,
    },
    /// An operation failed (e.g. its message is unknown to central).
    OpFailed {
        /// The operation's handle.
        op: OpId,
        /// Why.
        error: Error,
    },
    /// Answer of [`Connection::ask_central`].
    CentralAnswer {
        /// The operation's handle.
        op: OpId,
        /// What central said.
        answer: crate::ipc::introspect::Answer,
    },
    /// Answer of [`Connection::is_module_connected`].
    ModuleConnected {
        /// The operation's handle.
        op: OpId,
        /// Whether the module is connected.
        connected: bool,
    },
    /// Answer of [`Connection::look_up`]: what central knows of the
    /// message (`None`: it does not know it).
    LookedUp {
        /// The operation's handle.
        op: OpId,
        /// Central's answer.
        info: Option<super::MsgInfo>,
    },
    /// Answer of [`Connection::num_handlers`].
    NumHandlers {
        /// The operation's handle.
        op: OpId,
        /// Handler count.
        count: i32,
    },
    /// `x_ipc_connectNotify`: a module connected.
    ModuleConnect(String),
    /// `x_ipc_disconnectNotify`: a module disconnected.
    ModuleDisconnect(String),
    /// `V_watch_<msg>`: the handler count of `msg` changed.
    HandlerChange {
        /// Message name.
        msg: String,
        /// New handler count.
        count: i32,
    },
    /// Direct mode: connect to a receiver's listener (TCP, or the UNIX socket
    /// `/tmp/x_ipc/<port>` when `host` is our host name), then call
    /// [`Connection::direct_link_up`] or [`Connection::direct_link_failed`].
    /// Sends of direct messages wait until then (nothing is lost).
    DirectConnect {
        /// The link's handle.
        link: LinkId,
        /// Receiver's reported host name.
        host: String,
        /// Receiver's listen port.
        port: i32,
        /// Receiver's module name.
        module: String,
    },
    /// The connection failed or was closed; nothing more will happen.
    Closed(Option<Error>),
}
