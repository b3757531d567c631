//! Replays the central→module byte streams of the C demo capture
//! (`fixtures/ipc-module/demo-central-module*.txt`, cut from
//! `shared/fixtures/ipc/demo-central/decoded-fullhex.txt`) into the sans-I/O
//! module and checks that it writes the same frames, byte for byte, as the C
//! module1/module2 did (same msgRefs, handler ids, lookups in the same order).
//!
//! The driver feeds central's frames the way the C library reads them: only
//! while it waits for a reply, or when the program "listens" (its scripted
//! API calls are done), which is when [`Connection::poll_event`] runs.

use std::collections::VecDeque;
use std::time::Instant;

use courier_wire::ipc::module::{Connection, DeliveryKind, Event, ModuleConfig, MsgLength};

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn to_hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// (from_central, bytes, comment)
fn load(text: &str) -> Vec<(bool, Vec<u8>, String)> {
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let (frame, comment) = l.split_once('#').unwrap_or((l, ""));
            let mut it = frame.split_whitespace();
            let dir = it.next().unwrap();
            let h = it.next().unwrap();
            (dir == "C", hex(h), comment.trim().to_string())
        })
        .collect()
}

type Action = Box<dyn FnMut(&mut Connection)>;
type OnEvent = Box<dyn FnMut(&mut Connection, Event)>;

/// Runs the replay and checks the first `check` module→central frames.
fn replay(
    text: &str,
    cfg: ModuleConfig,
    actions: Vec<Action>,
    mut on_event: OnEvent,
    finally: Vec<Action>,
    check: usize,
) -> Connection {
    let mut finally: VecDeque<Action> = finally.into();
    let now = Instant::now();
    let mut conn = Connection::new(cfg, now);
    let mut actions: VecDeque<Action> = actions.into();
    let mut arrived: VecDeque<Vec<u8>> = VecDeque::new();
    let mut checked = 0;
    for (from_central, bytes, comment) in load(text) {
        if from_central {
            arrived.push_back(bytes);
            continue;
        }
        if checked == check {
            break;
        }
        let mut guard = 0;
        loop {
            guard += 1;
            assert!(guard < 10_000, "no progress before M frame {checked}");
            if let Some(t) = conn.poll_transmit() {
                assert_eq!(
                    to_hex(&t),
                    to_hex(&bytes),
                    "module->central frame {checked} ({comment}) differs"
                );
                break;
            }
            let waiting = !conn.is_connected() || conn.is_waiting();
            if waiting {
                if let Some(b) = arrived.pop_front() {
                    conn.receive(&b, now);
                    continue;
                }
            }
            if !waiting {
                if let Some(mut a) = actions.pop_front() {
                    a(&mut conn);
                    continue;
                }
            }
            if let Some(e) = conn.poll_event() {
                assert!(!matches!(e, Event::Closed(_)), "closed: {e:?}");
                on_event(&mut conn, e);
                continue;
            }
            if conn.has_transmit() {
                continue;
            }
            if let Some(b) = arrived.pop_front() {
                conn.receive(&b, now);
                continue;
            }
            // Nothing left to listen to: what the program does after IPC_dispatch.
            if let Some(mut a) = finally.pop_front() {
                a(&mut conn);
                continue;
            }
            panic!("module->central frame {checked} ({comment}) was not produced; {conn:?}");
        }
        checked += 1;
    }
    assert_eq!(checked, check, "capture has fewer frames than checked");
    conn
}

fn ack_all() -> OnEvent {
    Box::new(|c: &mut Connection, e: Event| {
        if let Event::Delivery {
            delivery,
            kind: DeliveryKind::Broadcast,
            ..
        } = e
        {
            c.ack(delivery).unwrap();
        }
    })
}

const MODULE1: &str = include_str!("fixtures/ipc-module/demo-central-module1.txt");
const MODULE2: &str = include_str!("fixtures/ipc-module/demo-central-module2.txt");

#[test]
fn module1_handshake_and_definitions_match_c() {
    let actions: Vec<Action> = vec![
        Box::new(|c| c.subscribe_connect().unwrap()),
        Box::new(|c| c.subscribe_connect().unwrap()),
        Box::new(|c| c.subscribe_disconnect().unwrap()),
        Box::new(|c| {
            c.define_format("T1", "{int, {enum : 3}, [double:2,3], double}")
                .unwrap()
        }),
        Box::new(|c| {
            c.define_format(
                "T2",
                "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
            )
            .unwrap()
        }),
        Box::new(|c| {
            c.define_msg("message1", MsgLength::Variable, Some("int"))
                .unwrap()
        }),
        Box::new(|c| {
            c.subscribe_handler_change("message1").unwrap();
        }),
    ];
    // Up to and including the lookup of message1 by IPC_subscribeHandlerChange;
    // after that the C module ran a queued V_watch handler in the middle of
    // IPC_subscribeHandlerChange (timing-dependent, see the report).
    let conn = replay(
        MODULE1,
        ModuleConfig::new("module1", "localhost"),
        actions,
        ack_all(),
        vec![],
        35,
    );
    assert!(conn.is_connected());
}

#[test]
fn module2_whole_session_matches_c() {
    let actions: Vec<Action> = vec![
        Box::new(|c| {
            c.define_msg("message2", MsgLength::Variable, Some("string"))
                .unwrap()
        }),
        Box::new(|c| {
            c.define_msg("response1", MsgLength::Variable, Some("T2"))
                .unwrap()
        }),
        Box::new(|c| {
            assert_eq!(
                c.subscribe("message1", "HND-message194665907509024")
                    .unwrap(),
                198
            );
        }),
        Box::new(|c| {
            assert_eq!(
                c.subscribe("query1", "HND-query194665907508752").unwrap(),
                197
            );
        }),
    ];
    let on_event: OnEvent = Box::new(|c: &mut Connection, e: Event| match e {
        Event::Delivery {
            delivery,
            kind: DeliveryKind::Broadcast,
            msg,
            data,
            ..
        } => {
            assert_eq!(msg, "message1");
            assert_eq!(data, 42i32.to_le_bytes());
            c.ack(delivery).unwrap();
        }
        Event::Delivery {
            delivery,
            kind: DeliveryKind::Query,
            msg,
            data,
            dispatch_ref,
            ..
        } => {
            assert_eq!(msg, "query1");
            assert_eq!(data.len(), 64);
            let mut s = 12i32.to_le_bytes().to_vec();
            s.extend_from_slice(b"Hello, world");
            c.publish("message2", s.clone(), dispatch_ref).unwrap();
            let mut r = s.clone();
            r.extend_from_slice(&1i32.to_le_bytes());
            r.extend_from_slice(&1i32.to_le_bytes());
            r.extend_from_slice(&data);
            r.extend_from_slice(&2i32.to_le_bytes());
            c.respond(delivery, "response1", r.clone()).unwrap();
        }
        _ => {}
    });
    let n = load(MODULE2).iter().filter(|(c, _, _)| !c).count();
    replay(
        MODULE2,
        ModuleConfig::new("module2", "127.1"),
        actions,
        on_event,
        vec![Box::new(|c| c.close().unwrap())],
        n,
    );
}

// ----- damaged central streams ----------------------------------------------------
//
// What central sends to module1 and module2 in the capture,
// damaged (`damage/mod.rs`) and fed to a module that makes the capture's
// API calls. A module must survive whatever comes from its socket: no
// panic, no loop, an error event or a closed connection instead, and API
// calls after that answer with an error.

mod damage;

use courier_wire::ipc::module::Error;
use damage::module::{api_call, CALLS};
use damage::{damage, damaged, Step};
use proptest::prelude::*;

/// Returns how many events the program handled before its connection
/// closed, if it did.
fn run_damaged_module(text: &str, damage: &[damage::Damage], chunk: usize) -> (usize, bool) {
    let now = Instant::now();
    let from_central: Vec<(u64, Vec<u8>)> = load(text)
        .into_iter()
        .filter(|(c, _, _)| *c)
        .map(|(_, b, _)| (0, b))
        .collect();
    // The calls module1 and module2 made (see the replay tests above), in
    // order, each once the module is connected and waits for nothing, so
    // that the undamaged stream answers them.
    type Call = fn(&mut Connection) -> Result<(), Error>;
    let (name, host, mut script): (_, _, VecDeque<Call>) = if text == MODULE1 {
        (
            "module1",
            "localhost",
            VecDeque::from([
                (|c| c.subscribe_connect()) as Call,
                |c| c.subscribe_connect(),
                |c| c.subscribe_disconnect(),
                |c| c.define_format("T1", "{int, {enum : 3}, [double:2,3], double}"),
                |c| {
                    c.define_format(
                        "T2",
                        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
                    )
                },
                |c| c.define_msg("message1", MsgLength::Variable, Some("int")),
                |c| c.subscribe_handler_change("message1").map(drop),
            ]),
        )
    } else {
        (
            "module2",
            "127.1",
            VecDeque::from([
                (|c| c.define_msg("message2", MsgLength::Variable, Some("string"))) as Call,
                |c| c.define_msg("response1", MsgLength::Variable, Some("T2")),
                |c| {
                    c.subscribe("message1", "HND-message194665907509024")
                        .map(drop)
                },
                |c| c.subscribe("query1", "HND-query194665907508752").map(drop),
            ]),
        )
    };
    let mut conn = Connection::new(ModuleConfig::new(name, host), now);
    let mut closed = false;
    let mut handled = 0;
    // Runs the program until it has nothing to do: answers what it is
    // given, writes what it has to write.
    let mut settle = |conn: &mut Connection, closed: &mut bool| {
        for _ in 0..10_000 {
            let mut moved = conn.poll_transmit().is_some();
            if conn.is_connected() && !conn.is_waiting() && !conn.has_transmit() {
                if let Some(call) = script.pop_front() {
                    let r = call(conn);
                    assert!(r.is_ok() || *closed, "{r:?}");
                    moved = true;
                }
            }
            while let Some(e) = conn.poll_event() {
                moved = true;
                if !*closed {
                    handled += 1;
                }
                match e {
                    Event::Delivery { delivery, kind, .. } => {
                        let r = match kind {
                            DeliveryKind::Broadcast => conn.ack(delivery),
                            DeliveryKind::Query => {
                                conn.respond(delivery, "response1", vec![1, 2, 3, 4])
                            }
                        };
                        // Only a closed connection refuses an answer.
                        assert!(r.is_ok() || *closed || !conn.is_connected(), "{r:?}");
                    }
                    Event::Closed(_) => *closed = true,
                    _ => {}
                }
            }
            if !moved {
                return;
            }
        }
        panic!("the module never settles");
    };
    for step in damaged(&from_central, damage) {
        match step {
            Step::Bytes(_, bytes) => {
                for piece in bytes.chunks(chunk.max(1)) {
                    conn.receive(piece, now);
                    settle(&mut conn, &mut closed);
                }
            }
            Step::Hangup(_) => {
                conn.handle_eof();
                settle(&mut conn, &mut closed);
                break;
            }
            Step::Other(what) => {
                let r = api_call(&mut conn, what);
                assert!(r.is_ok() || closed || !conn.is_connected(), "{r:?}");
                settle(&mut conn, &mut closed);
            }
        }
    }
    let closed_early = closed;
    conn.handle_eof();
    settle(&mut conn, &mut closed);
    // A closed connection refuses calls with an error.
    for what in 0..CALLS {
        let _ = api_call(&mut conn, what);
    }
    settle(&mut conn, &mut closed);
    (handled, closed_early)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(damage::cases(300)))]

    #[test]
    fn damaged_central_streams_never_break_a_module(
        which in 0usize..2,
        damage in prop::collection::vec(damage(), 1..8),
        chunk in prop_oneof![Just(usize::MAX), 1usize..64],
    ) {
        run_damaged_module([MODULE1, MODULE2][which], &damage, chunk);
    }
}

#[test]
fn undamaged_central_streams_run_through() {
    // Unchanged, the streams connect the modules and carry events to them
    // (module2: connected and its three deliveries; module1: connected and
    // a notification) without
    // breaking the connection.
    for (text, events) in [(MODULE1, 2), (MODULE2, 4)] {
        let (handled, closed) = run_damaged_module(text, &[], usize::MAX);
        assert!(
            handled >= events && !closed,
            "{handled} events, closed {closed}"
        );
    }
}
