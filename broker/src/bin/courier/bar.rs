//! A progress bar on stderr for long work with a known total (`courier
//! replay`): redrawn in place on a terminal, a plain line a second when
//! progress is asked for elsewhere (`--progress always` into a pipe),
//! nothing otherwise.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

use crate::cli::ProgressMode;

/// How the bar shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Look {
    Off,
    Lines,
    Redraw,
}

/// Progress of `done` out of `total` things.
pub struct Bar {
    look: Look,
    total: u64,
    what: &'static str,
    last: Option<Instant>,
    drawn: bool,
}

const WIDTH: u64 = 30;

impl Bar {
    /// A bar for `total` things called `what`, shown as `mode` says.
    pub fn new(mode: ProgressMode, total: u64, what: &'static str) -> Bar {
        let terminal = std::io::stderr().is_terminal();
        let look = match mode {
            ProgressMode::Never => Look::Off,
            ProgressMode::Auto if !terminal => Look::Off,
            _ if terminal => Look::Redraw,
            _ => Look::Lines,
        };
        Bar {
            look,
            total,
            what,
            last: None,
            drawn: false,
        }
    }

    /// The line for `done` things, `secs` into the work.
    pub fn line(&self, done: u64, secs: f64) -> String {
        let total = self.total.max(1);
        let pct = done.min(total) * 100 / total;
        let filled = (done.min(total) * WIDTH / total) as usize;
        format!(
            "[{}{}] {pct:>3}% {done}/{} {} {secs:.1} s",
            "#".repeat(filled),
            "-".repeat(WIDTH as usize - filled),
            self.total,
            self.what
        )
    }

    /// Shows `done` when it is time to (10 times a second on a terminal,
    /// once a second as lines).
    pub fn update(&mut self, done: u64, secs: f64) {
        let every = match self.look {
            Look::Off => return,
            Look::Redraw => Duration::from_millis(100),
            Look::Lines => Duration::from_secs(1),
        };
        if self.last.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        self.last = Some(Instant::now());
        self.draw(done, secs);
    }

    fn draw(&mut self, done: u64, secs: f64) {
        let line = self.line(done, secs);
        let mut e = std::io::stderr().lock();
        let _ = match self.look {
            Look::Off => return,
            Look::Redraw => write!(e, "\r\x1b[2Kcourier: {line}").and_then(|()| e.flush()),
            Look::Lines => writeln!(e, "courier: {line}"),
        };
        self.drawn = true;
    }

    /// Draws the last state and leaves the line (on a terminal).
    pub fn finish(&mut self, done: u64, secs: f64) {
        if self.look == Look::Off {
            return;
        }
        self.draw(done, secs);
        if self.look == Look::Redraw && self.drawn {
            let _ = writeln!(std::io::stderr());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_fills_in_proportion() {
        let b = Bar::new(ProgressMode::Never, 4, "messages");
        assert_eq!(
            b.line(1, 0.5),
            "[#######-----------------------]  25% 1/4 messages 0.5 s"
        );
        assert_eq!(
            b.line(4, 2.0),
            format!("[{}] 100% 4/4 messages 2.0 s", "#".repeat(30))
        );
        // an empty recording, or more than announced: no division by zero,
        // no overflowing bar
        let e = Bar::new(ProgressMode::Never, 0, "messages");
        assert_eq!(
            e.line(0, 0.0),
            format!("[{}]   0% 0/0 messages 0.0 s", "-".repeat(30))
        );
        assert!(b
            .line(9, 1.0)
            .starts_with(&format!("[{}] 100%", "#".repeat(30))));
    }
}
