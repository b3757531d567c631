//! The `central` binary as an operator runs it: a console line that is not
//! UTF-8, SIGHUP (and `nohup`), rules files edited while central runs, and
//! what a module refused by them is told. Every run listens on 127.0.0.1
//! only, without the UNIX socket, with rules files of its own in a scratch
//! directory; every wait is bounded and every central is killed at the end.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

mod common;
use common::{read_to_eof, tcp, Client, T};

const BIN: &str = env!("CARGO_BIN_EXE_central");

/// A scratch directory of this test's own (process id and test name).
fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("central-ops-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A running `central`, stdout and stderr read line by line on threads.
struct Central {
    child: Child,
    stdin: Option<ChildStdin>,
    out: mpsc::Receiver<String>,
    err: mpsc::Receiver<String>,
    seen_out: Vec<String>,
    seen_err: Vec<String>,
    port: u16,
}

impl Central {
    /// Starts central on a free port with rules files `allow` and `deny`
    /// and the extra flags, in `dir`; waits for `Expecting 1 on port <p>`.
    /// `ignore_hup`: start it with SIGHUP ignored, as `nohup` does.
    fn start(dir: &Path, allow: &Path, deny: &Path, extra: &[&str], ignore_hup: bool) -> Central {
        let mut cmd = Command::new(BIN);
        cmd.env_remove("RUST_LOG")
            .current_dir(dir)
            .args(["-p0", "--bind", "127.0.0.1", "--no-unix-socket"])
            .arg("--hosts-allow")
            .arg(allow)
            .arg("--hosts-deny")
            .arg(deny)
            .args(extra)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if ignore_hup {
            // SAFETY: signal(2) is async-signal-safe; it only sets this
            // child's disposition of SIGHUP between fork and exec.
            unsafe {
                cmd.pre_exec(|| {
                    if libc::signal(libc::SIGHUP, libc::SIG_IGN) == libc::SIG_ERR {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let mut child = cmd.spawn().unwrap();
        let mut c = Central {
            stdin: child.stdin.take(),
            out: lines_of(child.stdout.take().unwrap()),
            err: lines_of(child.stderr.take().unwrap()),
            child,
            seen_out: Vec::new(),
            seen_err: Vec::new(),
            port: 0,
        };
        let line = c.wait_out(|l| l.starts_with("Expecting "));
        c.port = line.rsplit(' ').next().unwrap().parse().unwrap();
        c
    }

    /// Waits for a stdout line that satisfies `f`.
    fn wait_out(&mut self, f: impl Fn(&str) -> bool) -> String {
        wait_line(&self.out, &mut self.seen_out, f, "stdout")
    }

    /// Waits for a stderr line that satisfies `f`.
    fn wait_err(&mut self, f: impl Fn(&str) -> bool) -> String {
        wait_line(&self.err, &mut self.seen_err, f, "stderr")
    }

    fn signal(&self, sig: libc::c_int) {
        let pid = libc::pid_t::try_from(self.child.id()).unwrap();
        // SAFETY: kill(2) on our own child's pid.
        assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
    }

    /// A module that has done the whole handshake.
    fn module(&self, name: &str) -> Client<std::net::TcpStream> {
        let mut c = Client::new(tcp(([127, 0, 0, 1], self.port).into()), name);
        c.sync();
        c
    }

    /// Connects and expects central to close the connection before any
    /// byte; returns the local port (named in central's log line).
    fn refused(&self) -> u16 {
        let mut s = tcp(([127, 0, 0, 1], self.port).into());
        let port = s.local_addr().unwrap().port();
        assert!(read_to_eof(&mut s).is_empty(), "refused before any byte");
        port
    }

    /// Waits for central to exit by itself (killed, and the test failed,
    /// if it does not within [`T`]); returns its exit code and every line
    /// of stdout and stderr.
    fn wait_exit(mut self) -> (Option<i32>, Vec<String>, Vec<String>) {
        let deadline = Instant::now() + T;
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                panic!(
                    "central did not exit by itself; stdout {:#?}\nstderr {:#?}",
                    self.seen_out, self.seen_err
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        drain(&self.out, &mut self.seen_out);
        drain(&self.err, &mut self.seen_err);
        (
            status.code(),
            std::mem::take(&mut self.seen_out),
            std::mem::take(&mut self.seen_err),
        )
    }
}

impl Drop for Central {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn lines_of(r: impl Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut r = BufReader::new(r);
        let mut buf = Vec::new();
        loop {
            buf.clear();
            match r.read_until(b'\n', &mut buf) {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
            let l = String::from_utf8_lossy(&buf);
            if tx.send(l.trim_end_matches('\n').to_string()).is_err() {
                return;
            }
        }
    });
    rx
}

fn wait_line(
    rx: &mpsc::Receiver<String>,
    seen: &mut Vec<String>,
    f: impl Fn(&str) -> bool,
    what: &str,
) -> String {
    if let Some(l) = seen.iter().find(|l| f(l)) {
        return l.clone();
    }
    let deadline = Instant::now() + T;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(l) => {
                seen.push(l.clone());
                if f(&l) {
                    return l;
                }
            }
            Err(e) => panic!("no such {what} line ({e}); so far: {seen:#?}"),
        }
    }
}

/// Reads what is left until the end (the exit closes the pipes).
fn drain(rx: &mpsc::Receiver<String>, seen: &mut Vec<String>) {
    let deadline = Instant::now() + T;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(l) => seen.push(l),
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
            Err(e) => panic!("output did not end ({e}): {seen:#?}"),
        }
    }
}

/// Empty allow and deny files in `dir`.
fn empty_rules(dir: &Path) -> (PathBuf, PathBuf) {
    let (allow, deny) = (dir.join("hosts.allow"), dir.join("hosts.deny"));
    std::fs::write(&allow, "# no rules\n").unwrap();
    std::fs::write(&deny, "# no rules\n").unwrap();
    (allow, deny)
}

/// A console line that is not UTF-8 is answered as an unknown command;
/// the console goes on, and `quit` after it stops central (its input stays
/// open: the end of input must not be what stops it).
#[test]
fn a_console_line_that_is_not_utf8_does_not_end_the_console() {
    let dir = scratch("console");
    let (allow, deny) = empty_rules(&dir);
    let mut c = Central::start(&dir, &allow, &deny, &[], false);
    let mut stdin = c.stdin.take().unwrap();
    stdin.write_all(b"status\n").unwrap();
    c.wait_out(|l| l == "Resource status");
    stdin.write_all(b"st\xffx\n\x01\xfe\r\n").unwrap();
    c.wait_out(|l| l == "Unknown command 'st\u{fffd}x' (type help)");
    stdin.write_all(b"memory\nquit\n").unwrap();
    stdin.flush().unwrap();
    let (code, out, err) = c.wait_exit();
    drop(stdin);
    assert_eq!(code, Some(0), "stdout {out:#?}\nstderr {err:#?}");
    assert!(
        out.iter().any(|l| l == "Cumulative Memory Usage:"),
        "{out:#?}"
    );
    assert!(err.iter().any(|l| l == "Central Quit"), "{err:#?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// SIGHUP (a terminal hanging up) stops central as SIGTERM does: exit 0,
/// the memory report, the abort line, and a complete file log even with
/// `F` (no flush after each line).
#[test]
fn sighup_stops_central_cleanly_and_the_file_log_is_complete() {
    let dir = scratch("hup");
    let (allow, deny) = empty_rules(&dir);
    let log = dir.join("central.log");
    let f = format!("-f{}", log.display());
    let mut c = Central::start(&dir, &allow, &deny, &["-u", "-LmsdFn", &f], false);
    let m = c.module("hup-test");
    c.wait_out(|l| l == "   modName : hup-test");
    c.signal(libc::SIGHUP);
    let (code, out, err) = c.wait_exit();
    drop(m);
    assert_eq!(code, Some(0), "stdout {out:#?}\nstderr {err:#?}");
    assert_eq!(
        err.first().map(String::as_str),
        Some("Cumulative Memory Usage:")
    );
    assert!(
        out.iter().any(|l| l == "Central Abort : Signal 1"),
        "{out:#?}"
    );
    let text = std::fs::read_to_string(&log).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines[0].starts_with("Logging Task Control Server 3.9.1 (Courier "),
        "{text}"
    );
    assert!(lines.contains(&"   modName : hup-test"), "{text}");
    assert_eq!(lines.last(), Some(&"Central Abort : Signal 1"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Started with SIGHUP ignored (`nohup central`), central leaves it so, as
/// the C central does: a hangup changes nothing, SIGTERM still stops it.
#[test]
fn sighup_ignored_at_start_stays_ignored() {
    let dir = scratch("nohup");
    let (allow, deny) = empty_rules(&dir);
    let mut c = Central::start(&dir, &allow, &deny, &["-u"], true);
    c.signal(libc::SIGHUP);
    // Still serving after the hangup.
    let _m = c.module("after-hup");
    c.wait_out(|l| l == "   modName : after-hup");
    c.signal(libc::SIGTERM);
    let (code, out, err) = c.wait_exit();
    assert_eq!(code, Some(0), "stdout {out:#?}\nstderr {err:#?}");
    assert!(
        out.iter().any(|l| l == "Central Abort : Signal 15"),
        "{out:#?}"
    );
    assert!(
        !out.iter().any(|l| l == "Central Abort : Signal 1"),
        "{out:#?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A rules file edited while central runs is in force from the next
/// connection on, as with tcpd; a file that became invalid or unreadable
/// leaves the rules read before in force, with one warning naming it.
#[test]
fn an_edited_rules_file_is_in_force_at_the_next_connection() {
    let dir = scratch("reload");
    let (allow, deny) = empty_rules(&dir);
    let mut c = Central::start(&dir, &allow, &deny, &["-u"], false);
    drop(c.module("before-edit"));
    c.wait_out(|l| l == "   modName : before-edit");

    std::fs::write(&deny, "central : ALL\n").unwrap();
    let port = c.refused();
    let want = format!(
        "WARNING: connection rejected from 127.0.0.1:{port} (denied by {}:1)",
        deny.display()
    );
    c.wait_out(|l| l == want);

    // Malformed now: the old rules stay, said once on stderr.
    std::fs::write(&deny, "# edited\ncentral : 10.0.0.0/40\n").unwrap();
    c.refused();
    let port = c.refused();
    let want = format!("127.0.0.1:{port} (denied by {}:1)", deny.display());
    c.wait_out(|l| l.ends_with(&want));
    let kept = format!("the rules last read from {} stay in force", deny.display());
    let warning = c.wait_err(|l| l.contains(&kept));
    assert!(
        warning.contains(&format!(
            "{}:2: prefix length 40 too long in '10.0.0.0/40'",
            deny.display()
        )),
        "{warning}"
    );
    // Unreadable (a directory in its place; root reads any file): the same.
    std::fs::remove_file(&deny).unwrap();
    std::fs::create_dir(&deny).unwrap();
    c.refused();
    c.refused();
    c.wait_err(|l| l.contains(&format!("cannot read {}: ", deny.display())));

    // Valid again: the new rules.
    std::fs::remove_dir(&deny).unwrap();
    std::fs::write(&deny, "central : 192.0.2.1\n").unwrap();
    drop(c.module("after-edit"));
    c.wait_out(|l| l == "   modName : after-edit");
    c.signal(libc::SIGTERM);
    let (code, out, err) = c.wait_exit();
    assert_eq!(code, Some(0), "stdout {out:#?}\nstderr {err:#?}");
    let warnings: Vec<&String> = err.iter().filter(|l| l.contains(&kept)).collect();
    assert_eq!(warnings.len(), 2, "one per trouble: {err:#?}");
    assert_eq!(
        out.iter()
            .filter(|l| l.contains("connection rejected"))
            .count(),
        5,
        "{out:#?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A module that central's rules refuse is told that this may be why,
/// not only that its name may be taken.
#[tokio::test]
async fn a_module_refused_by_the_rules_is_told_both_causes() {
    let dir = scratch("refused-msg");
    let (allow, deny) = empty_rules(&dir);
    std::fs::write(&deny, "ALL : ALL\n").unwrap();
    let mut c = Central::start(&dir, &allow, &deny, &["-u"], false);
    let connected = courier::Session::builder(format!("ipc://127.0.0.1:{}", c.port))
        .name("refused-robot")
        .connect_timeout(T)
        .connect()
        .await;
    let Err(e) = connected else {
        panic!("a refused module connected")
    };
    let e = e.to_string();
    for part in [
        "central closed the connection before the handshake ended",
        "access rules (--hosts-allow/--hosts-deny",
        "a module named \"refused-robot\" is already connected",
    ] {
        assert!(e.contains(part), "{part:?} in {e}");
    }
    c.wait_out(|l| l.starts_with("WARNING: connection rejected from 127.0.0.1:"));
    c.signal(libc::SIGTERM);
    let (code, _, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err:#?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A query made while central is stopped (`SIGSTOP`) says that central
/// did not answer either, where one that a server leaves unanswered says
/// only that no reply came: the session asks central who serves the
/// message shortly before the end, and tells the two apart by its answer.
#[tokio::test]
async fn a_query_while_central_is_stopped_says_central_was_silent() {
    let dir = scratch("silent");
    let (allow, deny) = empty_rules(&dir);
    let c = Central::start(&dir, &allow, &deny, &[], false);
    let url = format!("ipc://127.0.0.1:{}", c.port);
    let connect = |name: &'static str| {
        courier::Session::builder(url.clone())
            .name(name)
            .connect_timeout(T)
            .connect()
    };
    let server = connect("mute-server").await.unwrap();
    let client = connect("client").await.unwrap();
    // served, never answered
    let reqs = server.serve::<i32, i32>("q", "").await.unwrap();
    let ms = Duration::from_millis;
    let e = client
        .query::<i32, i32>("q", &1)
        .timeout(ms(500))
        .await
        .unwrap_err();
    assert!(matches!(e, courier::QueryError::Timeout { .. }), "{e}");
    c.signal(libc::SIGSTOP);
    let e = client
        .query::<i32, i32>("q", &2)
        .timeout(ms(500))
        .await
        .unwrap_err();
    c.signal(libc::SIGCONT);
    assert!(
        matches!(e, courier::QueryError::CentralSilent { asked, .. } if asked == ms(50)),
        "{e}"
    );
    assert!(
        e.to_string()
            .contains("central did not answer either (asked who serves it 50ms before the end)"),
        "{e}"
    );
    drop(reqs);
    client.close().await;
    server.close().await;
    c.signal(libc::SIGTERM);
    let (code, _, err) = c.wait_exit();
    assert_eq!(code, Some(0), "{err:#?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A log file that stops taking lines while central runs (a full file
/// system; here a pipe whose reader went, which fails the same way and
/// needs no mount) is said once on stderr, and central goes on.
#[test]
fn a_log_file_that_cannot_be_written_is_said_once_on_stderr() {
    use std::os::unix::ffi::OsStrExt;
    let dir = scratch("logfail");
    let (allow, deny) = empty_rules(&dir);
    let fifo = dir.join("central.log");
    let c_path = std::ffi::CString::new(fifo.as_os_str().as_bytes()).unwrap();
    // SAFETY: mkfifo(3) on a path of our own scratch directory.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
    let reader_path = fifo.clone();
    let reader = std::thread::spawn(move || {
        let mut r = BufReader::new(std::fs::File::open(reader_path).unwrap());
        let mut first = String::new();
        r.read_line(&mut first).unwrap();
        // Dropping it closes the only read end.
        first
    });
    let f = format!("-f{}", fifo.display());
    let mut c = Central::start(&dir, &allow, &deny, &["-u", "-Lmsd", &f], false);
    let first = reader.join().unwrap();
    assert!(
        first.starts_with("Logging Task Control Server 3.9.1"),
        "{first}"
    );
    let m1 = c.module("logfail-1");
    c.wait_err(|l| l.starts_with("central: cannot write the log file "));
    // Central goes on, and does not say it again.
    let m2 = c.module("logfail-2");
    c.wait_out(|l| l == "   modName : logfail-2");
    drop((m1, m2));
    c.signal(libc::SIGTERM);
    let (code, out, err) = c.wait_exit();
    assert_eq!(code, Some(0), "stdout {out:#?}\nstderr {err:#?}");
    let said: Vec<&String> = err
        .iter()
        .filter(|l| l.contains("cannot write the log file"))
        .collect();
    assert_eq!(said.len(), 1, "{err:#?}");
    assert_eq!(
        *said[0],
        format!(
            "central: cannot write the log file {}: Broken pipe (os error 32); logging to it stops",
            fifo.display()
        )
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An address that is not on this machine: central says so, not that
/// another central may be running (C's line, kept for a port in use).
/// The bind fails, so nothing leaves the machine.
#[test]
fn a_bind_address_not_on_this_machine_is_said_plainly() {
    let dir = scratch("badbind");
    let (allow, deny) = empty_rules(&dir);
    let out = Command::new(BIN)
        .env_remove("RUST_LOG")
        .current_dir(&dir)
        .args(["-p0", "--bind", "10.255.255.1", "--no-unix-socket", "-u"])
        .arg("--hosts-allow")
        .arg(&allow)
        .arg("--hosts-deny")
        .arg(&deny)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.lines().any(
            |l| l.starts_with("central: cannot listen on 10.255.255.1:0: ")
                && l.ends_with("(is the address on this machine?)")
        ),
        "{err}"
    );
    assert!(!err.contains("Is one already running"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
