//! Cut-through ([`Config::cut_through`](super::Config::cut_through)): a
//! large message or reply forwarded to its receiver while it still
//! arrives.

use std::time::SystemTime;

use super::log::Kind;
use super::process::read_opt_str;
use super::tables::{Carry, Dispatch, DispatchId, Linked, MsgId, Org, Relay, Status};
use super::{Bad, Body, Central, ConnId};
use crate::ipc::frame::{Header, HEADER_SIZE};
use crate::ipc::{ByteOrder, Reader};

impl Central {
    /// Passes the start of `bytes` on if a frame from `conn` is being
    /// forwarded; returns what follows that frame.
    pub(super) fn relay_bytes<'a>(&mut self, conn: ConnId, bytes: &'a [u8]) -> &'a [u8] {
        let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.as_mut()) else {
            return bytes;
        };
        let k = r.remaining.min(bytes.len());
        r.remaining -= k;
        let (to, done) = (r.to, r.remaining == 0);
        if k > 0 {
            self.transmit_relayed(to, bytes[..k].to_vec());
        }
        if done {
            self.finish_relay(conn);
        }
        &bytes[k..]
    }

    /// Starts forwarding the frame whose header (and class data) is at the
    /// front of `conn`'s receive buffer, if
    /// [`Config::cut_through`](super::Config::cut_through) allows it and its
    /// receiver can take it now. True if it did: the buffer's bytes have gone
    /// out with the frame's new header.
    pub(super) fn try_relay(
        &mut self,
        conn: ConnId,
        h: Header,
        n: usize,
        now: SystemTime,
    ) -> Result<bool, Bad> {
        let Some(min) = self.config.cut_through else {
            return Ok(false);
        };
        let data_log = Kind::Data.enabled(&self.config.terminal_log)
            || Kind::Data.enabled(&self.config.file_log);
        if n < min || data_log || self.config.resend_on_reconnect {
            return Ok(false);
        }
        let m = self.modules.linked(&conn)?;
        let c = h.class_total as usize;
        let avail = m.rx.len() - m.rx_pos;
        if m.relay.is_some() || avail < HEADER_SIZE + c {
            return Ok(false);
        }
        if h.class_id.data_order().is_none() || h.class_id.class_order().is_none() {
            // `process` closes the connection once the frame is whole.
            return Ok(false);
        }
        let start = m.rx_pos + HEADER_SIZE;
        let class_data = m.rx[start..start + c].to_vec();
        let first = m.rx[start + c..].to_vec();
        let total = n - c;
        let class = h.class_id.class();
        let started = match class {
            11 => self.relay_reply(conn, h, &class_data, &first, total)?,
            3 | 6 | 15 => self.relay_delivery(conn, h, &first, total, now)?,
            _ => false,
        };
        if started {
            let m = self.modules.linked_mut(&conn)?;
            m.rx_pos = m.rx.len();
            self.stats.frames_in += 1;
            self.watch_frame(conn, now);
        }
        Ok(started)
    }

    /// A receiver that can take a relayed frame now.
    fn can_take_relay(&self, from: ConnId, to: ConnId) -> bool {
        from != to
            && self
                .modules
                .get(&to)
                .is_some_and(|m| !m.closed && m.relay_from.is_none())
    }

    fn relay_delivery(
        &mut self,
        conn: ConnId,
        h: Header,
        first: &[u8],
        total: usize,
        now: SystemTime,
    ) -> Result<bool, Bad> {
        let class = h.class_id.class();
        let Some(name) = h
            .intent
            .checked_abs()
            .and_then(|id| self.by_id.get(&MsgId(id)))
            .cloned()
        else {
            return Ok(false);
        };
        let msg = self.msgs.linked(name.as_str())?;
        if msg.internal.is_some() {
            return Ok(false);
        }
        let hnd = match (class, msg.handlers.as_slice()) {
            (15, [only]) => only.clone(),
            (3 | 6, [.., last]) => last.clone(),
            _ => return Ok(false),
        };
        let to = self.modules.linked(&hnd.0)?;
        let free = to.takes_delivery_now() && to.handlers.contains_key(&hnd.1);
        if !free || !self.can_take_relay(conn, hnd.0) {
            return Ok(false);
        }
        self.start_relay(conn, hnd.0, name.clone(), total - first.len(), total, None)?;
        let did = self.alloc_dispatch(Dispatch {
            msg: name.clone(),
            class,
            class_id: h.class_id,
            org: Org::Module(conn),
            org_gone: None,
            org_ref: h.msg_ref,
            parent_ref: h.parent_ref,
            // Never stored: it passes through.
            data: Body::empty(),
            hnd: Some(hnd),
            status: Status::NoHandler,
        });
        self.attend_as(did, false, now, Carry::Relayed(first, total));
        Ok(true)
    }

    fn relay_reply(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        first: &[u8],
        total: usize,
    ) -> Result<bool, Bad> {
        let did = DispatchId(h.dispatch_ref);
        let Some(d) = self.dispatches.get(&did).filter(|d| d.attending_at(conn)) else {
            return Ok(false);
        };
        let Org::Module(org) = d.org else {
            return Ok(false);
        };
        if !self.can_take_relay(conn, org) {
            return Ok(false);
        }
        let reply_name = if class_data.is_empty() {
            None
        } else {
            let order = h.class_id.class_order().unwrap_or(ByteOrder::NATIVE);
            match read_opt_str(&mut Reader::new(class_data, order)) {
                Ok(n) => n,
                // `on_reply` reports it once the frame is whole.
                Err(_) => return Ok(false),
            }
        };
        let msg = d.msg.clone();
        let header = Self::reply_header(&h, did, d.org_ref);
        let head = Self::head(header, class_data, first, total);
        let remaining = total - first.len();
        self.start_relay(conn, org, msg, remaining, total, Some((h, reply_name)))?;
        self.transmit_relayed(org, head);
        Ok(true)
    }

    fn start_relay(
        &mut self,
        from: ConnId,
        to: ConnId,
        msg: String,
        remaining: usize,
        total: usize,
        reply: Option<(Header, Option<String>)>,
    ) -> Result<(), Bad> {
        // Both ends first: a half-made pair would hold the receiver's
        // frames for ever.
        self.modules.linked(&from)?;
        self.modules.linked_mut(&to)?.relay_from = Some(from);
        self.modules.linked_mut(&from)?.relay = Some(Relay {
            to,
            remaining,
            total,
            msg,
            reply,
        });
        Ok(())
    }

    /// The relayed frame from `conn` has passed: frames held for its
    /// receiver go out, and a reply's bookkeeping is done.
    fn finish_relay(&mut self, conn: ConnId) {
        let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.take()) else {
            return;
        };
        if let Some(to) = self.modules.get_mut(&r.to) {
            to.relay_from = None;
            let held = std::mem::take(&mut to.held);
            for (head, body) in held {
                self.transmit_parts(r.to, head, body);
            }
        }
        if let Some((h, reply_name)) = r.reply {
            let now = self.clock;
            self.reply_done(conn, h, reply_name, None, now);
        }
    }

    /// The sender of a relayed frame is gone: its receiver already has the
    /// start, so the frame is completed with zeros to keep the stream whole.
    pub(super) fn abandon_relay(&mut self, conn: ConnId) {
        let Some(r) = self.modules.get(&conn).and_then(|m| m.relay.as_ref()) else {
            return;
        };
        let (to, remaining, total, msg) = (r.to, r.remaining, r.total, r.msg.clone());
        let from = self.describe(conn);
        let dest = self.describe(to);
        self.log_line(
            Kind::Problem,
            format!(
                "WARNING: connection {from} ended in the middle of {msg} ({} of {total} bytes \
                 forwarded); the rest went to {dest} as zero bytes",
                total - remaining
            ),
        );
        if remaining > 0 {
            self.transmit_relayed(to, vec![0; remaining]);
        }
        if let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.as_mut()) {
            r.remaining = 0;
        }
        self.finish_relay(conn);
    }
}
