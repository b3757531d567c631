//! The API calls of a module (`IPC_defineMsg`, `IPC_subscribe`,
//! `IPC_publish`, …): each checks the connection and queues its
//! operation.

use super::delivery::HandlerKind;
#[cfg(doc)]
use super::event::Event;
use super::event::{DeliveryId, DeliveryKind, OpId};
use super::ops::Op;
use super::{Connection, Error, MsgLength, Stage, FRAME_ROOM};
use crate::ipc::Writer;

impl Connection {
    fn check_open(&self) -> Result<(), Error> {
        if matches!(self.stage, Stage::Closed) {
            Err(Error::Closed)
        } else {
            Ok(())
        }
    }

    /// Refuses a message whose frame would be larger than a frame may be.
    fn check_size(&self, msg: &str, data: &[u8]) -> Result<(), Error> {
        let max = self.cfg.max_frame.saturating_sub(FRAME_ROOM);
        if data.len() as u64 > max {
            return Err(Error::TooLarge {
                msg: msg.to_string(),
                len: data.len(),
                max,
            });
        }
        Ok(())
    }

    /// `IPC_defineFormat`: `x_ipc_registerNamedFormMsg {name, fmt}`.
    pub fn define_format(&mut self, name: &str, fmt: &str) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::DefineFormat {
            name: name.into(),
            fmt: fmt.into(),
        });
        Ok(())
    }

    /// `IPC_defineMsg`: `x_ipc_registerMessageMsg`, then a lookup.
    pub fn define_msg(
        &mut self,
        name: &str,
        len: MsgLength,
        user_format: Option<&str>,
    ) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::DefineMsg {
            name: name.into(),
            len,
            fmt: user_format.map(Into::into),
        });
        Ok(())
    }

    /// `IPC_subscribe`: registers handler `handler_name` for `msg`; returns
    /// its id (C's table: 199, 198, … descending). Re-subscribing the same
    /// name returns the same id and sends nothing.
    pub fn subscribe(&mut self, msg: &str, handler_name: &str) -> Result<i32, Error> {
        self.check_open()?;
        if let Some(id) = self
            .by_name
            .get(&(msg.to_string(), handler_name.to_string()))
        {
            return Ok(*id);
        }
        let id = self.alloc_handler(msg, handler_name, HandlerKind::User);
        self.push_op(Op::RegisterHandler {
            id,
            msg: msg.into(),
            hnd: handler_name.into(),
        });
        Ok(id)
    }

    /// `IPC_unsubscribe`: `x_ipc_deregisterHandlerMsg {0, msg, hnd}`.
    pub fn unsubscribe(&mut self, msg: &str, handler_name: &str) -> Result<(), Error> {
        self.check_open()?;
        let key = (msg.to_string(), handler_name.to_string());
        if let Some(id) = self.by_name.remove(&key) {
            self.handlers.remove(&id);
            self.retired.insert(key, id);
        }
        self.push_op(Op::Deregister {
            msg: msg.into(),
            hnd: handler_name.into(),
        });
        Ok(())
    }

    /// `IPC_publish`: wraps `data` per the message's format; the outcome is
    /// [`Event::Published`], [`Event::PublishDropped`] or [`Event::OpFailed`].
    /// `parent_ref` is the dispatch being handled (or -1). An owned `data`
    /// (a `Vec<u8>`) goes into the frame without being copied.
    pub fn publish(
        &mut self,
        msg: &str,
        data: impl Into<Vec<u8>>,
        parent_ref: i32,
    ) -> Result<OpId, Error> {
        self.check_open()?;
        let data = data.into();
        self.check_size(msg, &data)?;
        let op = self.alloc_op();
        self.push_op(Op::Publish {
            op,
            msg: msg.into(),
            data,
            parent: parent_ref,
        });
        Ok(op)
    }

    /// `IPC_queryNotify`/`IPC_queryResponse`: the answer comes as
    /// [`Event::Reply`]. `data` as in [`publish`](Self::publish).
    pub fn query(
        &mut self,
        msg: &str,
        data: impl Into<Vec<u8>>,
        parent_ref: i32,
    ) -> Result<OpId, Error> {
        self.check_open()?;
        let data = data.into();
        self.check_size(msg, &data)?;
        let op = self.alloc_op();
        self.push_op(Op::Query {
            op,
            msg: msg.into(),
            data,
            parent: parent_ref,
        });
        Ok(op)
    }

    /// `IPC_respond`: answers query delivery `delivery` with `reply_msg`
    /// (any time later, in any order: `IPC_delayResponse`).
    pub fn respond(
        &mut self,
        delivery: DeliveryId,
        reply_msg: &str,
        data: impl Into<Vec<u8>>,
    ) -> Result<(), Error> {
        self.check_open()?;
        let data = data.into();
        self.check_size(reply_msg, &data)?;
        let Some((kind, dispatch, link)) = self.unacked.get(&delivery).copied() else {
            return Err(Error::UnknownHandle(delivery));
        };
        if kind != DeliveryKind::Query {
            return Err(Error::UnknownHandle(delivery));
        }
        self.unacked.remove(&delivery);
        self.push_op(Op::Respond {
            delivery,
            msg: reply_msg.into(),
            data,
            dispatch,
            parent: dispatch,
            link,
        });
        Ok(())
    }

    /// Finishes query delivery `delivery` without an answer (the handler
    /// gave up, or its `Request` was dropped): through central, a Success
    /// frees this module's capacity slot there, so that the module keeps
    /// receiving; the asker gets no reply and runs into its timeout. On a
    /// direct link nothing is sent. (C has no such call: a C handler that
    /// never responds keeps the slot.)
    pub fn decline(&mut self, delivery: DeliveryId) -> Result<(), Error> {
        self.finish(delivery, DeliveryKind::Query)
    }

    /// Sends the Success ack of a broadcast delivery ("handler returned"),
    /// freeing a capacity slot in central.
    pub fn ack(&mut self, delivery: DeliveryId) -> Result<(), Error> {
        self.finish(delivery, DeliveryKind::Broadcast)
    }

    /// Forgets delivery `delivery` of `kind` and sends its Success to
    /// central (none on direct links, §8).
    fn finish(&mut self, delivery: DeliveryId, kind: DeliveryKind) -> Result<(), Error> {
        self.check_open()?;
        match self.unacked.get(&delivery).copied() {
            Some((k, dispatch, link)) if k == kind => {
                self.unacked.remove(&delivery);
                if link.is_none() {
                    self.send_success(dispatch);
                }
                Ok(())
            }
            _ => Err(Error::UnknownHandle(delivery)),
        }
    }

    /// The deliveries central may have outstanding with this module
    /// ([`set_capacity`](Self::set_capacity); 1 until set).
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// `IPC_setCapacity`: `x_ipc_registerResourceMsg {n, name}`.
    pub fn set_capacity(&mut self, n: i32) -> Result<(), Error> {
        self.check_open()?;
        let mut w = Writer::new();
        w.write_i32(n);
        w.write_str(&self.cfg.name);
        self.capacity = n.max(1) as usize;
        self.push_op(Op::Inform {
            msg: "x_ipc_registerResourceMsg",
            data: w.into_vec(),
        });
        Ok(())
    }

    /// `IPC_setMsgPriority`: `ipc_setMsgPriority {msg, p}`.
    pub fn set_priority(&mut self, msg: &str, priority: i32) -> Result<(), Error> {
        self.check_open()?;
        let mut w = Writer::new();
        w.write_str(msg);
        w.write_i32(priority);
        self.push_op(Op::Inform {
            msg: "ipc_setMsgPriority",
            data: w.into_vec(),
        });
        Ok(())
    }

    /// `IPC_setMsgQueueLength`: `x_ipc_limitPendingMsg {msg, name, n}`.
    pub fn set_queue_length(&mut self, msg: &str, n: i32) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::LimitPending {
            msg: msg.into(),
            limit: n,
        });
        Ok(())
    }

    /// `IPC_isModuleConnected`: answer in [`Event::ModuleConnected`].
    pub fn is_module_connected(&mut self, module: &str) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::ModuleConnectedQ {
            op,
            module: module.into(),
        });
        Ok(op)
    }

    /// Asks central about the other modules and messages (see
    /// [`crate::ipc::introspect`]): answer in [`Event::CentralAnswer`], or
    /// [`Event::OpFailed`] with [`Error::UnknownMessage`] when central does
    /// not offer that question (the C central has no `courier_getModules`).
    pub fn ask_central(&mut self, ask: crate::ipc::introspect::Ask) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::Ask { op, ask });
        Ok(op)
    }

    /// Looks `msg` up in central (`x_ipc_msgInfoMsg`, as a C module does
    /// before it first uses a message; safe for names central does not
    /// know, unlike `x_ipc_getMessageInfo`, which the C central 3.9.1 dies
    /// on): the answer is [`Event::LookedUp`]. A message already looked
    /// up is answered from what this connection learnt.
    pub fn look_up(&mut self, msg: &str) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::LookUp {
            op,
            msg: msg.into(),
        });
        Ok(op)
    }

    /// `IPC_numHandlers`: answer in [`Event::NumHandlers`].
    pub fn num_handlers(&mut self, msg: &str) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::NumHandlers {
            op,
            msg: msg.into(),
        });
        Ok(op)
    }

    /// `IPC_subscribeConnect`: [`Event::ModuleConnect`] for each module connecting.
    pub fn subscribe_connect(&mut self) -> Result<(), Error> {
        self.check_open()?;
        if !self.connect_subscribed {
            self.connect_subscribed = true;
            let m = "x_ipc_connectNotify";
            let id = self.alloc_handler(m, m, HandlerKind::ConnectNotify);
            self.push_op(Op::RegisterHandler {
                id,
                msg: m.into(),
                hnd: m.into(),
            });
        }
        Ok(())
    }

    /// `IPC_subscribeDisconnect`: [`Event::ModuleDisconnect`] for each module leaving.
    pub fn subscribe_disconnect(&mut self) -> Result<(), Error> {
        self.check_open()?;
        if !self.disconnect_subscribed {
            self.disconnect_subscribed = true;
            let m = "x_ipc_disconnectNotify";
            let id = self.alloc_handler(m, m, HandlerKind::DisconnectNotify);
            self.push_op(Op::RegisterHandler {
                id,
                msg: m.into(),
                hnd: m.into(),
            });
        }
        Ok(())
    }

    /// `IPC_subscribeHandlerChange`: the first time for `msg`, sends
    /// `x_ipc_notifyHandlerChange msg`, a `x_ipc_directMsgQuery` (its answer
    /// is reported as [`Event::NumHandlers`] with the returned id) and a
    /// `V_watch_<msg>` subscription (later changes: [`Event::HandlerChange`]).
    /// Further calls for the same message send nothing and return `None`,
    /// as in C.
    pub fn subscribe_handler_change(&mut self, msg: &str) -> Result<Option<OpId>, Error> {
        self.check_open()?;
        let w = format!("V_watch_{msg}");
        let key = (w.clone(), w.clone());
        if self.by_name.contains_key(&key) {
            return Ok(None);
        }
        let op = self.alloc_op();
        self.push_op(Op::Lookup(msg.into()));
        self.push_op(Op::NotifyHandlerChange { msg: msg.into() });
        self.push_op(Op::NumHandlers {
            op,
            msg: msg.into(),
        });
        let id = self.alloc_handler(&w, &w, HandlerKind::Watch(msg.into()));
        self.push_op(Op::RegisterHandler {
            id,
            msg: w.clone(),
            hnd: w,
        });
        Ok(Some(op))
    }

    /// `IPC_disconnect`: `x_ipc_CloseMsg`, then the shell closes the socket
    /// once [`poll_transmit`](Self::poll_transmit) is drained.
    pub fn close(&mut self) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::Close);
        Ok(())
    }
}
