//! Central's log: lines in the C central's layout
//! (`dispatchUpdateAndDisplay1` in dispatch.c, `Log_Time`/`Log_RefId`/
//! `Log_ParentId` in logging.c), where each goes (`-l`, `-L`, `-I`), the
//! data log's decoding of message bodies, and the budget that keeps a
//! misbehaving module from flooding it.

use std::time::{SystemTime, UNIX_EPOCH};

use super::tables::{Dispatch, DispatchId, Org};
use super::{Bad, Central, ConnId, LogOptions, LogTarget, Output, Peer, SERVER_NAME};
use crate::format::{Format, FormatRegistry};
use crate::ipc::frame::ClassId;
use crate::ipc::{ByteOrder, Reader};

/// Which `LOG_*` macro a line corresponds to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// `LOG`: on the terminal whatever the options (even `-lx`; only `-s`
    /// silences it), in the log file whenever there is one.
    Always,
    /// `LOG_MESSAGE`: message traffic (`m`).
    Message,
    /// `LOG_STATUS`: status (`s`).
    Status,
    /// `LOG_STATUS` between `Start_Ignore_Logging` and
    /// `End_Ignore_Logging`: status, unless the log ignores registrations
    /// (`i`, part of the default `-lmsi`).
    Registration,
    /// Data lines (`d`, only with `m`).
    Data,
    /// Courier's own `ERROR:`/`WARNING:` lines about bad input or a
    /// misbehaving module: on the terminal even when logging is off (`-lx`;
    /// `-s` still silences the terminal), and in the log file when there is
    /// one.
    Problem,
}

impl Kind {
    pub(super) fn enabled(self, o: &LogOptions) -> bool {
        match self {
            Kind::Always => o.any(),
            Kind::Message => o.messages,
            Kind::Status => o.status,
            Kind::Registration => o.status && !o.ignore_internal,
            Kind::Data => o.messages && o.data,
            Kind::Problem => o.any(),
        }
    }
}

/// `" {%d}"` when the log wants reference ids.
pub(super) fn ref_id(o: &LogOptions, id: DispatchId) -> String {
    if o.refs {
        format!(" {{{id}}}")
    } else {
        String::new()
    }
}

/// `" {%d}"` when the log wants parent ids.
pub(super) fn parent_id(o: &LogOptions, id: i32) -> String {
    if o.parent_refs {
        format!(" {{{id}}}")
    } else {
        String::new()
    }
}

/// `Log_Time(1)`: `%3d:%02d:%02d.%02d` (UTC; the C central uses local time).
pub(super) fn time(o: &LogOptions, now: SystemTime) -> String {
    if !o.time {
        return String::new();
    }
    let d = now.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs() % 86_400;
    format!(
        "{:>3}:{:02}:{:02}.{:02}",
        secs / 3600,
        (secs / 60) % 60,
        secs % 60,
        d.subsec_millis() / 10
    )
}

/// The class name `x_ipc_messageClassName` prints.
pub(super) fn class_name(class: u16) -> &'static str {
    match class {
        3 => "Query",
        4 => "Goal",
        5 => "Command",
        6 => "Inform",
        7 => "Exception",
        11 => "Reply",
        12 => "Success",
        13 => "Failure",
        15 => "Broadcast",
        16 => "MultiQuery",
        _ => "Unknown",
    }
}

/// Problem lines one connection may cause at once ([`ProblemBudget`]).
pub(super) const PROBLEM_BURST: u32 = 10;

/// A token bucket for one connection's problem lines: [`PROBLEM_BURST`] at
/// once, then one a second. A module that sends foreign acknowledgements or
/// unknown ids in a loop would otherwise write a line per frame to the
/// terminal and the log file, as fast as it can send; with the budget, what
/// is left out is counted and said with the next line that is printed (or
/// when the connection ends).
#[derive(Debug, Clone, Default)]
pub(super) struct ProblemBudget {
    spent: u32,
    since: Option<SystemTime>,
    suppressed: u64,
}

impl ProblemBudget {
    /// Whether a line may be printed now: `Some(n)` with the number of
    /// lines left out before it, or `None` (counted).
    pub(super) fn allow(&mut self, now: SystemTime) -> Option<u64> {
        let since = *self.since.get_or_insert(now);
        // A clock stepping back starts the second again.
        let secs = now.duration_since(since).map_or(0, |d| d.as_secs());
        if secs > 0 || now < since {
            let refill = u32::try_from(secs).unwrap_or(u32::MAX);
            self.spent = self.spent.saturating_sub(refill);
            self.since = Some(if now < since {
                now
            } else {
                since + std::time::Duration::from_secs(secs)
            });
        }
        if self.spent < PROBLEM_BURST {
            self.spent += 1;
            Some(std::mem::take(&mut self.suppressed))
        } else {
            self.suppressed += 1;
            None
        }
    }

    /// Lines left out and not yet reported; reports them.
    pub(super) fn take_suppressed(&mut self) -> u64 {
        std::mem::take(&mut self.suppressed)
    }
}

/// Connections that never named themselves whose lines are shown in each
/// [`STRANGER_WINDOW`] ([`StrangerBudget`]).
pub(super) const STRANGER_BURST: u32 = 10;

/// The interval of [`StrangerBudget`].
pub(super) const STRANGER_WINDOW: std::time::Duration = std::time::Duration::from_secs(10);

/// A central-wide bound on lines about connections that closed before
/// naming themselves (probes, port scanners, peers sending garbage):
/// each such connection has its own [`ProblemBudget`], so a peer that
/// connects, sends a few bad bytes and closes in a loop would otherwise
/// get its two lines every time. The first [`STRANGER_BURST`] such
/// connections of a [`STRANGER_WINDOW`] are logged as before; the others
/// are counted, and the count is said in one line when the window is over
/// (at the next connection, or the next stranger's line, after it).
#[derive(Debug, Clone, Default)]
pub(super) struct StrangerBudget {
    /// When the current window started (its first stranger).
    since: Option<SystemTime>,
    shown: u32,
    /// Left out: closed for a bad frame, closed by the peer, or closed
    /// for saying nothing ([`Config::handshake_timeout`](super::Config::handshake_timeout)).
    bad: u64,
    closed: u64,
    silent: u64,
}

/// How a stranger's connection ended ([`StrangerBudget::count`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Left {
    /// Central closed it for a frame it could not take.
    Bad,
    /// The peer closed it.
    Closed,
    /// Central closed it: no module name in time.
    Silent,
}

impl StrangerBudget {
    /// Whether a new stranger's lines are shown.
    pub(super) fn admit(&mut self, now: SystemTime) -> bool {
        self.since.get_or_insert(now);
        if self.shown < STRANGER_BURST {
            self.shown += 1;
            true
        } else {
            false
        }
    }

    /// A stranger whose lines were left out closed.
    pub(super) fn count(&mut self, left: Left) {
        match left {
            Left::Bad => self.bad += 1,
            Left::Closed => self.closed += 1,
            Left::Silent => self.silent += 1,
        }
    }

    /// When [`roll`](Self::roll) will have a line to say, if it will.
    pub(super) fn due(&self) -> Option<SystemTime> {
        let since = self.since?;
        (self.bad + self.closed + self.silent > 0).then(|| since + STRANGER_WINDOW)
    }

    /// At `now`, if the window is over: starts a new one, and returns the
    /// line that says what was left out in it, if anything was.
    pub(super) fn roll(&mut self, now: SystemTime) -> Option<String> {
        let since = self.since?;
        let elapsed = now.duration_since(since).ok();
        if elapsed.is_some_and(|d| d < STRANGER_WINDOW) {
            return None;
        }
        let (bad, closed, silent) = (self.bad, self.closed, self.silent);
        *self = StrangerBudget::default();
        if bad == 0 && closed == 0 && silent == 0 {
            return None;
        }
        let secs = elapsed.map_or(0, |d| d.as_secs());
        let mut what = Vec::new();
        if bad > 0 {
            what.push(format!("{bad} more connection(s) closed for bad frames"));
        }
        if closed > 0 {
            what.push(format!(
                "{closed} more connection(s) closed before naming themselves"
            ));
        }
        if silent > 0 {
            what.push(format!(
                "{silent} more connection(s) closed for not naming themselves in time"
            ));
        }
        Some(format!(
            "WARNING: … and {} in the last {secs} s (their lines left out: at most {STRANGER_BURST} such connections are logged every {} s)",
            what.join(", "),
            STRANGER_WINDOW.as_secs()
        ))
    }
}

impl Central {
    /// Whether lines about `conn` are left out: it has no name yet and
    /// the central-wide [`StrangerBudget`] is spent (decided at its first
    /// line, for all its lines). Says what was left out before, once a
    /// window is over.
    pub(super) fn stranger_quiet(&mut self, conn: ConnId) -> bool {
        let now = self.clock;
        let Some(m) = self.modules.get(&conn) else {
            return false;
        };
        if m.name.is_some() {
            return false;
        }
        if let Some(q) = m.quiet {
            return q;
        }
        self.stranger_summary(now);
        let quiet = !self.strangers.admit(now);
        if let Some(m) = self.modules.get_mut(&conn) {
            m.quiet = Some(quiet);
        }
        quiet
    }

    /// The line about strangers left out in a window that is over.
    pub(super) fn stranger_summary(&mut self, now: SystemTime) {
        if let Some(line) = self.strangers.roll(now) {
            self.log_line(Kind::Problem, line);
        }
    }

    pub(super) fn log_line(&mut self, kind: Kind, line: String) {
        let target = LogTarget {
            terminal: matches!(kind, Kind::Problem | Kind::Always)
                || kind.enabled(&self.config.terminal_log),
            file: kind.enabled(&self.config.file_log),
        };
        if target.terminal || target.file {
            self.outputs.push_back(Output::Log { target, line });
        }
    }

    /// Options of whichever log is the more verbose (ref/parent/time fields).
    pub(super) fn opts(&self) -> LogOptions {
        if self.config.terminal_log.any() {
            self.config.terminal_log
        } else {
            self.config.file_log
        }
    }

    /// Whether a `kind` line about `msg` goes anywhere: its kind is on in
    /// some log, and `msg` is not ignored (`-i` / `-I`). Checked before a
    /// line is formatted, so that a central with logging off (`-lx`) does
    /// no formatting work per message.
    pub(super) fn logs(&self, kind: Kind, msg: &str) -> bool {
        let o = self.opts();
        (kind.enabled(&self.config.terminal_log) || kind.enabled(&self.config.file_log))
            && !(self.ignore.contains(msg)
                && (o.ignore_internal || self.config.ignore.iter().any(|n| n == msg)))
    }

    /// `dispatchUpdateAndDisplay1`'s common layout:
    /// `Class      msg {ref}:     origin {parent} --> <to><time>`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn dispatch_line(
        &self,
        class: u16,
        msg: &str,
        did: Option<DispatchId>,
        org: &str,
        parent: i32,
        to: &str,
        now: SystemTime,
    ) -> String {
        let o = self.opts();
        format!(
            "{:<9} {:>15}{}: {:>10}{} --> {to}{}",
            class_name(class),
            msg,
            did.map(|d| ref_id(&o, d)).unwrap_or_default(),
            org,
            parent_id(&o, parent),
            time(&o, now)
        )
    }

    pub(super) fn module_name(&self, org: Org) -> String {
        match org {
            Org::Central => SERVER_NAME.to_string(),
            Org::Module(c) => self
                .modules
                .get(&c)
                .and_then(|m| m.name.clone())
                // A module not named yet (before its connect query).
                .unwrap_or_else(|| "**NEWMOD**".to_string()),
        }
    }

    /// The name of the module that sent `d`, also after it closed.
    pub(super) fn org_name(&self, d: &Dispatch) -> String {
        match &d.org_gone {
            Some(n) => n.clone(),
            None => self.module_name(d.org),
        }
    }

    pub(super) fn log_data(
        &mut self,
        msg: &str,
        class_id: ClassId,
        data: &[u8],
        reply_of: Option<&str>,
    ) {
        self.log_data_as(msg, class_id, data, reply_of, false)
    }

    /// `internal`: the data is an internal message's own format (its
    /// msgFormat), not a user message body.
    pub(super) fn log_data_as(
        &mut self,
        msg: &str,
        class_id: ClassId,
        data: &[u8],
        reply_of: Option<&str>,
        internal: bool,
    ) {
        if !Kind::Data.enabled(&self.config.terminal_log)
            && !Kind::Data.enabled(&self.config.file_log)
        {
            return;
        }
        let name = reply_of.unwrap_or(msg).to_string();
        let (mf, rf) = self.parsed(&name);
        let (mf, rf) = if internal { (None, mf) } else { (mf, rf) };
        self.log_decoded(&name, &mf, &rf, data, class_id);
    }

    /// The data lines of `data`, decoded as [`decode_user`] does.
    fn log_decoded(
        &mut self,
        name: &str,
        mf: &Option<Format>,
        rf: &Option<Format>,
        data: &[u8],
        class_id: ClassId,
    ) {
        let order = class_id.data_order().unwrap_or(ByteOrder::NATIVE);
        let text = match decode_user(mf, rf, data, order, &self.formats) {
            Ok(Some(t)) => t,
            Ok(None) => return,
            Err(e) => format!("    <cannot decode {name}: {e}>"),
        };
        for line in text.trim_end_matches('\n').split('\n') {
            self.log_line(Kind::Data, line.to_string());
        }
    }

    /// A broken link between central's tables found where no connection
    /// is to blame (see [`Linked`](super::tables::Linked)): it is logged,
    /// and central goes on without the missing entry.
    pub(super) fn report_broken(&mut self, e: Bad) {
        self.log_line(Kind::Problem, format!("ERROR: {}", e.0));
    }

    /// A line about something `conn` did wrong, within its
    /// [`ProblemBudget`]: a module repeating a mistake in a loop gets
    /// a burst of lines, then one a second, and a count of the rest.
    pub(super) fn complain(&mut self, conn: ConnId, line: String) {
        let now = self.clock;
        if self.stranger_quiet(conn) {
            return;
        }
        let allowed = match self.modules.get_mut(&conn) {
            Some(m) => m.problems.allow(now),
            None => Some(0),
        };
        if let Some(left_out) = allowed {
            self.report_left_out(conn, left_out);
            self.log_line(Kind::Problem, line);
        }
    }

    pub(super) fn report_left_out(&mut self, conn: ConnId, left_out: u64) {
        if left_out > 0 {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!("WARNING: {left_out} more problem line(s) about connection {who} left out"),
            );
        }
    }

    pub(super) fn describe(&self, conn: ConnId) -> String {
        match self.modules.get(&conn) {
            Some(m) => {
                let peer = match &m.peer {
                    Peer::Tcp(a) => a.clone(),
                    Peer::Unix => "unix socket".into(),
                    Peer::Other(s) => s.clone(),
                };
                match &m.name {
                    Some(n) => format!("{} ({n} from {peer})", m.sd),
                    None => format!("{} (from {peer})", m.sd),
                }
            }
            None => conn.0.to_string(),
        }
    }

    /// `  Done    <msg>:<time>`: an internal message handled.
    pub(super) fn log_done(&mut self, name: &str, rid: DispatchId, now: SystemTime) {
        let o = self.opts();
        let line = format!("  Done    {name:>15}{}:{}", ref_id(&o, rid), time(&o, now));
        self.log_line(Kind::Message, line);
    }

    /// `  Reply  <msg>: X_IPC Server --> <module>  <time>` and the reply's
    /// data, decoded with the internal message's reply format.
    pub(super) fn log_internal_reply(
        &mut self,
        name: &str,
        to: &str,
        (rid, parent): (DispatchId, i32),
        class_id: ClassId,
        reply: &[u8],
        now: SystemTime,
    ) {
        let o = self.opts();
        let line = format!(
            "  Reply  {:>15}{}: {:>10} --> {:<15}{}{}",
            name,
            ref_id(&o, rid),
            SERVER_NAME,
            to,
            parent_id(&o, parent),
            time(&o, now)
        );
        self.log_line(Kind::Message, line);
        if reply.is_empty() || !self.logs(Kind::Data, name) {
            return;
        }
        let (_, rf) = self.parsed(name);
        self.log_decoded(name, &None, &rf, reply, class_id);
    }
}

/// C's `Log_Data` line for a message that carries no data: `NO DATA`
/// right-aligned in `indent + 7` columns, the indent being 4.
const NO_DATA: &str = "    NO DATA";

/// Array elements decoded for a data log line: more than its five lines
/// of at most 80 columns can show (each element takes a character).
const LOGGED_ELEMENTS: usize = 4096;

/// Decodes a message body for the data log: the wire body (`{int,
/// <byte:1>}`, `[byte:N]` or the format itself) and then the user format.
fn decode_user(
    msg_format: &Option<Format>,
    res_format: &Option<Format>,
    data: &[u8],
    order: ByteOrder,
    reg: &FormatRegistry,
) -> Result<Option<String>, String> {
    let Some(user) = res_format.as_ref().or(msg_format.as_ref()) else {
        return Ok(None);
    };
    if *user == Format::Empty {
        return Ok(None);
    }
    let inner: &[u8] = match msg_format {
        Some(Format::Struct(f))
            if f.len() == 2
                && matches!(f[1], Format::VarArray { .. })
                && res_format.is_some()
                && !data.is_empty() =>
        {
            let mut r = Reader::new(data, order);
            let _len = r.read_i32().map_err(|e| e.to_string())?;
            let n = r.read_count(1).map_err(|e| e.to_string())?;
            r.take(n).map_err(|e| e.to_string())?
        }
        _ => data,
    };
    // A message with a format sent without data: `Log_Data` of NULL. C
    // central decodes `IPC_publish(msg, 0, NULL)` of a variable-length
    // message (a byte array of length 0) to NULL too.
    if inner.is_empty() {
        return Ok(Some(NO_DATA.to_string()));
    }
    let resolve = |n: &str| reg.get(n);
    let mut r = Reader::new(inner, order);
    // The log shows five lines: the first elements of a large array do.
    let v = crate::ipc::decode_value_prefix(user, &mut r, &resolve, LOGGED_ELEMENTS)
        .map_err(|e| e.to_string())?;
    Ok(Some(crate::ipc::log_data(user, &v)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_burst_then_one_a_second_and_the_rest_is_counted() {
        let t0 = UNIX_EPOCH + Duration::from_secs(1_000);
        let mut b = ProblemBudget::default();
        for _ in 0..PROBLEM_BURST {
            assert_eq!(b.allow(t0), Some(0));
        }
        for _ in 0..500 {
            assert_eq!(b.allow(t0 + Duration::from_millis(999)), None);
        }
        // One second later, one more line, which says what was left out.
        assert_eq!(b.allow(t0 + Duration::from_secs(1)), Some(500));
        assert_eq!(b.allow(t0 + Duration::from_millis(1_500)), None);
        assert_eq!(b.take_suppressed(), 1);
        assert_eq!(b.take_suppressed(), 0);
        // A quiet minute refills the burst, no more.
        let later = t0 + Duration::from_secs(61);
        for _ in 0..PROBLEM_BURST {
            assert_eq!(b.allow(later), Some(0));
        }
        assert_eq!(b.allow(later), None);
    }

    #[test]
    fn a_clock_stepping_back_neither_panics_nor_silences_for_long() {
        let t0 = UNIX_EPOCH + Duration::from_secs(1_000);
        let mut b = ProblemBudget::default();
        for _ in 0..PROBLEM_BURST {
            b.allow(t0);
        }
        assert_eq!(b.allow(t0 - Duration::from_secs(3_600)), None);
        assert_eq!(
            b.allow(t0 - Duration::from_secs(3_599)),
            Some(1),
            "a second after the step, lines flow again"
        );
    }
}
