//! How a command stops early: SIGINT (Ctrl-C), SIGTERM, SIGHUP (its
//! terminal or ssh session gone), its stdout gone (`courier echo … | head`)
//! or failing (a full disk), and what it then says it interrupted.

use std::sync::OnceLock;
use std::time::Duration;

use courier::Session;
use tokio::sync::watch;

use crate::Result;

/// Why a command was stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Why {
    /// A signal (its number: `SIGINT`, `SIGTERM`, `SIGHUP`).
    Signal(i32),
    /// Writing to stdout failed: nobody reads it any more (EPIPE).
    StdoutGone,
    /// Writing to stdout failed otherwise (ENOSPC, EIO, …): the output is
    /// lost; [`crate::text::stdout_error`] says why.
    StdoutFailed,
}

/// How a command ended.
#[derive(Debug)]
pub enum Ended {
    /// It did what it was asked.
    Done,
    /// It was stopped before; `what` completes "interrupted …": `after 3
    /// samples`, `while connecting to central at …`.
    Stopped { why: Why, what: String },
}

impl Ended {
    /// The exit code: 0 when done (or nobody reads the output any more),
    /// 1 when its output could not be written, 128 + the signal's number
    /// when a signal stopped it (130 for Ctrl-C, 143 for SIGTERM, 129 for
    /// SIGHUP), as shells report a command a signal killed.
    pub fn exit_code(&self) -> u8 {
        match self {
            Ended::Done
            | Ended::Stopped {
                why: Why::StdoutGone,
                ..
            } => 0,
            Ended::Stopped {
                why: Why::StdoutFailed,
                ..
            } => 1,
            Ended::Stopped {
                why: Why::Signal(s),
                ..
            } => u8::try_from(128 + s).unwrap_or(1),
        }
    }
}

static STOP: OnceLock<watch::Sender<Option<Why>>> = OnceLock::new();

fn sender() -> &'static watch::Sender<Option<Why>> {
    STOP.get_or_init(|| watch::channel(None).0)
}

/// Stops the command (the first reason counts).
pub fn stop(why: Why) {
    sender().send_if_modified(|w| {
        let first = w.is_none();
        if first {
            *w = Some(why);
        }
        first
    });
}

/// Resolves once the command is to stop. The signal handlers are installed
/// once, for the whole run, so a signal between two waits is not lost.
pub struct Stop(watch::Receiver<Option<Why>>);

impl Stop {
    /// Installs the handlers (inside the runtime). SIGHUP stops a command
    /// as SIGTERM does (a recording is finished), unless it is ignored
    /// (`nohup`): then it stays ignored.
    pub fn watch() -> std::io::Result<Stop> {
        use tokio::signal::unix::{signal, SignalKind};
        let (mut int, mut term) = (
            signal(SignalKind::interrupt())?,
            signal(SignalKind::terminate())?,
        );
        let mut hup = if courier_broker::signals::sighup_ignored() {
            None
        } else {
            Some(signal(SignalKind::hangup())?)
        };
        let rx = sender().subscribe();
        tokio::spawn(async move {
            let hangup = async {
                match &mut hup {
                    Some(h) => h.recv().await,
                    None => std::future::pending().await,
                }
            };
            let s = tokio::select! {
                _ = int.recv() => libc::SIGINT,
                _ = term.recv() => libc::SIGTERM,
                _ = hangup => libc::SIGHUP,
            };
            stop(Why::Signal(s));
        });
        Ok(Stop(rx))
    }

    /// Why the command is to stop, once it is.
    pub async fn wait(&mut self) -> Why {
        match self.0.wait_for(Option::is_some).await {
            Ok(w) => w.unwrap_or(Why::StdoutGone),
            // the sender is a static: never dropped
            Err(_) => std::future::pending().await,
        }
    }
}

/// How long closing may take after a stop before the process just exits.
const CLOSE_BOUND: Duration = Duration::from_secs(3);

/// Closes the session (DDS: the participant says goodbye), bounded.
pub async fn close(s: &Session) {
    let _ = tokio::time::timeout(CLOSE_BOUND, s.close()).await;
}

/// Runs `body` until it ends or the command is stopped (then `what` says
/// what was interrupted), and closes the session either way.
pub async fn run_session<F>(
    s: &Session,
    stop: &mut Stop,
    body: F,
    what: impl FnOnce() -> String,
) -> Result<Ended>
where
    F: std::future::Future<Output = Result<()>>,
{
    let r = tokio::select! {
        r = body => r.map(|()| Ended::Done),
        why = stop.wait() => Ok(Ended::Stopped { why, what: what() }),
    };
    close(s).await;
    r
}

/// Resolves at `until`, or never when there is none (a command's
/// `--duration`).
pub async fn deadline(until: Option<std::time::Instant>) {
    match until {
        Some(t) => tokio::time::sleep_until(t.into()).await,
        None => std::future::pending().await,
    }
}

/// "N thing(s)".
pub fn count(n: u64, thing: &str) -> String {
    if n == 1 {
        format!("1 {thing}")
    } else {
        format!("{n} {thing}s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_codes_follow_the_shell() {
        let stopped = |why| Ended::Stopped {
            why,
            what: String::new(),
        };
        assert_eq!(Ended::Done.exit_code(), 0);
        assert_eq!(stopped(Why::Signal(libc::SIGINT)).exit_code(), 130);
        assert_eq!(stopped(Why::Signal(libc::SIGTERM)).exit_code(), 143);
        assert_eq!(stopped(Why::Signal(libc::SIGHUP)).exit_code(), 129);
        assert_eq!(stopped(Why::StdoutGone).exit_code(), 0);
        assert_eq!(stopped(Why::StdoutFailed).exit_code(), 1);
        assert_eq!(count(1, "sample"), "1 sample");
        assert_eq!(count(0, "sample"), "0 samples");
    }
}
