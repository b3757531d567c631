//! Connections: a module connecting, its bytes read and cut into frames,
//! frames written to it, and its connection closed (a protocol error, its
//! goodbye or its end of stream).

use std::collections::VecDeque;
use std::time::SystemTime;

use super::internal;
use super::log::{self, Kind};
use super::small_map::SmallMap;
use super::tables::{unqueue, DispatchId, Linked, Module, Org, Status, FIRST_SD};
use super::{Bad, Body, Central, ConnId, Output, Peer};
use crate::ipc::frame::{ClassId, Header, MsgClass, HEADER_SIZE, QUERY_REPLY_INTENT, SPLIT_AT};
use crate::ipc::Writer;

impl Central {
    fn transmit(&mut self, conn: ConnId, bytes: Vec<u8>) {
        self.transmit_parts(conn, bytes, None);
    }

    /// A frame: `head`, then `body` if any.
    pub(super) fn transmit_parts(&mut self, conn: ConnId, head: Vec<u8>, body: Option<Body>) {
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            return;
        }
        if m.relay_from.is_some() {
            // Not in the middle of the frame being forwarded to it.
            m.held.push((head, body));
        } else {
            self.outputs.push_back(match body {
                None => Output::Transmit { conn, bytes: head },
                Some(body) => Output::TransmitBody { conn, head, body },
            });
        }
    }

    /// A frame carrying `data`: a large one shares it
    /// ([`Output::TransmitBody`]), a small one is one buffer.
    pub(super) fn transmit_frame(
        &mut self,
        conn: ConnId,
        header: Header,
        class_data: &[u8],
        data: &Body,
    ) {
        if data.len() >= SPLIT_AT {
            let head = Self::head(header, class_data, &[], data.len());
            self.transmit_parts(conn, head, Some(data.clone()));
        } else {
            let f = Self::frame(header, class_data, data);
            self.transmit(conn, f);
        }
    }

    /// Bytes of the frame being forwarded to `conn` (never held).
    pub(super) fn transmit_relayed(&mut self, conn: ConnId, bytes: Vec<u8>) {
        if self.modules.get(&conn).is_some_and(|m| !m.closed) {
            self.outputs.push_back(Output::Transmit { conn, bytes });
        }
    }

    pub(super) fn frame(header: Header, class_data: &[u8], data: &[u8]) -> Vec<u8> {
        Self::head(header, class_data, data, data.len())
    }

    /// A frame's header and class data followed by `data`, which is the
    /// whole body (`data_len` bytes) or, for a relayed frame, its start.
    pub(super) fn head(header: Header, class_data: &[u8], data: &[u8], data_len: usize) -> Vec<u8> {
        let mut h = header;
        h.class_total = class_data.len() as i32;
        h.msg_total = data_len as i32;
        let mut out = Vec::with_capacity(HEADER_SIZE + class_data.len() + data.len());
        out.extend_from_slice(&h.encode());
        out.extend_from_slice(class_data);
        out.extend_from_slice(data);
        out
    }

    /// `centralReply`: parentRef 0, intent -4, class 0, dispatchRef 0.
    pub(super) fn reply(&mut self, conn: ConnId, msg_ref: i32, data: &[u8]) {
        let h = Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: 0,
            intent: QUERY_REPLY_INTENT,
            class_id: ClassId::native(MsgClass::Unknown),
            dispatch_ref: 0,
            msg_ref,
        };
        let f = Self::frame(h, &[], data);
        self.transmit(conn, f);
    }

    /// The lowest socket number no module has (see `Module::sd`).
    fn free_sd(&self) -> i32 {
        let mut used: Vec<i32> = self.modules.values().map(|m| m.sd).collect();
        used.sort_unstable();
        let mut sd = FIRST_SD;
        for u in used {
            if u == sd {
                sd += 1;
            } else if u > sd {
                break;
            }
        }
        sd
    }

    /// A module connected: queues the 4-byte msgInfo id and the two
    /// formatter frames central speaks first (ipc.md §4).
    pub fn connect(&mut self, conn: ConnId, peer: Peer, now: SystemTime) {
        self.clock = now;
        self.stranger_summary(now);
        self.expect_name(conn, now);
        let sd = self.free_sd();
        self.modules.insert(
            conn,
            Box::new(Module {
                peer,
                sd,
                rx: Vec::new(),
                rx_pos: 0,
                name: None,
                host: String::new(),
                ready: false,
                capacity: 1,
                attending: 0,
                answering: 0,
                asking: 0,
                pending: VecDeque::new(),
                ahead: VecDeque::new(),
                msg_limits: Vec::new(),
                pending_limit: None,
                port: -1,
                handlers: SmallMap::new(),
                retired: SmallMap::new(),
                vars_read: SmallMap::new(),
                paused: false,
                frame_wait: false,
                closed: false,
                problems: log::ProblemBudget::default(),
                quiet: None,
                timed_out: false,
                relay: None,
                relay_from: None,
                held: Vec::new(),
                big_end: None,
                frame_progress: now,
            }),
        );
        let id = self.msgs.get(internal::MSG_INFO).and_then(|m| m.id);
        self.transmit(conn, id.map_or(0, |id| id.0).to_be_bytes().to_vec());
        for f in [self.msg_info_query.clone(), self.msg_info_reply.clone()] {
            let mut w = Writer::new();
            internal::write_formatter(&mut w, Some(&f));
            let h = Header {
                class_total: 0,
                msg_total: 0,
                parent_ref: 0,
                intent: 0,
                class_id: ClassId::native(MsgClass::Unknown),
                dispatch_ref: 0,
                msg_ref: 0,
            };
            let fr = Self::frame(h, &[], w.as_bytes());
            self.transmit(conn, fr);
        }
    }

    /// Bytes arrived on a connection (any split of the stream).
    pub fn receive(&mut self, conn: ConnId, bytes: &[u8], now: SystemTime) {
        self.clock = now;
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            return;
        }
        if m.big_end.is_some() || m.relay.is_some() {
            m.frame_progress = now;
        }
        // (what this adds to the queues: see `check_memory` below)
        let queued_before = self.queued_by_modules;
        let mut bytes = self.relay_bytes(conn, bytes);
        loop {
            let Some(m) = self.modules.get_mut(&conn) else {
                return;
            };
            match m.big_end {
                // A large frame's buffer takes its own bytes only.
                Some(end) => {
                    let k = (end - m.rx.len()).min(bytes.len());
                    m.rx.extend_from_slice(&bytes[..k]);
                    bytes = &bytes[k..];
                    if m.rx.len() == end {
                        m.big_end = None;
                    }
                }
                None => {
                    m.rx.extend_from_slice(bytes);
                    bytes = &[];
                }
            }
            if !self.take_frames(conn, now) {
                return;
            }
            if bytes.is_empty() {
                break;
            }
        }
        if let Some(m) = self.modules.get_mut(&conn) {
            if m.rx_pos == m.rx.len() {
                m.rx.clear();
                m.rx_pos = 0;
                // Everything was taken in: an idle module keeps no buffer
                // (however large what arrived at once made it).
                m.rx = Vec::new();
            } else if m.rx_pos > 0 {
                m.rx.drain(..m.rx_pos);
                m.rx_pos = 0;
            }
        }
        // Over the memory bound, a module whose frames queued messages is
        // read no more for now. One whose frames queued none (its
        // handshake, definitions, subscriptions, lookups; central's own
        // notices they cause do not count) is read on: stopping it held a
        // module that was only connecting until its 10 s handshake ran
        // out, for as long as a subscriber that stopped reading kept the
        // queues full.
        if self.queued_by_modules > queued_before {
            self.check_memory(conn);
        }
        self.wake_frame_waiters();
    }

    /// Processes the whole frames at the front of `conn`'s receive buffer.
    /// False if the connection was closed.
    fn take_frames(&mut self, conn: ConnId, now: SystemTime) -> bool {
        loop {
            let Some(m) = self.modules.get_mut(&conn) else {
                return false;
            };
            if m.closed {
                return false;
            }
            let avail = m.rx.len() - m.rx_pos;
            if avail < HEADER_SIZE {
                return true;
            }
            let header = match Header::decode(&m.rx[m.rx_pos..]) {
                Ok(h) => h,
                Err(e) => {
                    self.protocol_error(conn, e.to_string(), now);
                    return false;
                }
            };
            let n = match header.body_len(self.config.max_frame) {
                Ok(n) => n,
                Err(e) => {
                    self.protocol_error(conn, e.to_string(), now);
                    return false;
                }
            };
            if avail < HEADER_SIZE + n {
                match self.try_relay(conn, header, n, now) {
                    Ok(true) => {
                        // Everything read so far belonged to the frame.
                        if let Some(m) = self.modules.get_mut(&conn) {
                            m.big_end = None;
                        }
                        return true;
                    }
                    Ok(false) => {}
                    Err(Bad(e)) => {
                        self.protocol_error(conn, e, now);
                        return false;
                    }
                }
                let starts_big =
                    n >= SPLIT_AT && self.modules.get(&conn).is_some_and(|m| m.big_end.is_none());
                if starts_big && !self.room_for_frame(HEADER_SIZE + n) {
                    self.wait_for_frame_room(conn, HEADER_SIZE + n);
                    return true;
                }
                let Some(m) = self.modules.get_mut(&conn) else {
                    return false;
                };
                if n < SPLIT_AT {
                    m.rx.reserve(HEADER_SIZE + n - avail);
                } else if m.big_end.is_none() {
                    // Its own buffer, of its exact size (`max_frame` bounds it).
                    let mut frame = Vec::with_capacity(HEADER_SIZE + n);
                    frame.extend_from_slice(&m.rx[m.rx_pos..]);
                    m.rx = frame;
                    m.rx_pos = 0;
                    m.big_end = Some(HEADER_SIZE + n);
                    self.watch_frame(conn, now);
                }
                return true;
            }
            let start = m.rx_pos + HEADER_SIZE;
            let c = header.class_total as usize;
            // Class data is a few bytes (names, ids): kept off the heap.
            let class_data = smallvec::SmallVec::<[u8; 64]>::from_slice(&m.rx[start..start + c]);
            let data = if m.rx_pos == 0 && start + n == m.rx.len() && n - c >= SPLIT_AT {
                // The frame is the whole buffer: its data stays where it is.
                Body::in_frame(std::mem::take(&mut m.rx), start + c..start + n)
            } else {
                m.rx_pos = start + n;
                Body::from(&m.rx[start + c..start + n])
            };
            self.stats.frames_in += 1;
            if let Err(Bad(e)) = self.process(conn, header, &class_data, data, now) {
                self.protocol_error(conn, e, now);
                return false;
            }
        }
    }

    fn protocol_error(&mut self, conn: ConnId, why: String, now: SystemTime) {
        self.close_saying(conn, "ERROR", why, now);
    }

    /// Closes `conn` for `why`, with a `<level>: closing connection …` line
    /// (unless the strangers' budget leaves it out).
    pub(super) fn close_saying(&mut self, conn: ConnId, level: &str, why: String, now: SystemTime) {
        if !self.stranger_quiet(conn) {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!("{level}: closing connection {who}: {why}"),
            );
        }
        self.outputs.push_back(Output::Close { conn, reason: why });
        self.close_module(conn, false, now);
    }

    /// The connection ended (EOF, error, or after [`Output::Close`]).
    pub fn disconnect(&mut self, conn: ConnId, now: SystemTime) {
        self.clock = now;
        if !self.modules.contains_key(&conn) {
            return;
        }
        let partial = self.modules.get(&conn).map_or(0, |m| m.rx.len() - m.rx_pos);
        if partial > 0 && !self.stranger_quiet(conn) {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!("WARNING: connection {who} closed in the middle of a frame ({partial} byte(s) discarded)"),
            );
        }
        self.close_module(conn, true, now);
    }

    /// `x_ipcCloseMod`: forget a module, its handlers and its deliveries.
    /// `eof`: the connection ended without `x_ipc_CloseMsg` (C logs that
    /// path differently).
    pub(super) fn close_module(&mut self, conn: ConnId, eof: bool, now: SystemTime) {
        let _ = now;
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            self.modules.remove(&conn);
            return;
        }
        m.closed = true;
        let left_out = m.problems.take_suppressed();
        let left = if m.timed_out {
            log::Left::Silent
        } else if eof {
            log::Left::Closed
        } else {
            log::Left::Bad
        };
        let name = m.name.clone();
        let host = m.host.clone();
        let sd = m.sd;
        // A connection that never named itself, beyond what the log
        // takes of those: counted, not logged.
        let quiet = self.stranger_quiet(conn);
        if quiet {
            self.strangers.count(left);
        } else {
            self.report_left_out(conn, left_out);
        }
        // A frame it was sending through: its receiver needs the rest.
        self.abandon_relay(conn);
        if !quiet {
            if eof {
                // handleDataMsgRecv
                self.log_line(
                    Kind::Status,
                    format!("Closed Connection Detected from: sd: {sd}: "),
                );
                if let Some(n) = &name {
                    self.log_line(Kind::Always, format!(" Closing {n} on {host}"));
                }
            } else {
                // x_ipcCloseHnd
                self.log_line(
                    Kind::Always,
                    format!("x_ipcClose: Closed Connection Detected from: sd: {sd}:"),
                );
                if let Some(n) = &name {
                    self.log_line(Kind::Always, format!("x_ipcClose: Closing {n} on {host}"));
                }
            }
        }
        if let Some(n) = &name {
            self.log_line(Kind::Always, format!("close Module: Closing {n}"));
        }
        // Its handlers go away (`moduleClean`): watch variables of the
        // affected messages are updated in subscription order, then the
        // broadcast list is cleaned in its own order (`cleanBroadcast`).
        let Some(m) = self.modules.get(&conn) else {
            return;
        };
        let mut hnds: Vec<(u64, String, String)> = m
            .handlers
            .iter()
            .map(|(hn, h)| (h.seq, hn.clone(), h.msg.clone()))
            .collect();
        let queued: Vec<DispatchId> = m.ahead.iter().chain(&m.pending).copied().collect();
        hnds.sort();
        let mut changed: Vec<String> = Vec::new();
        for (_, hn, msg) in &hnds {
            if let Some(mm) = self.msgs.get_mut(msg) {
                mm.handlers.retain(|(c, n)| !(*c == conn && n == hn));
                if (mm.direct || mm.notify_handler_change) && !changed.contains(msg) {
                    changed.push(msg.clone());
                }
            }
        }
        // Deliveries it was handling, then those it had pending, in order.
        let mut mine: Vec<DispatchId> = self
            .dispatches
            .iter()
            .filter(|(_, d)| d.attending_at(conn))
            .map(|(id, _)| *id)
            .collect();
        mine.sort_unstable();
        // C (resourceDelete) only reports when something was being handled.
        let report = !mine.is_empty();
        mine.extend(queued);
        // Only a module that died keeps its messages for `-r`; one that
        // closed with `IPC_disconnect` meant to go.
        let keep_for = name
            .as_ref()
            .filter(|_| self.config.resend_on_reconnect && eof);
        let mut kept = Vec::new();
        for id in mine {
            let d = match self.dispatches.linked_mut(&id) {
                Ok(d) => d,
                // A queue naming a dispatch that is gone: nothing to clear.
                Err(e) => {
                    self.report_broken(e);
                    continue;
                }
            };
            if let Some(n) = keep_for {
                unqueue(&mut self.stats, d);
                d.status = Status::NoHandler;
                let msg = d.msg.clone();
                kept.push(id);
                self.log_line(
                    Kind::Status,
                    format!("Keeping {msg} {{{id}}} to resend when {n} reconnects"),
                );
            } else {
                // Freeing it takes it out of the queued bytes.
                let msg = d.msg.clone();
                self.free_dispatch_id(id);
                if report {
                    let o = self.opts();
                    self.log_line(
                        Kind::Always,
                        format!("Clearing handler for message {msg}{}", log::ref_id(&o, id)),
                    );
                }
            }
        }
        if let Some(n) = keep_for {
            self.keep_for_resend(n, &kept);
        }
        for msg in changed {
            self.update_direct_handlers(&msg);
        }
        // Queries it sent that are still out keep its name for the log
        // (their reply names it; C keeps the module record).
        if let Some(n) = &name {
            for d in self.dispatches.values_mut() {
                if d.org == Org::Module(conn) {
                    d.org_gone = Some(n.clone());
                }
            }
        }
        self.clean_broadcast();
        self.memory_paused.remove(&conn);
        self.answer_paused.remove(&conn);
        self.modules.remove(&conn);
        self.wake_frame_waiters();
        self.prune_handshakes();
        if let Some(n) = name {
            self.central_broadcast(internal::DISCONNECT_NOTIFY, |w| w.write_str(&n));
        }
    }
}
