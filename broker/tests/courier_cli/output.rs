//! Output that cannot be written: a full disk (/dev/full answers every
//! write with ENOSPC) is a failure said in one line, `courier <cmd>: cannot
//! write to stdout: <error>`, exit 1, for the commands that print as they
//! go (echo, hz, list) and those that print in one piece (completions); a
//! reader that goes (`| head -1`, EPIPE) ends a command quietly, exit 0.

use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::{Central, Proc, T};

const FULL: &str = "No space left on device (os error 28)";

/// Runs `courier args` with stdout on /dev/full, to its end (at most `T`):
/// exit code and stderr.
fn run_into_full_disk(args: &[&str]) -> (Option<i32>, String) {
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .expect("open /dev/full");
    let mut child = Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::from(full))
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn courier");
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stderr.read_to_string(&mut s);
        s
    });
    let deadline = Instant::now() + T;
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("courier {args:?} did not exit within {T:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    (status.code(), reader.join().unwrap())
}

#[test]
fn output_to_a_full_disk_fails_in_one_line() {
    let c = Central::start();
    let u = c.url.as_str();
    // an int on `tick` at 20 Hz, until dropped
    let mut publ = Proc::start(&[
        "pub", u, "tick", "1", "--format", "int", "--count", "0", "--rate", "20", "--wait", "0",
    ]);
    publ.expect("ready");
    for (cmd, args) in [
        ("echo", &["echo", u, "tick", "--count", "3"][..]),
        ("echo", &["echo", u, "tick", "--count", "3", "--json"][..]),
        ("hz", &["hz", u, "tick", "--count", "40"][..]),
        ("list", &["list", u][..]),
    ] {
        let (code, err) = run_into_full_disk(args);
        assert_eq!(
            (code, err.as_str()),
            (
                Some(1),
                format!("courier {cmd}: cannot write to stdout: {FULL}\n").as_str()
            ),
            "courier {args:?} > /dev/full"
        );
    }
    // a reader that goes after one line is no failure: a quiet end
    let mut child = Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(["echo", u, "tick"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert_eq!(first, "1\n");
    // the read end closed (dropped above): the next sample ends it
    let deadline = Instant::now() + T;
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            panic!("courier echo did not end when its reader went");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert_eq!((status.code(), err.as_str()), (Some(0), ""));
}

#[test]
fn completions_to_a_full_disk_fail_in_one_line() {
    for shell in ["bash", "zsh"] {
        let (code, err) = run_into_full_disk(&["completions", shell]);
        assert_eq!(
            (code, err.as_str()),
            (
                Some(1),
                format!("courier completions: cannot write to stdout: {FULL}\n").as_str()
            ),
            "courier completions {shell} > /dev/full"
        );
    }
}
