//! Log lines in the C central's layout (`dispatchUpdateAndDisplay1` in
//! dispatch.c, `Log_Time`/`Log_RefId`/`Log_ParentId` in logging.c).

use std::time::{SystemTime, UNIX_EPOCH};

use super::LogOptions;

/// Which `LOG_*` macro a line corresponds to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// `LOG`: printed whenever the log is on at all.
    Always,
    /// `LOG_MESSAGE`: message traffic (`m`).
    Message,
    /// `LOG_STATUS`: status (`s`).
    Status,
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
            Kind::Data => o.messages && o.data,
            Kind::Problem => o.any(),
        }
    }
}

/// `" {%d}"` when the log wants reference ids.
pub(super) fn ref_id(o: &LogOptions, id: i32) -> String {
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
