//! The `central` binary: its flags, its startup lines, the console, file
//! logging, access control files and signals. Every run listens on
//! 127.0.0.1 only, without the UNIX socket, and every wait is bounded.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

mod common;
use common::{read_to_eof, tcp, Client, T};

const BIN: &str = env!("CARGO_BIN_EXE_central");

/// A running `central` with its stdout read line by line on a thread.
struct Central {
    child: Child,
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
    /// Stderr read line by line too, once [`Central::watch_stderr`] is called.
    errs: Option<mpsc::Receiver<String>>,
    seen_err: Vec<String>,
    port: u16,
}

impl Central {
    /// Starts central on a free port (`-p0`) with the given extra flags and
    /// waits for `Expecting 1 on port <port>`.
    fn start(extra: &[&str], stdin: Stdio) -> Central {
        Central::start_in(&temp(""), extra, stdin)
    }

    /// The same in working directory `dir` (where automatic log files go).
    fn start_in(dir: &Path, extra: &[&str], stdin: Stdio) -> Central {
        Central::start_env(dir, extra, stdin, None)
    }

    /// The same with `RUST_LOG` set to `rust_log` (`None`: unset).
    fn start_env(dir: &Path, extra: &[&str], stdin: Stdio, rust_log: Option<&str>) -> Central {
        let mut cmd = Command::new(BIN);
        match rust_log {
            Some(v) => cmd.env("RUST_LOG", v),
            None => cmd.env_remove("RUST_LOG"),
        };
        let mut child = cmd
            .current_dir(dir)
            .args(["-p0", "--bind", "127.0.0.1", "--no-unix-socket"])
            .args(extra)
            .stdin(stdin)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let lines = spawn_reader(child.stdout.take().unwrap());
        let mut c = Central {
            child,
            lines,
            seen: Vec::new(),
            errs: None,
            seen_err: Vec::new(),
            port: 0,
        };
        let line = c.wait_line(|l| l.starts_with("Expecting "));
        c.port = line.rsplit(' ').next().unwrap().parse().unwrap();
        c
    }

    /// Starts central with `-s` (which prints no `Expecting` line) on a
    /// free port, stderr watched, and waits until a connection succeeds:
    /// that first connection is accepted (and, if the rules say so,
    /// refused).
    fn start_silent(extra: &[&str]) -> Central {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let mut child = Command::new(BIN)
            .env_remove("RUST_LOG")
            .current_dir(temp(""))
            .args(["--bind", "127.0.0.1", "--no-unix-socket", "-s"])
            .arg(format!("-p{port}"))
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let lines = spawn_reader(child.stdout.take().unwrap());
        let mut c = Central {
            child,
            lines,
            seen: Vec::new(),
            errs: None,
            seen_err: Vec::new(),
            port,
        };
        c.watch_stderr();
        let deadline = Instant::now() + T;
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "central did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
        c
    }

    /// Reads stderr line by line from now on (see [`Central::wait_err_line`]).
    fn watch_stderr(&mut self) {
        self.errs = Some(spawn_reader(self.child.stderr.take().unwrap()));
    }

    fn wait_err_line(&mut self, f: impl Fn(&str) -> bool) -> String {
        if let Some(l) = self.seen_err.iter().find(|l| f(l)) {
            return l.clone();
        }
        let errs = self.errs.as_ref().expect("watch_stderr first");
        let deadline = Instant::now() + T;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match errs.recv_timeout(left) {
                Ok(l) => {
                    self.seen_err.push(l.clone());
                    if f(&l) {
                        return l;
                    }
                }
                Err(e) => panic!("no such stderr line ({e}); so far: {:#?}", self.seen_err),
            }
        }
    }

    fn wait_line(&mut self, f: impl Fn(&str) -> bool) -> String {
        if let Some(l) = self.seen.iter().find(|l| f(l)) {
            return l.clone();
        }
        let deadline = Instant::now() + T;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if f(&l) {
                        return l;
                    }
                }
                Err(e) => panic!("no such line ({e}); output so far: {:#?}", self.seen),
            }
        }
    }

    fn connect(&self) -> TcpStream {
        tcp(([127, 0, 0, 1], self.port).into())
    }

    /// A module that has done the whole IPC handshake.
    fn module(&self, name: &str) -> Client<TcpStream> {
        let mut c = Client::new(self.connect(), name);
        c.sync();
        c
    }

    fn signal(&self, sig: libc::c_int) {
        let pid = libc::pid_t::try_from(self.child.id()).unwrap();
        // SAFETY: kill(2) on our own child's pid.
        assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
    }

    /// Waits for the exit; returns the status code, every line of stdout
    /// and stderr.
    fn wait_exit_all(mut self) -> (Option<i32>, Vec<String>, String) {
        let (code, err) = self.exit();
        // The reader thread ends at EOF, which the exit brings.
        let deadline = Instant::now() + T;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => self.seen.push(l),
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
                Err(e) => panic!("stdout did not end ({e}): {:#?}", self.seen),
            }
        }
        (code, std::mem::take(&mut self.seen), err)
    }

    /// Waits for the exit; returns the status code and stderr.
    fn wait_exit(mut self) -> (Option<i32>, String) {
        self.exit()
    }

    fn exit(&mut self) -> (Option<i32>, String) {
        let deadline = Instant::now() + T;
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                panic!("central did not exit; output: {:#?}", self.seen);
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut err = String::new();
        match (self.child.stderr.take(), self.errs.take()) {
            (Some(mut e), _) => {
                e.read_to_string(&mut err).unwrap();
            }
            (None, Some(errs)) => {
                let deadline = Instant::now() + T;
                loop {
                    let left = deadline.saturating_duration_since(Instant::now());
                    match errs.recv_timeout(left) {
                        Ok(l) => self.seen_err.push(l),
                        Err(mpsc::RecvTimeoutError::Disconnected) => break,
                        Err(e) => panic!("stderr did not end ({e}): {:#?}", self.seen_err),
                    }
                }
                for l in &self.seen_err {
                    err.push_str(l);
                    err.push('\n');
                }
            }
            (None, None) => {}
        }
        (status.code(), err)
    }
}

impl Drop for Central {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn spawn_reader(out: impl Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Runs the binary to completion (it must not wait for anything).
fn run(args: &[&str]) -> (Option<i32>, String, String) {
    let mut child = Command::new(BIN)
        .current_dir(temp(""))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + T;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("central {args:?} did not exit");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let mut out = String::new();
    let mut err = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (status.code(), out, err)
}

thread_local! {
    /// This test's scratch directory: the harness runs each test on a
    /// thread of its own, and the directory goes with it, also when the
    /// test fails (one per process was left in the temporary directory by
    /// every run).
    static SCRATCH: tempfile::TempDir = tempfile::Builder::new()
        .prefix("central-cli-")
        .tempdir()
        .unwrap();
}

/// A path in this test's scratch directory.
fn temp(name: &str) -> PathBuf {
    SCRATCH.with(|d| d.path().join(name))
}

#[test]
fn bad_flags_exit_2_with_one_line_naming_them() {
    for (args, want) in [
        (
            &["-pabc"][..],
            "central: option -p: 'abc' is not a port number (0-65535)",
        ),
        (
            &["-p70000"][..],
            "central: option -p: '70000' is not a port number (0-65535)",
        ),
        (
            &["-lq"][..],
            "central: option -lq: unknown logging option 'q' in -l",
        ),
        (
            &["-LmQ"][..],
            "central: option -LmQ: unknown logging option 'Q' in -L",
        ),
        (&["-z"][..], "central: unknown option '-z' (see --help)"),
        (
            &["--frob"][..],
            "central: unknown option '--frob' (see --help)",
        ),
        (
            &["--bind", "bogus"][..],
            "central: option --bind: 'bogus' is not an IP address",
        ),
        (&["--bind"][..], "central: option --bind needs a value"),
        (
            &["-s", "-u", "-f"][..],
            "central: option -f needs a file name",
        ),
        (&["stray"][..], "central: unexpected argument 'stray'"),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(out.is_empty(), "{args:?}: {out}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with(want), "{args:?}: {err}");
    }
}

/// An empty rules file (no rules, but it exists).
fn empty_rules(name: &str) -> PathBuf {
    let p = temp(name);
    std::fs::write(&p, "# no rules\n").unwrap();
    p
}

#[test]
fn bad_hosts_file_exits_2_naming_file_and_line() {
    let deny = temp("bad.deny");
    std::fs::write(&deny, "# rules\ncentral : 10.0.0.0/40\n").unwrap();
    let allow = empty_rules("empty.allow");
    let (code, _, err) = run(&[
        "-p0",
        "--bind",
        "127.0.0.1",
        "--no-unix-socket",
        "-u",
        "--hosts-allow",
        allow.to_str().unwrap(),
        "--hosts-deny",
        deny.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert_eq!(
        err.trim_end(),
        format!(
            "central: {}:2: prefix length 40 too long in '10.0.0.0/40'",
            deny.display()
        )
    );
}

/// Access control fails closed: a rules file named on the command line
/// that does not exist or cannot be read stops central before it listens,
/// with one line naming the file and the OS error.
#[test]
fn named_hosts_file_missing_or_unreadable_exits_2() {
    let empty = empty_rules("exists.rules");
    let empty = empty.to_str().unwrap();
    let dir = temp("");
    let dir = dir.to_str().unwrap();
    for (allow, deny, want) in [
        (
            empty,
            "/nonexistent/hosts.deny",
            "central: cannot read /nonexistent/hosts.deny: No such file or directory (os error 2)"
                .to_string(),
        ),
        (
            "/nonexistent/hosts.allow",
            empty,
            "central: cannot read /nonexistent/hosts.allow: No such file or directory (os error 2)"
                .to_string(),
        ),
        (
            dir,
            empty,
            format!("central: cannot read {dir}: Is a directory (os error 21)"),
        ),
    ] {
        let (code, out, err) = run(&[
            "-p0",
            "--bind",
            "127.0.0.1",
            "--no-unix-socket",
            "-u",
            "--hosts-allow",
            allow,
            "--hosts-deny",
            deny,
        ]);
        assert_eq!(code, Some(2), "{allow} {deny}: {err}");
        assert_eq!(out, "", "nothing started, nothing printed");
        assert_eq!(err, format!("{want}\n"));
    }
}

/// Without `--hosts-*`, the default files may be missing: central starts,
/// with one warning line on stderr saying which rules are not in force.
#[test]
fn missing_default_hosts_files_give_one_warning_line() {
    let allow = Path::new("/etc/hosts.allow").exists();
    let deny = Path::new("/etc/hosts.deny").exists();
    let want = match (allow, deny) {
        (true, true) => None,
        (false, false) => Some("central: WARNING: no access rules in force: neither /etc/hosts.allow nor /etc/hosts.deny exists; every host may connect"),
        (true, false) => Some("central: WARNING: no deny rules in force: /etc/hosts.deny does not exist; every host may connect"),
        (false, true) => Some("central: WARNING: no allow rules in force: /etc/hosts.allow does not exist; only /etc/hosts.deny decides"),
    };
    let c = Central::start(&["-u"], Stdio::null());
    c.signal(libc::SIGTERM);
    let (code, out, err) = c.wait_exit_all();
    assert_eq!(code, Some(0), "{err}");
    // SIGTERM prints the memory report on stderr, as C's central does
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("WARNING")).collect();
    assert_eq!(lines, want.into_iter().collect::<Vec<_>>(), "stderr: {err}");
    assert!(err.contains("Cumulative Memory Usage:"), "stderr: {err}");
    assert!(
        !out.iter().any(|l| l.contains("in force")),
        "not on stdout too: {out:?}"
    );
}

#[test]
fn version_and_help() {
    let (code, out, _) = run(&["-v"]);
    assert_eq!(code, Some(0));
    let first = out.lines().next().unwrap();
    assert_eq!(
        first,
        format!(
            "Task Control Server 3.9.1 (Courier {})",
            env!("CARGO_PKG_VERSION")
        )
    );
    let (code, out, _) = run(&["--help"]);
    assert_eq!(code, Some(0));
    assert!(out.starts_with("central command line options:"), "{out}");
    for flag in [
        " -l:",
        " -L:",
        " -f",
        " -p<port>",
        " -c:",
        " -I<",
        " -s:",
        " -u:",
        " -r:",
        "--bind",
        "--hosts-allow",
        "--no-unix-socket",
    ] {
        assert!(out.contains(flag), "{flag} missing from --help");
    }
}

#[test]
fn starts_accepts_and_exits_0_on_sigterm() {
    let (allow, deny) = (empty_rules("start.allow"), empty_rules("start.deny"));
    let mut c = Central::start(
        &[
            "-u",
            "--hosts-allow",
            allow.to_str().unwrap(),
            "--hosts-deny",
            deny.to_str().unwrap(),
        ],
        Stdio::null(),
    );
    assert_eq!(
        c.seen[0],
        format!(
            "Task Control Server 3.9.1 (Courier {})",
            env!("CARGO_PKG_VERSION")
        )
    );
    assert_eq!(c.seen[1], format!("Expecting 1 on port {}", c.port));
    let mut s = c.connect();
    let mut first = [0u8; 4];
    s.read_exact(&mut first).unwrap();
    assert!(i32::from_be_bytes(first) >= 2, "the msgInfo id");
    let mut m = c.module("cli-test");
    c.wait_line(|l| l == " Received a new connection: 6");
    c.wait_line(|l| l == "   modName : cli-test");
    c.signal(libc::SIGTERM);
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err}");
    // As C on a signal: the memory report on stderr; the abort line went
    // to the log (stdout), messages being logged. No warning: both rules
    // files exist.
    assert!(
        err.starts_with("Cumulative Memory Usage:\n") && !err.contains("WARNING"),
        "{err}"
    );
    // Central closed the modules' connections on the way out.
    read_to_eof(&mut s);
    read_to_eof(&mut m.sock);
}

/// `RUST_LOG` chooses central's diagnostics on stderr; one that does not
/// parse is named and the default kept.
#[test]
fn rust_log_is_honoured_and_a_bad_one_named() {
    let mut c = Central::start_env(&temp(""), &["-u"], Stdio::null(), Some("debug"));
    let m = c.module("log-test");
    drop(m);
    c.wait_line(|l| l.contains("modName : log-test"));
    c.signal(libc::SIGTERM);
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("DEBUG"),
        "debug lines with RUST_LOG=debug:\n{err}"
    );

    let c = Central::start_env(&temp(""), &["-u"], Stdio::null(), Some("=x=y"));
    c.signal(libc::SIGTERM);
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("RUST_LOG=\"=x=y\" ignored"), "{err}");
    assert!(!err.contains("DEBUG"), "{err}");
}

#[test]
fn sigint_stops_it_too_and_expected_count_is_printed() {
    let mut c = Central::start(&["-u", "3"], Stdio::null());
    let want = format!("Expecting 3 on port {}", c.port);
    c.wait_line(|l| l == want);
    c.signal(libc::SIGINT);
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err}");
}

#[test]
fn console_commands_and_end_of_input() {
    let mut c = Central::start(&[], Stdio::piped());
    let mut stdin = c.child.stdin.take().unwrap();
    writeln!(stdin, "help").unwrap();
    c.wait_line(|l| l.contains("close <module>"));
    writeln!(stdin, "status").unwrap();
    writeln!(stdin, "bogus").unwrap();
    // End of input ends the console, not central.
    drop(stdin);
    let _m = c.module("after-eof");
    c.wait_line(|l| l == "   modName : after-eof");
    c.signal(libc::SIGTERM);
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err}");
}

#[test]
fn quit_on_the_console_stops_central() {
    let mut c = Central::start(&[], Stdio::piped());
    let mut stdin = c.child.stdin.take().unwrap();
    writeln!(stdin, "quit").unwrap();
    let (code, err) = c.wait_exit();
    assert_eq!(code, Some(0));
    assert!(err.contains("Central Quit"), "{err}");
}

#[test]
fn silent_prints_nothing() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut child = Command::new(BIN)
        .current_dir(temp(""))
        .args(["--bind", "127.0.0.1", "--no-unix-socket", "-u", "-s"])
        .arg(format!("-p{port}"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Listening means running (signal handlers come before the listener).
    let deadline = Instant::now() + T;
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "central did not start");
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = libc::pid_t::try_from(child.id()).unwrap();
    // SAFETY: kill(2) on our own child.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
    let deadline = Instant::now() + T;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline);
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(0));
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    assert_eq!(out, "");
}

#[test]
fn file_log_goes_to_the_named_file() {
    let log = temp("central.log");
    let _ = std::fs::remove_file(&log);
    let f = format!("-f{}", log.display());
    let c = Central::start(&["-u", "-lx", "-Lms", &f], Stdio::null());
    assert_eq!(c.seen[0], format!("Logging File Name: {}", log.display()));
    assert_eq!(c.seen[1], format!("Logging to {};", log.display()));
    let _m = c.module("logged");
    let deadline = Instant::now() + T;
    loop {
        let text = std::fs::read_to_string(&log).unwrap();
        if text.contains("   modName : logged") {
            let lines: Vec<&str> = text.lines().collect();
            assert!(lines[0].starts_with("Logging Task Control Server 3.9.1 (Courier "));
            assert_eq!(lines[1], format!("Expecting 1 on port {}", c.port));
            break;
        }
        assert!(Instant::now() < deadline, "log file: {text}");
        std::thread::sleep(Duration::from_millis(20));
    }
    // -lx: the terminal shows no log lines.
    c.signal(libc::SIGTERM);
    let seen = c.seen.clone();
    let (code, _) = c.wait_exit();
    assert_eq!(code, Some(0));
    assert!(!seen.iter().any(|l| l.contains("Received")), "{seen:?}");
    std::fs::remove_file(&log).unwrap();
}

#[test]
fn hosts_deny_refuses_before_any_byte_and_says_why() {
    let deny = temp("hosts.deny");
    let allow = temp("hosts.allow");
    std::fs::write(&allow, "sshd : ALL\n").unwrap();
    std::fs::write(&deny, "central : localhost\n").unwrap();
    let dir = temp("deny-cwd");
    std::fs::create_dir_all(&dir).unwrap();
    let mut c = Central::start_in(
        &dir,
        &[
            "-u",
            "--hosts-allow",
            allow.to_str().unwrap(),
            "--hosts-deny",
            deny.to_str().unwrap(),
        ],
        Stdio::null(),
    );
    let mut s = c.connect();
    let port = s.local_addr().unwrap().port();
    assert!(
        read_to_eof(&mut s).is_empty(),
        "no protocol byte for a denied peer"
    );
    let want = format!(
        "WARNING: connection rejected from 127.0.0.1:{port} (denied by {}:1)",
        deny.display()
    );
    c.wait_line(|l| l == want);
    c.signal(libc::SIGTERM);
    let (code, out, err) = c.wait_exit_all();
    assert_eq!(code, Some(0));
    assert_eq!(out.iter().filter(|l| l.contains("rejected")).count(), 1);
    assert!(
        !err.contains("rejected"),
        "logged once, not on stderr too: {err}"
    );
    let files: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
    assert!(files.is_empty(), "no file log without -L: {files:?}");
}

/// A refusal is logged exactly once: on the terminal log when it is on,
/// else (`-lx`, or `-s`, which prints nothing on stdout) on stderr.
#[test]
fn a_refusal_is_logged_once_whatever_the_logging() {
    let deny = temp("once.deny");
    let allow = empty_rules("once.allow");
    std::fs::write(&deny, "central : ALL\n").unwrap();
    let rejected = |l: &str| l.contains("connection rejected from 127.0.0.1:");
    for (flag, on_stdout) in [(None, true), (Some("-lx"), false), (Some("-s"), false)] {
        let mut args = vec![
            "-u",
            "--hosts-allow",
            allow.to_str().unwrap(),
            "--hosts-deny",
            deny.to_str().unwrap(),
        ];
        args.extend(flag);
        let mut c = if flag == Some("-s") {
            // Its probe connection is the first refusal.
            Central::start_silent(&args)
        } else {
            let mut c = Central::start(&args, Stdio::null());
            c.watch_stderr();
            let mut s = c.connect();
            assert!(read_to_eof(&mut s).is_empty());
            c
        };
        // A second refusal, whose line shows that the first was written.
        let mut s = c.connect();
        let port = s.local_addr().unwrap().port();
        assert!(read_to_eof(&mut s).is_empty());
        let second = move |l: &str| l.contains(&format!("127.0.0.1:{port} "));
        if on_stdout {
            c.wait_line(second);
        } else {
            c.wait_err_line(second);
        }
        c.signal(libc::SIGTERM);
        let (code, out, err) = c.wait_exit_all();
        assert_eq!(code, Some(0), "{flag:?}: {err}");
        let n_out = out.iter().filter(|l| rejected(l)).count();
        let n_err = err.lines().filter(|l| rejected(l)).count();
        let want = if on_stdout { (2, 0) } else { (0, 2) };
        assert_eq!(
            (n_out, n_err),
            want,
            "{flag:?}: stdout {out:#?}\nstderr {err}"
        );
    }
}

#[test]
fn file_log_without_f_gets_c_style_name_in_working_directory() {
    let dir = temp("auto-log");
    std::fs::create_dir_all(&dir).unwrap();
    let c = Central::start_in(&dir, &["-u", "-Lsn"], Stdio::null());
    let logging = c
        .seen
        .iter()
        .find(|l| l.starts_with("Logging to "))
        .unwrap()
        .clone();
    let name = logging
        .strip_prefix("Logging to ")
        .and_then(|n| n.strip_suffix(';'))
        .unwrap()
        .to_string();
    let secs = name.strip_prefix("x_ipc.log.").unwrap();
    assert!(secs.parse::<u64>().is_ok(), "{name}");
    c.signal(libc::SIGTERM);
    assert_eq!(c.wait_exit().0, Some(0));
    let text = std::fs::read_to_string(dir.join(&name)).unwrap();
    assert!(
        text.starts_with("Logging Task Control Server 3.9.1"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn port_in_use_fails_clearly() {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let p = format!("-p{port}");
    let (code, _, err) = run(&[&p, "--bind", "127.0.0.1", "--no-unix-socket", "-u"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("Unable to start server"), "{err}");
    assert!(err.contains(&format!("127.0.0.1:{port}")), "{err}");
}

/// `central --help | head -1` where `head` is gone before central writes:
/// exit 0, no panic (it printed "failed printing to stdout: Broken pipe"
/// and exited 101).
#[test]
fn help_into_a_closed_pipe_exits_cleanly() {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = std::process::Command::new(BIN)
        .arg("--help")
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
