//! `central`: a drop-in replacement for CMU IPC's central server.
//!
//! Options are those of the IPC manual §2, with their values glued to the
//! flag as the C central expects (`-lmsd`, `-p1381`, `-fcentral.log`), plus
//! `--bind`, `--hosts-allow`, `--hosts-deny` and `--no-unix-socket`.

use std::io::{BufRead, Write};
use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};

use courier_broker::access::AccessControl;
use courier_broker::{CentralServer, Config, LogOptions, LogTarget};

const USAGE: &str = "usage: central [options]
  -v               display server version information
  -l<options>      logging onto terminal: m s t d i h r p x (-l alone = -lmstdh; default -lmsi)
  -L<options>      logging into file: as -l, plus F (no flush) n (no prompt); default -Lx
  -f<filename>     log file name (default: central-<date>-<time>.log)
  -p<port>         port to listen on (default 1381)
  -c               direct (module to module) connections when possible
  -I<msgName>      do not log this message (may repeat); -I<file>: names in a file
  -s               silent: print nothing on the terminal
  -u               no terminal (stdin) commands
  -r               resend non-completed messages when modules crash and reconnect
  --bind <addr>    listen on this address only (default: all interfaces, as C)
  --hosts-allow <file>, --hosts-deny <file>
                   access rules (default /etc/hosts.allow, /etc/hosts.deny)
  --no-unix-socket do not listen on /tmp/x_ipc/<port>
  --help           this text";

#[derive(Debug)]
struct Options {
    config: Config,
    port: u16,
    bind: IpAddr,
    log_file: Option<PathBuf>,
    silent: bool,
    console: bool,
    version: bool,
    unix: bool,
    allow: PathBuf,
    deny: PathBuf,
}

fn parse_args(args: Vec<String>) -> Result<Option<Options>, String> {
    let mut o = Options {
        config: Config::default(),
        port: courier_broker::DEFAULT_PORT,
        bind: "0.0.0.0".parse().unwrap(),
        log_file: None,
        silent: false,
        console: true,
        version: false,
        unix: true,
        allow: "/etc/hosts.allow".into(),
        deny: "/etc/hosts.deny".into(),
    };
    let mut it = args.into_iter();
    while let Some(a) = it.next() {
        let mut long_value = |name: &str| -> Result<String, String> {
            it.next()
                .ok_or_else(|| format!("option {name} needs a value"))
        };
        match a.as_str() {
            "--help" | "-h" => return Ok(None),
            "--bind" => {
                let v = long_value("--bind")?;
                o.bind = v
                    .parse()
                    .map_err(|_| format!("option --bind: '{v}' is not an IP address"))?;
                continue;
            }
            "--hosts-allow" => {
                o.allow = long_value("--hosts-allow")?.into();
                continue;
            }
            "--hosts-deny" => {
                o.deny = long_value("--hosts-deny")?.into();
                continue;
            }
            "--no-unix-socket" => {
                o.unix = false;
                continue;
            }
            _ => {}
        }
        let Some(rest) = a.strip_prefix('-') else {
            return Err(format!(
                "unexpected argument '{a}' (options start with '-'; see --help)"
            ));
        };
        let mut chars = rest.chars();
        let flag = chars.next().ok_or("empty option '-'")?;
        let value: String = chars.collect();
        match flag {
            'v' if value.is_empty() => o.version = true,
            'l' => {
                o.config.terminal_log =
                    LogOptions::parse(&value, false).map_err(|e| e.to_string())?
            }
            'L' => {
                o.config.file_log = LogOptions::parse(&value, true).map_err(|e| e.to_string())?
            }
            'f' => {
                if value.is_empty() {
                    return Err("option -f needs a file name glued to it (-fcentral.log)".into());
                }
                o.log_file = Some(value.into());
            }
            'p' => {
                o.port = value
                    .parse::<u16>()
                    .ok()
                    .filter(|p| *p > 0)
                    .ok_or_else(|| {
                        format!("option -p: '{value}' is not a port number (1-65535)")
                    })?;
            }
            'I' => {
                if value.is_empty() {
                    return Err("option -I needs a message name or file glued to it".into());
                }
                let path = std::path::Path::new(&value);
                if path.is_file() {
                    let text = std::fs::read_to_string(path)
                        .map_err(|e| format!("option -I: cannot read {value}: {e}"))?;
                    o.config
                        .ignore
                        .extend(text.split_whitespace().map(str::to_string));
                } else {
                    o.config.ignore.push(value);
                }
            }
            'c' if value.is_empty() => o.config.direct = true,
            'r' if value.is_empty() => o.config.resend_on_reconnect = true,
            's' if value.is_empty() => o.silent = true,
            'u' if value.is_empty() => o.console = false,
            _ => return Err(format!("unknown option '{a}' (see --help)")),
        }
    }
    Ok(Some(o))
}

/// `central-YYYYMMDD-HHMMSS.log` (UTC).
fn default_log_name() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
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
    PathBuf::from(format!(
        "central-{y:04}{m:02}{d:02}-{:02}{:02}{:02}.log",
        tod / 3600,
        (tod / 60) % 60,
        tod % 60
    ))
}

fn main() -> ExitCode {
    let opts = match parse_args(std::env::args().skip(1).collect()) {
        Ok(Some(o)) => o,
        Ok(None) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("central: {e}");
            return ExitCode::from(2);
        }
    };
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("central: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    rt.block_on(run(opts))
}

async fn run(opts: Options) -> ExitCode {
    let banner = format!(
        "Task Control Server 3.9.1 (Courier {})",
        env!("CARGO_PKG_VERSION")
    );
    if opts.version {
        println!("{banner}");
        println!("Courier central: a Rust implementation of the CMU IPC 3.9 central server");
    }
    let access = match AccessControl::load(&opts.allow, &opts.deny) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("central: {e}");
            return ExitCode::from(2);
        }
    };
    let file: Option<Arc<Mutex<std::io::BufWriter<std::fs::File>>>> = if opts.config.file_log.any()
    {
        let path = opts.log_file.clone().unwrap_or_else(default_log_name);
        match std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
        {
            Ok(f) => {
                let mut w = std::io::BufWriter::new(f);
                let _ = writeln!(w, "{banner}");
                Some(Arc::new(Mutex::new(w)))
            }
            Err(e) => {
                eprintln!("central: cannot open log file {}: {e}", path.display());
                return ExitCode::from(2);
            }
        }
    } else {
        None
    };
    let silent = opts.silent;
    let flush = !opts.config.file_log.no_flush;
    let file_sink = file.clone();
    let sink = Arc::new(move |target: LogTarget, line: &str| {
        if target.terminal && !silent {
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{line}");
        }
        if target.file {
            if let Some(f) = &file_sink {
                let mut f = f.lock().unwrap();
                let _ = writeln!(f, "{line}");
                if flush {
                    let _ = f.flush();
                }
            }
        }
    });
    let server = CentralServer::builder()
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
            eprintln!("central: {e}");
            return ExitCode::FAILURE;
        }
    };
    if !silent {
        println!("{banner}");
        println!("Expecting 1 on port {}", server.local_addr().port());
        let _ = std::io::stdout().flush();
    }
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    if opts.console {
        std::thread::spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
    } else {
        drop(tx);
    }
    let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("central: cannot watch SIGTERM: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut console_open = opts.console;
    let signal = loop {
        tokio::select! {
            _ = tokio::signal::ctrl_c() => break 2,
            _ = term.recv() => break 15,
            line = rx.recv(), if console_open => match line {
                Some(l) => server.command(&l),
                None => console_open = false,
            },
        }
    };
    let stats = server.stats();
    server.shutdown().await;
    if !silent {
        println!(
            "Central stopped by signal {signal} ({} module(s) connected; at most {} byte(s) were queued)",
            stats.modules, stats.peak_queued_bytes
        );
    }
    if let Some(f) = file {
        let _ = f.lock().unwrap().flush();
    }
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(a: &[&str]) -> Result<Option<Options>, String> {
        parse_args(a.iter().map(|s| s.to_string()).collect())
    }

    #[test]
    fn c_style_options() {
        let o = parse(&[
            "-lmsd", "-Lx", "-p1400", "-c", "-r", "-s", "-u", "-Ifoo", "-fx.log",
        ])
        .unwrap()
        .unwrap();
        assert!(o.config.terminal_log.messages && o.config.terminal_log.data);
        assert!(!o.config.file_log.any());
        assert_eq!(o.port, 1400);
        assert!(o.config.direct && o.config.resend_on_reconnect && o.silent && !o.console);
        assert_eq!(o.config.ignore, vec!["foo".to_string()]);
        assert_eq!(o.log_file, Some(PathBuf::from("x.log")));
        let o = parse(&["-l"]).unwrap().unwrap();
        assert!(o.config.terminal_log.time && o.config.terminal_log.handle_summary);
    }

    #[test]
    fn bad_options_say_what_is_wrong() {
        for (args, want) in [
            (&["-pabc"][..], "option -p: 'abc' is not a port number"),
            (&["-p70000"][..], "option -p: '70000'"),
            (&["-p"][..], "option -p: ''"),
            (&["-lq"][..], "unknown logging option 'q' in -l"),
            (&["-LZ"][..], "unknown logging option 'Z' in -L"),
            (&["-lF"][..], "unknown logging option 'F' in -l"),
            (&["-x"][..], "unknown option '-x'"),
            (&["-cc"][..], "unknown option '-cc'"),
            (
                &["--bind", "nowhere"][..],
                "option --bind: 'nowhere' is not an IP address",
            ),
            (&["--bind"][..], "option --bind needs a value"),
            (&["-f"][..], "option -f needs a file name"),
            (&["stray"][..], "unexpected argument 'stray'"),
        ] {
            let e = parse(args).unwrap_err();
            assert!(e.starts_with(want), "{args:?}: {e}");
        }
    }

    #[test]
    fn log_name_looks_like_a_date() {
        let n = default_log_name().display().to_string();
        assert!(n.starts_with("central-20") && n.ends_with(".log"), "{n}");
        assert_eq!(n.len(), "central-20261122-170000.log".len());
    }
}
