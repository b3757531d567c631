//! Log lines the C central 3.9.1 prints, checked against it on its own test
//! programs (module1/2/3, ipcTest1; issue 30 item 2) and pinned here:
//! when each line appears, and its exact text.

use courier_wire::ipc::central::{Config, LogOptions};

use crate::support::{define, Sim};

fn config(terminal: &str) -> Config {
    let mut c = Config::default();
    c.terminal_log = LogOptions::parse(terminal, false).unwrap();
    c
}

/// `Registration: Message X Found. Updating.` is a status line inside
/// C's ignore-logging bracket: not under the default `-lmsi`, printed
/// with `-lms`.
#[test]
fn registration_line_only_without_i() {
    for (opts, shown) in [("msi", false), ("ms", true)] {
        let mut sim = Sim::new(config(opts));
        let a = sim.connect("a");
        let b = sim.connect("b");
        define(&mut sim, a, "m", "int");
        sim.pump();
        define(&mut sim, b, "m", "int");
        sim.pump();
        let has = sim
            .logs
            .iter()
            .any(|l| l == "Registration: Message m Found. Updating.");
        assert_eq!(has, shown, "-l{opts}: {:#?}", sim.logs);
    }
}

/// Socket numbers start at 5 and come back when their module is gone,
/// as C's file descriptors do.
#[test]
fn socket_numbers_are_reused() {
    let mut sim = Sim::new(config("msi"));
    let a = sim.connect("a");
    let _b = sim.connect("b");
    sim.close(a);
    let _c = sim.connect("c");
    let lines: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.starts_with(" Received a new connection") || l.contains("sd:"))
        .collect();
    assert_eq!(
        lines,
        [
            " Received a new connection: 5",
            " Received a new connection: 6",
            "Closed Connection Detected from: sd: 5: ",
            " Received a new connection: 5",
        ],
        "{:#?}",
        sim.logs
    );
}

/// The connect and close lines are C's `LOG`: printed under `-lx` too.
#[test]
fn connect_and_close_lines_under_lx() {
    let mut sim = Sim::new(config("x"));
    let a = sim.connect("a");
    sim.m(a).close().unwrap();
    sim.pump();
    assert_eq!(
        sim.logs,
        [
            " Received a new connection: 5",
            "   modName : a",
            "   hostName: localhost",
            "x_ipcClose: Closed Connection Detected from: sd: 5:",
            "x_ipcClose: Closing a on localhost",
            "close Module: Closing a",
        ]
    );
}

/// Central's own variables are registered with C's format texts: the log
/// variables' without spaces, a handler list through `directMsgHandler`.
#[test]
fn variable_formats_as_c_writes_them() {
    let mut config = config("msd");
    config.direct = true;
    let mut sim = Sim::new(config);
    let a = sim.connect("a");
    define(&mut sim, a, "m", "int");
    sim.pump();
    assert!(
        sim.logs
            .iter()
            .any(|l| l == "     {*int,int,int,int,int,int,int,int,int,int,int,int}\"}"),
        "{:#?}",
        sim.logs
    );
    assert!(
        sim.logs
            .iter()
            .any(|l| l == "    {\"m\", \"{int, <directMsgHandler: 1>}\"}"),
        "{:#?}",
        sim.logs
    );
}

/// With `-r`, a module that closed with `IPC_disconnect` leaves nothing to
/// resend; one that died does.
#[test]
fn resend_keeps_only_what_a_crashed_module_had() {
    for crash in [false, true] {
        let mut config = config("msi");
        config.resend_on_reconnect = true;
        let mut sim = Sim::new(config);
        let a = sim.connect("a");
        let b = sim.connect("b");
        define(&mut sim, a, "m", "int");
        sim.m(b).subscribe("m", "HND-m").unwrap();
        sim.pump();
        // Two: one is being handled, one waits behind it (capacity 1).
        sim.m(a).publish("m", 1i32.to_le_bytes(), -1).unwrap();
        sim.m(a).publish("m", 2i32.to_le_bytes(), -1).unwrap();
        sim.pump();
        if crash {
            sim.close(b);
        } else {
            sim.m(b).close().unwrap();
            sim.pump();
        }
        let kept = sim.logs.iter().any(|l| l.starts_with("Keeping m {"));
        assert_eq!(kept, crash, "crash {crash}: {:#?}", sim.logs);
    }
}

/// A second module with the name of a live one is refused with one line;
/// the first goes on.
#[test]
fn a_second_module_of_a_live_name_is_refused() {
    let mut sim = Sim::new(config("msi"));
    let a = sim.connect("dup");
    let _second = sim.add("dup");
    sim.pump();
    assert!(
        sim.logs.iter().any(|l| l
            == "ERROR: refused module dup on localhost (sd 6): a module named dup is already \
                connected (on localhost, sd 5)"),
        "{:#?}",
        sim.logs
    );
    assert_eq!(
        sim.logs
            .iter()
            .filter(|l| l.starts_with(" Received a new connection"))
            .count(),
        1
    );
    define(&mut sim, a, "m", "int");
    sim.pump();
    assert_eq!(sim.central().stats().modules, 1);
}

/// `IPC_publish(msg, 0, NULL)` of a message with a format: C's data log
/// shows `NO DATA` under the broadcast (checked with the C library's
/// variable-length `int` message); with data, the value.
#[test]
fn an_empty_publish_logs_no_data() {
    let mut sim = Sim::new(config("msd"));
    let a = sim.connect("a");
    let b = sim.connect("b");
    define(&mut sim, a, "m", "int");
    sim.m(b).subscribe("m", "HND-m").unwrap();
    sim.pump();
    sim.m(a).publish("m", Vec::new(), -1).unwrap();
    sim.pump();
    for (d, ..) in sim.deliveries(b) {
        sim.m(b).ack(d).unwrap();
    }
    sim.m(a).publish("m", 7i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let after: Vec<&str> = sim
        .logs
        .iter()
        .enumerate()
        .filter(|(_, l)| l.starts_with("Broadcast               m:") && l.ends_with("(Sent)"))
        .map(|(i, _)| sim.logs[i + 1].as_str())
        .collect();
    assert_eq!(after, ["    NO DATA", "    7"], "{:#?}", sim.logs);
}

/// A querier gone before its answer: the reply line names it by its module
/// name, and — as C's central, whose dead-module warning tests the
/// message's registered class, which an IPC message never has — no
/// warning follows. Checked against the C central with a querier killed
/// and one that called `IPC_disconnect`.
#[test]
fn a_dead_querier_is_named_and_not_warned_about() {
    for crash in [false, true] {
        let mut sim = Sim::new(config("msd"));
        let asker = sim.connect("qclient");
        let server = sim.connect("qserver");
        define(&mut sim, asker, "q", "int");
        define(&mut sim, asker, "r", "int");
        sim.m(server).subscribe("q", "HND-q").unwrap();
        sim.pump();
        sim.m(asker).query("q", 3i32.to_le_bytes(), -1).unwrap();
        sim.pump();
        if crash {
            sim.close(asker);
        } else {
            sim.m(asker).close().unwrap();
            sim.pump();
        }
        let deliveries = sim.deliveries(server);
        assert_eq!(deliveries.len(), 1, "{:#?}", sim.logs);
        sim.m(server)
            .respond(deliveries[0].0, "r", 5i32.to_le_bytes())
            .unwrap();
        sim.pump();
        let at = sim
            .logs
            .iter()
            .position(|l| l.starts_with("  Reply                q:"))
            .unwrap_or_else(|| panic!("no reply line: {:#?}", sim.logs));
        assert_eq!(
            sim.logs[at..at + 2],
            [
                "  Reply                q:    qserver --> qclient        ",
                "    5"
            ],
            "crash {crash}: {:#?}",
            sim.logs
        );
        assert!(
            !sim.logs.iter().any(|l| l.contains("WARNING")),
            "crash {crash}: {:#?}",
            sim.logs
        );
    }
}
