//! Central's log: times, internal messages as the C central logs them,
//! the log options and reconfiguring them.

use std::time::SystemTime;

use courier_wire::ipc::central::{Central, Config, LogOptions};

use crate::support::{define, pub_sub, Sim};

/// With `-t` every message line carries the time, central's own variable
/// broadcasts and the replies and completions of internal messages
/// included, as in the C central's log.
#[test]
fn timed_log_lines_all_carry_the_time() {
    let mut config = Config::default();
    config.terminal_log = LogOptions::parse("mt", false).unwrap();
    let wall = SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(3_723_450);
    // (No delay on the network: the clock stands still.)
    let mut sim = Sim::new_at(config, wall);
    let a = sim.connect("a");
    let b = sim.connect("b");
    define(&mut sim, a, "m", "int");
    sim.m(b).subscribe("m", "HND-m").unwrap();
    sim.pump();
    sim.m(a).publish("m", 1i32.to_le_bytes(), -1).unwrap();
    sim.pump();
    let message_lines: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| {
            ["Query", "Inform", "Broadcast", "  Reply", "  Done"]
                .iter()
                .any(|p| l.starts_with(p))
        })
        .collect();
    assert!(
        message_lines
            .iter()
            .any(|l| l.starts_with("Broadcast") && l.contains("V_watch_")),
        "{message_lines:#?}"
    );
    assert!(message_lines
        .iter()
        .any(|l| l.starts_with("  Done    x_ipc_registerHandlerMsg:")));
    assert!(message_lines
        .iter()
        .any(|l| l.starts_with("  Reply  x_ipc_msgInfoMsg:")));
    for l in message_lines {
        assert!(l.ends_with("  1:02:03.45"), "no time on {l:?}");
    }
}

/// Internal messages logged as the C central logs them when `i` is not
/// among the options: a module not named yet is `**NEWMOD**`, the connect
/// reply names it, replies carry their data (`x_ipc_waitMsg`'s `1`
/// included) and `x_ipc_CloseMsg` completes with a Done line.
/// With `-lmsrp` (no `i`) the C central logs registering its own
/// variables at start-up, and every internal message with its dispatch
/// id and its parent's: lines from the C central 3.9.1's terminal log
/// with module1 (`central -lmsrp`, routed, captured in session 20; the
/// host name is the machine's).
#[test]
fn internal_messages_carry_ids_and_parents_like_c() {
    let mut config = Config::default();
    config.terminal_log = LogOptions::parse("msrp", false).unwrap();
    let mut sim = Sim::new(config);
    let c_start = [
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_CENTRAL_TERMINAL_LOG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_CENTRAL_TERMINAL_LOG_VAR {0}:",
        "Inform    V_set_CENTRAL_FILE_LOG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_CENTRAL_FILE_LOG_VAR {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_X_IPC_TAPPED_MSG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_X_IPC_TAPPED_MSG_VAR {0}:",
        "Inform    x_ipc_registerGlobalVar {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    x_ipc_registerGlobalVar {0}:",
        "Inform    V_set_X_IPC_BROADCAST_MSG_VAR {0}: X_IPC Server {-1} --> X_IPC Server    (Sent)",
        "  Done    V_set_X_IPC_BROADCAST_MSG_VAR {0}:",
    ];
    assert_eq!(sim.logs, c_start);
    sim.logs.clear();
    sim.connect("module1");
    let c_connect = [
        "Query     x_ipc_msgInfoMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_msgInfoMsg {0}: X_IPC Server --> **NEWMOD**      {-1}",
        "Query     x_ipc_classInfoMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_classInfoMsg {0}: X_IPC Server --> **NEWMOD**      {-1}",
        "Query     x_ipc_newModuleConnectMsg {0}: **NEWMOD** {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_newModuleConnectMsg {0}: X_IPC Server --> module1         {-1}",
        "Query     x_ipc_msgInfoMsg {0}:    module1 {-1} --> X_IPC Server    (Sent)",
        "  Reply  x_ipc_msgInfoMsg {0}: X_IPC Server --> module1         {-1}",
        "Query     V_get_CENTRAL_TERMINAL_LOG_VAR {0}:    module1 {-1} --> X_IPC Server    (Sent)",
    ];
    for line in c_connect {
        assert!(
            sim.logs.iter().any(|l| l == line),
            "no {line:?} in {:#?}",
            sim.logs
        );
    }
    // Nothing of this reaches a log file: C opens it after start-up.
    let mut config = Config::default();
    config.file_log = LogOptions::parse("msrp", true).unwrap();
    let mut central = Central::new(config);
    assert_eq!(central.poll_output(), None);
}

#[test]
fn internal_messages_are_logged_like_c() {
    let mut config = Config::default();
    config.terminal_log = LogOptions::parse("md", false).unwrap();
    let mut sim = Sim::new(config);
    let a = sim.connect("a");
    let logs = std::mem::take(&mut sim.logs);
    let at = |p: &str| {
        logs.iter()
            .position(|l| l.starts_with(p))
            .unwrap_or_else(|| panic!("no line {p:?} in {logs:#?}"))
    };
    assert!(logs[at("Query     x_ipc_msgInfoMsg:")].contains(" **NEWMOD** --> X_IPC Server"));
    assert!(logs[at("  Reply  x_ipc_newModuleConnectMsg:")].contains("X_IPC Server --> a "));
    let info = at("  Reply  x_ipc_msgInfoMsg:");
    assert!(logs[info + 1].starts_with("    *{"), "{}", logs[info + 1]);
    let wait = at("  Reply    x_ipc_waitMsg:");
    assert_eq!(logs[wait + 1], "    1");
    // A subscription changes the broadcast list: central's own V_set
    // around the broadcast to the list's watchers.
    define(&mut sim, a, "m", "int");
    sim.m(a).subscribe("m", "HND-m").unwrap();
    sim.pump();
    let logs = std::mem::take(&mut sim.logs);
    let at = |p: &str| {
        logs.iter()
            .position(|l| l.starts_with(p))
            .unwrap_or_else(|| panic!("no line {p:?} in {logs:#?}"))
    };
    let set =
        at("Inform    V_set_X_IPC_BROADCAST_MSG_VAR: X_IPC Server --> X_IPC Server    (Sent)");
    assert!(logs[set + 1].starts_with("    {"), "{}", logs[set + 1]);
    let watch = at("Broadcast V_watch_X_IPC_BROADCAST_MSG_VAR: X_IPC Server --> a");
    let done = at("  Done    V_set_X_IPC_BROADCAST_MSG_VAR:");
    assert!(set < watch && watch < done, "{logs:#?}");
    sim.m(a).close().unwrap();
    sim.pump();
    assert!(
        sim.logs
            .iter()
            .any(|l| l.starts_with("  Done     x_ipc_CloseMsg:")),
        "{:#?}",
        sim.logs
    );
}

#[test]
fn log_options_parse_like_c() {
    let o = LogOptions::parse("MSD", false).unwrap();
    assert!(o.messages && o.status && o.data && !o.time);
    assert!(
        !LogOptions::parse("mxs", false).unwrap().any(),
        "any x turns the log off"
    );
    let f = LogOptions::parse("mF", true).unwrap();
    assert!(f.messages && f.no_flush);
    let e = LogOptions::parse("mq", false).unwrap_err().to_string();
    assert!(e.contains("unknown logging option 'q' in -l"), "{e}");
    assert!(
        LogOptions::parse("F", false).is_err(),
        "F is for the file log only"
    );
}

/// The console's options reach central through `reconfigure`.
#[test]
fn reconfiguring_changes_what_is_logged() {
    let (mut sim, a, _) = pub_sub(Config::default(), ("a", "b"), "foo", "int");
    let publish = |sim: &mut Sim| {
        let before = sim.logs.len();
        sim.m(a).publish("foo", 1i32.to_le_bytes(), -1).unwrap();
        sim.pump();
        sim.logs[before..]
            .iter()
            .filter(|l| l.contains(" foo"))
            .count()
    };
    assert!(publish(&mut sim) > 0, "logged with -lmsi");
    // The console's `-Ifoo`.
    sim.central().reconfigure(|c| c.ignore.push("foo".into()));
    assert_eq!(publish(&mut sim), 0, "ignored");
    assert!(sim.central().config().ignore.contains(&"foo".to_string()));
    // `-lmd -Lx` and no `-I`: logged again, and no file log.
    sim.central().reconfigure(|c| {
        c.ignore.clear();
        c.terminal_log = LogOptions::parse("md", false).unwrap();
        c.file_log = LogOptions::parse("x", true).unwrap();
    });
    assert!(!sim.central().config().file_log.any());
    assert!(publish(&mut sim) > 0, "logged again");
}
