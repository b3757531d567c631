//! Replays the exact module→central byte streams of the C modules in the
//! captures (`fixtures/ipc-central/*.txt`, extracted from
//! `../shared/fixtures/ipc` by `tools/ipc-fixtures/extract.py`) into our
//! central and checks every central→module frame against what the C central
//! sent, connection by connection, in order.
//!
//! Normalisation (fields that legitimately differ):
//! - message ids: central numbers them freely (ipc.md §5). The ids the C
//!   central handed out are mapped to ours as they are learned (the raw first
//!   4 bytes and every msgInfo reply), both in the replayed module frames
//!   (`intent`, keeping the sign that means "direct") and when comparing
//!   msgInfo replies (the id field; everything else byte for byte);
//! - dispatch ids (the `msgRef` of a delivery, `dispatchRef`/`parentRef` of
//!   Success, Reply and frames sent inside a handler): mapped the same way,
//!   learned from each delivery;
//! - the `FILE` pointer in the values of the two log variables
//!   (`V_get_CENTRAL_*_LOG_VAR`); the log options after it must match
//!   (both centrals log with `-lmsid`).
//! - the order *between* central's replies and its deliveries on one
//!   connection: it depends on the order in which the C central happened to
//!   read its sockets (a registration from one module that triggers a
//!   `V_watch_*` delivery to another), which the capture timestamps do not
//!   show. Replies must match in order, deliveries must match in order.
//!
//! Everything else — headers, class data, message data — must be identical.

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::SystemTime;

use courier_wire::ipc::central::{Central, Config, ConnId, LogOptions, Output, Peer};
use courier_wire::ipc::frame::{ClassId, Header, MsgClass};

struct Line {
    conn: u64,
    central: bool,
    bytes: Vec<u8>,
    label: String,
}

fn load(name: &str) -> Vec<Line> {
    let path = format!(
        "{}/tests/fixtures/ipc-central/{name}.txt",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let (body, label) = l.split_once("  # ").unwrap_or((l, ""));
            let mut w = body.split_whitespace();
            let _t = w.next().unwrap();
            let conn = w.next().unwrap().parse().unwrap();
            let central = w.next().unwrap() == "C";
            let hex = w.next().unwrap_or("");
            let bytes = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            Line {
                conn,
                central,
                bytes,
                label: label.to_string(),
            }
        })
        .collect()
}

fn word(b: &[u8], i: usize) -> i32 {
    i32::from_be_bytes(b[4 * i..4 * i + 4].try_into().unwrap())
}

fn set_word(b: &mut [u8], i: usize, v: i32) {
    b[4 * i..4 * i + 4].copy_from_slice(&v.to_be_bytes());
}

fn le(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

#[derive(Default)]
struct Maps {
    /// C message id -> ours.
    ids: HashMap<i32, i32>,
    /// C dispatch id -> ours.
    dispatch: HashMap<i32, i32>,
}

impl Maps {
    fn id(&self, c: i32) -> i32 {
        let a = c.checked_abs().unwrap_or(0);
        match self.ids.get(&a) {
            Some(o) => o * c.signum(),
            None => c,
        }
    }
    fn did(&self, c: i32) -> i32 {
        if c < 0 {
            c
        } else {
            *self.dispatch.get(&c).unwrap_or(&c)
        }
    }
}

/// Rewrites a replayed module frame from C's numbering into ours.
fn rewrite_module_frame(b: &mut [u8], maps: &Maps) {
    let h = Header::decode(b).unwrap();
    let class = h.class_id.class();
    if class != 11 && class != 12 && h.intent != 0 {
        set_word(b, 3, maps.id(h.intent));
    }
    set_word(b, 2, maps.did(h.parent_ref));
    set_word(b, 5, maps.did(h.dispatch_ref));
}

fn check(name: &str, direct: bool) -> usize {
    let lines = load(name);
    let mut config = Config::default();
    config.direct = direct;
    // The C central's options in each capture (its log variables say so).
    if name.starts_with("flowcontrol") {
        config.terminal_log = LogOptions::parse("msi", false).unwrap();
        config.quiet = true;
    } else {
        config.terminal_log = LogOptions::parse("msid", false).unwrap();
    }
    let mut central = Central::new(config);
    let now = SystemTime::UNIX_EPOCH;
    let mut maps = Maps::default();
    let mut actual: HashMap<u64, VecDeque<Vec<u8>>> = HashMap::new();
    let mut connected = HashSet::new();
    let mut compared = 0;
    let drain = |central: &mut Central, actual: &mut HashMap<u64, VecDeque<Vec<u8>>>| {
        while let Some(o) = central.poll_output() {
            if let Some((conn, bytes)) = o.transmitted() {
                actual.entry(conn.0).or_default().push_back(bytes);
            }
        }
    };
    for (n, l) in lines.iter().enumerate() {
        if connected.insert(l.conn) {
            central.connect(
                ConnId(l.conn),
                Peer::Other(format!("capture {}", l.conn)),
                now,
            );
            drain(&mut central, &mut actual);
        }
        let at = format!("{name} line {n} (conn {} {})", l.conn, l.label);
        if !l.central {
            let mut b = l.bytes.clone();
            rewrite_module_frame(&mut b, &maps);
            central.receive(ConnId(l.conn), &b, now);
            drain(&mut central, &mut actual);
            continue;
        }
        // Replies (and the handshake) and deliveries are two ordered streams.
        let want_delivery = is_delivery(&l.bytes);
        let got = actual
            .get_mut(&l.conn)
            .and_then(|q| {
                let i = q.iter().position(|f| is_delivery(f) == want_delivery)?;
                q.remove(i)
            })
            .unwrap_or_else(|| panic!("{at}: our central sent nothing; C sent {:02x?}", l.bytes));
        compared += 1;
        let want = &l.bytes;
        if std::env::var_os("REPLAY_DEBUG").is_some() {
            eprintln!("{at}\n  C   {}\n  us  {}", hex(want), hex(&got));
        }
        if want.len() == 4 {
            assert_eq!(got.len(), 4, "{at}: raw id");
            maps.ids.insert(word(want, 0), word(&got, 0));
            continue;
        }
        let (hw, hg) = (Header::decode(want).unwrap(), Header::decode(&got).unwrap());
        let mut got_n = got.clone();
        // Deliveries carry a dispatch id in msgRef; forwarded replies in dispatchRef.
        let delivery = hw.intent >= 0 && hw.class_id.class() != 0;
        if delivery {
            maps.dispatch.insert(hw.msg_ref, hg.msg_ref);
            set_word(&mut got_n, 6, hw.msg_ref);
        }
        if hw.class_id.class() == 11 {
            assert_eq!(
                maps.did(hw.dispatch_ref),
                hg.dispatch_ref,
                "{at}: reply dispatchRef"
            );
            set_word(&mut got_n, 5, hw.dispatch_ref);
        }
        if hw.parent_ref > 0 {
            assert_eq!(maps.did(hw.parent_ref), hg.parent_ref, "{at}: parentRef");
            set_word(&mut got_n, 2, hw.parent_ref);
        }
        if l.label.starts_with("x_ipc_msgInfoMsg REPLY") && want.len() > 28 && want[28] == b'Z' {
            // The id field right after the pointer flag.
            assert_eq!(got_n.len(), want.len(), "{at}: msgInfo reply length");
            let (cid, oid) = (le(want, 29), le(&got_n, 29));
            let known = maps.ids.insert(cid.abs(), oid.abs());
            assert!(
                known.is_none() || known == Some(oid.abs()),
                "{at}: id map changed"
            );
            assert_eq!(cid.signum(), oid.signum(), "{at}: direct sign of the id");
            got_n[29..33].copy_from_slice(&cid.to_le_bytes());
        }
        if l.label.contains("REPLY to V_get_CENTRAL_") {
            assert_eq!(got_n.len(), want.len(), "{at}: log variable length");
            // Header, pointer flag, then the C central's FILE pointer.
            if want.len() > 33 && want[28] == b'Z' {
                got_n[29..33].copy_from_slice(&want[29..33]);
            }
        }
        assert_eq!(
            hex(&got_n),
            hex(want),
            "{at}: frame differs\n ours: {hg:?}\n    C: {hw:?}"
        );
    }
    for (conn, q) in actual {
        assert!(
            q.is_empty(),
            "{name}: our central sent {} more frame(s) to conn {conn} than C did: first {:02x?}",
            q.len(),
            q.front()
        );
    }
    compared
}

/// A delivery to a handler (intent = handler id), as opposed to a reply
/// (intent -4), the raw id or a handshake formatter (intent 0).
fn is_delivery(b: &[u8]) -> bool {
    b.len() >= 28 && word(b, 3) > 0
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

#[test]
fn demo_central() {
    assert!(check("demo-central", false) > 100);
}

#[test]
fn wiretest_central() {
    assert!(check("wiretest-central", false) > 80);
}

#[test]
fn flowcontrol_capacity1() {
    assert!(check("flowcontrol-capacity1", false) > 50);
}

#[test]
fn flowcontrol_capacity2() {
    assert!(check("flowcontrol-capacity2", false) > 50);
}

#[test]
fn demo_direct() {
    assert!(check("demo-direct", true) > 100);
}

#[test]
fn wiretest_direct() {
    assert!(check("wiretest-direct", true) > 80);
}

/// A capture replayed into our central, its module frames renumbered into
/// our ids as they are learned (as `check` does, which proves the frames
/// equal); the connections are numbered as the C central's socket
/// descriptors were (5, 6, …).
struct Replay {
    central: Central,
    /// Our terminal log so far.
    log: Vec<String>,
    /// Frames our central sent that the capture has not shown yet.
    actual: HashMap<u64, VecDeque<Vec<u8>>>,
    /// The module→central frames as our central was given them, in order.
    stream: Vec<(u64, Vec<u8>)>,
}

fn replay(name: &str, direct: bool) -> Replay {
    let lines = load(name);
    let mut config = Config::default();
    config.direct = direct;
    config.terminal_log = LogOptions::parse("msid", false).unwrap();
    let mut r = Replay {
        central: Central::new(config),
        log: Vec::new(),
        actual: HashMap::new(),
        stream: Vec::new(),
    };
    let now = SystemTime::UNIX_EPOCH;
    let mut connected = HashSet::new();
    let mut maps = Maps::default();
    for l in &lines {
        let conn = ConnId(l.conn + 5);
        if connected.insert(l.conn) {
            r.central.connect(conn, Peer::Other("capture".into()), now);
            drain_log(&mut r.central, &mut r.actual, &mut r.log);
        }
        if l.central {
            let want_delivery = is_delivery(&l.bytes);
            let q = r.actual.entry(l.conn).or_default();
            let i = q
                .iter()
                .position(|f| is_delivery(f) == want_delivery)
                .unwrap();
            let got = q.remove(i).unwrap();
            if l.bytes.len() == 4 {
                maps.ids.insert(word(&l.bytes, 0), word(&got, 0));
            } else if want_delivery {
                maps.dispatch.insert(word(&l.bytes, 6), word(&got, 6));
            } else if l.label.starts_with("x_ipc_msgInfoMsg REPLY")
                && l.bytes.len() > 33
                && l.bytes[28] == b'Z'
            {
                maps.ids.insert(le(&l.bytes, 29).abs(), le(&got, 29).abs());
            }
        } else {
            let mut b = l.bytes.clone();
            rewrite_module_frame(&mut b, &maps);
            r.central.receive(conn, &b, now);
            drain_log(&mut r.central, &mut r.actual, &mut r.log);
            r.stream.push((conn.0, b));
        }
    }
    r
}

/// Our terminal log for a replayed capture.
fn replay_log(name: &str, direct: bool, close_order: &[u64]) -> Vec<String> {
    let Replay {
        mut central,
        mut log,
        mut actual,
        ..
    } = replay(name, direct);
    let now = SystemTime::UNIX_EPOCH;
    // The modules ended with IPC_disconnect (x_ipc_CloseMsg, then EOF);
    // where the capture stops before that, send it as they did, in the
    // order the C central saw their connections end.
    let close_id = central.message_id("x_ipc_CloseMsg").unwrap();
    for &c in close_order {
        // Deliveries sent after the capture stopped: the module handled and
        // acknowledged them before closing.
        drain_log(&mut central, &mut actual, &mut log);
        let late: Vec<Vec<u8>> = actual.entry(c).or_default().drain(..).collect();
        for f in late.iter().filter(|f| is_delivery(f) && f[19] == 15) {
            let ack = Header {
                class_total: 0,
                msg_total: 0,
                parent_ref: word(f, 6),
                intent: -1,
                class_id: ClassId::native(MsgClass::Success),
                dispatch_ref: word(f, 6),
                msg_ref: -1,
            };
            central.receive(ConnId(c + 5), &ack.encode(), now);
        }
        let h = Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: -1,
            intent: close_id,
            class_id: ClassId::native(MsgClass::Inform),
            dispatch_ref: -1,
            msg_ref: 1000,
        };
        central.receive(ConnId(c + 5), &h.encode(), now);
        central.disconnect(ConnId(c + 5), now);
    }
    while let Some(o) = central.poll_output() {
        if let Output::Log { target, line } = o {
            if target.terminal {
                log.push(line);
            }
        }
    }
    log
}

fn drain_log(
    central: &mut Central,
    actual: &mut HashMap<u64, VecDeque<Vec<u8>>>,
    log: &mut Vec<String>,
) {
    while let Some(o) = central.poll_output() {
        match o {
            Output::Transmit { .. } | Output::TransmitBody { .. } => {
                let (conn, bytes) = o.transmitted().unwrap();
                actual.entry(conn.0 - 5).or_default().push_back(bytes)
            }
            Output::Log { target, line } if target.terminal => log.push(line),
            _ => {}
        }
    }
}

/// The C central's log between its banner and its exit report.
fn c_log(name: &str) -> Vec<String> {
    let path = format!(
        "{}/tests/fixtures/ipc-central/{name}.central.log",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(2)
        .take_while(|l| !l.starts_with("Cumulative Memory Usage"))
        .map(|l| l.trim_end().to_string())
        .collect()
}

fn compare_logs(name: &str, direct: bool, close_order: &[u64]) {
    let ours: Vec<String> = replay_log(name, direct, close_order)
        .into_iter()
        .map(|l| l.trim_end().to_string())
        .collect();
    let theirs = c_log(name);
    assert_eq!(ours.join("\n"), theirs.join("\n"), "{name}: log differs");
}

#[test]
fn demo_central_log_matches_c() {
    compare_logs("demo-central", false, &[0, 1, 2]);
}

#[test]
fn demo_direct_log_matches_c() {
    compare_logs("demo-direct", true, &[0, 1, 2]);
}

#[test]
fn wiretest_central_log_matches_c() {
    compare_logs("wiretest-central", false, &[1, 0]);
}

#[test]
fn wiretest_direct_log_matches_c() {
    compare_logs("wiretest-direct", true, &[1, 0]);
}

// ----- mutated captures ---------------------------------------------------------
//
// The captures' module streams, renumbered into our ids so that unchanged
// they drive central through registration, lookups, deliveries, queries,
// replies, capacity and notifications, then damaged the ways a broken or
// hostile module damages its stream (`damage/mod.rs`). Whatever the damage,
// central must not panic or loop, must close a connection it gives up on
// with a log line saying why, must free every queued byte and dispatch when
// the modules are gone (but for queries waiting for a handler, which C
// keeps too), and must still serve new modules. The bound on queued bytes
// has its own tests in `central_sim.rs`.

use courier_wire::ipc::module::{Connection, Event, ModuleConfig, MsgLength};
use damage::central::carry_out;
use damage::{damage, damaged, Step};
use proptest::prelude::*;
use std::time::Instant;

mod damage;

/// Replays the damaged steps, `chunk` bytes per read, honouring central's
/// pause requests as a shell does, and disconnects every module at the end.
fn run_damaged(config: Config, steps: Vec<Step>, chunk: usize) -> Central {
    let now = SystemTime::UNIX_EPOCH;
    let mut central = Central::new(config);
    let mut open: HashSet<u64> = HashSet::new();
    let mut gone: HashSet<u64> = HashSet::new();
    let mut paused: HashSet<u64> = HashSet::new();
    // Bytes a paused connection could not deliver yet (its socket buffer).
    let mut held: HashMap<u64, Vec<u8>> = HashMap::new();
    for step in steps {
        match step {
            Step::Bytes(conn, bytes) => {
                if gone.contains(&conn) {
                    continue;
                }
                if open.insert(conn) {
                    central.connect(ConnId(conn), Peer::Other("fuzz".into()), now);
                }
                let buf = held.entry(conn).or_default();
                buf.extend_from_slice(&bytes);
                for c in held.keys().copied().collect::<Vec<_>>() {
                    while !paused.contains(&c) && !gone.contains(&c) {
                        let buf = held.get_mut(&c).unwrap();
                        if buf.is_empty() {
                            break;
                        }
                        let k = chunk.min(buf.len());
                        let piece: Vec<u8> = buf.drain(..k).collect();
                        central.receive(ConnId(c), &piece, now);
                        carry_out(&mut central, &mut paused, &mut gone);
                    }
                }
            }
            Step::Hangup(conn) => {
                if open.contains(&conn) && gone.insert(conn) {
                    central.disconnect(ConnId(conn), now);
                    carry_out(&mut central, &mut paused, &mut gone);
                }
            }
            Step::Other(what) => {
                damage::central::console(
                    &mut central,
                    what,
                    ["module1", "module2", "wiretest"],
                    now,
                );
                carry_out(&mut central, &mut paused, &mut gone);
            }
        }
    }
    for conn in open {
        if gone.insert(conn) {
            central.disconnect(ConnId(conn), now);
            carry_out(&mut central, &mut paused, &mut gone);
        }
    }
    central
}

/// Two new modules connect to `central`: the second subscribes, the first
/// sees its handler; through a routing central it also publishes, and the
/// message arrives.
fn still_serves(central: &mut Central) {
    let now = SystemTime::UNIX_EPOCH;
    let t = Instant::now();
    let mut mods = [
        (
            ConnId(900),
            Connection::new(ModuleConfig::new("after-a", "localhost"), t),
        ),
        (
            ConnId(901),
            Connection::new(ModuleConfig::new("after-b", "localhost"), t),
        ),
    ];
    for (c, _) in &mods {
        central.connect(*c, Peer::Other("after".into()), now);
    }
    // Moves bytes until nothing moves; the modules' events, by module.
    let pump = |central: &mut Central, mods: &mut [(ConnId, Connection); 2]| {
        let mut events: [Vec<Event>; 2] = Default::default();
        for _ in 0..100 {
            let mut moved = false;
            for (c, m) in mods.iter_mut() {
                while let Some(bytes) = m.poll_transmit() {
                    central.receive(*c, &bytes, now);
                    moved = true;
                }
            }
            while let Some(o) = central.poll_output() {
                if let Some((conn, bytes)) = o.transmitted() {
                    if let Some((_, m)) = mods.iter_mut().find(|(c, _)| *c == conn) {
                        m.receive(&bytes, t);
                        moved = true;
                    }
                }
            }
            for (i, (_, m)) in mods.iter_mut().enumerate() {
                while let Some(e) = m.poll_event() {
                    if matches!(e, Event::DirectListenRequested) {
                        m.announce_direct_port(40000 + i as i32);
                    }
                    events[i].push(e);
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
        events
    };
    let ev = pump(central, &mut mods);
    for (i, e) in ev.iter().enumerate() {
        assert!(
            e.iter().any(|e| matches!(e, Event::Connected)),
            "module {i} did not connect: {e:?}"
        );
    }
    mods[1].1.subscribe("after_msg", "h").unwrap();
    pump(central, &mut mods);
    let (_, a) = &mut mods[0];
    a.define_msg("after_msg", MsgLength::Fixed(4), None)
        .unwrap();
    a.num_handlers("after_msg").unwrap();
    let ev = pump(central, &mut mods);
    assert!(
        ev[0]
            .iter()
            .any(|e| matches!(e, Event::NumHandlers { count: 1, .. })),
        "central no longer registers handlers: {ev:?}"
    );
    if central.config().direct {
        return;
    }
    mods[0]
        .1
        .publish("after_msg", vec![1, 2, 3, 4], -1)
        .unwrap();
    let ev = pump(central, &mut mods);
    let got: Vec<&[u8]> = ev[1]
        .iter()
        .filter_map(|e| match e {
            Event::Delivery { data, .. } => Some(&data[..]),
            _ => None,
        })
        .collect();
    assert_eq!(
        got,
        [&[1u8, 2, 3, 4][..]],
        "central no longer routes: {ev:?}"
    );
}

/// A capture's name, whether its central was direct, and its module
/// frames in our ids.
type Capture = (&'static str, bool, Vec<(u64, Vec<u8>)>);

fn streams() -> &'static [Capture] {
    static S: std::sync::OnceLock<Vec<Capture>> = std::sync::OnceLock::new();
    S.get_or_init(|| {
        [
            ("demo-central", false),
            ("wiretest-central", false),
            ("flowcontrol-capacity1", false),
            ("flowcontrol-capacity2", false),
            ("demo-direct", true),
            ("wiretest-direct", true),
        ]
        .into_iter()
        .map(|(n, d)| (n, d, replay(n, d).stream))
        .collect()
    })
}

#[test]
fn undamaged_captures_leave_nothing_behind() {
    for (name, direct, stream) in streams() {
        for pick in 0..6 {
            let steps = stream
                .iter()
                .cloned()
                .map(|(c, b)| Step::Bytes(c, b))
                .collect();
            let mut central =
                run_damaged(damage::central::config(pick, *direct), steps, usize::MAX);
            let s = central.stats();
            assert_eq!((s.modules, s.queued_bytes), (0, 0), "{name} config {pick}");
            still_serves(&mut central);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(damage::cases(400)))]

    #[test]
    fn damaged_captures_leave_central_up(
        which in 0usize..6,
        pick in any::<u8>(),
        damage in prop::collection::vec(damage(), 1..8),
        chunk in prop_oneof![Just(usize::MAX), 1usize..64],
    ) {
        let (_, direct, stream) = &streams()[which];
        let steps = damaged(stream, &damage);
        let mut central = run_damaged(damage::central::config(pick, *direct), steps, chunk);
        let s = central.stats();
        prop_assert_eq!(s.modules, 0);
        prop_assert_eq!(s.queued_bytes, 0, "bytes still queued after every module left");
        if !central.config().resend_on_reconnect {
            prop_assert_eq!(
                s.dispatches,
                s.waiting_for_handler,
                "dispatches alive after every module left"
            );
        }
        still_serves(&mut central);
    }
}
