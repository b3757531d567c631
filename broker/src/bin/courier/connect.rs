//! Connecting a session: what it waits for (with progress on a terminal),
//! a failure that says where it tried and what to check, and a stop while
//! it waits that says so.

use std::time::{Duration, Instant};

use courier::{ConnectError, Session};

use crate::cli::{kind, Kind};
use crate::stop::{Ended, Stop};
use crate::text::progress;
use crate::Result;

/// What a URL connects to, for messages: `central at 127.0.0.1:1381`,
/// `DDS domain 7`.
pub fn target(url: &str) -> String {
    match kind(url) {
        Kind::Ipc => match courier::ipc_backend::parse_url(url) {
            Ok((h, p)) => format!("central at {h}:{p}"),
            Err(_) => url.to_string(),
        },
        Kind::Dds => match courier::RtpsOptions::from_url(url) {
            Ok(o) => format!("DDS domain {}", o.domain),
            Err(_) => url.to_string(),
        },
    }
}

/// How often a wait reports progress.
pub const PROGRESS_EVERY: Duration = Duration::from_secs(1);

/// Connects, or says what was interrupted when the command is stopped
/// first. While it waits (an IPC central that does not answer yet), the
/// wait reports progress every second.
/// The module / participant name `--name` gives: `%p` is this process's
/// id, so that the default names (`courier-echo-%p`, …) of two commands on
/// one central differ (central refuses a second module of a live name).
pub fn module_name(name: &str) -> String {
    name.replace("%p", &std::process::id().to_string())
}

pub async fn connect(
    url: &str,
    name: &str,
    stop: &mut Stop,
) -> Result<std::result::Result<Session, Ended>> {
    let target = target(url);
    let started = Instant::now();
    let connecting = Session::builder(url).name(module_name(name)).connect();
    tokio::pin!(connecting);
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    loop {
        tokio::select! {
            r = &mut connecting => {
                return match r {
                    Ok(s) => {
                        if s.xrce().is_ok() {
                            say_agent_outages(&s, url.to_string());
                        }
                        Ok(Ok(s))
                    }
                    Err(e) => Err(failed(&target, e, started.elapsed()).into()),
                }
            }
            why = stop.wait() => {
                return Ok(Err(Ended::Stopped {
                    why,
                    what: format!(
                        "while connecting to {target} ({:.1} s)",
                        started.elapsed().as_secs_f64()
                    ),
                }))
            }
            _ = tick.tick() => {
                let hint = match kind(url) {
                    Kind::Ipc => " (is central running?)",
                    Kind::Dds => "",
                };
                progress(format_args!(
                    "connecting to {target} for {} s{hint}",
                    started.elapsed().as_secs()
                ));
            }
        }
    }
}

/// An XRCE session reconnects by itself, and what it publishes meanwhile
/// waits: an agent that stops answering, and its return, are said on
/// stderr, one line each, so that an outage shows in the journal (nothing
/// was said for minutes).
fn say_agent_outages(s: &Session, url: String) {
    use courier::SessionEvent;
    use futures::StreamExt;
    let mut ev = s.events();
    tokio::spawn(async move {
        while let Some(e) = ev.next().await {
            match e {
                SessionEvent::AgentLost { silent: true } => eprintln!(
                    "courier: the agent at {url} stopped answering; waiting for it (what is \
                     published meanwhile waits too)"
                ),
                SessionEvent::AgentLost { silent: false } => {
                    eprintln!("courier: the agent at {url} lost the session; making it again")
                }
                SessionEvent::AgentBack => eprintln!("courier: the agent at {url} answers again"),
                SessionEvent::SessionRecreated { entities } => eprintln!(
                    "courier: the session was made again on the agent at {url} ({entities} \
                     entities)"
                ),
                _ => {}
            }
        }
    });
}

/// The message of a failed connect: where it tried, how long, the last
/// error, and what to check.
fn failed(target: &str, e: ConnectError, took: Duration) -> String {
    match e {
        ConnectError::Unreachable {
            addr,
            attempts,
            source,
        } => {
            if attempts <= 1 {
                format!("cannot connect to central at {addr}: {source}")
            } else {
                format!(
                    "cannot connect to central at {addr} ({attempts} attempts in {:.1} s): \
                     {source}; is central running there?",
                    took.as_secs_f64()
                )
            }
        }
        e => format!("cannot connect to {target}: {e}"),
    }
}

/// Watches the handlers of `msg` (IPC), which also looks it up in central
/// (`message_info` knows it once a later `num_handlers` answered); a
/// message central does not know is not watched, and not an error here:
/// `courier list` reports it as unknown.
pub async fn watch_if_known(ipc: &courier::Ipc<'_>, msg: &str) -> Result<()> {
    use courier::ipc::module::Error as Central;
    match ipc.watch_handlers(msg).await {
        Err(courier::ControlError::Central {
            source: Central::UnknownMessage(_),
            ..
        }) => Ok(()),
        r => Ok(r?),
    }
}
