//! `courier hz` and `courier bw` over IPC and RTPS.

use crate::{run, url, Central, Proc};

/// The number after `key ` in a report line.
fn field(line: &str, key: &str) -> f64 {
    let rest = line
        .split_once(&format!("{key} "))
        .unwrap_or_else(|| panic!("{key} in {line}"))
        .1;
    rest.split_whitespace().next().unwrap().parse().unwrap()
}

const PING_FORMAT: &str = "{uint, ulong, string}";

#[test]
fn hz_and_bw_over_ipc() {
    let c = Central::start();
    let u = c.url.as_str();
    // --gap: samples of a loaded machine may come in bunches
    let hz = Proc::start(&["hz", u, "t", "--duration", "3", "--gap", "1000"]);
    // pub waits for hz's subscription before it sends
    let text = format!(r#"[1, 2, "{}"]"#, "x".repeat(100));
    let (code, _, err) = run(&[
        "pub",
        u,
        "t",
        &text,
        "--format",
        PING_FORMAT,
        "--count",
        "5",
        "--rate",
        "50",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = hz.finish();
    assert_eq!(code, Some(0), "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert!(lines.len() >= 2, "{out}");
    assert!(lines[0].starts_with("rate "), "{out}");
    assert!(lines[0].ends_with(" window 5 gaps 0"), "{out}");
    assert!(field(lines[0], "rate") > 1.0, "{out}");
    assert_eq!(lines[1], "no new samples", "{out}");
    // nothing at all: the end says so
    let (code, out, err) = run(&["hz", u, "nothing", "--duration", "1"]);
    assert_eq!((code, out.as_str()), (0, "no samples in 1 s\n"), "{err}");
    // bw: IPC data of {uint, ulong, string} with 100 characters: 4 + 8 + 4 + 100
    let bw = Proc::start(&["bw", u, "t", "--count", "5"]);
    let (code, _, err) = run(&[
        "pub",
        u,
        "t",
        &text,
        "--format",
        PING_FORMAT,
        "--count",
        "5",
        "--rate",
        "50",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = bw.finish();
    assert_eq!(code, Some(0), "{err}");
    let last = out.lines().last().unwrap_or_default();
    assert!(last.starts_with("bw "), "{out}");
    assert!(
        last.ends_with(" from 5 samples size mean 116 B min 116 B max 116 B window 5"),
        "{out}"
    );
}

#[test]
fn hz_and_bw_over_rtps() {
    let u = url(220);
    let _publ = Proc::start(&["ping", &u, "--publish", "--period", "20", "--size", "100"]);
    let (code, out, err) = run(&["hz", &u, "ping", "--count", "10", "--gap", "1000"]);
    assert_eq!(code, 0, "{err}");
    let last = out.lines().last().unwrap_or_default();
    assert!(last.ends_with(" window 10 gaps 0"), "{out}");
    assert!(field(last, "rate") > 1.0, "{out}");
    // CDR: 4 (header) + 4 (seq) + 4 (padding) + 8 (stamp) + 4 (length) +
    // 101, padded to a multiple of 4 as RTPS sends it
    let (code, out, err) = run(&["bw", &u, "ping", "--count", "10"]);
    assert_eq!(code, 0, "{err}");
    let last = out.lines().last().unwrap_or_default();
    assert!(
        last.ends_with(" from 10 samples size mean 128 B min 128 B max 128 B window 10"),
        "{out}"
    );
}
