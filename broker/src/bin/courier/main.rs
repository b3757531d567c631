//! `courier`: command-line tools over any session URL (`courier --help`).
//!
//! Each subcommand lives in a module of its own; `cli` holds the
//! arguments, `stop` the signals and exit codes, `text` what lines look
//! like, `connect` the connect with progress, `values` the types the tool
//! knows and how samples print.
//!
//! Output is one event or sample a line, flushed, so that tests and
//! scripts can read it. Exit codes: 0 done, 1 runtime failure, 2 usage
//! error (a bad option, URL or VALUE; a VALUE checked only against the
//! format central holds is a [`cli::LateUsage`]; 1 too when stdout cannot
//! be written, said in one line, `courier <cmd>: cannot write to stdout:
//! <error>`; a closed pipe, `| head`, ends a command quietly with 0), 128+N
//! stopped by signal N before the command was done (then it says what it
//! interrupted): SIGINT, SIGTERM and SIGHUP alike. The SDK's warnings go
//! to stderr (`RUST_LOG` chooses another level).
#![deny(unsafe_code)]

mod bar;
mod call;
mod cdr_value;
mod central_format;
mod cli;
mod connect;
mod dds_type;
mod echo;
mod gen;
mod list;
mod perf;
mod ping;
mod pong;
mod publish;
mod rate;
mod reader_kind;
mod record;
mod recording;
mod replay;
mod scan;
mod spy;
mod stop;
mod text;
mod values;
mod wait;

use std::process::ExitCode;

use clap::{CommandFactory, Parser};

use cli::{Cli, Command};
use stop::{Ended, Stop, Why};
use text::{err, out, stdout_error_exit};

type Error = Box<dyn std::error::Error>;
type Result<T> = std::result::Result<T, Error>;

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Err(e) = cli.check() {
        e.exit();
    }
    // the SDK's warnings (a direct link dropped, a close that gave up on
    // unacknowledged samples, a peer's malformed data) reach stderr, as
    // central's and xrce-agent's do; `RUST_LOG` tunes them
    courier_broker::logging::init(tracing::level_filters::LevelFilter::WARN, false);
    text::set_progress(cli.progress);
    let progress_mode = cli.progress;
    // commands whose stdout is a log of events say there what stopped
    // them; the others keep stdout for data and say it on stderr
    let events_on_stdout = matches!(
        cli.command,
        Command::List(_)
            | Command::Perf(_)
            | Command::Ping(_)
            | Command::Pong(_)
            | Command::Pub(_)
            | Command::Record(_)
            | Command::Replay(_)
            | Command::Spy(_)
    );
    let name = cli.command.name();
    let cmd = match cli.command {
        Command::Completions { shell } => {
            // into memory first: clap_complete panics on a failed write
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "courier", &mut script);
            return text::write_stdout(name, &script);
        }
        Command::Gen(o) => return gen::run(o),
        c => c,
    };
    let rt = match tokio::runtime::Runtime::new() {
        Ok(rt) => rt,
        Err(e) => {
            err(format_args!("courier: cannot start the runtime: {e}"));
            return ExitCode::from(1);
        }
    };
    let r = rt.block_on(async {
        let stop = Stop::watch().map_err(|e| format!("cannot watch signals: {e}"))?;
        match cmd {
            Command::Call(o) => call::run(o, stop).await,
            Command::Echo(o) => echo::run(o, stop).await,
            Command::Hz(o) => rate::run(o, rate::Mode::Hz, stop).await,
            Command::Bw(o) => rate::run(o, rate::Mode::Bw, stop).await,
            Command::List(o) => list::run(o, stop).await,
            Command::Perf(o) => perf::run(o, stop).await,
            Command::Ping(o) => ping::run(o, stop).await,
            Command::Pong(o) => pong::pong(o, stop).await,
            Command::Pub(o) => publish::run(o, stop).await,
            Command::Spy(o) => spy::run(o, stop).await,
            Command::Record(o) => record::run(o, stop).await,
            Command::Replay(o) => replay::run(o, progress_mode, stop).await,
            Command::Completions { .. } | Command::Gen(_) => Ok(Ended::Done),
        }
    });
    match r {
        Ok(ended) => {
            if let Ended::Stopped {
                why: Why::Signal(_),
                what,
            } = &ended
            {
                if events_on_stdout {
                    out(format_args!("interrupted {what}"));
                } else {
                    err(format_args!("courier: interrupted {what}"));
                }
            }
            // output lost (a full disk): said, and no success, even when
            // the command went on to its end (`list` prints and is done);
            // a signal that stopped it first keeps its 128+N
            match (text::stdout_error(), &ended) {
                (None, _) => ExitCode::from(ended.exit_code()),
                (
                    Some(e),
                    Ended::Stopped {
                        why: Why::Signal(_),
                        ..
                    },
                ) => {
                    stdout_error_exit(name, e);
                    ExitCode::from(ended.exit_code())
                }
                (Some(e), _) => stdout_error_exit(name, e),
            }
        }
        Err(e) => {
            if let Some(u) = e.downcast_ref::<cli::LateUsage>() {
                // a usage error the command line alone could not show
                let _ = cli::usage_error(u.sub, &u.msg).print();
                return ExitCode::from(2);
            }
            err(format_args!("courier: {}", text::with_sources(&*e)));
            ExitCode::from(1)
        }
    }
}
