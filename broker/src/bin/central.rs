//! `central`: a drop-in replacement for CMU IPC's central server.
//!
//! Options are those of the IPC manual §2 with their values glued to the
//! flag, parsed as the C central parses them (`-lmsd`, `-Lx`, `-fname`,
//! `-p1381`, `-Imsg` or `-Ifile`, `-v -s -u -r -c`, and a bare number for
//! the expected module count), plus `--bind <addr>`, `--hosts-allow <file>`,
//! `--hosts-deny <file>`, `--no-unix-socket` and `--help`.
//!
//! Where it differs from the C central on purpose — options, console,
//! signals, sockets, access control, routing and logs — is listed in one
//! place: "Deviations from the C central" in the `courier::central`
//! documentation (`sdk/src/central/mod.rs`); `--help` says so too.
#![deny(unsafe_code)]

use std::io::{BufRead, IsTerminal, Write};
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use courier_broker::access::{AccessControl, RulesFile, DEFAULT_ALLOW, DEFAULT_DENY};
use courier_broker::{BindError, CentralServer, Config, LogOptions, LogSink, LogTarget};
use courier_wire::ipc::central::MAX_SEND_AHEAD;

/// `println!` that does not panic when stdout is gone (`central --help |
/// head -1`, a console whose reader closed): what central prints is for
/// people, and a closed pipe must not stop it.
macro_rules! say {
    ($($t:tt)*) => {{
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}

/// `eprintln!` that does not panic when stderr is gone: once central runs,
/// its stderr may be a terminal that hung up (SIGHUP), and the way out
/// must still flush the file log.
macro_rules! esay {
    ($($t:tt)*) => {{
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}

/// `X_IPC_VERSION_MAJOR.MINOR.MICRO` of the C central we stand in for.
const IPC_VERSION: &str = "3.9.1";
/// `--send-ahead <module>` without a depth.
const DEFAULT_SEND_AHEAD: usize = 8;

const USAGE: &str = "central command line options:
 -v: display server version info.
 -l: logging onto terminal.
     options are: m (message traffic)
                  s (status of IPC)
                  t (time messages are handled)
                  d (data associated with message)
                  i (ignore logging registration and deregistration messages)
                  h (incoming message handle time summary)
                  r (log the reference Id as well as the msg name)
                  p (log the reference Id of the message's parent)
                  x (no logging; a module's bad input is still reported)
     -l is equivalent to -lmstdh; the default is -lmsi
 -L: logging into file.
     options are the same as above with the addition of F.
                  F (don't flush file after each line)
                  n (do not prompt the user for comments)
     the default is -Lx
 -f<fileName>: filename to use for logging (default x_ipc.log.<time>).
 -p<port>: specify the server port - the default port is: 1381 (0: any free port)
 -c: Use direct (not via central) conntections where possible.
 -i<msgName>: Ignore logging this message (can occur multiple times).
 -I<msgName or fileName>: Ignore logging this message, or the messages named
     one per line in this file.
 -s: silent running, don't print anything to stdout.
 -u: Don't run the user interface (stdin).
 -r: try resending non-completed messages when modules crash
 -d: debugging diagnostics on stderr (RUST_LOG=<filter>, e.g. debug or
     courier_broker=trace, chooses them in detail).
 <number>: the number of modules expected (printed only).
 --bind <addr>: listen on this address only (default: all interfaces).
 --hosts-allow <file>, --hosts-deny <file>: access rules
     (default /etc/hosts.allow and /etc/hosts.deny, daemon name 'central').
     A file named here must exist and be readable; a missing default file
     holds no rules (with a warning). A file that changes is read again at
     the next connection (one that became unreadable or invalid: its
     previous rules stay, with a warning).
 --no-unix-socket: do not listen on /tmp/x_ipc/<port>.
 --handshake-timeout <s>: close a connection that has not said its module
     name (IPC_connect) within <s> seconds, with a log line (default 10;
     0: never, as in C), so that silent connections cannot hold central's
     file descriptors.
 --frame-stall-timeout <s>: close a connection whose large frame (16 KiB or
     more, or one forwarded with --cut-through) has had no byte for <s>
     seconds, with a log line (default 30; 0: never, as in C), so that a
     peer stopped half way through a frame cannot hold the room other
     large frames wait for. Time central does not read it does not count.
 --busy-poll <us>: after each frame keep polling for <us> microseconds
     (1..=1000000) instead of sleeping: lower latency for CPU (default off).
 --cut-through <bytes>: forward a message or reply of at least <bytes>
     (1..=2147483647) while it still arrives, when its receiver can take it
     at once, instead of after its last byte (default off, as in C; not with
     data logging or -r). If its sender dies in the middle, the receiver
     gets the rest as zero bytes.
 --send-ahead <module>[=<n>]: while that module handles as many
     broadcasts as its capacity allows, write up to <n> (1..=1024, default
     8) of those queued for it to its socket already, so it finds the next
     one waiting (default: none, as in C). Repeat for more modules. Only for
     modules that consume without waiting in their handlers (no queries, no
     IPC_listen): a C module handles queued messages while it waits.
 --help, -h: this text.
Where this central differs from the C central: the list \"Deviations from
the C central\" in the documentation of the courier crate, courier::central.";

#[derive(Debug)]
struct Options {
    config: Config,
    port: u16,
    bind: IpAddr,
    log_file: Option<PathBuf>,
    expected: u32,
    console: bool,
    version: bool,
    help: bool,
    debug: bool,
    unix: bool,
    /// `--hosts-allow`; `None`: the default file, which may be missing.
    allow: Option<PathBuf>,
    /// `--hosts-deny`; `None`: the default file, which may be missing.
    deny: Option<PathBuf>,
    busy_poll: Option<std::time::Duration>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            config: Config::default(),
            port: courier_broker::DEFAULT_PORT,
            bind: IpAddr::from([0, 0, 0, 0]),
            log_file: None,
            expected: 1,
            console: true,
            version: false,
            help: false,
            debug: false,
            unix: true,
            allow: None,
            deny: None,
            busy_poll: None,
        }
    }
}

/// The value of option `--<name>`: a whole number from 1 to `max`.
fn number(name: &str, v: &str, max: u64, what: &str) -> Result<u64, String> {
    v.parse::<u64>()
        .ok()
        .filter(|n| (1..=max).contains(n))
        .ok_or_else(|| format!("option --{name}: '{v}' is not a number of {what} from 1 to {max}"))
}

/// A timeout option: whole seconds up to a day, 0 for none (C's way).
fn timeout(name: &str, v: &str) -> Result<Option<std::time::Duration>, String> {
    let secs = v
        .parse::<u64>()
        .ok()
        .filter(|s| *s <= 86_400)
        .ok_or_else(|| {
            format!("option --{name}: '{v}' is not a number of seconds from 0 (never) to 86400")
        })?;
    Ok((secs > 0).then(|| std::time::Duration::from_secs(secs)))
}

/// Logging letters as C reads them: case does not matter (except `F`/`f`
/// and `n`/`N` being file-only), and any `x` means no logging at all.
fn log_options(letters: &str, file: bool) -> Result<LogOptions, String> {
    let flag = if file { 'L' } else { 'l' };
    let norm: String = letters
        .chars()
        .map(|c| match c {
            'f' if file => 'F',
            'N' if file => 'n',
            'M' | 'S' | 'T' | 'D' | 'I' | 'H' | 'R' | 'P' | 'X' => c.to_ascii_lowercase(),
            c => c,
        })
        .collect();
    let parsed =
        LogOptions::parse(&norm, file).map_err(|e| format!("option -{flag}{letters}: {e}"))?;
    if norm.contains('x') {
        return Ok(LogOptions::NONE);
    }
    Ok(parsed)
}

fn parse_args(args: Vec<String>) -> Result<Options, String> {
    let mut o = Options::default();
    let mut it = args.into_iter();
    while let Some(a) = it.next() {
        // Long options: `--name value` or `--name=value`.
        if let Some(long) = a.strip_prefix("--") {
            let (name, inline) = match long.split_once('=') {
                Some((n, v)) => (n, Some(v.to_string())),
                None => (long, None),
            };
            let mut value = |takes: bool| -> Result<String, String> {
                match (&inline, takes) {
                    (Some(v), true) => Ok(v.clone()),
                    (None, true) => it
                        .next()
                        .ok_or_else(|| format!("option --{name} needs a value")),
                    (Some(v), false) => Err(format!("option --{name} takes no value (got '{v}')")),
                    (None, false) => Ok(String::new()),
                }
            };
            match name {
                "help" => {
                    value(false)?;
                    o.help = true;
                }
                "bind" => {
                    let v = value(true)?;
                    o.bind = v
                        .parse()
                        .map_err(|_| format!("option --bind: '{v}' is not an IP address"))?;
                }
                "busy-poll" => {
                    let us = number(name, &value(true)?, 1_000_000, "microseconds")?;
                    o.busy_poll = Some(std::time::Duration::from_micros(us));
                }
                "cut-through" => {
                    let n = number(name, &value(true)?, i32::MAX as u64, "bytes")?;
                    o.config.cut_through = Some(n as usize);
                }
                "send-ahead" => {
                    let v = value(true)?;
                    let (module, n) = match v.split_once('=') {
                        Some((m, n)) => (m, Some(n)),
                        None => (v.as_str(), None),
                    };
                    if module.is_empty() {
                        return Err(format!("option --send-ahead: '{v}' names no module"));
                    }
                    // `--send-ahead -p0`: the module was forgotten, and the
                    // next option would be taken for it
                    if module.starts_with('-') {
                        return Err(format!(
                            "option --send-ahead: '{v}' is an option, not a module name: \
                             --send-ahead <module>[=<n>]"
                        ));
                    }
                    let n = match n {
                        None => DEFAULT_SEND_AHEAD,
                        Some(n) => number(name, n, MAX_SEND_AHEAD as u64, "messages")? as usize,
                    };
                    o.config.send_ahead.insert(module.to_string(), n);
                }
                "handshake-timeout" => {
                    o.config.handshake_timeout = timeout(name, &value(true)?)?;
                }
                "frame-stall-timeout" => {
                    o.config.frame_stall_timeout = timeout(name, &value(true)?)?;
                }
                "hosts-allow" => o.allow = Some(value(true)?.into()),
                "hosts-deny" => o.deny = Some(value(true)?.into()),
                "no-unix-socket" => {
                    value(false)?;
                    o.unix = false;
                }
                _ => return Err(format!("unknown option '{a}' (see --help)")),
            }
            continue;
        }
        let Some(rest) = a.strip_prefix('-') else {
            // C: a bare number is the number of modules expected.
            if a.starts_with(|c: char| c.is_ascii_digit()) {
                o.expected = a
                    .parse::<u32>()
                    .map_err(|_| format!("'{a}' is not a number of modules"))?
                    .max(1);
                continue;
            }
            return Err(format!(
                "unexpected argument '{a}' (options start with '-'; see --help)"
            ));
        };
        let mut chars = rest.chars();
        let Some(flag) = chars.next() else {
            return Err("empty option '-' (see --help)".into());
        };
        let value = chars.as_str();
        let no_value = |set: &mut bool| -> Result<(), String> {
            if value.is_empty() {
                *set = true;
                Ok(())
            } else {
                Err(format!("option -{flag} takes no value (got '{a}')"))
            }
        };
        match flag {
            'l' => o.config.terminal_log = log_options(value, false)?,
            'L' => o.config.file_log = log_options(value, true)?,
            'f' => {
                if value.is_empty() {
                    return Err("option -f needs a file name glued to it (-fcentral.log)".into());
                }
                o.log_file = Some(value.into());
            }
            'p' => {
                if value.is_empty() {
                    // C's form: `-p 1381` would leave the port unset
                    return Err("option -p needs a port number glued to it (-p1381)".into());
                }
                o.port = value
                    .parse::<u16>()
                    .map_err(|_| format!("option -p: '{value}' is not a port number (0-65535)"))?;
            }
            'i' => {
                if value.is_empty() {
                    return Err("option -i needs a message name glued to it (-imsgName)".into());
                }
                o.config.ignore.push(value.to_string());
            }
            'I' => {
                if value.is_empty() {
                    return Err("option -I needs a message name or a file name glued to it".into());
                }
                let path = Path::new(value);
                if path.is_file() {
                    let text = std::fs::read_to_string(path)
                        .map_err(|e| format!("option -I: cannot read '{value}': {e}"))?;
                    o.config.ignore.extend(
                        text.lines()
                            .map(str::trim)
                            .filter(|l| !l.is_empty())
                            .map(str::to_string),
                    );
                } else {
                    o.config.ignore.push(value.to_string());
                }
            }
            'v' => no_value(&mut o.version)?,
            'h' => no_value(&mut o.help)?,
            'c' => no_value(&mut o.config.direct)?,
            'r' => no_value(&mut o.config.resend_on_reconnect)?,
            's' => no_value(&mut o.config.quiet)?,
            'u' => {
                let mut off = false;
                no_value(&mut off)?;
                o.console = false;
            }
            'd' => no_value(&mut o.debug)?,
            _ => return Err(format!("unknown option '{a}' (see --help)")),
        }
    }
    Ok(o)
}

/// C's automatic log file name: `x_ipc.log.<time(0)>`.
fn default_log_name(now: SystemTime) -> PathBuf {
    let secs = now.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    PathBuf::from(format!("x_ipc.log.{secs}"))
}

/// `ctime()` layout, in UTC: `Sun Nov 22 17:10:24 2026`.
fn ctime_utc(now: SystemTime) -> String {
    let secs = now.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let tod = secs % 86_400;
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    const WD: [&str; 7] = ["Thu", "Fri", "Sat", "Sun", "Mon", "Tue", "Wed"];
    const MON: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    format!(
        "{} {} {d:>2} {:02}:{:02}:{:02} {y}",
        WD[days.rem_euclid(7) as usize],
        MON[(m - 1) as usize],
        tod / 3600,
        (tod / 60) % 60,
        tod % 60
    )
}

fn banner() -> String {
    format!(
        "Task Control Server {IPC_VERSION} (Courier {})",
        env!("CARGO_PKG_VERSION")
    )
}

/// The file log, opened when the first line for it comes (at start with
/// `-L`, or later when the console turns file logging on, as C does).
struct FileLog {
    path: PathBuf,
    file: Option<std::io::BufWriter<std::fs::File>>,
    failed: bool,
    flush: bool,
}

impl FileLog {
    fn open(&mut self, now: SystemTime, silent: bool) -> std::io::Result<()> {
        if self.file.is_some() {
            return Ok(());
        }
        let f = std::fs::File::create(&self.path)?;
        let mut w = std::io::BufWriter::new(f);
        if !silent {
            say!("Logging to {};", self.path.display());
        }
        writeln!(
            w,
            "Logging Task Control Server {IPC_VERSION} (Courier {}) on {}",
            env!("CARGO_PKG_VERSION"),
            ctime_utc(now)
        )?;
        w.flush()?;
        self.file = Some(w);
        Ok(())
    }

    fn line(&mut self, line: &str, silent: bool) {
        if self.failed {
            return;
        }
        if self.file.is_none() {
            if let Err(e) = self.open(SystemTime::now(), silent) {
                esay!("ERROR: Can not open file {}: {e}", self.path.display());
                self.failed = true;
                return;
            }
        }
        if let Some(f) = self.file.as_mut() {
            let flush = self.flush;
            let r = writeln!(f, "{line}").and_then(|()| if flush { f.flush() } else { Ok(()) });
            if let Err(e) = r {
                self.write_failed(&e);
            }
        }
    }

    /// Writes what is buffered (at exit, with `-LF`).
    fn flush(&mut self) {
        if let Some(Err(e)) = self.file.as_mut().map(|f| f.flush()) {
            self.write_failed(&e);
        }
    }

    /// A write to the log file failed (a full file system, a file too
    /// large, a pipe whose reader went): said once on stderr, and the
    /// file is given up (a line cut in the middle is not followed by more
    /// lines with holes before them).
    fn write_failed(&mut self, e: &std::io::Error) {
        esay!(
            "central: cannot write the log file {}: {e}; logging to it stops",
            self.path.display()
        );
        self.failed = true;
        if let Some(f) = self.file.take() {
            // What is still buffered cannot be written either.
            let _ = f.into_parts();
        }
    }

    /// C's `add_comments_to_log_file`: lines up to a blank one, boxed.
    fn add_comments(&mut self, input: &mut dyn BufRead) {
        const STARS: &str =
            "********************************************************************************";
        const TITLE: &str =
            "*                                   Comments                                   *";
        const SPACER: &str =
            "*                                                                              *";
        let Some(f) = self.file.as_mut() else { return };
        say!("Enter any comments in the log file (end with blank line)");
        let _ = std::io::stdout().flush();
        let mut any = false;
        let mut line = String::new();
        loop {
            line.clear();
            match input.read_line(&mut line) {
                Ok(0) | Err(_) => break,
                Ok(_) => {}
            }
            let text = line.trim_end_matches(['\n', '\r']);
            if text.is_empty() {
                break;
            }
            if !any {
                let _ = write!(f, "\n{STARS}\n{TITLE}\n{SPACER}\n");
                any = true;
            }
            let _ = writeln!(f, "* {text:<77}*");
        }
        if any {
            let _ = write!(f, "{SPACER}\n{STARS}\n\n");
        }
        let _ = f.flush();
    }
}

fn main() -> ExitCode {
    courier_broker::keep_freed_memory();
    let opts = match parse_args(std::env::args().skip(1).collect()) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("central: {e}");
            return ExitCode::from(2);
        }
    };
    if opts.help {
        say!("{USAGE}");
        return ExitCode::SUCCESS;
    }
    if opts.version {
        say!("{}", banner());
        say!(" Implementation : Courier central (Rust), IPC protocol 3.9");
        say!(" Released : Courier {}", env!("CARGO_PKG_VERSION"));
        return ExitCode::SUCCESS;
    }
    let level = if opts.debug {
        tracing::Level::DEBUG
    } else {
        tracing::Level::WARN
    };
    courier_broker::logging::init(level.into(), true);
    // One thread, like the C central's select loop: the state machine runs
    // on one task anyway, and a single thread avoids cross-thread wake-ups.
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("central: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let code = rt.block_on(run(opts));
    // Reverse DNS lookups still running must not hold the exit up.
    rt.shutdown_timeout(Duration::from_millis(200));
    code
}

/// Why the console loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stop {
    /// SIGHUP (1), SIGINT (2) or SIGTERM (15).
    Signal(i32),
    /// `quit` on the console.
    Quit,
    /// The server task is gone.
    Gone,
}

/// True if SIGHUP is ignored (`nohup central`, or a supervisor that set
/// it so): then central leaves it ignored, as the C central (which never
/// touches SIGHUP) does.
#[allow(unsafe_code)]
fn hangup_ignored() -> bool {
    // SAFETY: sigaction(2) with a null new action only reads the current
    // disposition into `old`, a zeroed sigaction owned by this frame.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(libc::SIGHUP, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

/// The next SIGHUP, or never if SIGHUP is not watched.
async fn hangup(hup: &mut Option<tokio::signal::unix::Signal>) {
    match hup {
        Some(s) => {
            s.recv().await;
        }
        None => std::future::pending().await,
    }
}

async fn run(opts: Options) -> ExitCode {
    // Signals first: from the moment central listens, SIGTERM, SIGINT and
    // SIGHUP (the terminal of an ssh session closing) mean a clean stop,
    // the file log flushed. A SIGHUP ignored at start (`nohup`) stays so.
    use tokio::signal::unix::{signal, SignalKind};
    let hup = if hangup_ignored() {
        Ok(None)
    } else {
        signal(SignalKind::hangup()).map(Some)
    };
    let (mut term, mut int, mut hup) = match (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
        hup,
    ) {
        (Ok(t), Ok(i), Ok(h)) => (t, i, h),
        (Err(e), _, _) | (_, Err(e), _) | (_, _, Err(e)) => {
            eprintln!("central: cannot watch signals: {e}");
            return ExitCode::FAILURE;
        }
    };
    // A file named on the command line must be there (a typo must not
    // leave central open); only the default files may be missing.
    fn file<'a>(given: &'a Option<PathBuf>, default: &'static str) -> RulesFile<'a> {
        match given {
            Some(p) => RulesFile::Given(p),
            None => RulesFile::Default(Path::new(default)),
        }
    }
    let access = match AccessControl::load_files(
        file(&opts.allow, DEFAULT_ALLOW),
        file(&opts.deny, DEFAULT_DENY),
    ) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("central: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(w) = access.missing_files_warning() {
        eprintln!("central: WARNING: {w}");
    }
    let silent = opts.config.quiet;
    if let (Some(f), false) = (&opts.log_file, silent) {
        say!("Logging File Name: {}", f.display());
    }
    let now = SystemTime::now();
    let file = Arc::new(Mutex::new(FileLog {
        path: opts
            .log_file
            .clone()
            .unwrap_or_else(|| default_log_name(now)),
        file: None,
        failed: false,
        flush: !opts.config.file_log.no_flush,
    }));
    if opts.config.file_log.any() {
        let mut f = file.lock().unwrap_or_else(|e| e.into_inner());
        if let Err(e) = f.open(now, silent) {
            eprintln!("central: cannot open log file {}: {e}", f.path.display());
            return ExitCode::from(2);
        }
        if !opts.config.file_log.no_prompt && std::io::stdin().is_terminal() {
            f.add_comments(&mut std::io::stdin().lock());
        }
    }
    let sink_file = file.clone();
    let sink = LogSink::new(move |target: LogTarget, line: &str| {
        if target.terminal && !silent {
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{line}");
            let _ = out.flush();
        }
        if target.file {
            sink_file
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .line(line, silent);
        }
    });
    let file_log_on = opts.config.file_log.any();
    let messages_logged = opts.config.terminal_log.messages || opts.config.file_log.messages;
    let mut server = CentralServer::builder();
    if let Some(w) = opts.busy_poll {
        server = server.busy_poll(w);
    }
    let server = server
        .port(opts.port)
        .bind(opts.bind)
        .unix_socket(opts.unix)
        .config(opts.config)
        .access(access)
        .log_sink(sink)
        .spawn()
        .await;
    let server = match server {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{}", bind_error_line(&e));
            return ExitCode::FAILURE;
        }
    };
    tracing::debug!(
        addr = %server.local_addr(),
        unix_socket = opts.unix,
        "central listening"
    );
    let expecting = format!(
        "Expecting {} on port {}",
        opts.expected,
        server.local_addr().port()
    );
    if !silent {
        say!("{}", banner());
        say!("{expecting}");
        let _ = std::io::stdout().flush();
    }
    if file_log_on {
        file.lock()
            .unwrap_or_else(|e| e.into_inner())
            .line(&expecting, silent);
    }
    // The console: stdin lines are central commands; EOF ends the console
    // only. A plain thread, since reading stdin blocks.
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    if opts.console {
        let spawned = std::thread::Builder::new()
            .name("central-console".into())
            .spawn(move || console_lines(&mut std::io::stdin().lock(), |l| tx.send(l).is_ok()));
        if let Err(e) = spawned {
            esay!("central: no console: {e}");
        }
    } else {
        drop(tx);
    }
    let mut console_open = opts.console;
    // What stopped central: a signal's number, or the console's `quit`.
    let stop = loop {
        tokio::select! {
            _ = hangup(&mut hup) => break Stop::Signal(1),
            _ = int.recv() => break Stop::Signal(2),
            _ = term.recv() => break Stop::Signal(15),
            line = rx.recv(), if console_open => match line {
                Some(l) => {
                    let l = l.trim();
                    if l == "quit" {
                        break Stop::Quit;
                    } else if !server.command(l) {
                        break Stop::Gone;
                    }
                }
                None => console_open = false,
            },
        }
    };
    // As C (`x_ipcError`, `stdinHnd`): the memory report on stderr unless
    // silent, then the reason.
    if stop != Stop::Gone && !silent {
        if let Some(stats) = server.stats().await {
            let mut err = std::io::stderr().lock();
            for l in courier_broker::memory_report(&stats) {
                let _ = writeln!(err, "{l}");
            }
        }
    }
    match stop {
        Stop::Signal(n) => {
            // C logs it where messages are logged, else on stderr.
            let line = format!("Central Abort : Signal {n}");
            if messages_logged {
                if !silent {
                    say!("{line}");
                }
                if file_log_on {
                    file.lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .line(&line, silent);
                }
            } else {
                esay!("{line}");
            }
        }
        Stop::Quit => esay!("Central Quit"),
        Stop::Gone => {}
    }
    server.shutdown().await;
    file.lock().unwrap_or_else(|e| e.into_inner()).flush();
    ExitCode::SUCCESS
}

/// What central says when it cannot listen: C's line when the address is
/// taken (another central is likely running), what is wrong otherwise.
fn bind_error_line(e: &BindError) -> String {
    let source = match e {
        BindError::Tcp { source, .. } | BindError::Unix { source, .. } => Some(source),
        _ => None,
    };
    match source.map(std::io::Error::kind) {
        Some(std::io::ErrorKind::AddrInUse) => {
            format!("ERROR: Unable to start server, Is one already running? ({e})")
        }
        Some(std::io::ErrorKind::AddrNotAvailable) => {
            // Without the errno's "(os error 99)" before the hint.
            let text = e.to_string();
            let text = match text.rfind(" (os error ") {
                Some(i) if text.ends_with(')') => &text[..i],
                _ => &text,
            };
            format!("central: {text} (is the address on this machine?)")
        }
        _ => format!("central: {e}"),
    }
}

/// Reads console lines from `input` and hands each to `send` until it
/// returns false or the input ends. A line is bytes: one that is not UTF-8
/// (a stray byte from a serial console, a terminal in another encoding) is
/// decoded with U+FFFD in place of what does not decode, and so answered
/// as an unknown command rather than ending the console. A read error ends
/// the console with one line saying so.
fn console_lines(input: &mut dyn BufRead, mut send: impl FnMut(String) -> bool) {
    let mut buf = Vec::new();
    loop {
        buf.clear();
        match input.read_until(b'\n', &mut buf) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e) => {
                esay!("central: console closed: {e}");
                return;
            }
        }
        let mut line = &buf[..];
        if let Some(l) = line.strip_suffix(b"\n") {
            line = l.strip_suffix(b"\r").unwrap_or(l);
        }
        if !send(String::from_utf8_lossy(line).into_owned()) {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(a: &[&str]) -> Result<Options, String> {
        parse_args(a.iter().map(|s| s.to_string()).collect())
    }

    #[test]
    fn c_style_options() {
        let o = parse(&[
            "-lmsd", "-Lx", "-p1400", "-c", "-r", "-s", "-u", "-Ifoo", "-ibar", "-fx.log", "3",
        ])
        .unwrap();
        assert!(o.config.terminal_log.messages && o.config.terminal_log.data);
        assert!(!o.config.terminal_log.time);
        assert!(!o.config.file_log.any());
        assert_eq!(o.port, 1400);
        assert!(o.config.direct && o.config.resend_on_reconnect && o.config.quiet && !o.console);
        assert_eq!(o.config.ignore, ["foo", "bar"]);
        assert_eq!(o.log_file, Some(PathBuf::from("x.log")));
        assert_eq!(o.expected, 3);
        let o = parse(&["-l"]).unwrap();
        let t = o.config.terminal_log;
        assert!(t.messages && t.status && t.time && t.data && t.handle_summary);
        assert!(!t.ignore_internal);
        let o = parse(&[]).unwrap();
        assert_eq!(o.port, 1381);
        assert!(o.unix && o.console && !o.config.quiet);
        assert_eq!((o.allow, o.deny), (None, None), "the default files");
        let t = o.config.terminal_log;
        assert!(t.messages && t.status && t.ignore_internal && !t.data);
    }

    #[test]
    fn logging_letters_like_c() {
        let o = parse(&["-lMS", "-LmfN"]).unwrap();
        assert!(o.config.terminal_log.messages && o.config.terminal_log.status);
        let f = o.config.file_log;
        assert!(f.messages && f.no_flush && f.no_prompt);
        // Any x means no logging, wherever it is.
        let o = parse(&["-lmx", "-Lxm"]).unwrap();
        assert!(!o.config.terminal_log.any() && !o.config.file_log.any());
    }

    #[test]
    fn long_options() {
        let o = parse(&[
            "--bind",
            "127.0.0.1",
            "--hosts-allow=/a",
            "--hosts-deny",
            "/d",
            "--no-unix-socket",
            "--busy-poll=50",
            "--cut-through",
            "65536",
            "--send-ahead=logger=4",
            "--send-ahead",
            "recorder",
        ])
        .unwrap();
        assert_eq!(
            o.config.send_ahead,
            [
                ("logger".into(), 4),
                ("recorder".into(), DEFAULT_SEND_AHEAD)
            ]
            .into()
        );
        assert!(parse(&[]).unwrap().config.send_ahead.is_empty());
        assert_eq!(o.busy_poll, Some(std::time::Duration::from_micros(50)));
        assert_eq!(o.config.cut_through, Some(65536));
        assert_eq!(parse(&[]).unwrap().config.cut_through, None);
        assert_eq!(o.bind, IpAddr::from([127, 0, 0, 1]));
        assert_eq!(
            (o.allow.as_deref(), o.deny.as_deref()),
            (Some(Path::new("/a")), Some(Path::new("/d")))
        );
        assert!(!o.unix);
        assert_eq!(
            parse(&["--bind=::1"]).unwrap().bind,
            "::1".parse::<IpAddr>().unwrap()
        );
        assert!(parse(&["--help"]).unwrap().help);
        assert!(parse(&["-h"]).unwrap().help);
        assert!(parse(&["-v"]).unwrap().version);
        assert_eq!(parse(&["-p0"]).unwrap().port, 0);
    }

    #[test]
    fn timeout_options() {
        use std::time::Duration;
        let handshake = |a: &[&str]| parse(a).map(|o| o.config.handshake_timeout);
        let stall = |a: &[&str]| parse(a).map(|o| o.config.frame_stall_timeout);
        assert_eq!(handshake(&[]), Ok(Some(Duration::from_secs(10))));
        assert_eq!(stall(&[]), Ok(Some(Duration::from_secs(30))));
        for (name, get) in [
            ("handshake-timeout", &handshake as &dyn Fn(&[&str]) -> _),
            ("frame-stall-timeout", &stall),
        ] {
            let opt = format!("--{name}");
            assert_eq!(get(&[&opt, "3"]), Ok(Some(Duration::from_secs(3))));
            assert_eq!(get(&[&format!("{opt}=0")]), Ok(None));
            for bad in ["x", "-1", "86401", "", "1.5"] {
                assert_eq!(
                    get(&[&opt, bad]),
                    Err(format!(
                        "option {opt}: '{bad}' is not a number of seconds from 0 (never) to 86400"
                    ))
                );
            }
            assert_eq!(get(&[&opt]), Err(format!("option {opt} needs a value")));
        }
    }

    #[test]
    fn ignore_file_one_name_per_line() {
        let path = std::env::temp_dir().join(format!("central-ignore-{}", std::process::id()));
        std::fs::write(&path, "msgA\n  msgB  \n\nmsgC").unwrap();
        let o = parse(&[&format!("-I{}", path.display())]).unwrap();
        assert_eq!(o.config.ignore, ["msgA", "msgB", "msgC"]);
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn bad_options_say_what_is_wrong() {
        for (args, want) in [
            (&["-pabc"][..], "option -p: 'abc' is not a port number"),
            (&["-p70000"][..], "option -p: '70000' is not a port number"),
            (
                &["-p"][..],
                "option -p needs a port number glued to it (-p1381)",
            ),
            (
                &["-p", "1382"][..],
                "option -p needs a port number glued to it",
            ),
            (&["-p-1"][..], "option -p: '-1'"),
            (&["-lq"][..], "option -lq: unknown logging option 'q' in -l"),
            (&["-LZ"][..], "option -LZ: unknown logging option 'Z' in -L"),
            (&["-lF"][..], "option -lF: unknown logging option 'F' in -l"),
            (&["-x"][..], "unknown option '-x'"),
            (&["-t"][..], "unknown option '-t'"),
            (&["-cc"][..], "option -c takes no value (got '-cc')"),
            (&["-vv"][..], "option -v takes no value"),
            (&["-u1"][..], "option -u takes no value"),
            (
                &["--bind", "nowhere"][..],
                "option --bind: 'nowhere' is not an IP address",
            ),
            (&["--bind"][..], "option --bind needs a value"),
            (
                &["--busy-poll", "0"][..],
                "option --busy-poll: '0' is not a number of microseconds",
            ),
            (
                &["--busy-poll=2s"][..],
                "option --busy-poll: '2s' is not a number of microseconds",
            ),
            (
                &["--cut-through", "0"][..],
                "option --cut-through: '0' is not a number of bytes",
            ),
            (
                &["--cut-through=1MiB"][..],
                "option --cut-through: '1MiB' is not a number of bytes",
            ),
            (&["--cut-through"][..], "option --cut-through needs a value"),
            (
                &["--send-ahead", "logger=0"][..],
                "option --send-ahead: '0' is not a number of messages from 1 to 1024",
            ),
            (
                &["--send-ahead=logger=1025"][..],
                "option --send-ahead: '1025' is not a number of messages",
            ),
            (
                &["--send-ahead=logger=lots"][..],
                "option --send-ahead: 'lots' is not a number of messages",
            ),
            (
                &["--send-ahead", "=8"][..],
                "option --send-ahead: '=8' names no module",
            ),
            (&["--send-ahead"][..], "option --send-ahead needs a value"),
            (
                &["--send-ahead", "-p0"][..],
                "option --send-ahead: '-p0' is an option, not a module name",
            ),
            (
                &["--no-unix-socket=yes"][..],
                "option --no-unix-socket takes no value",
            ),
            (&["--frobnicate"][..], "unknown option '--frobnicate'"),
            (&["-f"][..], "option -f needs a file name"),
            (&["-I"][..], "option -I needs a message name or a file name"),
            (&["-"][..], "empty option '-'"),
            (&["stray"][..], "unexpected argument 'stray'"),
            (&["3x"][..], "'3x' is not a number of modules"),
        ] {
            let e = parse(args).unwrap_err();
            assert!(e.starts_with(want), "{args:?}: {e}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
    }

    #[test]
    fn console_lines_that_are_not_utf8_do_not_end_the_console() {
        let mut got = Vec::new();
        let input = b"status\nst\xffx\r\n\x01\xfe\nquit\nlast without newline";
        console_lines(&mut &input[..], |l| {
            got.push(l);
            true
        });
        assert_eq!(
            got,
            [
                "status",
                "st\u{fffd}x",
                "\u{1}\u{fffd}",
                "quit",
                "last without newline"
            ]
        );
        // A receiver that is gone stops the reading.
        let mut n = 0;
        console_lines(&mut &b"a\nb\nc\n"[..], |_| {
            n += 1;
            false
        });
        assert_eq!(n, 1);
    }

    #[test]
    fn log_name_and_time_like_c() {
        let t = UNIX_EPOCH + Duration::from_secs(1_795_367_424);
        assert_eq!(default_log_name(t), PathBuf::from("x_ipc.log.1795367424"));
        assert_eq!(ctime_utc(t), "Sun Nov 22 17:10:24 2026");
        assert_eq!(ctime_utc(UNIX_EPOCH), "Thu Jan  1 00:00:00 1970");
    }

    #[test]
    fn bind_errors_say_what_is_wrong() {
        use std::io::{Error, ErrorKind};
        let addr = "10.255.255.1:1381".parse().unwrap();
        let tcp = |kind: ErrorKind, text: &str| BindError::Tcp {
            addr,
            source: Error::new(kind, text),
        };
        assert_eq!(
            bind_error_line(&tcp(
                ErrorKind::AddrNotAvailable,
                "Cannot assign requested address"
            )),
            "central: cannot listen on 10.255.255.1:1381: Cannot assign requested address \
             (is the address on this machine?)"
        );
        assert_eq!(
            bind_error_line(&tcp(ErrorKind::AddrInUse, "Address in use")),
            "ERROR: Unable to start server, Is one already running? \
             (cannot listen on 10.255.255.1:1381: Address in use)"
        );
        assert_eq!(
            bind_error_line(&tcp(ErrorKind::PermissionDenied, "Permission denied")),
            "central: cannot listen on 10.255.255.1:1381: Permission denied"
        );
    }

    #[test]
    fn comments_are_boxed() {
        let path = std::env::temp_dir().join(format!("central-comments-{}", std::process::id()));
        let mut f = FileLog {
            path: path.clone(),
            file: None,
            failed: false,
            flush: true,
        };
        f.open(UNIX_EPOCH, true).unwrap();
        f.add_comments(&mut &b"first run\n\nignored\n"[..]);
        f.line("Expecting 1 on port 1381", true);
        drop(f);
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].starts_with("Logging Task Control Server 3.9.1 (Courier "));
        assert!(lines[0].ends_with(" on Thu Jan  1 00:00:00 1970"));
        assert_eq!(lines[2].len(), 80);
        assert_eq!(lines[5], format!("* {:<77}*", "first run"));
        assert_eq!(lines.last(), Some(&"Expecting 1 on port 1381"));
    }
}
