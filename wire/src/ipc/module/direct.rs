//! Direct mode, sending and receiving side (ipc.md §8): links to other
//! modules, the handler lists that name them, and sends that wait for
//! their links.

use super::delivery::HandlerKind;
use super::event::Event;
use super::ops::Op;
use super::proto::{self, MsgInfo};
use super::replies::Pending;
use super::{class_order, Connection, DirectHandler, Error, Link, LinkId, LINK_WAIT};
use crate::ipc::frame::{ClassId, Deframer, Frame, Header, MsgClass, NO_REF, QUERY_REPLY_INTENT};
use crate::ipc::Reader;

impl Connection {
    /// Reports the direct listener's port (after [`Event::DirectListenRequested`]):
    /// sends `x_ipc_directResMsg {port, name}` and continues the handshake.
    pub fn announce_direct_port(&mut self, port: i32) {
        if let Some(pos) = self
            .ops
            .iter()
            .position(|o| matches!(o, Op::WaitDirectPort))
        {
            self.ops[pos] = Op::DirectRes(port);
            if self.blocked == Some(i32::MIN) {
                self.blocked = None;
            }
            self.pump();
        }
    }

    /// Bytes to write on a direct link (§8).
    pub fn poll_direct_transmit(&mut self) -> Option<(LinkId, Vec<u8>)> {
        self.direct_tx.pop_front()
    }

    pub(super) fn push_direct(&mut self, link: LinkId, frame: Frame) {
        let (head, data) = frame.into_parts();
        self.direct_tx.push_back((link, head));
        if let Some(data) = data {
            self.direct_tx.push_back((link, data));
        }
    }

    /// A peer connected to our direct listener: returns the link's handle
    /// for [`receive_direct`](Self::receive_direct).
    pub fn accept_direct(&mut self) -> LinkId {
        let link = LinkId(self.next_link);
        self.next_link += 1;
        self.link_in.insert(link, Deframer::new(self.cfg.max_frame));
        link
    }

    /// Bytes read from a direct link (accepted or connected), in any split:
    /// deliveries to our handlers (no Success ack is sent for them) and
    /// replies to our direct queries. A malformed stream closes only the
    /// link: the error is returned and the shell drops the socket.
    pub fn receive_direct(&mut self, link: LinkId, mut bytes: &[u8]) -> Result<(), Error> {
        let mut d = self
            .link_in
            .remove(&link)
            .unwrap_or_else(|| Deframer::new(self.cfg.max_frame));
        loop {
            let frame = match d.next(&mut bytes) {
                Ok(Some(f)) => f,
                Ok(None) => break,
                Err(e) => return Err(Error::DirectLink(format!("bad frame: {e}"))),
            };
            if frame.header.intent == QUERY_REPLY_INTENT {
                // Only the link a query went out on answers it (a listener
                // takes connections from anyone: a stranger answered other
                // modules' queries, and central's lookups). Others, and late
                // answers to cancelled queries, are ignored.
                let r = frame.header.msg_ref;
                if self.reply_links.get(&r) == Some(&link) {
                    self.reply_links.remove(&r);
                    self.handle_reply(frame)?;
                }
            } else if let Err(why) = self.check_link_delivery(&frame) {
                return Err(Error::DirectLink(why));
            } else if let Err(why) = self.inbox_room() {
                return Err(Error::DirectLink(why));
            } else {
                self.inbox.push_back((frame, Some(link)));
            }
        }
        // Frames half received on all direct links together hold at most
        // two of the largest frame (and a sixteenth of one for their
        // headers): past it the link that went over is
        // closed. A direct listener takes connections from anyone, and six
        // holding 200 MiB of a 255 MiB frame each took a module to 1.2 GB.
        let max = self.cfg.max_frame;
        let limit =
            usize::try_from(max.saturating_mul(2).saturating_add(max / 16)).unwrap_or(usize::MAX);
        let held: usize =
            self.link_in.values().map(Deframer::buffered).sum::<usize>() + d.buffered();
        if held > limit {
            return Err(Error::DirectLink(format!(
                "frames being received on direct links would hold {held} bytes, more than \
                 {limit} (twice the largest frame)"
            )));
        }
        self.link_in.insert(link, d);
        Ok(())
    }

    /// The shell connected direct link `link`: queued sends proceed.
    pub fn direct_link_up(&mut self, link: LinkId) {
        for l in self.links.values_mut() {
            if l.id == link {
                l.up = true;
            }
        }
        if self.blocked == Some(LINK_WAIT) {
            self.blocked = None;
            self.pump();
        }
    }

    /// The shell could not connect `link`: its receivers are skipped (as C
    /// does after a failed connect); queued sends proceed to the others.
    pub fn direct_link_failed(&mut self, link: LinkId) {
        let dead: Vec<(String, i32)> = self
            .links
            .iter()
            .filter(|(_, l)| l.id == link)
            .map(|(k, _)| k.clone())
            .collect();
        for k in &dead {
            self.links.remove(k);
            for list in self.direct_handlers.values_mut() {
                list.retain(|h| (h.host.as_str(), h.port) != (k.0.as_str(), k.1));
            }
        }
        self.direct_link_up(link);
    }

    /// A direct link the shell had (connected or accepted) closed: the peer
    /// left, or the link failed. A receiver still listed at its address
    /// gets a new link before the next send to it (a module that took the
    /// port of one that left, say), instead of frames for a dead link.
    pub fn direct_link_closed(&mut self, link: LinkId) {
        self.links.retain(|_, l| l.id != link);
        // (its queries stay pending, answerable by none, until the shell's
        // timeout cancels them; link ids are not reused)
        self.link_in.remove(&link);
        if self.blocked == Some(LINK_WAIT) {
            // a send waiting for its links looks again (and links anew)
            self.blocked = None;
            self.pump();
        }
    }

    /// Starts a link to each receiver of `list` that has none, or whose
    /// link was made for another module at the same address; true if each
    /// has one that is up.
    fn link_all(&mut self, list: &[DirectHandler]) -> bool {
        let mut all_up = true;
        for h in list {
            let key = (h.host.clone(), h.port);
            match self.links.get(&key) {
                Some(l) if l.module == h.module => all_up &= l.up,
                _ => {
                    let id = LinkId(self.next_link);
                    self.next_link += 1;
                    let module = h.module.clone();
                    self.links.insert(
                        key,
                        Link {
                            id,
                            up: false,
                            module,
                        },
                    );
                    self.events.push_back(Event::DirectConnect {
                        link: id,
                        host: h.host.clone(),
                        port: h.port,
                        module: h.module.clone(),
                    });
                    all_up = false;
                }
            }
        }
        all_up
    }

    pub(super) fn set_direct_handlers(&mut self, msg: &str, list: Vec<DirectHandler>) {
        self.link_all(&list);
        if !list.is_empty() {
            // queries that waited for a first handler go first, in order
            for op in self
                .awaiting_handler
                .remove(msg)
                .unwrap_or_default()
                .into_iter()
                .rev()
            {
                self.ops.push_front(op);
            }
        }
        self.direct_handlers.insert(msg.to_string(), list);
    }

    /// Sends a direct publish/query, first learning the receivers and
    /// waiting for their links, so that no message is lost.
    pub(super) fn direct_send(&mut self, op: Op, info: &MsgInfo) {
        let (op_id, msg, data, parent, query) = match op {
            Op::Publish {
                op,
                msg,
                data,
                parent,
            } => (op, msg, data, parent, false),
            Op::Query {
                op,
                msg,
                data,
                parent,
            } => (op, msg, data, parent, true),
            other => {
                self.ops.push_front(other);
                return;
            }
        };
        let rebuild = |msg: String, data: Vec<u8>| {
            if query {
                Op::Query {
                    op: op_id,
                    msg,
                    data,
                    parent,
                }
            } else {
                Op::Publish {
                    op: op_id,
                    msg,
                    data,
                    parent,
                }
            }
        };
        let Some(list) = self.direct_handlers.get(&msg).cloned() else {
            self.ops.push_front(rebuild(msg.clone(), data));
            self.ops.push_front(Op::DirectQuery { msg });
            return;
        };
        if !self.link_all(&list) {
            self.ops.push_front(rebuild(msg, data));
            self.blocked = Some(LINK_WAIT);
            return;
        }
        if list.is_empty() {
            if query {
                // No handler yet: the query waits for one, within the
                // asker's timeout, as a routed query waits in central.
                self.awaiting_handler
                    .entry(msg.clone())
                    .or_default()
                    .push(rebuild(msg, data));
                return;
            }
            // C: "No handlers for direct message"; reported, not silent.
            self.events
                .push_back(Event::PublishDropped { op: op_id, msg });
            return;
        }
        let body = match proto::wrap(info, &msg, data) {
            Ok(b) => b,
            Err((error, _)) => {
                self.events.push_back(Event::OpFailed { op: op_id, error });
                return;
            }
        };
        let msg_ref = self.next_msg_ref();
        let class = if query {
            MsgClass::Query
        } else {
            MsgClass::from_u16(info.class as u16).unwrap_or(MsgClass::Broadcast)
        };
        // Last handler first (C walks the list backwards); a query goes to
        // the first handler only.
        let targets: Vec<&DirectHandler> = if query {
            list.iter().take(1).collect()
        } else {
            list.iter().rev().collect()
        };
        let mut sent_on = None;
        for h in targets {
            let Some(link) = self.links.get(&(h.host.clone(), h.port)).map(|l| l.id) else {
                continue;
            };
            sent_on = Some(link);
            let frame = Frame {
                header: Header {
                    class_total: 0,
                    msg_total: 0,
                    parent_ref: parent,
                    intent: h.intent,
                    class_id: ClassId::native(class),
                    dispatch_ref: NO_REF,
                    msg_ref,
                },
                class_data: Vec::new(),
                data: body.clone(),
            };
            self.push_direct(link, frame);
        }
        if query {
            self.pending.insert(msg_ref, Pending::UserQuery(op_id));
            self.query_refs.insert(op_id, msg_ref);
            if let Some(link) = sent_on {
                self.reply_links.insert(msg_ref, link);
            }
        } else {
            self.events.push_back(Event::Published { op: op_id });
        }
    }

    /// Whether a frame that came on a direct link may be delivered: a
    /// peer sends only to our user handlers, for the message each handles.
    /// A frame for one of central's handlers (the broadcast list, connect
    /// notices, variables) ended the whole session when it did not decode,
    /// and one naming another message was delivered as the handler's.
    /// A handler we do not have is let through (and dropped): a peer's
    /// list may lag an unsubscribe.
    fn check_link_delivery(&self, frame: &Frame) -> Result<(), String> {
        let Some(h) = self.handlers.get(&frame.header.intent) else {
            return Ok(());
        };
        if h.kind != HandlerKind::User {
            return Err(format!(
                "a frame for central's handler {} ({}), which direct links do not carry",
                frame.header.intent, h.msg
            ));
        }
        if frame.class_data.is_empty() {
            return Ok(());
        }
        let named = class_order(&frame.header).ok().and_then(|o| {
            Reader::new(&frame.class_data, o)
                .read_str()
                .ok()
                .map(str::to_string)
        });
        match named {
            Some(m) if m == h.msg => Ok(()),
            Some(m) => Err(format!(
                "a frame of message {m} for handler {} of message {}",
                h.name, h.msg
            )),
            None => Err("a frame whose class data does not decode".into()),
        }
    }
}
