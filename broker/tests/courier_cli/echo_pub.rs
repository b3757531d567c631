//! `courier echo` and `courier pub`, against modules of the test's own and
//! each other, over IPC and RTPS.

use courier::IpcMessage;
use futures::StreamExt;

use crate::{await_handlers, cyclone_reader, run, url, Central, Proc, T};

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Point {
    x: f64,
    y: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "demo::Path")]
struct Path {
    name: String,
    n: i32,
    #[ipc(len = "n")]
    points: Vec<Point>,
}

#[test]
fn echo_and_pub_over_ipc_through_central() {
    let c = Central::start();
    let u = c.url.as_str();
    let m = c.session("module");
    c.rt.block_on(m.define::<Path>("path")).unwrap();
    let path = Path {
        name: "a".into(),
        n: 2,
        points: vec![Point { x: 0.5, y: 1.0 }, Point { x: 1.5, y: 2.0 }],
    };
    // a module publishes a derived type: echo decodes it through the
    // format central holds for it (named formats expanded)
    for (json, want) in [
        (false, r#"{"a", 2, <{0.50, 1.00}, {1.50, 2.00}>}"#),
        (true, r#"["a",2,[[0.5,1.0],[1.5,2.0]]]"#),
    ] {
        let mut args = vec!["echo", u, "path", "--count", "1"];
        if json {
            args.push("--json");
        }
        let mut echo = Proc::start(&args);
        await_handlers(&c, &m, "path", 1);
        c.rt.block_on(async { m.publish("path", &path).await })
            .unwrap();
        assert_eq!(echo.expect(""), want);
        assert_eq!(echo.wait(), Some(0));
    }
    // pub takes the format central holds too: the module's typed
    // subscriber gets a Path
    let mut sub = c.rt.block_on(m.subscribe::<Path>("path")).unwrap();
    let (code, out, err) = run(&["pub", u, "path", r#"["b", 1, [[3, 4]]]"#]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "ready\nmatched 1\nsent 1\ndone\n");
    let got =
        c.rt.block_on(async { tokio::time::timeout(T, sub.next()).await })
            .unwrap()
            .unwrap()
            .unwrap();
    assert_eq!(
        got.value,
        Path {
            name: "b".into(),
            n: 1,
            points: vec![Point { x: 3.0, y: 4.0 }]
        }
    );
    drop(sub);
    // pub --format defines a message of its own; a plain string needs no
    // JSON quotes
    let mut echo = Proc::start(&["echo", u, "status", "--count", "2"]);
    let (code, out, err) = run(&[
        "pub",
        u,
        "status",
        r#"[7, "x", "Send"]"#,
        "--format",
        "{int, string, {enum Wait, Send}}",
        "--count",
        "2",
        "--rate",
        "50",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "ready\nmatched 1\nsent 1\nsent 2\ndone\n");
    assert_eq!(echo.expect(""), r#"{7, "x", Send}"#);
    assert_eq!(echo.expect(""), r#"{7, "x", Send}"#);
    assert_eq!(echo.wait(), Some(0));
    let mut echo = Proc::start(&["echo", u, "text", "--count", "1", "--json"]);
    let (code, _, err) = run(&["pub", u, "text", "hello world", "--format", "string"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(echo.expect(""), r#""hello world""#);
    // failures name the message and what is wrong: a message central
    // does not know is a runtime failure (exit 1), a VALUE that does not
    // fit the format central holds a usage error (exit 2), as one that
    // does not fit --format
    let (code, out, err) = run(&["pub", u, "nosuch", "1"]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert!(
        err.ends_with(
            "courier: central knows no message \"nosuch\": give its format with --format\n"
        ),
        "{err}"
    );
    for (args, want) in [
        (
            &["pub", u, "path", "[1]"][..],
            "error: \"[1]\" is not a value of {string, int, <{double, double}:2>}: \
             invalid type: a number, expected a string at line 1 column 2\n\n\
             Usage: courier pub [OPTIONS] <URL> <TOPIC> <VALUE>\n",
        ),
        (
            &["pub", u, "path", r#"["b", 3, [[3, 4]]]"#][..],
            "error: field 3: variable array has 1 element(s), but its size fields say 3\n\n\
             Usage: courier pub ",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        assert!(err.starts_with(want), "{args:?}: {want:?} in {err:?}");
    }
    // Ctrl-C says what was interrupted, exit 130: echo on stderr (its
    // stdout is data), pub on stdout (its stdout is events)
    let mut echo = Proc::start(&["echo", u, "path"]);
    await_handlers(&c, &m, "path", 1);
    echo.signal(libc::SIGINT);
    assert_eq!(
        echo.expect_err("courier: interrupted"),
        "courier: interrupted after 0 samples"
    );
    assert_eq!(echo.wait(), Some(130));
    let mut lonely = Proc::start(&["pub", u, "status", "[1, \"\", 0]"]);
    lonely.expect("ready");
    lonely.signal(libc::SIGINT);
    assert_eq!(
        lonely.expect("interrupted"),
        "interrupted while waiting for subscribers of \"status\""
    );
    assert_eq!(lonely.wait(), Some(130));
}

#[test]
fn echo_and_pub_over_rtps() {
    let u = url(210);
    // waiting shows what discovery found so far
    let mut echo = Proc::start(&[
        "--progress",
        "always",
        "echo",
        &u,
        "chatter",
        "--count",
        "2",
        // the longest bound there is (it panicked adding it to the clock)
        "--duration",
        "18446744073709551615",
    ]);
    let p = echo.expect_err("courier: no sample of \"chatter\" for 1 s: ");
    assert!(p.ends_with(", 0 publications of \"chatter\""), "{p}");
    let (code, out, err) = run(&[
        "pub",
        &u,
        "chatter",
        r#"[1, 2, "hi"]"#,
        "--count",
        "2",
        "--rate",
        "50",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "ready\nmatched 1\nsent 1\nsent 2\ndone\n");
    assert_eq!(echo.expect("{"), r#"{1, 2, "hi"}"#);
    assert_eq!(echo.expect("{"), r#"{1, 2, "hi"}"#);
    assert_eq!(echo.wait(), Some(0));
    // ROS 2's std_msgs/String, as JSON, as a JSON string and as plain
    // text (its only field is a string)
    let mut echo = Proc::start(&["echo", &u, "rt/chatter", "--count", "3", "--json"]);
    for value in [r#"["hello ros"]"#, r#""hello json""#, "hello plain text"] {
        let (code, _, err) = run(&[
            "pub",
            &u,
            "rt/chatter",
            value,
            "--type",
            "std_msgs::msg::dds_::String_",
        ]);
        assert_eq!(code, 0, "{value}: {err}");
    }
    assert_eq!(echo.expect(""), r#"["hello ros"]"#);
    assert_eq!(echo.expect(""), r#"["hello json"]"#);
    assert_eq!(echo.expect(""), r#"["hello plain text"]"#);
    assert_eq!(echo.wait(), Some(0));
    // a primitive by its DDS name, as a Courier session publishes an i32
    // (the CLI knew only its own types and ROS 2's string)
    let mut echo = Proc::start(&["echo", &u, "n", "--count", "1", "--type", "int32"]);
    let (code, _, err) = run(&["pub", &u, "n", "42", "--type", "int32"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(echo.expect(""), "42");
    assert_eq!(echo.wait(), Some(0));
    // any type whose layout an IPC format describes: a participant of the
    // test subscribes a derived type, pub writes it through the format,
    // echo reads it through the format
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (rx, mut sub) = rt.block_on(async {
        let s = courier::Session::builder(u.as_str())
            .name("rx")
            .connect()
            .await
            .unwrap();
        let sub = s.subscribe::<Path>("paths").await.unwrap();
        (s, sub)
    });
    let f = "{string, int, <{double, double}:2>}";
    let mut echo = Proc::start(&["echo", &u, "paths", "--format", f, "--count", "1"]);
    let (code, _, err) = run(&[
        "pub",
        &u,
        "paths",
        r#"["a", 1, [[3, 4]]]"#,
        "--format",
        f,
        "--type",
        "demo::Path",
        "--wait",
        "2",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(echo.expect(""), r#"{"a", 1, <{3.00, 4.00}>}"#);
    let got = rt
        .block_on(async { tokio::time::timeout(T, sub.next()).await })
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(
        got.value,
        Path {
            name: "a".into(),
            n: 1,
            points: vec![Point { x: 3.0, y: 4.0 }]
        }
    );
    rt.block_on(async { tokio::time::timeout(T, rx.close()).await.unwrap() });
    // a keyed topic: Cyclone DDS's reader matches only a keyed writer, and
    // a layout says nothing of keys, so pub writes it as its readers want
    let (k, mut cyclone) = cyclone_reader(211, "k", "keyed", 1, &[]);
    let (code, out, err) = run(&[
        "pub",
        &k,
        "k",
        r#"[7, 1, "hi"]"#,
        "--format",
        "{int, uint, string}",
        "--type",
        "courier::test::Keyed",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        out,
        "ready\nkeyed, as the readers of \"k\" are\nmatched 1\nsent 1\ndone\n"
    );
    assert_eq!(
        cyclone.expect_line("sample", T).unwrap(),
        "sample 7 1 hi",
        "{}",
        cyclone.stderr()
    );
    // a type Courier does not know, without its layout: a usage error
    let (code, _, err) = run(&["pub", &u, "t", "[1]", "--type", "x::Y", "--wait", "0"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.starts_with(
            "error: type \"x::Y\" is not one Courier knows (courier::Ping, \
             std_msgs::msg::dds_::String_, int8, uint8, int16, uint16, int32, uint32, int64, \
             uint64, float, double, boolean, string): give its layout with --format\n"
        ),
        "{err}"
    );
}

/// A keyed type whose key is its first field (what `echo` decodes a
/// dispose's key as: the leading fields the key's bytes fill).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "demo::Robot")]
struct Robot {
    #[ipc(key)]
    id: i32,
    name: String,
}

/// A dispose or unregister is no sample: echo prints what happened to
/// which key on a line of its own (as spy marks it), as text and as JSON,
/// never as a sample that does not decode.
#[test]
fn echo_prints_instance_changes_on_lines_of_their_own() {
    let u = url(212);
    let f = "{int, string}";
    // --count counts samples, not the changes between them
    let text = Proc::start(&["echo", &u, "robots", "--format", f, "--count", "3"]);
    let json = Proc::start(&[
        "echo", &u, "robots", "--format", f, "--count", "3", "--json",
    ]);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let s = rt.block_on(async {
        courier::Session::builder(u.as_str())
            .name("robots")
            .connect()
            .await
            .unwrap()
    });
    let p = rt.block_on(async {
        // autodispose off: an unregister is not a dispose too
        let p = s
            .publisher::<Robot>("robots")
            .autodispose(false)
            .build()
            .await
            .unwrap();
        tokio::time::timeout(T, async {
            while s.num_handlers("robots").await.unwrap() < 2 {
                tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            }
        })
        .await
        .expect("both echoes matched within T");
        p
    });
    let r = |id, name: &str| Robot {
        id,
        name: name.into(),
    };
    rt.block_on(async {
        p.publish(&r(1, "a")).await.unwrap();
        p.dispose(&r(1, "")).await.unwrap();
        p.publish(&r(2, "b")).await.unwrap();
        p.unregister(&r(2, "")).await.unwrap();
        p.publish(&r(3, "c")).await.unwrap();
    });
    let (code, out, err) = text.finish();
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(
        out, "{1, \"a\"}\n(disposed) key={1}\n{2, \"b\"}\n(unregistered) key={2}\n{3, \"c\"}\n",
        "{err}"
    );
    assert!(!err.contains("does not decode"), "{err}");
    let (code, out, err) = json.finish();
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(
        out,
        "[1,\"a\"]\n{\"disposed\":true,\"key\":[1]}\n[2,\"b\"]\n\
         {\"unregistered\":true,\"key\":[2]}\n[3,\"c\"]\n",
        "{err}"
    );
    assert!(!err.contains("does not decode"), "{err}");
    rt.block_on(async { tokio::time::timeout(T, s.close()).await.unwrap() });
}
