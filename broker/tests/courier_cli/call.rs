//! `courier call`: an IPC query answered by a module of the test, and a
//! DDS service call answered by a participant of the test.

use std::time::Duration;

use courier::{IpcMessage, Session};
use futures::StreamExt;

use crate::{run, url, Central, Proc, T};

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Point {
    x: f64,
    y: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Path {
    name: String,
    n: i32,
    #[ipc(len = "n")]
    points: Vec<Point>,
}

/// The Ping type of `courier ping` (the same DDS type name and fields).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::Ping")]
struct Ping {
    seq: u32,
    stamp_ns: u64,
    text: String,
}

#[test]
fn call_an_ipc_query() {
    let c = Central::start();
    let u = c.url.as_str();
    let m = c.session("server");
    // the server answers a Path with the number of its points and the
    // first point's x
    let mut reqs =
        c.rt.block_on(m.serve::<Path, Point>("centroid", ""))
            .unwrap();
    c.rt.spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let p = Point {
                x: f64::from(r.value.n),
                y: r.value.points.first().map_or(0.0, |p| p.x),
            };
            let _ = r.reply(&p).await;
        }
    });
    for (json, want) in [(false, "{1.00, 3.00}\n"), (true, "[1.0,3.0]\n")] {
        let mut args = vec!["call", u, "centroid", r#"["p", 1, [[3, 4]]]"#];
        if json {
            args.push("--json");
        }
        let (code, out, err) = run(&args);
        assert_eq!(code, 0, "{err}");
        assert_eq!(out, want);
    }
    // formats given on the command line
    let (code, out, err) = run(&[
        "call",
        u,
        "centroid",
        r#"["p", 2, [[5, 0], [6, 0]]]"#,
        "--format",
        "{string, int, <{double, double}:2>}",
        "--reply-format",
        "[double:2]",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "[2.00, 5.00]\n");
    // failures: a message central does not know, a query nobody answers
    c.rt.block_on(m.define::<Point>("nobody")).unwrap();
    for (args, want) in [
        (
            &["call", u, "nope", "1"][..],
            "courier: central knows no message \"nope\" (is its server running?)\n",
        ),
        (
            &["call", u, "nobody", "[1, 2]", "--timeout", "300"][..],
            "courier: nobody serves \"nobody\" (waited 300ms for a server; central keeps the query until one subscribes)\n",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (1, ""), "{args:?}: {err}");
        assert!(err.ends_with(want), "{args:?}: {want:?} in {err:?}");
    }
    // a request that does not fit the format central holds: a usage
    // error, as one that does not fit --format (exit 2)
    let (code, out, err) = run(&["call", u, "centroid", "[1]"]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(
        err.starts_with(
            "error: \"[1]\" is not a value of {string, int, <{double, double}:2>}: \
             invalid type: a number, expected a string at line 1 column 2\n\n\
             Usage: courier call "
        ),
        "{err}"
    );
    let mut waiting = Proc::start(&["call", u, "nobody", "[1, 2]"]);
    std::thread::sleep(Duration::from_millis(500));
    waiting.signal(libc::SIGINT);
    let i = waiting.expect_err("courier: interrupted");
    assert!(
        i.starts_with("courier: interrupted while waiting for the reply to \"nobody\" ("),
        "{i}"
    );
    assert_eq!(waiting.wait(), Some(130));
}

#[test]
fn call_a_dds_service() {
    let u = url(230);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let server = rt.block_on(async {
        let s = Session::builder(u.as_str())
            .name("server")
            .connect()
            .await
            .unwrap();
        let mut reqs = s.serve::<Ping, Ping>("echo", "").await.unwrap();
        tokio::spawn(async move {
            while let Some(Ok(r)) = reqs.next().await {
                let mut p = r.value.clone();
                p.seq += 1;
                p.text.push('!');
                let _ = r.reply(&p).await;
            }
        });
        s
    });
    let (code, out, err) = run(&["call", &u, "echo", r#"[1, 2, "x"]"#, "--timeout", "8000"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "{2, 2, \"x!\"}\n");
    // the same service through formats (the layout of the derived type)
    let (code, out, err) = run(&[
        "call",
        &u,
        "echo",
        r#"[5, 0, "y"]"#,
        "--format",
        "{uint, ulong, string}",
        "--type",
        "courier::Ping",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "[6,0,\"y!\"]\n");
    // a reply that does not fit --reply-format: said to be of the body
    // only (Courier took the request/reply header off)
    let (code, out, err) = run(&[
        "call",
        &u,
        "echo",
        r#"[5, 0, "y"]"#,
        "--type",
        "courier::Ping",
        "--reply-format",
        "{long}",
    ]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert!(
        err.starts_with("courier: the reply does not decode as {long}: ")
            && err.ends_with(
                " (--reply-format describes the reply's body only: Courier took the \
                 request/reply header off)\n"
            ),
        "{err}"
    );
    let (code, out, err) = run(&["call", &u, "nobody", r#"[1, 2, "x"]"#, "--timeout", "500"]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert!(
        err.starts_with("courier: nobody serves \"nobody\""),
        "{err}"
    );
    rt.block_on(async { tokio::time::timeout(T, server.close()).await.unwrap() });
}
