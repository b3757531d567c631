//! `courier list`: discovery on RTPS; modules and messages on IPC.

use crate::{run, url, Central, Proc, T};

#[test]
fn list_on_an_empty_domain_says_it_found_nobody() {
    let u = url(251);
    let (code, out, err) = run(&["list", &u, "--duration", "1"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "", "the list itself is empty");
    assert!(
        err.contains("no participant found in 1 s on DDS domain"),
        "{err}"
    );
}

/// A central with no module but the listing's and no message: said on
/// stderr, as for an empty DDS domain, the list itself (stdout) empty.
#[test]
fn list_on_an_empty_central_says_it_found_nothing() {
    let c = Central::start();
    let (code, out, err) = run(&["list", &c.url]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "", "the list itself is empty");
    let addr = c.url.trim_start_matches("ipc://");
    assert_eq!(
        err,
        format!(
            "courier: no module but this listing and no message found at central at {addr} \
             (another central, or the modules not started yet?)\n"
        )
    );
    // a module and no message: it is listed, and nothing more is said
    let _m = c.session("lonely");
    let (code, out, err) = run(&["list", &c.url]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("module lonely host="), "{out}");
    assert_eq!(err, "");
}

#[test]
fn list_what_dds_discovery_finds() {
    let u = url(250);
    // the listing listens first: it hears every announcement
    let list = Proc::start(&["list", &u, "--duration", "3"]);
    std::thread::sleep(std::time::Duration::from_millis(300));
    let mut talker = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--topic",
        "chatter",
        "--name",
        "talker",
    ]);
    let mut listener = Proc::start(&[
        "ping",
        &u,
        "--subscribe",
        "--topic",
        "chatter",
        "--name",
        "listener",
    ]);
    talker.expect("matched 1");
    listener.expect("matched 1");
    let (code, out, err) = list.finish();
    assert_eq!(code, Some(0), "{err}");
    let lines: Vec<&str> = out.lines().collect();
    // participants by name, each followed by its endpoints
    let at = |name: &str| {
        lines
            .iter()
            .position(|l| l.starts_with("participant ") && l.contains(&format!(" name={name} ")))
            .unwrap_or_else(|| panic!("{name} in {out}"))
    };
    let (l, t) = (at("listener"), at("talker"));
    assert!(l < t, "{out}");
    assert!(
        lines[l + 1].starts_with("  subscription ")
            && lines[l + 1].contains(" topic=chatter type=courier::Ping reliability=reliable "),
        "{out}"
    );
    assert!(
        lines[t + 1].starts_with("  publication ")
            && lines[t + 1].contains(" topic=chatter type=courier::Ping "),
        "{out}"
    );
    // --watch: changes as they come; Ctrl-C says how long it watched
    let mut watch = Proc::start(&["list", &u, "--watch"]);
    watch.expect("ready");
    drop(talker);
    let mut newcomer = Proc::start(&["ping", &u, "--publish", "--name", "newcomer"]);
    newcomer.expect("ready");
    let p = watch.expect("participant found ");
    let p = if p.contains(" name=newcomer ") {
        p
    } else {
        // the others, announced again, may come first
        loop {
            let p = watch.expect("participant found ");
            if p.contains(" name=newcomer ") {
                break p;
            }
        }
    };
    let prefix = p.split_whitespace().nth(2).unwrap().to_string();
    let e = loop {
        let e = watch.expect("publication found ");
        if e.contains(&format!(" {prefix}")) {
            break e;
        }
    };
    assert!(e.contains(" topic=ping type=courier::Ping "), "{e}");
    watch.signal(libc::SIGINT);
    let i = watch.expect("interrupted");
    assert!(i.starts_with("interrupted after watching "), "{i}");
    assert_eq!(watch.wait(), Some(130));
}

#[test]
fn list_modules_and_messages_of_an_ipc_central() {
    let c = Central::start();
    let u = c.url.as_str();
    let m = c.session("module1");
    c.rt.block_on(m.ipc().unwrap().define("msg", Some("{int, string}")))
        .unwrap();
    let (code, out, err) = run(&[
        "list",
        u,
        "--module",
        "module1",
        "--module",
        "nobody",
        "--message",
        "msg",
        "--message",
        "nope",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        out,
        "module module1 connected\nmodule nobody not-connected\n\
         message msg format=\"{int, string}\" handlers=0\nmessage nope unknown\n"
    );
    // without names: every module and message, through Courier's
    // central's courier_getModules and the C central's x_ipc_getMessages /
    // x_ipc_getMessageInfo
    let (code, out, err) = run(&["list", u]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2, "{out}");
    assert!(lines[0].starts_with("module module1 host="), "{out}");
    // its handlers include the one that watches central's broadcast list
    assert!(lines[0].ends_with(" waiting=0"), "{out}");
    assert_eq!(
        lines[1],
        "message msg class=publish format=\"{int, string}\" handlers=0 module=-"
    );
    let sub = c.rt.block_on(m.subscribe_raw("msg")).unwrap();
    let (code, out, err) = run(&["list", u]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.ends_with(
            "message msg class=publish format=\"{int, string}\" handlers=1 module=module1\n"
        ),
        "{out}"
    );
    drop(sub);
    // --watch: modules as they come and go, handlers of the messages named
    let mut watch = Proc::start(&["list", u, "--watch", "--message", "msg"]);
    watch.expect("ready");
    let newcomer = c.session("newcomer");
    assert_eq!(watch.expect("module "), "module newcomer connected");
    let sub = c.rt.block_on(newcomer.subscribe_raw("msg")).unwrap();
    assert_eq!(watch.expect("message "), "message msg handlers=1");
    drop(sub);
    c.rt.block_on(async { tokio::time::timeout(T, newcomer.close()).await.unwrap() });
    assert_eq!(watch.expect("module "), "module newcomer disconnected");
    watch.signal(libc::SIGTERM);
    watch.expect("interrupted after watching ");
    assert_eq!(watch.wait(), Some(143));
}
