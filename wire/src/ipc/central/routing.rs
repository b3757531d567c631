//! Routing: a module's message or central's own broadcast becomes
//! dispatches, each delivered to its handler's module (or queued), and the
//! Success or Reply that completes it.

use std::time::SystemTime;

use super::log::{self, Kind};
use super::process::read_opt_str;
use super::tables::{
    awaits_answer, broken, unqueue, Carry, Dispatch, DispatchId, Linked, Org, Status,
};
use super::{Bad, Body, Central, ConnId};
use crate::ipc::frame::{ClassId, Header, MsgClass, NO_REF, QUERY_REPLY_INTENT};
use crate::ipc::{ByteOrder, Reader, Writer};

impl Central {
    pub(super) fn route(
        &mut self,
        conn: ConnId,
        h: Header,
        name: String,
        data: Body,
        now: SystemTime,
    ) -> Result<(), Bad> {
        let class = h.class_id.class();
        let org = Org::Module(conn);
        match class {
            15 => {
                let hnds = self.msgs.linked(name.as_str())?.handlers.clone();
                for hnd in hnds {
                    let did = self.alloc_dispatch(Dispatch {
                        msg: name.clone(),
                        class,
                        class_id: h.class_id,
                        org,
                        org_gone: None,
                        org_ref: h.msg_ref,
                        parent_ref: h.parent_ref,
                        data: data.clone(),
                        hnd: Some(hnd),
                        status: Status::NoHandler,
                    });
                    self.deliver_or_pend(did, now);
                }
            }
            3 | 6 => {
                let hnd = self.msgs.linked(name.as_str())?.handlers.last().cloned();
                let did = self.alloc_dispatch(Dispatch {
                    msg: name.clone(),
                    class,
                    class_id: h.class_id,
                    org,
                    org_gone: None,
                    org_ref: h.msg_ref,
                    parent_ref: h.parent_ref,
                    data,
                    hnd: hnd.clone(),
                    status: Status::NoHandler,
                });
                if hnd.is_some() {
                    self.deliver_or_pend(did, now);
                } else {
                    self.msgs.linked_mut(name.as_str())?.waiting.push_back(did);
                    self.bound_waiting(conn, &name, did)?;
                    if self.logs(Kind::Message, &name) {
                        let to = format!("Resource {name:<6} (Pending)");
                        let org_name = self.module_name(org);
                        let line = self.dispatch_line(
                            class,
                            &name,
                            Some(did),
                            &org_name,
                            h.parent_ref,
                            &to,
                            now,
                        );
                        self.log_line(Kind::Message, line);
                    }
                }
            }
            other => {
                let who = self.describe(conn);
                self.complain(
                    conn,
                    format!(
                        "WARNING: {name} sent with class {} ({other}) by {who}: not supported by IPC; ignored",
                        log::class_name(other)
                    ),
                );
            }
        }
        Ok(())
    }

    /// Central's own broadcast (`centralBroadcast`): notifications and
    /// `V_watch_*` updates.
    pub(super) fn central_broadcast(&mut self, name: &str, write: impl FnOnce(&mut Writer)) {
        let mut w = Writer::new();
        write(&mut w);
        self.central_broadcast_bytes(name, w.into_vec());
    }

    pub(super) fn central_broadcast_bytes(&mut self, name: &str, bytes: Vec<u8>) {
        let Some(m) = self.msgs.get(name) else {
            return;
        };
        let hnds = m.handlers.clone();
        if hnds.is_empty() {
            return;
        }
        // Watchers of a variable now know its current value.
        if let Some(var) = name.strip_prefix("V_watch_") {
            for (conn, _) in &hnds {
                self.note_var_read(*conn, var);
            }
        }
        let data = Body::from(bytes);
        for hnd in hnds {
            self.central_deliver(name, data.clone(), hnd);
        }
    }

    /// One delivery of central's own broadcast `name` to handler `hnd`.
    pub(super) fn central_deliver(&mut self, name: &str, data: Body, hnd: (ConnId, String)) {
        let did = self.alloc_dispatch(Dispatch {
            msg: name.to_string(),
            class: MsgClass::Broadcast as u16,
            class_id: ClassId::native(MsgClass::Broadcast),
            org: Org::Central,
            org_gone: None,
            org_ref: NO_REF,
            parent_ref: NO_REF,
            data,
            hnd: Some(hnd),
            status: Status::NoHandler,
        });
        self.deliver_or_pend(did, self.clock);
    }

    pub(super) fn deliver_or_pend(&mut self, did: DispatchId, now: SystemTime) {
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        let Some(conn) = d.hnd.as_ref().map(|h| h.0) else {
            return;
        };
        let Some(m) = self.modules.get(&conn) else {
            self.free_dispatch_id(did);
            return;
        };
        if m.takes_delivery_now() {
            self.attend(did, false, now);
        } else {
            self.pend(did, now);
        }
    }

    pub(super) fn attend(&mut self, did: DispatchId, from_pending: bool, now: SystemTime) {
        self.attend_as(did, from_pending, now, Carry::Frame)
    }

    /// A delivery takes one of its module's capacity slots: it is written
    /// (as `carry` says), counted and logged.
    pub(super) fn attend_as(
        &mut self,
        did: DispatchId,
        from_pending: bool,
        now: SystemTime,
        carry: Carry<'_>,
    ) {
        // Nothing is cloned here unless the delivery is logged: this runs
        // for every message central routes.
        let Some(d) = self.dispatches.get_mut(&did) else {
            return;
        };
        let Some((conn, hnd_name)) = d.hnd.as_ref() else {
            return;
        };
        let conn = *conn;
        unqueue(&mut self.stats, d);
        d.status = Status::Attending;
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        m.attending += 1;
        if awaits_answer(d.class) {
            m.answering += 1;
        }
        if !m.handlers.contains_key(hnd_name) {
            return;
        }
        match carry {
            Carry::Frame => self.write_delivery(did, None),
            Carry::Relayed(first, total) => self.write_delivery(did, Some((first, total))),
            Carry::Ahead => {}
        }
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        if self.logs(Kind::Message, &d.msg) {
            let (msg, class, class_id, org, parent_ref, data) = (
                d.msg.clone(),
                d.class,
                d.class_id,
                d.org,
                d.parent_ref,
                d.data.clone(),
            );
            let dest = self
                .modules
                .get(&conn)
                .and_then(|m| m.name.clone())
                .unwrap_or_default();
            let o = self.opts();
            let line = if from_pending {
                format!(
                    "{:<9} {:>15}{}: Resource {} --> {:<15} (Sent){}",
                    log::class_name(class),
                    msg,
                    log::ref_id(&o, did),
                    dest,
                    dest,
                    log::time(&o, now)
                )
            } else {
                let to = format!("{dest:<15} (Sent)");
                let org_name = self.module_name(org);
                self.dispatch_line(class, &msg, Some(did), &org_name, parent_ref, &to, now)
            };
            self.log_line(Kind::Message, line);
            self.log_data(&msg, class_id, &data, None);
        }
    }

    /// Writes delivery `did` to its handler's module. `relayed`: the body's
    /// first bytes and its whole length, for a frame forwarded while it
    /// arrives (the rest follows by [`Self::relay_bytes`]).
    pub(super) fn write_delivery(&mut self, did: DispatchId, relayed: Option<(&[u8], usize)>) {
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        let Some((conn, hnd_name)) = d.hnd.as_ref() else {
            return;
        };
        let Some(m) = self.modules.get(conn) else {
            return;
        };
        let Some(hnd) = m.handlers.get(hnd_name) else {
            return;
        };
        let conn = *conn;
        let mut cd = Writer::new();
        if !hnd.knows_msg {
            cd.write_str(&d.msg);
        }
        let header = Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: d.parent_ref,
            intent: hnd.id,
            class_id: ClassId(
                (d.class_id.0 & 0x0fff_0000)
                    | (ClassId::native(MsgClass::Unknown).0 & 0xf000_0000)
                    | d.class as u32,
            ),
            dispatch_ref: NO_REF,
            msg_ref: did.0,
        };
        let resume = m.paused;
        match relayed {
            None => {
                let data = d.data.clone();
                self.transmit_frame(conn, header, cd.as_bytes(), &data);
            }
            Some((first, total)) => {
                let f = Self::head(header, cd.as_bytes(), first, total);
                self.transmit_relayed(conn, f);
            }
        }
        if resume {
            // Its acknowledgements must be read.
            self.resume_read(conn);
        }
    }

    pub(super) fn on_success(
        &mut self,
        conn: ConnId,
        did: DispatchId,
        now: SystemTime,
    ) -> Result<(), Bad> {
        // A module that finishes a message sent ahead before the ones it
        // was given earlier (it handles them concurrently): the message
        // takes its slot now, so that it is logged as sent before done.
        let ahead = self.modules.get(&conn).and_then(|m| {
            let d = self.dispatches.get(&did)?;
            let here = d.hnd.as_ref().is_some_and(|(c, _)| *c == conn);
            (d.status == Status::Ahead && here).then(|| m.ahead.iter().position(|x| *x == did))?
        });
        if let Some(i) = ahead {
            self.modules.linked_mut(&conn)?.ahead.remove(i);
            self.attend_as(did, true, now, Carry::Ahead);
        }
        let ok = self
            .dispatches
            .get(&did)
            .is_some_and(|d| d.attending_at(conn));
        if !ok {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!(
                    "WARNING: Success for unknown or foreign dispatch {did} from {who} ignored"
                ),
            );
            return Ok(());
        }
        let d = self.free_dispatch_id(did).ok_or_else(|| broken(&did))?;
        if self.logs(Kind::Message, &d.msg) {
            let word = if d.class == 6 || d.class == 15 {
                "Done    "
            } else {
                "Success "
            };
            let o = self.opts();
            let line = format!(
                "  {word}{:>15}{}:{}",
                d.msg,
                log::ref_id(&o, did),
                log::time(&o, now)
            );
            self.log_line(Kind::Message, line);
        }
        self.handled(conn, d.class);
        self.process_pending(conn, now);
        Ok(())
    }

    pub(super) fn on_reply(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        data: Body,
        now: SystemTime,
    ) -> Result<(), Bad> {
        let did = DispatchId(h.dispatch_ref);
        let ok = self
            .dispatches
            .get(&did)
            .is_some_and(|d| d.attending_at(conn));
        if !ok {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!("WARNING: Reply for unknown or foreign dispatch {did} from {who} ignored"),
            );
            return Ok(());
        }
        let reply_name = if class_data.is_empty() {
            None
        } else {
            let order = h.class_id.class_order().unwrap_or(ByteOrder::NATIVE);
            read_opt_str(&mut Reader::new(class_data, order))?
        };
        let d = self.dispatches.linked(&did)?;
        if let Org::Module(org) = d.org {
            if self.modules.get(&org).is_some_and(|m| !m.closed) {
                let header = Self::reply_header(&h, did, d.org_ref);
                self.transmit_frame(org, header, class_data, &data);
            }
        }
        self.reply_done(conn, h, reply_name, Some(&data), now);
        Ok(())
    }

    /// The header of a reply forwarded to the module that asked.
    pub(super) fn reply_header(h: &Header, did: DispatchId, org_ref: i32) -> Header {
        Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: h.parent_ref,
            intent: QUERY_REPLY_INTENT,
            class_id: h.class_id,
            dispatch_ref: did.0,
            msg_ref: org_ref,
        }
    }

    /// What follows a reply once it has gone to the asking module: the
    /// query is complete, its log lines, and the responder takes its next.
    /// `data`: the reply's body, for the data log (`None` when it was
    /// forwarded while it arrived, which data logging rules out).
    pub(super) fn reply_done(
        &mut self,
        conn: ConnId,
        h: Header,
        reply_name: Option<String>,
        data: Option<&[u8]>,
        now: SystemTime,
    ) {
        let did = DispatchId(h.dispatch_ref);
        let Some(d) = self.free_dispatch_id(did) else {
            return;
        };
        if self.logs(Kind::Message, &d.msg) {
            let responder = self.module_name(Org::Module(conn));
            let org_alive = match d.org {
                Org::Module(c) => self.modules.get(&c).is_some_and(|m| !m.closed),
                Org::Central => false,
            };
            let o = self.opts();
            let line = format!(
                "  Reply  {:>15}{}: {:>10} --> {:<15}{}{}",
                d.msg,
                log::ref_id(&o, did),
                responder,
                self.org_name(&d),
                log::parent_id(&o, d.parent_ref),
                log::time(&o, now)
            );
            self.log_line(Kind::Message, line);
            // C warns from its two-way-message branch only, which tests
            // the message's registered class: an IPC message (registered
            // as a broadcast) is answered to a dead querier silently.
            let two_way = self
                .msgs
                .get(&d.msg)
                .is_some_and(|m| matches!(m.class, MsgClass::Query | MsgClass::MultiQuery));
            if !org_alive && two_way {
                let dead = self.org_name(&d);
                self.log_line(
                    Kind::Message,
                    format!("WARNING: Reply Ignored for dead module: {dead}"),
                );
            }
            if let Some(data) = data {
                let rn = reply_name.clone().unwrap_or(d.msg.clone());
                self.log_data(&d.msg, h.class_id, data, Some(&rn));
            }
        }
        self.handled(conn, d.class);
        self.process_pending(conn, now);
    }

    /// `conn` finished handling a delivery of class `class`.
    pub(super) fn handled(&mut self, conn: ConnId, class: u16) {
        if let Some(m) = self.modules.get_mut(&conn) {
            m.attending = m.attending.saturating_sub(1);
            if awaits_answer(class) {
                m.answering = m.answering.saturating_sub(1);
            }
        }
    }
}
