//! `courier ping` and `courier spy`.

use crate::{await_handlers, run, url, Central, Proc};

#[test]
fn ping_publisher_to_ping_subscriber() {
    let u = url(200);
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "3", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--period",
        "50",
        "--size",
        "10",
        "--name",
        "tx",
    ]);
    publ.expect("ready");
    publ.expect("matched 1");
    let mut seqs = Vec::new();
    for _ in 0..3 {
        let l = sub.expect("received ");
        // received <seq> from <32 hex digits> 10 B
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!((f.len(), f[2], f[4], f[5]), (6, "from", "10", "B"), "{l}");
        assert_eq!(f[3].len(), 32, "{l}");
        seqs.push(f[1].parse::<u32>().unwrap());
    }
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "in order: {seqs:?}"
    );
    assert!(sub.seen.iter().any(|l| l == "matched 1"), "{:?}", sub.seen);
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    // the subscriber left: the publisher counts down
    publ.expect("matched 0");
}

#[test]
fn spy_prints_discovery_decoded_samples_and_a_clean_leave() {
    let u = url(201);
    let mut spy = Proc::start(&["spy", &u, "--type", "courier::*", "--duration", "20"]);
    spy.expect("ready");
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--period",
        "50",
        "--topic",
        "chatter",
        "--strength",
        "3",
        "--name",
        "talker",
    ]);
    publ.expect("ready");
    // participant found <prefix> name=talker unicast=127.0.0.1:<port>,... multicast=-
    let p = spy.expect("participant found ");
    assert!(p.contains(" name=talker "), "{p}");
    assert!(p.contains(" unicast=127.0.0.1:"), "{p}");
    assert!(p.ends_with(" multicast=-"), "{p}");
    let prefix = p.split_whitespace().nth(2).unwrap().to_string();
    assert_eq!(prefix.len(), 24, "{p}");
    let e = spy.expect("publication found ");
    let guid = e.split_whitespace().nth(2).unwrap().to_string();
    assert!(guid.starts_with(&prefix), "{e}");
    for want in [
        " topic=chatter ",
        " type=courier::Ping ",
        " reliability=reliable ",
        " durability=volatile ",
        " history=keep-all ",
        " deadline=infinite ",
        " ownership=exclusive(3) ",
        " partitions=[] ",
        // a final type: XCDR1, what Fast DDS 2.9 reads too
        " representation=[XCDR1]",
    ] {
        assert!(e.contains(want), "{want} in {e}");
    }
    // sample <topic> <type> from <writer> <bytes> B: <decoded>
    let s = spy.expect("sample chatter courier::Ping from ");
    let f: Vec<&str> = s.split_whitespace().collect();
    assert_eq!(
        (f[4], f[6], f[7], f[8]),
        (guid.as_str(), "B", "XCDR1", "CDR_LE:"),
        "{s}"
    );
    assert!(s.contains(": courier::Ping { seq: "), "{s}");
    spy.expect("sample chatter courier::Ping from ");
    // Ctrl-C: the publisher closes its session, so the spy sees it leave at
    // once (a goodbye, not a lease expiry); it says what it interrupted and
    // exits 130, as a shell reports Ctrl-C
    publ.signal(libc::SIGINT);
    let i = publ.expect("interrupted");
    assert!(
        i.starts_with("interrupted after ") && i.ends_with(" samples sent"),
        "{i}"
    );
    assert_eq!(publ.wait(), Some(130));
    assert_eq!(
        spy.expect("publication lost "),
        format!("publication lost {guid}")
    );
    assert_eq!(
        spy.expect("participant lost "),
        format!("participant lost {prefix} goodbye")
    );
    spy.signal(libc::SIGTERM);
    assert!(spy.expect("interrupted").starts_with("interrupted after "));
    assert_eq!(spy.wait(), Some(143));
}

#[test]
fn deadlines_and_incompatible_qos_are_reported() {
    let u = url(202);
    let mut sub = Proc::start(&[
        "ping",
        &u,
        "--subscribe",
        "--deadline",
        "100",
        "--count",
        "2",
        "--name",
        "rx",
    ]);
    sub.expect("ready");
    // nothing comes: a miss every deadline, counted
    sub.expect("deadline missed 1");
    sub.expect("deadline missed 2");
    // a publisher offering a longer deadline than requested does not match
    let mut slow = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--deadline",
        "1000",
        "--period",
        "50",
        "--name",
        "slow",
    ]);
    let i = slow.expect("incompatible ");
    assert!(i.contains("deadline"), "{i}");
    let i = sub.expect("incompatible ");
    assert!(i.contains("deadline"), "{i}");
    sub.expect("matched 0");
    drop(slow);
    // one offering a shorter one does
    let mut fast = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--deadline",
        "50",
        "--period",
        "20",
        "--name",
        "fast",
    ]);
    fast.expect("matched 1");
    sub.expect("matched 1");
    sub.expect("received ");
    sub.expect("received ");
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    drop(fast);
    // a publisher writing less often than it offers is told so
    let mut late = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--deadline",
        "100",
        "--period",
        "400",
        "--name",
        "late",
    ]);
    late.expect("sent 1");
    late.expect("offered deadline missed 1");
    late.expect("offered deadline missed 2");
}

/// Liveliness from the command line: a manual publisher that writes less
/// often than its lease is told it lapsed, a subscriber requesting it
/// follows the publication alive and not alive, the spy shows what each
/// offers, and an automatic publisher does not match a manual request.
#[test]
fn liveliness_is_offered_requested_and_reported() {
    let u = url(206);
    let mut spy = Proc::start(&["spy", &u, "--type", "courier::*", "--duration", "30"]);
    spy.expect("ready");
    let mut sub = Proc::start(&[
        "ping",
        &u,
        "--subscribe",
        "--liveliness",
        "manual-by-topic",
        "--lease",
        "2000",
        "--name",
        "rx",
    ]);
    sub.expect("ready");
    // one sample a second, a lease of 300 ms: alive at each sample,
    // lapsed 300 ms later
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--liveliness",
        "manual-by-topic",
        "--lease",
        "300",
        "--period",
        "1000",
        "--name",
        "tx",
    ]);
    // the subscriber and the spy's reader, in either order
    publ.expect("matched ");
    publ.expect("liveliness lost 1");
    let alive = sub.expect("liveliness ");
    let f: Vec<&str> = alive.split_whitespace().collect();
    assert_eq!(f.len(), 5, "{alive}");
    assert_eq!(f[1].len(), 32, "a writer GUID: {alive}");
    assert_eq!(&f[2..], ["alive", "alive=1", "not-alive=0"], "{alive}");
    let lapsed = sub.expect("liveliness ");
    assert_eq!(
        lapsed,
        format!("liveliness {} not-alive alive=0 not-alive=1", f[1])
    );
    // the next sample revives it (the event comes before the sample), and
    // it lapses again
    let back = sub.expect("liveliness ");
    assert_eq!(
        back,
        format!("liveliness {} alive alive=1 not-alive=0", f[1])
    );
    let again = sub.expect("liveliness ");
    assert_eq!(again, lapsed);
    assert!(
        sub.seen.iter().any(|l| l.starts_with("received ")),
        "{:?}",
        sub.seen
    );
    let e = spy.expect("publication found ");
    assert!(
        e.contains(" lifespan=infinite liveliness=manual-by-topic(300ms) "),
        "{e}"
    );
    // found before or after the publication
    let e = match spy
        .seen
        .iter()
        .find(|l| l.starts_with("subscription found "))
    {
        Some(l) => l.clone(),
        None => spy.expect("subscription found "),
    };
    assert!(e.contains(" liveliness=manual-by-topic(2000ms) "), "{e}");
    drop(publ);
    // an automatic publication (--lease alone) offers less than manual by
    // topic: refused on both sides, naming liveliness
    let mut auto = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--lease",
        "500",
        "--period",
        "50",
        "--name",
        "auto",
    ]);
    let i = auto.expect("incompatible ");
    assert!(i.contains("liveliness"), "{i}");
    let i = sub.expect("incompatible ");
    assert!(i.contains("liveliness"), "{i}");
}

/// An endpoint of another type on the topic is reported once on each side,
/// naming both types (the session reports it as a type mismatch, no longer
/// also as an incompatible QoS).
#[test]
fn another_type_on_the_topic_is_reported_with_both_names() {
    let u = url(205);
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--topic", "t", "--count", "1"]);
    sub.expect("ready");
    let mut publ = Proc::start(&[
        // a wait long enough for discovery on a loaded machine: the line
        // comes while it waits (with 1 s, a CI run once saw none)
        "pub", &u, "t", "7", "--format", "int", "--type", "Seven", "--wait", "8",
    ]);
    let line = publ.expect("incompatible ");
    assert!(
        line.ends_with("where this side has \"Seven\"") && line.contains("type \"courier::Ping\""),
        "{line}"
    );
    let line = sub.expect("incompatible ");
    assert!(
        line.ends_with("type \"Seven\" where this side has \"courier::Ping\""),
        "{line}"
    );
    drop(publ);
    drop(sub);
}

#[test]
fn a_counted_publisher_finishes_while_a_spy_watches() {
    // the spy's readers are best effort and never acknowledge: the last
    // sample (which waits for every reliable reader's acknowledgement) and
    // the publisher's keep-all history must not wait for them
    let u = url(203);
    let mut spy = Proc::start(&["spy", &u, "--duration", "20"]);
    spy.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "100", "--count", "5"]);
    publ.expect("matched 1");
    publ.expect("sent 5");
    publ.expect("done");
    let (code, _, err) = publ.finish();
    assert_eq!(code, Some(0), "{err}");
    // waiting for the spy's acknowledgement would end, after 5 s, in
    // "sample 5 not acknowledged by every reader"
    assert!(!err.contains("not acknowledged"), "{err}");
    spy.expect("sample ping courier::Ping ");
}

#[test]
fn ping_over_ipc_through_central() {
    let central = Central::start();
    let u = central.url.clone();
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "2", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "50", "--name", "tx"]);
    publ.expect("ready");
    publ.expect("matched 1");
    // IPC does not say who sent it
    assert_eq!(sub.expect("received ").split_whitespace().nth(3), Some("?"));
    sub.expect("received ");
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    publ.expect("matched 0");
    drop(publ);
    // DDS QoS on IPC: refused, not ignored
    for flag in [
        &["--publish", "--strength", "3"][..],
        &["--subscribe", "--deadline", "100"][..],
        &["--subscribe", "--best-effort"][..],
        &["--publish", "--liveliness", "manual-by-topic"][..],
        &["--subscribe", "--lease", "1000"][..],
    ] {
        let mut args = vec!["ping", u.as_str()];
        args.extend_from_slice(flag);
        let (code, _, err) = run(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(&format!("{} is DDS QoS", flag[1])), "{err}");
    }
    // spy on IPC names its messages: central has no list to match a
    // pattern against
    for (args, want) in [
        (&["spy", &u][..], "spy on ipc:// needs --topic MESSAGE"),
        (
            &["spy", &u, "--topic", "p*"][..],
            "--topic \"p*\" is a pattern",
        ),
        (
            &["spy", &u, "--topic", "p", "--type", "x"][..],
            "--type is for rtps://",
        ),
    ] {
        let (code, _, err) = run(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
    }
}

#[test]
fn spy_on_ipc_decodes_the_messages_named() {
    let central = Central::start();
    let u = central.url.clone();
    let m = central.session("observer");
    let mut spy = Proc::start(&["spy", &u, "--topic", "ping", "--topic", "status"]);
    spy.expect("ready");
    // its subscriptions reached central
    await_handlers(&central, &m, "ping", 1);
    await_handlers(&central, &m, "status", 1);
    // a module comes, publishes two messages of different formats
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--period",
        "50",
        "--count",
        "2",
        "--size",
        "3",
        "--name",
        "tx",
    ]);
    assert_eq!(spy.expect("module "), "module tx connected");
    let s = spy.expect("sample ping ");
    assert!(
        s.starts_with("sample ping \"{uint, ulong, string}\" from ? 19 B: {1, "),
        "{s}"
    );
    assert!(s.ends_with(", \"xxx\"}"), "{s}");
    publ.expect("done");
    assert_eq!(publ.wait(), Some(0));
    assert_eq!(spy.expect("module "), "module tx disconnected");
    let (code, _, err) = run(&["pub", &u, "status", "Send", "--format", "{enum Wait, Send}"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        spy.expect("sample status "),
        "sample status \"{enum Wait, Send}\" from ? 4 B: Send"
    );
    spy.signal(libc::SIGINT);
    assert!(spy.expect("interrupted").starts_with("interrupted after "));
    assert_eq!(spy.wait(), Some(130));
}
