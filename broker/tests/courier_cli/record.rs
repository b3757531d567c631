//! `courier record` and `courier replay`: recordings made on IPC (through a
//! central embedded in the test, no C) replayed onto IPC and onto RTPS,
//! where a Cyclone DDS 0.10 reader (`tests/peers/rtps/cyclone_peer`,
//! pinned to lo) receives the same values; recordings read by Python's
//! `mcap` package; damaged files; usage errors.

use std::path::{Path, PathBuf};
use std::time::Duration;

use courier_tests::peers::fnv1a32;

use crate::{cyclone_reader, run, url, Central, Proc, T};

/// `Msg` of `tests/peers/rtps/types.idl` (`unsigned long seq; string text;
/// sequence<octet> payload`) as an IPC format: the payload's length is the
/// `seq` field (field 1), as the derive lays a `<T:k>` out in CDR.
const MSG: &str = "{uint, string, <ubyte:1>}";

/// A directory of the test's own, removed when dropped.
struct Dir(PathBuf);

impl Dir {
    fn new(name: &str) -> Dir {
        let d = std::env::temp_dir().join(format!("courier-record-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Dir(d)
    }

    fn file(&self, name: &str) -> String {
        self.0.join(name).to_str().unwrap().to_string()
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Publishes `value` of `format` once with `courier pub` (which waits for
/// the recorder's subscription).
fn publish(u: &str, topic: &str, format: &str, value: &str) {
    let (code, out, err) = run(&["pub", u, topic, value, "--format", format]);
    assert_eq!(
        (code, out.as_str()),
        (0, "ready\nmatched 1\nsent 1\ndone\n"),
        "{err}"
    );
}

/// Records `msg` (three samples of MSG) and `text` (two strings) on the
/// central into `file`: the recorder's output.
fn record_ipc(c: &Central, file: &str, extra: &[&str]) -> String {
    let u = c.url.as_str();
    let mut args = vec!["record", u, "msg", "text", "-o", file, "--count", "5"];
    args.extend_from_slice(extra);
    let mut rec = Proc::start(&args);
    rec.expect("ready");
    for seq in 1..=3u32 {
        let payload: Vec<String> = (0..seq)
            .map(|i| ((seq * 7 + i) % 256).to_string())
            .collect();
        publish(
            u,
            "msg",
            MSG,
            &format!("[{seq}, \"ipc-{seq}\", [{}]]", payload.join(", ")),
        );
    }
    publish(u, "text", "string", "hello");
    publish(u, "text", "string", "world");
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{out}{err}");
    out
}

/// Replays `file` onto `rtps` with `args` once one reader has matched
/// (transient-local, at ten times the recorded pace): its output.
fn replay_to_reader(file: &str, rtps: &str, args: &[&str]) -> String {
    let mut a = vec!["replay", file, rtps];
    a.extend_from_slice(args);
    a.extend_from_slice(&["--wait", "1", "--transient-local", "--rate", "10"]);
    let (code, out, err) = run(&a);
    assert_eq!(code, 0, "{err}");
    out
}

/// The payload of sample `seq` as `record_ipc` publishes it.
fn payload(seq: u32) -> Vec<u8> {
    (0..seq).map(|i| ((seq * 7 + i) % 256) as u8).collect()
}

#[test]
fn a_recording_made_on_ipc_replays_onto_ipc_and_onto_cyclone_dds() {
    let dir = Dir::new("ipc-dds");
    let file = dir.file("ipc.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    let out = record_ipc(&c, &file, &[]);
    assert!(out.starts_with("channel msg ipc ipc-format:msg\n"), "{out}");
    assert!(out.contains("channel text ipc ipc-format:text\n"), "{out}");
    let size = std::fs::metadata(&file).unwrap().len();
    assert!(
        out.ends_with(&format!(
            "recorded 5 messages on 2 channels in {file} ({size} B)\ndone\n"
        )),
        "{out}"
    );

    // back onto IPC: echo prints the values published
    let mut echo = Proc::start(&["echo", u, "msg", "--count", "3", "--json"]);
    let (code, out, err) = run(&[
        "replay", &file, u, "--topic", "msg", "--wait", "1", "--rate", "10",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        out,
        format!(
            "channel msg ipc {:?}\nready\nreplayed 3 messages\ndone\n",
            MSG
        )
    );
    assert_eq!(echo.expect(""), r#"[1,"ipc-1",[7]]"#);
    assert_eq!(echo.expect(""), r#"[2,"ipc-2",[14,15]]"#);
    assert_eq!(echo.expect(""), r#"[3,"ipc-3",[21,22,23]]"#);
    assert_eq!(echo.wait(), Some(0));

    // onto RTPS: Cyclone DDS 0.10 reads courier::test::Msg, the values
    // re-encoded as CDR
    let (rtps, mut sub) = cyclone_reader(260, "msg", "msg", 3, &["--transient-local"]);
    let out = replay_to_reader(
        &file,
        &rtps,
        &["--topic", "msg", "--type", "msg=courier::test::Msg"],
    );
    assert_eq!(
        out,
        "channel msg ipc->cdr courier::test::Msg\nready\nreplayed 3 messages\ndone\n"
    );
    for seq in 1..=3u32 {
        let p = payload(seq);
        assert_eq!(
            sub.expect_line("sample", T).unwrap(),
            format!("sample {seq} ipc-{seq} {} {:08x}", p.len(), fnv1a32(&p)),
            "{}",
            sub.stderr()
        );
    }
    sub.expect_line("done", T).unwrap();

    // a channel recorded on IPC has no DDS type name until one is given
    let (code, _, err) = run(&["replay", &file, &rtps, "--topic", "text"]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        "courier: channel \"text\" (2): it was recorded on IPC, and DDS readers match on a type \
         name: give one with --type text=TYPE\n"
    );
    // all channels: the one that cannot be replayed stops the replay, and
    // the error says how to replay the others
    let (code, _, err) = run(&["replay", &file, &rtps, "--type", "msg=courier::test::Msg"]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        "courier: channel \"text\" (2): it was recorded on IPC, and DDS readers match on a type \
         name: give one with --type text=TYPE; or leave it out: --topic msg replays the others \
         only\n"
    );
    let (code, _, err) = run(&["replay", &file, u, "--topic", "nosuch"]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!("courier: --topic \"nosuch\": {file} has no channel of that topic (it has: msg, text)\n")
    );
}

/// `Keyed` of `tests/peers/rtps/types.idl` (`@key long id; unsigned long
/// seq; string text`) as an IPC format.
const KEYED: &str = "{int, uint, string}";

/// A recording's type says nothing of keys, and Cyclone DDS matches a
/// keyed reader only with a keyed writer: replay writes a topic keyed
/// when its readers are.
#[test]
fn a_recording_replays_onto_a_keyed_dds_topic() {
    let dir = Dir::new("keyed");
    let file = dir.file("keyed.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    let mut rec = Proc::start(&["record", u, "k", "-o", &file, "--count", "2"]);
    rec.expect("ready");
    publish(u, "k", KEYED, "[7, 1, \"k-1\"]");
    publish(u, "k", KEYED, "[9, 2, \"k-2\"]");
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{out}{err}");

    let (rtps, mut sub) = cyclone_reader(262, "k", "keyed", 2, &["--transient-local"]);
    let out = replay_to_reader(&file, &rtps, &["--type", "k=courier::test::Keyed"]);
    assert_eq!(
        out,
        "channel k ipc->cdr courier::test::Keyed\nready\nchannel k keyed, as its readers are\n\
         replayed 2 messages\ndone\n"
    );
    assert_eq!(
        sub.expect_line("sample", T).unwrap(),
        "sample 7 1 k-1",
        "{}",
        sub.stderr()
    );
    assert_eq!(
        sub.expect_line("sample", T).unwrap(),
        "sample 9 2 k-2",
        "{}",
        sub.stderr()
    );
    sub.expect_line("done", T).unwrap();
}

#[test]
fn a_recording_made_on_rtps_replays_onto_ipc() {
    let dir = Dir::new("dds-ipc");
    let file = dir.file("dds.mcap");
    let u = url(261);
    let mut rec = Proc::start(&["record", &u, "chatter", "-o", &file, "--count", "2"]);
    rec.expect("ready");
    let (code, _, err) = run(&[
        "pub",
        &u,
        "chatter",
        r#"[1, 2, "hi"]"#,
        "--count",
        "2",
        "--rate",
        "20",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{err}");
    assert!(
        out.starts_with("channel chatter cdr omgidl:courier::Ping\n"),
        "{out}"
    );
    let c = Central::start();
    let mut echo = Proc::start(&["echo", &c.url, "chatter", "--count", "2"]);
    let (code, out, err) = run(&["replay", &file, &c.url, "--wait", "1", "--rate", "5"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        out,
        "channel chatter cdr->ipc \"{uint, ulong, string}\"\nready\nreplayed 2 messages\ndone\n"
    );
    assert_eq!(echo.expect(""), r#"{1, 2, "hi"}"#);
    assert_eq!(echo.expect(""), r#"{1, 2, "hi"}"#);
}

/// The Python that has the `mcap` package: `COURIER_MCAP_PYTHON`, else
/// `COURIER_CYCLONEDDS_PYTHON` (the README's one Python for both), else
/// the venv `.ci/run` makes in the target directory (`cyclonedds-py`).
fn mcap_python() -> PathBuf {
    // target/debug/courier -> target
    let target = Path::new(env!("CARGO_BIN_EXE_courier"))
        .ancestors()
        .nth(2)
        .unwrap()
        .to_path_buf();
    let venv = target.join("cyclonedds-py");
    let python = std::env::var_os("COURIER_MCAP_PYTHON")
        .or_else(|| std::env::var_os("COURIER_CYCLONEDDS_PYTHON"))
        .map_or_else(|| venv.join("bin/python"), PathBuf::from);
    let ok = std::process::Command::new(&python)
        .args(["-c", "import mcap"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "reading recordings with another tool needs Python's mcap package in {}: install it \
         with `{}/bin/pip install 'mcap==1.*'` (what .ci/run does), or point \
         COURIER_MCAP_PYTHON at a Python that has it",
        python.display(),
        venv.display()
    );
    python
}

/// Lists a recording's channels, schemas and messages with Python's mcap.
const LIST: &str = r#"
import sys
from mcap.reader import make_reader
with open(sys.argv[1], "rb") as f:
    r = make_reader(f)
    s = r.get_summary()
    # chunks are closed at least once a second: one or more
    assert len(s.chunk_indexes) == s.statistics.chunk_count >= 1
    print("messages", s.statistics.message_count)
    for cid, c in sorted(s.channels.items()):
        sc = s.schemas.get(c.schema_id)
        print("channel", c.topic, c.message_encoding, dict(c.metadata),
              s.statistics.channel_message_counts.get(cid, 0))
        print("schema", sc.name, sc.encoding, repr(sc.data.decode()))
    for sc, c, m in r.iter_messages():
        assert m.publish_time == m.log_time > 0
        print(c.topic, m.data.hex())
"#;

#[test]
fn recordings_open_in_pythons_mcap() {
    let python = mcap_python();
    let dir = Dir::new("python");
    let file = dir.file("ipc.mcap");
    let c = Central::start();
    record_ipc(&c, &file, &[]);
    let out = std::process::Command::new(python)
        .args(["-c", LIST, &file])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta =
        |f: &str| format!("{{'byte_order': 'little', 'ipc_format': '{f}', 'recorded_on': 'ipc'}}");
    assert_eq!(
        String::from_utf8(out.stdout).unwrap(),
        format!(
            "messages 5\n\
             channel msg ipc {} 3\n\
             schema msg ipc-format '{MSG}'\n\
             channel text ipc {} 2\n\
             schema text ipc-format 'string'\n\
             msg 01000000050000006970632d310100000007\n\
             msg 02000000050000006970632d32020000000e0f\n\
             msg 03000000050000006970632d3303000000151617\n\
             text 0500000068656c6c6f\n\
             text 05000000776f726c64\n",
            meta(MSG),
            meta("string"),
        )
    );
}

/// The offsets of the top-level chunk records of an MCAP file.
fn chunks(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut at = 8;
    let mut v = Vec::new();
    while at + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        if bytes[at] == 0x06 {
            v.push((at, 9 + len));
        }
        if bytes[at] == 0x0f {
            break;
        }
        at += 9 + len;
    }
    v
}

/// Replays `file` onto the central for an echo of `msg` that expects
/// `want`: replay's exit code and stderr.
fn replay_damaged(c: &Central, file: &str, want: &[&str]) -> (i32, String) {
    let n = want.len().to_string();
    let mut echo = Proc::start(&["echo", &c.url, "msg", "--count", &n, "--json"]);
    let (code, out, err) = run(&[
        "replay", file, &c.url, "--topic", "msg", "--wait", "1", "--rate", "10",
    ]);
    assert_eq!(
        out,
        format!(
            "channel msg ipc {MSG:?}\nready\nreplayed {} messages\ndone\n",
            want.len()
        ),
        "{err}"
    );
    for w in want {
        assert_eq!(echo.expect(""), *w);
    }
    assert_eq!(echo.wait(), Some(0));
    (code, err)
}

#[test]
fn a_damaged_recording_says_where_and_replays_what_is_intact() {
    let dir = Dir::new("damaged");
    let file = dir.file("ok.mcap");
    let c = Central::start();
    // a chunk per record that follows a full one: msg's schema and
    // channel, then its three messages, one a chunk (then text's)
    record_ipc(&c, &file, &["--chunk-size", "1"]);
    let bytes = std::fs::read(&file).unwrap();
    let ch = chunks(&bytes);
    assert_eq!(ch.len(), 6, "{ch:?}");
    let all = [
        r#"[1,"ipc-1",[7]]"#,
        r#"[2,"ipc-2",[14,15]]"#,
        r#"[3,"ipc-3",[21,22,23]]"#,
    ];
    let damaged = |f: &str| {
        format!("courier: {f} is damaged (1 problem, said above): what is intact was replayed\n")
    };

    // cut in the third message's chunk: the first two replay
    let cut = dir.file("cut.mcap");
    let (at, len) = ch[3];
    std::fs::write(&cut, &bytes[..at + len / 2]).unwrap();
    let (code, err) = replay_damaged(&c, &cut, &all[..2]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!(
            "courier: {cut}: truncated at byte {}: the chunk record at byte {at} needs {} bytes, \
             {} remain\n{}",
            at + len / 2,
            len - 9,
            len / 2 - 9,
            damaged(&cut)
        )
    );

    // a corrupted chunk (the second message's) is skipped, the ones after
    // it replay
    let bad = dir.file("bad.mcap");
    let mut b = bytes.clone();
    let (at, len) = ch[2];
    for x in &mut b[at + len - 8..at + len] {
        *x ^= 0x5a;
    }
    std::fs::write(&bad, &b).unwrap();
    let (code, err) = replay_damaged(&c, &bad, &[all[0], all[2]]);
    assert_eq!(code, 1);
    let prefix = format!("courier: {bad}: the chunk at byte {at} is damaged (zstd data: ");
    let suffix = format!("): its messages are skipped\n{}", damaged(&bad));
    assert!(err.starts_with(&prefix) && err.ends_with(&suffix), "{err}");

    // the first chunk, which held the channel records: the summary repeats them
    let first = dir.file("first.mcap");
    let mut b = bytes.clone();
    let (at, len) = ch[0];
    for x in &mut b[at + len - 8..at + len] {
        *x ^= 0x5a;
    }
    std::fs::write(&first, &b).unwrap();
    let (code, err) = replay_damaged(&c, &first, &all);
    assert_eq!(code, 1);
    assert!(
        err.starts_with(&format!(
            "courier: {first}: the chunk at byte {at} is damaged"
        )),
        "{err}"
    );

    // no summary, cut right after a chunk: the file was not finished
    let unfinished = dir.file("unfinished.mcap");
    let (at, len) = ch[2];
    std::fs::write(&unfinished, &bytes[..at + len]).unwrap();
    let (code, err) = replay_damaged(&c, &unfinished, &all[..2]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!(
            "courier: {unfinished}: truncated at byte {}: the file ends before its data end \
             record (the recording was not finished)\n{}",
            at + len,
            damaged(&unfinished)
        )
    );

    // a recorder killed (kill -9) while a chunk was open leaves the chunk
    // record's header with the placeholder length (u64::MAX) the writer
    // fills in when it closes the chunk: the same bytes here, after the
    // second message's chunk
    let killed = dir.file("killed.mcap");
    let (at, len) = ch[2];
    let mut b = bytes[..at + len].to_vec();
    let open_at = b.len();
    b.push(0x06);
    b.extend_from_slice(&u64::MAX.to_le_bytes());
    // start and end times, uncompressed size (placeholder), CRC,
    // compression, compressed size (placeholder): as the writer left them
    b.extend_from_slice(&[0; 16]);
    b.extend_from_slice(&u64::MAX.to_le_bytes());
    b.extend_from_slice(&[0; 4]);
    b.extend_from_slice(&4u32.to_le_bytes());
    b.extend_from_slice(b"zstd");
    b.extend_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(&killed, &b).unwrap();
    let (code, err) = replay_damaged(&c, &killed, &all[..2]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!(
            "courier: {killed}: the chunk at byte {open_at} was left unfinished: the recorder \
             was stopped before it wrote it (its length is still the placeholder), so its \
             messages are lost\n{}",
            damaged(&killed)
        )
    );
    assert!(!err.contains("18446744073709551615"), "{err}");

    // not MCAP at all: nothing to replay
    let junk = dir.file("junk.mcap");
    std::fs::write(&junk, b"hello, world").unwrap();
    let (code, out, err) = run(&["replay", &junk, &c.url]);
    assert_eq!((code, out.as_str()), (1, ""));
    assert_eq!(
        err,
        format!("courier: {junk} is not an MCAP file: it does not begin with the MCAP magic\n")
    );
    let missing = dir.file("missing.mcap");
    let (code, _, err) = run(&["replay", &missing, &c.url]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!("courier: cannot open {missing}: No such file or directory (os error 2)\n")
    );
    // a directory, to either command
    let d = dir.file("");
    let d = d.trim_end_matches('/');
    let (code, _, err) = run(&["replay", d, &c.url]);
    assert_eq!(
        (code, err),
        (
            1,
            format!("courier: {d} is a directory, not an MCAP file\n")
        )
    );
    let (code, _, err) = run(&["record", &c.url, "x", "-o", d, "--overwrite"]);
    assert_eq!(
        (code, err),
        (
            1,
            format!(
                "courier: cannot create {d}: it is a directory (-o names the MCAP file to write)\n"
            )
        )
    );
}

#[test]
fn ctrl_c_finishes_the_recording_and_replay_loops() {
    let dir = Dir::new("ctrl-c");
    let file = dir.file("int.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    // --count 0: no limit, as pub --count 0 (the recording goes on until
    // Ctrl-C)
    // once the recorder says it has both, Ctrl-C
    record_two_then(u, &file, libc::SIGINT);
    // the file is whole: summary and all
    let mut echo = Proc::start(&["echo", u, "text", "--count", "5"]);
    let mut rep = Proc::start(&["replay", &file, u, "--loop", "--rate", "20", "--wait", "1"]);
    for w in ["\"one\"", "\"two\"", "\"one\"", "\"two\"", "\"one\""] {
        assert_eq!(echo.expect(""), w);
    }
    assert_eq!(echo.wait(), Some(0));
    rep.expect("ready");
    rep.signal(libc::SIGINT);
    let line = rep.expect("interrupted after");
    assert!(line.ends_with(" messages replayed"), "{line}");
    let (code, _, err) = rep.finish();
    assert_eq!(code, Some(130), "{err}");
    // a file that exists is not overwritten unless asked
    let (code, _, err) = run(&["record", u, "text", "-o", &file, "--count", "1"]);
    assert_eq!(code, 1);
    assert_eq!(
        err,
        format!(
            "courier: cannot create {file}: File exists (os error 17) (--overwrite replaces it)\n"
        )
    );
    // --duration ends a recording that got nothing
    let empty = dir.file("empty.mcap");
    let (code, out, err) = run(&["record", u, "nothing", "-o", &empty, "--duration", "1"]);
    assert_eq!(code, 0, "{err}");
    let size = std::fs::metadata(&empty).unwrap().len();
    assert_eq!(
        out,
        format!("ready\nrecorded 0 messages on 0 channels in {empty} ({size} B)\ndone\n")
    );
}

#[test]
fn bad_flags_are_usage_errors() {
    let u = "ipc://127.0.0.1:9";
    for (args, want) in [
        (
            &["record", u, "-o", "x.mcap"][..],
            "record on ipc:// needs the messages to record",
        ),
        (
            &["record", u, "a*", "-o", "x.mcap"][..],
            "\"a*\" is a pattern; on ipc:// name each message",
        ),
        (
            &["record", u, "a"][..],
            "the following required arguments were not provided:\n  --output <FILE.mcap>",
        ),
        (
            &["record", u, "a", "-o", "x", "--duration", "0"][..],
            "invalid value '0' for '--duration <SECS>': expected 1 or more",
        ),
        (
            &["replay", "x.mcap", u, "--rate", "0"][..],
            "invalid value '0' for '--rate <X>': expected a factor",
        ),
        (
            &["replay", "x.mcap", u, "--rate", "fast"][..],
            "invalid value 'fast' for '--rate <X>'",
        ),
        (
            &["replay", "x.mcap", u, "--type", "t"][..],
            "invalid value 't' for '--type <TOPIC=TYPE>': \"t\" is not TOPIC=TYPE",
        ),
        (
            &["replay", "x.mcap", u, "--transient-local"][..],
            "--transient-local is DDS durability; ipc:// has none",
        ),
        (
            &["replay", "x.mcap", "rtps://0", "--depth", "5"][..],
            "the following required arguments were not provided:\n  --transient-local",
        ),
        (
            &["replay", "x.mcap", "foo://x"][..],
            "unknown scheme \"foo\"",
        ),
        (
            &["replay", "x.mcap", u, "--lop"][..],
            "tip: a similar argument exists: '--loop'",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err:?}");
    }
    // --count 0 is documented as no limit, as pub's
    for sub in ["record", "pub"] {
        let (code, out, _) = run(&[sub, "--help"]);
        assert_eq!(code, 0);
        assert!(out.contains("(0: until interrupted"), "{sub}: {out}");
    }
}

/// Records `values` of `topic` of `format` into `file`, on a central of
/// its own.
fn record_one(file: &str, topic: &str, format: &str, values: &[&str]) {
    let c = Central::start();
    let u = c.url.as_str();
    let mut rec = Proc::start(&[
        "record",
        u,
        topic,
        "-o",
        file,
        "--count",
        &values.len().to_string(),
    ]);
    rec.expect("ready");
    for v in values {
        publish(u, topic, format, v);
    }
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{out}{err}");
}

/// Central's format of `msg`, as a module that just connected sees it.
fn central_format(c: &Central, msg: &str) -> Option<String> {
    let s = c.session("check");
    let info = c.rt.block_on(s.ipc().unwrap().look_up(msg)).unwrap();
    info.and_then(|i| i.res_format).map(|f| f.to_string())
}

/// Replay and pub refuse to define a message anew with a format that
/// central's does not fit (as `Session::define` refuses), since its
/// subscribers would fail to decode; `--redefine` does it anyway.
#[test]
fn replay_and_pub_do_not_redefine_a_message_central_holds() {
    let dir = Dir::new("redefine");
    let file = dir.file("int.mcap");
    record_one(&file, "counter", "int", &["1", "2"]);
    let c = Central::start();
    let u = c.url.as_str();
    let holder = c.session("holder");
    c.rt.block_on(holder.define::<String>("counter")).unwrap();

    let (code, out, err) = run(&["pub", u, "counter", "5", "--format", "int", "--wait", "0"]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(
        err.contains(
            "central defines counter as string, which does not fit --format int: at the top, \
             the data has int where the reader has string; defining it anew would make its \
             subscribers fail to decode (--redefine replaces central's format anyway)"
        ),
        "{err}"
    );
    // the same format, or one it fits, is no redefinition
    let (code, _, err) = run(&[
        "pub", u, "counter", "x", "--format", "string", "--wait", "0",
    ]);
    assert_eq!(code, 0, "{err}");

    let (code, out, err) = run(&["replay", &file, u, "--topic", "counter"]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert_eq!(
        err,
        "courier: channel \"counter\" (1): central defines counter as string, which does not \
         fit the recorded format int: at the top, the data has int where the reader has \
         string; defining it anew would make its subscribers fail to decode (--redefine replaces \
         central's format anyway)\n"
    );
    assert_eq!(central_format(&c, "counter").as_deref(), Some("string"));

    let (code, out, err) = run(&["replay", &file, u, "--redefine", "--rate", "100"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.ends_with("replayed 2 messages\ndone\n"), "{out}");
    assert_eq!(central_format(&c, "counter").as_deref(), Some("int"));
    let (code, _, err) = run(&["replay", &file, &url(283), "--redefine"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("--redefine replaces the format central holds; rtps:// has no central"),
        "{err}"
    );
}

/// `--topic B` plays B alone (that it starts at B's first message, not
/// after the other channels' gap, is `scan::tests`: no timing here).
#[test]
fn a_replay_of_one_topic_starts_at_its_first_message() {
    let dir = Dir::new("gap");
    let file = dir.file("gap.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    let mut rec = Proc::start(&["record", u, "a", "b", "-o", &file, "--count", "3"]);
    rec.expect("ready");
    publish(u, "a", "int", "1");
    std::thread::sleep(Duration::from_millis(2500));
    publish(u, "b", "int", "2");
    publish(u, "b", "int", "3");
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{out}{err}");
    let (code, out, err) = run(&["replay", &file, u, "--topic", "b"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.ends_with("replayed 2 messages\ndone\n"), "{out}");
}

/// A file cut in its summary or footer has every message, but is damaged
/// all the same: said, with where, and exit 1, as other damage is.
#[test]
fn a_recording_cut_in_its_summary_says_so() {
    let dir = Dir::new("summary");
    let file = dir.file("ok.mcap");
    let c = Central::start();
    record_ipc(&c, &file, &[]);
    let bytes = std::fs::read(&file).unwrap();
    let all = [
        r#"[1,"ipc-1",[7]]"#,
        r#"[2,"ipc-2",[14,15]]"#,
        r#"[3,"ipc-3",[21,22,23]]"#,
    ];
    for cut in [100, 10] {
        let f = dir.file(&format!("cut{cut}.mcap"));
        let len = bytes.len() - cut;
        std::fs::write(&f, &bytes[..len]).unwrap();
        let (code, err) = replay_damaged(&c, &f, &all);
        assert_eq!(code, 1, "{err}");
        let prefix = format!("courier: {f}: truncated at byte {len}: ");
        let suffix = format!(
            " is lost (the messages before it are intact)\ncourier: {f} is damaged (1 problem, \
             said above): what is intact was replayed\n"
        );
        assert!(
            err.starts_with(&prefix)
                && err.ends_with(&suffix)
                && err.contains(": the summary after the data end record at byte "),
            "{err}"
        );
    }
}

/// `--type` naming another DDS type than the recorded one: refused when
/// Courier knows both layouts and they differ, else written unchanged with
/// a warning; a reader of another type is reported while `--wait`ing.
#[test]
fn a_dds_channel_replayed_as_another_type_is_refused_or_warned_of() {
    let dir = Dir::new("retype");
    let file = dir.file("dds.mcap");
    let u = url(282);
    let mut rec = Proc::start(&["record", &u, "chatter", "-o", &file, "--count", "1"]);
    rec.expect("ready");
    let (code, _, err) = run(&["pub", &u, "chatter", r#"[1, 2, "hi"]"#]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(0), "{out}{err}");

    let (code, out, err) = run(&[
        "replay",
        &file,
        &u,
        "--type",
        "chatter=std_msgs::msg::dds_::String_",
    ]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert_eq!(
        err,
        "courier: channel \"chatter\" (1): it was recorded as DDS type courier::Ping ({uint, \
         ulong, string}), whose samples do not read as std_msgs::msg::dds_::String_ ({string}) of \
         --type chatter=std_msgs::msg::dds_::String_: at the top, the data has {uint, ulong, \
         string} where the reader has {string}; replay writes a channel's CDR unchanged, it does \
         not convert between DDS types\n"
    );

    // a reader of the recorded type sees a writer of another
    let mut sub = Proc::start(&[
        "ping",
        &u,
        "--subscribe",
        "--topic",
        "chatter",
        "--count",
        "1",
    ]);
    sub.expect("ready");
    let mut rep = Proc::start(&[
        "replay",
        &file,
        &u,
        "--type",
        "chatter=my::Renamed",
        "--wait",
        "1",
    ]);
    assert_eq!(
        rep.expect_err("courier: channel"),
        "courier: channel \"chatter\": recorded as DDS type courier::Ping, written unchanged as \
         my::Renamed (--type): readers of my::Renamed decode its samples only if my::Renamed is \
         laid out as courier::Ping ({uint, ulong, string})"
    );
    rep.expect("channel chatter cdr my::Renamed (recorded as courier::Ping)");
    let line = rep.expect("channel chatter incompatible ");
    assert!(
        line.ends_with("type \"courier::Ping\" where this side has \"my::Renamed\""),
        "{line}"
    );
}

/// A disk that fills up (/dev/full answers every write with ENOSPC) stops
/// the recording with what that means for the file, not a bare I/O error.
#[test]
fn a_full_disk_says_what_the_file_holds() {
    let c = Central::start();
    let u = c.url.as_str();
    let mut rec = Proc::start(&["record", u, "text", "-o", "/dev/full", "--overwrite"]);
    rec.expect("ready");
    publish(u, "text", "string", "hello");
    let (code, _, err) = rec.finish();
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains(
            "cannot write /dev/full: I/O error from writing, or reading a compression stream: \
             No space left on device (os error 28), after 0 messages recorded; the file ends \
             without its summary: courier replay reads what it holds (other MCAP tools after \
             `mcap recover`)"
        ),
        "{err}"
    );
}

/// SIGHUP (a dropped ssh session) finishes the recording as SIGTERM and
/// Ctrl-C do: every message recorded is in the file, which has its summary
/// (exit 129). It used to kill the recorder, losing its last chunk.
#[test]
fn a_hang_up_finishes_the_recording() {
    let dir = Dir::new("sighup");
    let file = dir.file("hup.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    record_two_then(u, &file, libc::SIGHUP);
    // the file is whole and replays both
    let mut echo = Proc::start(&["echo", u, "text", "--count", "2"]);
    let (code, out, err) = run(&["replay", &file, u, "--wait", "1", "--rate", "20"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("replayed 2 messages"), "{out}");
    assert!(
        !err.contains("unfinished") && !err.contains("damaged"),
        "{err}"
    );
    assert_eq!(echo.expect(""), "\"one\"");
    assert_eq!(echo.expect(""), "\"two\"");
    assert_eq!(echo.wait(), Some(0));
}

/// Under `nohup` (SIGHUP ignored) a hang-up stays ignored: the recording
/// goes on.
#[test]
fn under_nohup_a_hang_up_is_ignored() {
    let dir = Dir::new("nohup");
    let file = dir.file("nohup.mcap");
    let c = Central::start();
    let u = c.url.as_str();
    let mut rec = recorder(u, &file, true);
    rec.expect("ready");
    publish(u, "text", "string", "one");
    await_recorded(&mut rec, "1 message");
    rec.signal(libc::SIGHUP);
    std::thread::sleep(Duration::from_millis(300));
    publish(u, "text", "string", "two");
    await_recorded(&mut rec, "2 messages");
    rec.signal(libc::SIGTERM);
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(143), "{out}{err}");
    assert!(
        out.ends_with("\ninterrupted after 2 messages recorded\n"),
        "{out}"
    );
}

/// `courier record` of topic `text` of `u` into `file`, with no count
/// limit and progress lines on stderr; under `nohup` if `nohup`.
fn recorder(u: &str, file: &str, nohup: bool) -> Proc {
    let args = [
        "--progress",
        "always",
        "record",
        u,
        "text",
        "-o",
        file,
        "--count",
        "0",
    ];
    if nohup {
        Proc::start_nohup(&args)
    } else {
        Proc::start(&args)
    }
}

/// Waits until the recorder's progress says it has `what` ("2 messages").
fn await_recorded(rec: &mut Proc, what: &str) {
    let want = format!(": {what} on 1 channel");
    while !rec.expect_err("courier: recording for ").contains(&want) {}
}

/// Records two messages published on `u`'s topic `text` into `file`, then
/// stops the recorder with `sig`: it exits 128 + `sig` and says it
/// recorded both and was interrupted.
fn record_two_then(u: &str, file: &str, sig: i32) {
    let mut rec = recorder(u, file, false);
    rec.expect("ready");
    publish(u, "text", "string", "one");
    publish(u, "text", "string", "two");
    rec.expect("channel text");
    await_recorded(&mut rec, "2 messages");
    rec.signal(sig);
    let (code, out, err) = rec.finish();
    assert_eq!(code, Some(128 + sig), "{out}{err}");
    let size = std::fs::metadata(file).unwrap().len();
    assert_eq!(
        out,
        format!(
            "recorded 2 messages on 1 channel in {file} ({size} B)\ninterrupted after 2 \
             messages recorded\n"
        )
    );
}
