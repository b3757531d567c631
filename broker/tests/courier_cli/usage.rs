//! Usage errors, bad URLs, a dead central: what each says, and exit 2
//! for usage, 1 for a runtime failure, 130 for Ctrl-C.

use crate::{run, url, Proc};

#[test]
fn usage_errors_name_the_problem() {
    let u = url(204);
    let u = u.as_str();
    for (args, want) in [
        (&["fly"][..], "unrecognized subcommand 'fly'"),
        (&["echp"][..], "a similar subcommand exists: 'echo'"),
        (
            &["ping", u][..],
            "the following required arguments were not provided",
        ),
        (
            &["ping", u, "--publish", "--subscribe"][..],
            "'--publish' cannot be used with '--subscribe'",
        ),
        (
            &["ping", u, "--publish", "--colour", "red"][..],
            "unexpected argument '--colour'",
        ),
        (
            &["ping", u, "--publsh"][..],
            "a similar argument exists: '--publish'",
        ),
        (
            &["ping", u, "--publish", "--period", "soon"][..],
            "invalid value 'soon' for '--period <MS>'",
        ),
        (
            &["ping", u, "--publish", "--period=0"][..],
            "invalid value '0' for '--period <MS>'",
        ),
        (
            &["ping", u, "--subscribe", "--count", "0"][..],
            "invalid value '0' for '--count <N>'",
        ),
        (
            &["ping", u, "--publish=yes"][..],
            "unexpected value 'yes' for '--publish'",
        ),
        (
            &["ping", u, "--publish", "--exclusive"][..],
            "'--publish' cannot be used with '--exclusive'",
        ),
        (&["ping", u, u, "--publish"][..], "unexpected argument"),
        (
            &["ping", "--publish"][..],
            "the following required arguments were not provided",
        ),
        (
            &["spy", u, "--count"][..],
            "a value is required for '--count <N>'",
        ),
        (
            &["spy", u, "--duration", "-1"][..],
            "unexpected argument '-1'",
        ),
        (
            &["spy", u, "--frobnicate"][..],
            "unexpected argument '--frobnicate'",
        ),
        (
            &["spy", u, "--topic", "a", "--topic", "b"][..],
            "--topic takes one fnmatch pattern",
        ),
        (
            &[
                "ping",
                "rtps://999?interface=lo&peers=127.0.0.1",
                "--publish",
            ][..],
            "domain 999 is above 232",
        ),
        (&["completions", "tcsh"][..], "invalid value 'tcsh'"),
        (
            &["echo", u, "t", "--format", "{int, format}"][..],
            "a format field has no CDR layout for --format on rtps://",
        ),
        (
            &["echo", "ipc://127.0.0.1:1", "t", "--format", "{int"][..],
            "invalid value '{int' for '--format <FORMAT>': \"{int\" is not an IPC format",
        ),
        (
            &["echo", "ipc://127.0.0.1:1", "t", "--format", "{int, T1}"][..],
            "refers to a named format; spell it out",
        ),
        (&["echo", u][..], "required arguments were not provided"),
        (
            &["pub", "ipc://127.0.0.1:1", "t", "1", "--type", "x"][..],
            "--type is for DDS sessions (rtps://, xrce+…://); on ipc:// give --format",
        ),
        (
            &["pub", u, "t", "1", "--format", "int"][..],
            "--format on rtps:// needs --type: the DDS type name subscribers match on",
        ),
        (
            &["pub", u, "t", "1", "--rate", "0"][..],
            "invalid value '0' for '--rate <HZ>': expected a number of samples a second above 0",
        ),
        (&["pub", u, "t"][..], "required arguments were not provided"),
        (
            &["hz", u, "t", "--window", "1"][..],
            "invalid value '1' for '--window <N>': 1 is not in 2..=1000000",
        ),
        (
            &["bw", u, "t", "--gap", "0"][..],
            "invalid value '0' for '--gap <MS>'",
        ),
        (&["hz", "tcp://x", "t"][..], "unknown scheme \"tcp\""),
        (
            &["ping", u, "--rtt", "--subscribe"][..],
            "'--rtt' cannot be used with '--subscribe'",
        ),
        (
            &["ping", u, "--rtt", "--best-effort"][..],
            "cannot be used with",
        ),
        (
            &["pong", u, "--count", "0"][..],
            "invalid value '0' for '--count <N>'",
        ),
        (
            &["bw", "ipc://127.0.0.1:1", "t", "--gap", "100"][..],
            "--gap is for `courier hz`",
        ),
        (
            &["call", "ipc://127.0.0.1:1", "q", "1", "--type", "x"][..],
            "--type and --reply-type are for DDS sessions (rtps://, xrce+…://)",
        ),
        (
            &["call", u, "q", "1", "--reply-format", "int"][..],
            "--reply-format on rtps:// needs --reply-type (or --type)",
        ),
        (
            &["call", u, "q", "1", "--format", "int"][..],
            "--format on rtps:// needs --type",
        ),
        (
            &["call", u, "q", "1", "--timeout", "0"][..],
            "invalid value '0' for '--timeout <MS>'",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.starts_with("error: "), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
        assert!(out.is_empty(), "{args:?}: {out}");
    }
    // a --count, --duration, … of 0 says what it takes, not clap's open
    // range (1..18446744073709551615)
    for (args, want) in [
        (
            &["ping", u, "--subscribe", "--count", "0"][..],
            "invalid value '0' for '--count <N>': expected 1 or more",
        ),
        (
            &["echo", u, "t", "--duration", "0"][..],
            "invalid value '0' for '--duration <SECS>': expected 1 or more",
        ),
        (
            &["replay", "x.mcap", u, "--transient-local", "--depth", "0"][..],
            "invalid value '0' for '--depth <N>': expected 1 or more",
        ),
        (
            &["perf", "sub", u, "--count", "0"][..],
            "invalid value '0' for '--count <N>': expected 1 or more",
        ),
        (
            &["call", u, "q", "1", "--timeout", "x"][..],
            "invalid value 'x' for '--timeout <MS>': expected a whole number, 1 or more",
        ),
    ] {
        let (code, _, err) = run(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
        assert!(!err.contains("18446744073709551615"), "{args:?}: {err}");
    }
    // no command at all: the help, as a usage error
    let (code, _, err) = run(&[]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("Commands:"), "{err}");
    for (args, want) in [
        (&["--help"][..], "spy"),
        (&["help"][..], "ping"),
        (&["ping", "--help"][..], "--min-separation"),
        (&["spy", "-h"][..], "participant found|changed"),
        // a dispose is a line of its own, never a sample that does not decode
        (&["echo", "--help"][..], "(disposed) key=<key>"),
        (
            &["echo", "--help"][..],
            "{\"unregistered\":true,\"key\":<key>}",
        ),
        // the formats of a DDS call are of the bodies: Courier adds and
        // takes off the ROS 2 request/reply header
        (
            &["call", "--help"][..],
            "--format and --reply-format describe the request's and the reply's bodies\nonly",
        ),
        (
            &["call", "--help"][..],
            "as the URL's services= option says",
        ),
        (&["call", "--help"][..], "--reply-format '{long}'"),
        (
            &["--version"][..],
            concat!("courier ", env!("CARGO_PKG_VERSION")),
        ),
        (&["ping", "--version"][..], "courier-ping "),
        (&["completions", "bash"][..], "_courier()"),
        (&["completions", "zsh"][..], "#compdef courier"),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(out.contains(want), "{args:?}: {want:?} in {out}");
    }
}

/// Options that need --type name the URL's own scheme, XRCE's too.
#[test]
fn format_without_type_names_the_urls_scheme() {
    let x = "xrce+udp://127.0.0.1:1?domain=3";
    for (args, want) in [
        (
            &["call", x, "svc", "5", "--format", "int"][..],
            "error: --format on xrce+udp:// needs --type: the DDS type name the service matches on",
        ),
        (
            &["call", x, "svc", "5", "--reply-format", "int"][..],
            "error: --reply-format on xrce+udp:// needs --reply-type (or --type)",
        ),
        (
            &["pub", x, "t", "5", "--format", "int"][..],
            "error: --format on xrce+udp:// needs --type: the DDS type name subscribers match on",
        ),
        (
            &["pub", "XRCE+TCP://127.0.0.1:1", "t", "5", "--format", "int"][..],
            "error: --format on xrce+tcp:// needs --type",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        assert!(err.starts_with(want), "{args:?}: {want:?} in {err}");
    }
}

/// A VALUE (pub) or REQUEST (call) that does not fit its type is a usage
/// error, as the README and `courier --help` say (exit 2), found before
/// anything connects when the command line gives the type: nobody listens
/// at these URLs. Without --type on DDS the type is courier::Ping, and
/// the error says so, on rtps:// and xrce+…:// alike.
#[test]
fn values_that_do_not_fit_are_usage_errors() {
    let u = url(204);
    let u = u.as_str();
    let x = "xrce+udp://127.0.0.1:1?domain=3";
    let dead = "ipc://127.0.0.1:1";
    let ping = "; without --type the type is courier::Ping ([seq, stamp_ns, \"text\"]): \
                name another with --type (with --format for one Courier does not know)";
    for (args, want) in [
        (
            &["pub", dead, "t", "notjson", "--format", "int"][..],
            "error: \"notjson\" is not a value of int: ".to_string(),
        ),
        (
            &["pub", u, "t", "notjson", "--format", "int", "--type", "I"][..],
            "error: \"notjson\" is not a value of int: ".to_string(),
        ),
        (
            &[
                "pub",
                dead,
                "t",
                "[1, [1, 2]]",
                "--format",
                "{int, <int:1>}",
            ][..],
            "error: field 2: variable array has 2 element(s), but its size fields say 1"
                .to_string(),
        ),
        (
            &["call", dead, "q", "notjson", "--format", "int"][..],
            "error: \"notjson\" is not a value of int: ".to_string(),
        ),
        (
            &[
                "call",
                x,
                "q",
                "[1]",
                "--format",
                "{int, int}",
                "--type",
                "P",
                "--reply-format",
                "int",
            ][..],
            "error: \"[1]\" is not a value of {int, int}: ".to_string(),
        ),
        (
            &["pub", u, "t", "[1]", "--type", "x::Y"][..],
            "error: type \"x::Y\" is not one Courier knows (courier::Ping, \
             std_msgs::msg::dds_::String_, int8, uint8, int16, uint16, int32, uint32, int64, \
             uint64, float, double, boolean, string): give its layout with --format"
                .to_string(),
        ),
        (
            &["call", u, "q", "[1]", "--reply-type", "x::Y"][..],
            "error: type \"x::Y\" is not one Courier knows (courier::Ping, \
             std_msgs::msg::dds_::String_, int8, uint8, int16, uint16, int32, uint32, int64, \
             uint64, float, double, boolean, string): give the reply's layout with --reply-format"
                .to_string(),
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        assert!(err.starts_with(&want), "{args:?}: {want:?} in {err}");
    }
    // no --type: courier::Ping, said with the error
    for args in [
        &["pub", x, "chatter", "hello"][..],
        &["pub", u, "chatter", "hello"][..],
        &["call", x, "svc", "hello"][..],
        &["call", u, "svc", "hello"][..],
    ] {
        let (code, out, err) = run(args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        let first = err.lines().next().unwrap_or_default();
        assert!(
            first.starts_with("error: \"hello\" is not a value of {uint, ulong, string}: ")
                && first.ends_with(ping),
            "{args:?}: {err}"
        );
    }
    // and pub --help says it
    let (code, out, _) = run(&["pub", "--help"]);
    assert_eq!(code, 0);
    assert!(
        out.contains("or without --type\ncourier::Ping (the samples of `courier ping`)")
            && out.contains("A VALUE that does not fit the\ntype is a usage error (exit 2)"),
        "{out}"
    );
}

/// The commonest slip with replay, the URL first and the recording second,
/// is named as such rather than as a URL without a scheme.
#[test]
fn replay_with_its_arguments_swapped_says_which_comes_first() {
    let (code, _, err) = run(&["replay", "ipc://127.0.0.1:1", "run.mcap"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("\"run.mcap\" is a recording, not a session URL")
            && err.contains("courier replay FILE.mcap URL"),
        "{err}"
    );
    // an existing file or directory in the URL's place is named as a path
    let (code, _, err) = run(&["spy", "/"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("\"/\" is a path, not a session URL"), "{err}");
}

/// Every session URL is checked before anything connects, and a bad one
/// names the schemes this program knows.
#[test]
fn bad_urls_are_usage_errors_naming_the_known_schemes() {
    for (url, want) in [
        (
            "foo://x",
            "invalid value 'foo://x' for '<URL>': unknown scheme \"foo\" in \"foo://x\"; \
             known schemes: ipc, rtps",
        ),
        (
            "localhost:1381",
            "no scheme in \"localhost:1381\"; a session URL is SCHEME://…, known schemes: ipc, rtps",
        ),
        ("ipc://h:0", "bad IPC URL: '0' is not a port number"),
        ("rtps://x", "domain \"x\" is not a number"),
        (
            "rtps://1?interface=lo&colour=red",
            "unknown option \"colour\"",
        ),
    ] {
        for cmd in [&["ping", url, "--publish"][..], &["spy", url][..]] {
            let (code, _, err) = run(cmd);
            assert_eq!(code, 2, "{cmd:?}: {err}");
            assert!(err.contains(want), "{cmd:?}: {want:?} in {err}");
        }
    }
}

/// A free port of 127.0.0.1 that nobody listens on (bound, then closed).
fn dead_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// A central that is not there: the wait shows what it waits for (with
/// `--progress always`, as on a terminal), Ctrl-C says it interrupted the
/// connect and exits 130, and giving up names the address and what to
/// check. A host name that does not resolve fails at once.
#[test]
fn a_dead_central_is_reported_where_it_was_looked_for() {
    let port = dead_port();
    let u = format!("ipc://127.0.0.1:{port}");
    let mut waiting = Proc::start(&["--progress", "always", "ping", &u, "--subscribe"]);
    assert_eq!(
        waiting.expect_err("courier: connecting"),
        format!("courier: connecting to central at 127.0.0.1:{port} for 1 s (is central running?)")
    );
    waiting.signal(libc::SIGINT);
    let i = waiting.expect("interrupted");
    assert!(
        i.starts_with(&format!(
            "interrupted while connecting to central at 127.0.0.1:{port} ("
        )),
        "{i}"
    );
    assert_eq!(waiting.wait(), Some(130));
    let (code, out, err) = run(&["ping", &u, "--subscribe"]);
    assert_eq!(code, 1, "{err}");
    assert!(out.is_empty(), "{out}");
    let want = format!("courier: cannot connect to central at 127.0.0.1:{port} (");
    assert!(err.starts_with(&want), "{want:?} in {err}");
    assert!(
        err.trim_end()
            .ends_with("Connection refused (os error 111); is central running there?"),
        "{err}"
    );
    // no progress unless asked for (stderr is not a terminal here)
    assert_eq!(err.lines().count(), 1, "{err}");
    // a label of 64 bytes: glibc refuses the name without asking a name
    // server, so nothing leaves this machine
    let host = "a".repeat(64);
    let (code, _, err) = run(&["ping", &format!("ipc://{host}:1381"), "--subscribe"]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.starts_with(&format!(
            "courier: cannot connect to central at {host}:1381: cannot resolve \"{host}\""
        )),
        "{err}"
    );
    // one attempt: a retried connect says "(<n> attempts in <t> s)" before the colon
    assert!(!err.contains("attempts"), "retried: {err}");
}
