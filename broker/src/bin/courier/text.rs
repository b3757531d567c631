//! Output: event lines on stdout, diagnostics and progress on stderr, and
//! the text of the things lines name (GUIDs, QoS, locators, bytes).

use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

use courier::qos::LivelinessKind;
use courier::{DurabilityKind, EndpointInfo, History, ParticipantInfo, Reliability};

use crate::cli::ProgressMode;
use crate::stop::{stop, Why};

/// The first write to stdout that failed otherwise than by a closed pipe.
static STDOUT_ERROR: OnceLock<String> = OnceLock::new();

/// Prints one line on stdout, flushed. When stdout is gone (`| head`), the
/// command stops as on a signal: it closes its session and exits 0. When
/// it cannot be written (a full disk), the command stops too, and
/// [`stdout_error`] says why (it then exits 1).
pub fn out(line: impl std::fmt::Display) {
    let mut o = std::io::stdout().lock();
    if let Err(e) = writeln!(o, "{line}").and_then(|()| o.flush()) {
        stdout_failed(&e);
    }
}

/// Notes a failed write to stdout and stops the command: quietly when
/// nobody reads stdout any more (EPIPE), else as a failure.
fn stdout_failed(e: &std::io::Error) {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        stop(Why::StdoutGone);
    } else {
        let _ = STDOUT_ERROR.set(e.to_string());
        stop(Why::StdoutFailed);
    }
}

/// Why stdout could not be written, when a write to it failed otherwise
/// than by a closed pipe.
pub fn stdout_error() -> Option<&'static str> {
    STDOUT_ERROR.get().map(String::as_str)
}

/// Says that `courier <cmd>` could not write its output: the one line
/// `courier <cmd>: cannot write to stdout: <error>`; exit code 1.
pub fn stdout_error_exit(cmd: &str, e: impl std::fmt::Display) -> ExitCode {
    err(format_args!("courier {cmd}: cannot write to stdout: {e}"));
    ExitCode::from(1)
}

/// Writes all of `bytes` to stdout, flushed, for `courier <cmd>`, which
/// prints its output in one piece (`gen`, `completions`): 0 when written
/// or when nobody reads stdout any more (EPIPE: `| head`), else the line
/// of [`stdout_error_exit`] and 1.
pub fn write_stdout(cmd: &str, bytes: &[u8]) -> ExitCode {
    let mut o = std::io::stdout().lock();
    match o.write_all(bytes).and_then(|()| o.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => stdout_error_exit(cmd, e),
    }
}

/// Prints a diagnostic on stderr; a closed stderr is no reason to panic.
pub fn err(line: impl std::fmt::Display) {
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

static PROGRESS: AtomicBool = AtomicBool::new(false);

/// Decides once whether long waits report progress on stderr.
pub fn set_progress(mode: ProgressMode) {
    let on = match mode {
        ProgressMode::Auto => std::io::stderr().is_terminal(),
        ProgressMode::Always => true,
        ProgressMode::Never => false,
    };
    PROGRESS.store(on, Ordering::Relaxed);
}

/// Says what a long wait is waiting for (`courier: …` on stderr), when
/// progress is shown.
pub fn progress(line: impl std::fmt::Display) {
    if PROGRESS.load(Ordering::Relaxed) {
        err(format_args!("courier: {line}"));
    }
}

/// An error and its sources, each said once (many errors already repeat
/// their source in their own text).
pub fn with_sources(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        cur = c.source();
    }
    s
}

/// A word of a line: as is, or quoted when it would not stay one word.
pub fn word(s: &str) -> String {
    if s.is_empty() || s.contains(|c: char| c.is_whitespace() || c == '"') {
        format!("{s:?}")
    } else {
        s.to_string()
    }
}

/// The first 64 bytes in hex (`…` when there are more), `-` when none.
pub fn hex(data: &[u8]) -> String {
    if data.is_empty() {
        return "-".into();
    }
    let hex: String = data.iter().take(64).map(|b| format!("{b:02x}")).collect();
    if data.len() > 64 {
        format!("{hex}…")
    } else {
        hex
    }
}

pub fn prefix_hex(g: courier::Guid) -> String {
    g.prefix().iter().map(|b| format!("{b:02x}")).collect()
}

pub fn qos_text(e: &EndpointInfo) -> String {
    let q = &e.qos;
    let rel = match q.reliability {
        Reliability::BestEffort => "best-effort",
        Reliability::Reliable => "reliable",
    };
    let dur = match q.durability {
        DurabilityKind::Volatile => "volatile",
        DurabilityKind::TransientLocal => "transient-local",
        DurabilityKind::Transient => "transient",
        DurabilityKind::Persistent => "persistent",
        _ => "other",
    };
    let hist = match q.history {
        History::KeepLast(n) => format!("keep-last({n})"),
        History::KeepAll => "keep-all".into(),
    };
    let ms = |d: Option<std::time::Duration>| match d {
        Some(d) if d != std::time::Duration::MAX => format!("{}ms", d.as_millis()),
        _ => "infinite".into(),
    };
    let dl = ms(q.deadline);
    let life = ms(q.lifespan);
    let lively = match q.liveliness {
        None => "automatic(infinite)".into(),
        Some(l) => {
            let kind = match l.kind {
                LivelinessKind::Automatic => "automatic",
                LivelinessKind::ManualByParticipant => "manual-by-participant",
                LivelinessKind::ManualByTopic => "manual-by-topic",
            };
            format!("{kind}({})", ms(Some(l.lease)))
        }
    };
    let own = q
        .exclusive
        .map_or("shared".into(), |s| format!("exclusive({s})"));
    let reps: Vec<String> = q
        .data_representation
        .iter()
        .map(|r| courier::rtps::matching::RepresentationName(*r).to_string())
        .collect();
    format!(
        "reliability={rel} durability={dur} history={hist} deadline={dl} lifespan={life} \
         liveliness={lively} ownership={own} partitions=[{}] representation=[{}]",
        q.partitions.join(","),
        reps.join(",")
    )
}

/// The representation of a serialized payload, from its encapsulation
/// header: `XCDR2 D_CDR2_LE`, `XCDR1 CDR_LE`, …; `-` without a header,
/// `unknown(0x....)` for an id that is not CDR.
pub fn encapsulation_text(data: &[u8]) -> String {
    use courier::cdr::{RepresentationId as R, Version};
    let Some(h) = data.get(..2) else {
        return "-".into();
    };
    let id = u16::from_be_bytes([h[0], h[1]]);
    let Some(r) = R::from_u16(id) else {
        return format!("unknown(0x{id:04x})");
    };
    let name = match r {
        R::CdrBe => "CDR_BE",
        R::CdrLe => "CDR_LE",
        R::PlCdrBe => "PL_CDR_BE",
        R::PlCdrLe => "PL_CDR_LE",
        R::Cdr2Be => "CDR2_BE",
        R::Cdr2Le => "CDR2_LE",
        R::DCdr2Be => "D_CDR2_BE",
        R::DCdr2Le => "D_CDR2_LE",
        R::PlCdr2Be => "PL_CDR2_BE",
        R::PlCdr2Le => "PL_CDR2_LE",
    };
    let version = match r.encoding().version() {
        Version::Xcdr1 => "XCDR1",
        Version::Xcdr2 => "XCDR2",
    };
    format!("{version} {name}")
}

/// `<guid> topic=<topic> type=<type> <qos>`.
pub fn endpoint_text(e: &EndpointInfo) -> String {
    format!(
        "{} topic={} type={} {}",
        e.guid,
        word(&e.topic),
        word(&e.type_name),
        qos_text(e)
    )
}

pub fn endpoint_line(kind: &str, what: &str, e: &EndpointInfo) -> String {
    format!("{kind} {what} {}", endpoint_text(e))
}

pub fn incompatible_line(remote: courier::Guid, reason: &courier::Incompatible) -> String {
    format!("incompatible {remote} {reason}")
}

/// An endpoint of another type on the topic: an `incompatible` line too.
pub fn type_mismatch_line(remote: courier::Guid, local_type: &str, remote_type: &str) -> String {
    format!("incompatible {remote} type {remote_type:?} where this side has {local_type:?}")
}

/// Socket addresses, or `-`.
fn locators(v: &[std::net::SocketAddr]) -> String {
    if v.is_empty() {
        "-".into()
    } else {
        v.iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// `<guid prefix> name=<name> unicast=<addrs> multicast=<addrs>`.
pub fn participant_text(p: &ParticipantInfo) -> String {
    format!(
        "{} name={} unicast={} multicast={}",
        prefix_hex(p.guid),
        p.name.as_deref().map_or("-".into(), word),
        locators(&p.unicast),
        locators(&p.multicast),
    )
}

pub fn participant_line(what: &str, p: &ParticipantInfo) -> String {
    format!("participant {what} {}", participant_text(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_stay_words() {
        assert_eq!(word("talker"), "talker");
        assert_eq!(word("my rx"), "\"my rx\"");
        assert_eq!(word(""), "\"\"");
    }

    #[test]
    fn hex_is_bounded() {
        assert_eq!(hex(&[0xab, 0x01]), "ab01");
        assert_eq!(hex(&[0x5a; 65]), format!("{}…", "5a".repeat(64)));
        assert_eq!(hex(&[]), "-");
    }
}
