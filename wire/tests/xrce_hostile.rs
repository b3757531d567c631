//! Malformed and hostile input to the XRCE client and agent machines:
//! errors that say what is wrong, never a panic, memory bounded by the
//! configuration, and a machine that goes on working afterwards.

use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use courier_wire::xrce::{
    flags, Agent, AgentCommandError, AgentConfig, AgentEvent, AgentRepresentation,
    BaseObjectRequest, Client, ClientConfig, ClientKey, ClientRepresentation, CommandError,
    ConnectError, CreationMode, Data, Event, FragmentError, Heartbeat, InputError, LostReason,
    Message, MessageHeader, ObjectId, ObjectKind, ObjectVariant, Payload, QueueError,
    Representation, RequestId, ResultStatus, State, Status, StatusAgent, StatusCode, StreamError,
    StreamId, Submessage,
};
use proptest::prelude::*;

const STATUS_AGENT: [u8; 19] = [
    0x81, 0, 0, 0, 4, 1, 11, 0, 0, 0, b'X', b'R', b'C', b'E', 1, 0, 1, 0x0F, 0,
];

fn msg(header: MessageHeader, subs: Vec<Submessage>) -> Vec<u8> {
    Message::new(header, subs).to_vec().unwrap()
}

fn h(stream: u8, seq: u16) -> MessageHeader {
    MessageHeader::new(0x81, StreamId(stream), seq)
}

fn sub(p: Payload) -> Submessage {
    Submessage::new(p)
}

fn fragment(body: Vec<u8>, last: bool) -> Submessage {
    let f = flags::LITTLE_ENDIAN | if last { flags::LAST_FRAGMENT } else { 0 };
    Submessage::with_flags(f, Payload::Fragment(body))
}

fn data(req: u16, object: ObjectId, d: &[u8]) -> Submessage {
    sub(Payload::Data(Data {
        request: BaseObjectRequest::new(req, object),
        data: d.to_vec(),
    }))
}

fn reader() -> ObjectId {
    ObjectId::new(1, ObjectKind::DataReader)
}

fn no_keepalive(key: u32) -> ClientConfig {
    ClientConfig {
        keepalive: None,
        ..ClientConfig::new(key)
    }
}

fn connected(cfg: ClientConfig) -> (Client, Instant) {
    let now = Instant::now();
    let mut c = Client::new(cfg);
    c.connect(now);
    c.handle_input(&STATUS_AGENT, now).unwrap();
    drain(&mut c);
    (c, now)
}

fn drain(c: &mut Client) -> (Vec<Vec<u8>>, Vec<Event>) {
    let mut out = Vec::new();
    while let Some(m) = c.poll_transmit() {
        out.push(m);
    }
    let mut ev = Vec::new();
    while let Some(e) = c.poll_event() {
        ev.push(e);
    }
    (out, ev)
}

fn captured_agent_messages() -> Vec<Vec<u8>> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/xrce");
    let mut v = Vec::new();
    for cap in [
        "udp_fragmentation_large_sample",
        "udp_request_reply",
        "udp_ping",
    ] {
        let text = std::fs::read_to_string(dir.join(format!("{cap}.hex"))).unwrap();
        for l in text.lines().filter(|l| !l.starts_with('#')) {
            let f: Vec<&str> = l.split_whitespace().collect();
            let b = (0..f[4].len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&f[4][i..i + 2], 16).unwrap())
                .collect();
            v.push(b);
        }
    }
    v
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn any_bytes_to_the_client_in_any_state(
        state in 0u8..3,
        inputs in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..600), 1..8),
    ) {
        let now = Instant::now();
        let mut c = Client::new(ClientConfig::new(0xCCCC_DDDD));
        if state >= 1 { c.connect(now); }
        if state >= 2 { c.handle_input(&STATUS_AGENT, now).unwrap(); }
        for (i, b) in inputs.iter().enumerate() {
            let t = now + Duration::from_millis(i as u64 * 50);
            let _ = c.handle_input(b, t);
            c.handle_timeout(t);
            drain(&mut c);
        }
        prop_assert!(c.buffered_bytes() < 64 * 1024);
    }

    #[test]
    fn captured_agent_messages_with_bytes_changed(
        picks in prop::collection::vec((any::<prop::sample::Index>(), any::<prop::sample::Index>(), any::<u8>()), 1..40),
    ) {
        let msgs = captured_agent_messages();
        let (mut c, now) = connected(ClientConfig::new(0x2222_0002));
        for (k, (m, at, b)) in picks.iter().enumerate() {
            let mut bytes = m.get(&msgs).clone();
            let i = at.index(bytes.len());
            bytes[i] ^= b | 1;
            let t = now + Duration::from_millis(k as u64 * 10);
            let _ = c.handle_input(&bytes, t);
            c.handle_timeout(t);
            drain(&mut c);
        }
    }

    #[test]
    fn any_bytes_to_the_agent_from_any_address(
        inputs in prop::collection::vec((0u8..4, prop::collection::vec(any::<u8>(), 0..600)), 1..12),
    ) {
        let now = Instant::now();
        let mut a: Agent<u8> = Agent::new(AgentConfig::default(), now, SystemTime::UNIX_EPOCH);
        // one real session, from address 0
        a.handle_input(0, &create_client(0xCCCC_DDDD, 0x81), now).unwrap();
        for (i, (from, b)) in inputs.iter().enumerate() {
            let t = now + Duration::from_millis(i as u64 * 50);
            let _ = a.handle_input(*from, b, t);
            a.handle_timeout(t);
            while a.poll_transmit().is_some() {}
            while a.poll_event().is_some() {}
        }
        prop_assert!(a.buffered_bytes() < 1 << 20);
    }

    #[test]
    fn captured_client_messages_with_bytes_changed_to_the_agent(
        picks in prop::collection::vec((any::<prop::sample::Index>(), any::<prop::sample::Index>(), any::<u8>()), 1..40),
    ) {
        let msgs = captured_agent_messages();
        let now = Instant::now();
        let mut a: Agent<u8> = Agent::new(AgentConfig::default(), now, SystemTime::UNIX_EPOCH);
        a.handle_input(0, &create_client(0xCCCC_DDDD, 0x81), now).unwrap();
        for (k, (m, at, b)) in picks.iter().enumerate() {
            let mut bytes = m.get(&msgs).clone();
            let i = at.index(bytes.len());
            bytes[i] ^= b | 1;
            let _ = a.handle_input(0, &bytes, now + Duration::from_millis(k as u64));
            while a.poll_transmit().is_some() {}
            while a.poll_event().is_some() {}
        }
    }
}

#[test]
fn messages_outside_the_window_are_acknacked_but_not_held() {
    let (mut c, now) = connected(no_keepalive(1));
    let payload = vec![7u8; 400];
    for seq in (100u16..20_000).step_by(7) {
        let m = msg(h(0x80, seq), vec![data(10, reader(), &payload)]);
        c.handle_input(&m, now).unwrap();
        let (out, _) = drain(&mut c);
        // an ACKNACK that still waits for 0
        assert_eq!(out, [vec![0x81, 0, 0, 0, 0x0A, 1, 5, 0, 0, 0, 0, 0, 0x80]]);
    }
    assert!(c.buffered_bytes() < 1024, "{}", c.buffered_bytes());
    // early messages inside the window are held, at most a window of them
    for seq in 1u16..=40 {
        let m = msg(h(0x80, seq), vec![data(10, reader(), &payload)]);
        c.handle_input(&m, now).unwrap();
    }
    let (out, ev) = drain(&mut c);
    assert!(ev.is_empty());
    // 1..=15 held (the window is 0..=15): only 0 is missing
    assert_eq!(out.last().unwrap()[8..12], [0, 0, 0, 1]);
    assert!(c.buffered_bytes() <= 16 * 500, "{}", c.buffered_bytes());
    // 0 arrives: all sixteen are handed on, in order
    c.handle_input(&msg(h(0x80, 0), vec![data(10, reader(), &payload)]), now)
        .unwrap();
    let (_, ev) = drain(&mut c);
    assert_eq!(ev.len(), 16);
    assert!(c.buffered_bytes() < 1024);
}

#[test]
fn reassembly_is_bounded_and_the_stream_goes_on() {
    let mut cfg = no_keepalive(1);
    cfg.streams.max_reassembly = 4096;
    let (mut c, now) = connected(cfg);
    let mut errors = Vec::new();
    for seq in 0u16..30 {
        let m = msg(h(0x80, seq), vec![fragment(vec![1; 400], false)]);
        if let Err(e) = c.handle_input(&m, now) {
            errors.push(e);
        }
        assert!(c.buffered_bytes() <= 4096 + 600, "{}", c.buffered_bytes());
    }
    assert_eq!(
        errors,
        [InputError::Fragment(FragmentError::TooLarge {
            max: 4096,
            object: None
        })]
    );
    // the last fragment ends the oversized submessage, which is dropped
    c.handle_input(&msg(h(0x80, 30), vec![fragment(vec![1; 10], true)]), now)
        .unwrap();
    c.handle_input(&msg(h(0x80, 31), vec![data(10, reader(), b"ok")]), now)
        .unwrap();
    // an oversized DATA names its reader (its first fragment may be short)
    let mut big = Vec::new();
    data(10, reader(), &[9; 6000]).encode(&mut big, 0).unwrap();
    let mut errors = Vec::new();
    for (i, part) in std::iter::once(&big[..3])
        .chain(big[3..].chunks(400))
        .enumerate()
    {
        let last = 3 + i * 400 >= big.len();
        let seq = 32 + i as u16;
        let m = msg(h(0x80, seq), vec![fragment(part.to_vec(), last)]);
        if let Err(e) = c.handle_input(&m, now) {
            errors.push(e);
        }
    }
    assert_eq!(
        errors,
        [InputError::Fragment(FragmentError::TooLarge {
            max: 4096,
            object: Some(reader())
        })]
    );
    // each loss is an event too, whatever else its input returned
    let (_, ev) = drain(&mut c);
    assert_eq!(
        ev,
        [
            Event::TooLarge {
                object: None,
                max: 4096
            },
            Event::Data {
                reader: reader(),
                request: RequestId(10),
                stream: StreamId::RELIABLE,
                data: b"ok".to_vec()
            },
            Event::TooLarge {
                object: Some(reader()),
                max: 4096
            }
        ]
    );
}

#[test]
fn fragments_that_do_not_fit_together_are_errors() {
    let (mut c, now) = connected(no_keepalive(1));
    let whole = {
        let mut v = Vec::new();
        data(10, reader(), b"hello").encode(&mut v, 0).unwrap();
        v
    };
    let cases: Vec<(Vec<u8>, FragmentError)> = vec![
        (
            msg(h(0x01, 0), vec![fragment(whole.clone(), true)]),
            FragmentError::NotReliable(0x01),
        ),
        (
            msg(
                h(0x80, 0),
                vec![
                    fragment(whole[..4].to_vec(), false),
                    data(10, reader(), b"x"),
                ],
            ),
            FragmentError::NotLastInMessage,
        ),
        (
            msg(h(0x80, 1), vec![fragment(whole[..4].to_vec(), false)]),
            FragmentError::Interleaved("x"),
        ),
        (
            msg(h(0x80, 3), vec![fragment(vec![0xEE; 9], true)]),
            FragmentError::Nested,
        ),
    ];
    // 1 starts a submessage that 2 interrupts
    let (m0, e0) = &cases[0];
    assert_eq!(
        c.handle_input(m0, now),
        Err(InputError::Fragment(e0.clone()))
    );
    let (m1, e1) = &cases[1];
    assert_eq!(
        c.handle_input(m1, now),
        Err(InputError::Fragment(e1.clone()))
    );
    c.handle_input(&cases[2].0, now).unwrap();
    let interrupted = c.handle_input(&msg(h(0x80, 2), vec![data(10, reader(), b"y")]), now);
    assert_eq!(
        interrupted,
        Err(InputError::Fragment(FragmentError::Interleaved("DATA")))
    );
    // garbage reassembled
    let r = c.handle_input(&cases[3].0, now);
    assert!(
        matches!(r, Err(InputError::Fragment(FragmentError::Decode(_)))),
        "{r:?}"
    );
    // a FRAGMENT rebuilt from fragments
    let mut nested = Vec::new();
    fragment(whole.clone(), true)
        .encode(&mut nested, 0)
        .unwrap();
    let r = c.handle_input(&msg(h(0x80, 4), vec![fragment(nested, true)]), now);
    assert_eq!(r, Err(InputError::Fragment(FragmentError::Nested)));
    // and a good one still works
    c.handle_input(
        &msg(h(0x80, 5), vec![fragment(whole[..7].to_vec(), false)]),
        now,
    )
    .unwrap();
    c.handle_input(
        &msg(h(0x80, 6), vec![fragment(whole[7..].to_vec(), true)]),
        now,
    )
    .unwrap();
    let (_, ev) = drain(&mut c);
    let got: Vec<_> = ev
        .iter()
        .filter_map(|e| match e {
            Event::Data { data, .. } => Some(data.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(got, [b"x".to_vec(), b"y".to_vec(), b"hello".to_vec()]);
}

#[test]
fn client_input_errors_say_what_is_wrong() {
    let mut cfg = no_keepalive(0x1122_3344);
    cfg.session_id = 0x01;
    let (mut keyed, now) = {
        let now = Instant::now();
        let mut c = Client::new(cfg);
        c.connect(now);
        let sa = msg(
            MessageHeader::with_key(0x01, ClientKey::from(0x1122_3344), StreamId::NONE, 0),
            vec![sub(Payload::StatusAgent(StatusAgent {
                result: ResultStatus::default(),
                agent: AgentRepresentation::default(),
            }))],
        );
        c.handle_input(&sa, now).unwrap();
        (c, now)
    };
    let other_key = msg(
        MessageHeader::with_key(0x01, ClientKey::from(0x5555_6666), StreamId::NONE, 0),
        vec![],
    );
    assert_eq!(
        keyed.handle_input(&other_key, now),
        Err(InputError::WrongClientKey {
            expected: 0x1122_3344,
            got: 0x5555_6666
        })
    );
    let (mut c, now) = connected(no_keepalive(1));
    let cases: Vec<(Vec<u8>, InputError)> = vec![
        (
            msg(MessageHeader::new(0x82, StreamId::NONE, 0), vec![]),
            InputError::WrongSession {
                expected: 0x81,
                got: 0x82,
            },
        ),
        (
            msg(
                h(0x80, 0),
                vec![sub(Payload::Status(Status {
                    request: BaseObjectRequest::new(99, reader()),
                    result: ResultStatus::default(),
                }))],
            ),
            InputError::Unsolicited { what: "STATUS" },
        ),
        (
            STATUS_AGENT.to_vec(),
            InputError::Unsolicited {
                what: "STATUS_AGENT",
            },
        ),
        (
            msg(
                h(0x80, 1),
                vec![Submessage::with_flags(
                    flags::LITTLE_ENDIAN | flags::FORMAT_SAMPLE,
                    Payload::Data(Data {
                        request: BaseObjectRequest::new(10, reader()),
                        data: vec![],
                    }),
                )],
            ),
            InputError::DataFormat(flags::FORMAT_SAMPLE),
        ),
        (
            msg(
                h(0x80, 2),
                vec![data(10, ObjectId::new(1, ObjectKind::Requester), &[0, 10])],
            ),
            InputError::ShortData {
                object: 0x0017,
                len: 2,
                needed: 4,
            },
        ),
        (
            msg(
                h(0x80, 3),
                vec![data(10, ObjectId::new(1, ObjectKind::Replier), &[0; 20])],
            ),
            InputError::ShortData {
                object: 0x0018,
                len: 20,
                needed: 24,
            },
        ),
        (
            msg(
                h(0x80, 4),
                vec![data(10, ObjectId::new(1, ObjectKind::DataWriter), &[])],
            ),
            InputError::Unexpected {
                what: "DATA for an object that does not read",
                stream: 0x80,
            },
        ),
        (
            msg(
                h(0x80, 5),
                vec![sub(Payload::Delete(BaseObjectRequest::new(10, reader())))],
            ),
            InputError::Unexpected {
                what: "DELETE",
                stream: 0x80,
            },
        ),
    ];
    for (m, e) in cases {
        assert_eq!(c.handle_input(&m, now), Err(e.clone()), "{e}");
    }
    assert!(matches!(
        c.handle_input(&[0x81, 0, 0], now),
        Err(InputError::Decode(_))
    ));
    // still working
    c.handle_input(&msg(h(0x80, 6), vec![data(10, reader(), b"z")]), now)
        .unwrap();
    assert!(drain(&mut c)
        .1
        .iter()
        .any(|e| matches!(e, Event::Data { .. })));
    assert_eq!(c.state(), State::Connected);
}

#[test]
fn status_errors_name_the_xrce_code_and_drop_the_definition() {
    let (mut c, now) = connected(no_keepalive(1));
    let p = ObjectId::new(1, ObjectKind::Participant);
    let v = ObjectVariant::Participant {
        representation: Representation::Reference("default_xrce_participant".into()),
        domain_id: 0,
    };
    let req = c.create(p, v, CreationMode::CREATE, now).unwrap();
    assert_eq!(c.objects().len(), 1);
    drain(&mut c);
    let st = msg(
        h(0x80, 0),
        vec![sub(Payload::Status(Status {
            request: BaseObjectRequest::new(req.0, p),
            result: ResultStatus {
                status: StatusCode::ERR_ALREADY_EXISTS,
                implementation_status: 0,
            },
        }))],
    );
    c.handle_input(&st, now).unwrap();
    let (_, ev) = drain(&mut c);
    let Some(Event::Status {
        request,
        object,
        result: Err(e),
    }) = ev.first()
    else {
        panic!("{ev:?}")
    };
    assert_eq!((*request, *object), (req, p));
    assert_eq!(
        e.to_string(),
        "the XRCE agent answered STATUS_ERR_ALREADY_EXISTS (0x82)"
    );
    assert!(c.objects().is_empty());
}

#[test]
fn create_client_is_retried_then_given_up() {
    let t0 = Instant::now();
    let mut c = Client::new(no_keepalive(1));
    c.connect(t0);
    let mut sent = drain(&mut c).0.len();
    let mut t = t0;
    while let Some(d) = c.poll_timeout() {
        t = d;
        c.handle_timeout(t);
        let (out, ev) = drain(&mut c);
        sent += out.len();
        if !ev.is_empty() {
            assert_eq!(
                ev,
                [Event::ConnectFailed(ConnectError::NoAnswer {
                    attempts: 10
                })]
            );
            break;
        }
    }
    assert_eq!(sent, 10);
    assert_eq!(t - t0, Duration::from_secs(10));
    assert_eq!(c.state(), State::Idle);
    // refused
    c.connect(t);
    let mut refused = STATUS_AGENT;
    refused[8] = StatusCode::ERR_INCOMPATIBLE.0;
    c.handle_input(&refused, t).unwrap();
    let e = ConnectError::Refused(StatusCode::ERR_INCOMPATIBLE);
    assert_eq!(drain(&mut c).1, [Event::ConnectFailed(e.clone())]);
    assert!(e.to_string().contains("STATUS_ERR_INCOMPATIBLE"));
}

#[test]
fn commands_need_a_session_matching_kinds_and_room() {
    let now = Instant::now();
    let mut c = Client::new(no_keepalive(1));
    let w = ObjectId::new(1, ObjectKind::DataWriter);
    assert_eq!(
        c.write(w, StreamId::RELIABLE, b"x", now),
        Err(CommandError::NotConnected)
    );
    let mut cfg = no_keepalive(1);
    cfg.streams.max_backlog = 2000;
    let (mut c, now) = connected(cfg);
    assert!(matches!(
        c.write(reader(), StreamId::RELIABLE, b"x", now),
        Err(CommandError::KindMismatch { .. })
    ));
    let r = c.create(
        w,
        ObjectVariant::Participant {
            representation: Representation::Xml(String::new()),
            domain_id: 0,
        },
        CreationMode::REPLACE,
        now,
    );
    assert!(matches!(r, Err(CommandError::KindMismatch { .. })));
    assert_eq!(
        c.write(w, StreamId::BEST_EFFORT, &[0; 600], now),
        Err(CommandError::Queue(QueueError::Stream(
            StreamError::TooLarge {
                stream: 1,
                len: 608,
                max: 504
            }
        )))
    );
    assert!(matches!(
        c.write(w, StreamId::NONE, b"x", now),
        Err(CommandError::Queue(QueueError::BadStream(0)))
    ));
    // the reliable window (16) takes 16 messages; then the backlog fills
    let mut n = 0;
    let err = loop {
        match c.write(w, StreamId::RELIABLE, &[0; 200], now) {
            Ok(_) => n += 1,
            Err(e) => break e,
        }
    };
    assert!(matches!(
        err,
        CommandError::Queue(QueueError::Stream(StreamError::Backlog { .. }))
    ));
    assert_eq!(n, 9);
    drain(&mut c);
    assert!(c.buffered_bytes() < 8 * 1024);
}

#[test]
fn request_ids_count_from_10_and_wrap_past_0xffff_to_10() {
    let (mut c, now) = connected(no_keepalive(1));
    let w = ObjectId::new(1, ObjectKind::DataWriter);
    let first = c.write(w, StreamId::BEST_EFFORT, b"x", now).unwrap();
    assert_eq!(first, RequestId(10));
    let mut last = first;
    for _ in 0..(0xFFFF - 10) {
        last = c.write(w, StreamId::BEST_EFFORT, b"x", now).unwrap();
        while c.poll_transmit().is_some() {}
    }
    assert_eq!(last, RequestId(0xFFFF));
    assert_eq!(
        c.write(w, StreamId::BEST_EFFORT, b"x", now).unwrap(),
        RequestId(10)
    );
}

#[test]
fn keepalive_pings_then_reports_the_agent_lost_and_back() {
    let (mut c, t0) = connected(ClientConfig::new(1));
    c.handle_timeout(t0 + Duration::from_millis(999));
    assert!(drain(&mut c).0.is_empty());
    let mut pings = 0;
    let mut t = t0;
    while c.state() == State::Connected {
        t = c.poll_timeout().unwrap();
        c.handle_timeout(t);
        pings += drain(&mut c).0.len();
    }
    assert_eq!(t - t0, Duration::from_secs(3));
    assert_eq!(pings, 3);
    assert_eq!(drain(&mut c).1, []);
    // an in-session pong: back
    let pong = [
        0x81, 0, 0, 0, 6, 1, 0x1C, 0, 0, 0x0A, 0xFF, 0xFD, 0, 1, 1, 0x0D, b'X', b'R', b'C', b'E',
        1, 0, 1, 0x0F, 0, 1, 0x0D, 0, 1, 0, 0, 0, 0, 0, 0, 0,
    ];
    c.handle_input(&pong, t).unwrap();
    let (_, ev) = drain(&mut c);
    assert!(ev.contains(&Event::AgentBack), "{ev:?}");
    assert_eq!(c.state(), State::Connected);
    // a pong of an agent that forgot the session
    let mut forgot = pong;
    forgot[13] = 0;
    c.ping(t);
    c.handle_input(&forgot, t).unwrap();
    let (_, ev) = drain(&mut c);
    assert!(
        ev.contains(&Event::AgentLost(LostReason::SessionUnknown)),
        "{ev:?}"
    );
    // ...which, pinged again while lost, is not taken for the agent back
    c.ping(t);
    c.handle_input(&forgot, t).unwrap();
    let (_, ev) = drain(&mut c);
    assert!(!ev.contains(&Event::AgentBack), "{ev:?}");
    assert_eq!(c.state(), State::Lost);
}

/// A session whose application stopped reading (a full subscription) is
/// not reported lost for the silence: it is its own, not the agent's; from
/// when it reads again, silence counts afresh.
#[test]
fn a_deaf_session_is_not_reported_lost_for_its_own_silence() {
    let (mut c, t0) = connected(ClientConfig::new(1));
    c.set_deaf(true, t0);
    let mut t = t0;
    while t - t0 < Duration::from_secs(60) {
        t = c.poll_timeout().unwrap();
        c.handle_timeout(t);
        assert!(drain(&mut c).1.is_empty(), "at {:?}", t - t0);
    }
    assert_eq!(c.state(), State::Connected);
    c.set_deaf(false, t);
    // the agent still silent: lost 3 s after listening again
    let resumed = t;
    while c.state() == State::Connected {
        t = c.poll_timeout().unwrap();
        c.handle_timeout(t);
        drain(&mut c);
    }
    assert_eq!(t - resumed, Duration::from_secs(3));
}

/// At its most sessions the agent makes room for a new client by deleting
/// the session silent the longest, if silent for `evict_after` (a client
/// that died without DELETE); until then it refuses, and says so. With a
/// `client_timeout`, silent sessions go by themselves.
#[test]
fn dead_clients_make_room_and_time_out() {
    let now = Instant::now();
    let cfg = AgentConfig {
        max_clients: 2,
        evict_after: Duration::from_secs(60),
        client_timeout: Some(Duration::from_secs(300)),
        ..AgentConfig::default()
    };
    let mut a: Agent<u32> = Agent::new(cfg, now, UNIX_EPOCH + Duration::from_secs(1_700_000_000));
    let events = |a: &mut Agent<u32>| std::iter::from_fn(|| a.poll_event()).collect::<Vec<_>>();
    let at = |s: u64| now + Duration::from_secs(s);
    a.handle_input(1, &create_client(1, 0x81), at(0)).unwrap();
    a.handle_input(2, &create_client(2, 0x81), at(0)).unwrap();
    while a.poll_transmit().is_some() {}
    events(&mut a);
    // full, and nobody silent for a minute yet
    a.handle_input(3, &create_client(3, 0x81), at(10)).unwrap();
    assert_eq!(status_agent_code(&mut a), StatusCode::ERR_RESOURCES);
    assert_eq!(
        events(&mut a),
        [AgentEvent::ClientRefused {
            client: ClientKey::from(3),
            status: StatusCode::ERR_RESOURCES
        }]
    );
    // client 1 speaks again (its session created anew, objects kept)
    a.handle_input(1, &create_client(1, 0x81), at(30)).unwrap();
    while a.poll_transmit().is_some() {}
    events(&mut a);
    // client 3 again: client 2 has been silent longest, 70 s
    a.handle_input(3, &create_client(3, 0x81), at(70)).unwrap();
    assert_eq!(status_agent_code(&mut a), StatusCode::OK);
    let ev = events(&mut a);
    assert_eq!(
        ev[..2],
        [
            AgentEvent::ClientExpired {
                client: ClientKey::from(2),
                silent: Duration::from_secs(70),
                for_client: Some(ClientKey::from(3)),
            },
            AgentEvent::ClientDeleted {
                client: ClientKey::from(2)
            },
        ]
    );
    let mut keys: Vec<u32> = a.clients().map(u32::from).collect();
    keys.sort();
    assert_eq!(keys, [1, 3]);
    // past the timeout, silent sessions go by themselves
    assert_eq!(a.poll_timeout(), Some(at(330)));
    a.handle_timeout(at(330));
    let ev = events(&mut a);
    assert!(
        ev.contains(&AgentEvent::ClientExpired {
            client: ClientKey::from(1),
            silent: Duration::from_secs(300),
            for_client: None,
        }),
        "{ev:?}"
    );
    let keys: Vec<u32> = a.clients().map(u32::from).collect();
    assert_eq!(keys, [3]);
}

fn create_client(key: u32, session_id: u8) -> Vec<u8> {
    let rep = ClientRepresentation::new(ClientKey::from(key), session_id, 508);
    msg(
        MessageHeader::create_client(session_id, ClientKey::from(key)),
        vec![sub(Payload::CreateClient(rep))],
    )
}

fn agent() -> (Agent<u32>, Instant) {
    let now = Instant::now();
    (
        Agent::new(
            AgentConfig::default(),
            now,
            UNIX_EPOCH + Duration::from_secs(1_700_000_000),
        ),
        now,
    )
}

fn status_agent_code(a: &mut Agent<u32>) -> StatusCode {
    let (_, m) = a.poll_transmit().unwrap();
    let m = Message::decode(&m).unwrap();
    let Payload::StatusAgent(s) = &m.submessages[0].payload else {
        panic!()
    };
    s.result.status
}

#[test]
fn create_client_is_checked_by_the_agent() {
    let (mut a, now) = agent();
    a.handle_input(1, &create_client(0xCCCC_DDDD, 0x81), now)
        .unwrap();
    // the captured STATUS_AGENT (udp_xml_reliable_pubsub #2)
    assert_eq!(a.poll_transmit(), Some((1, STATUS_AGENT.to_vec())));
    let bad = |f: &dyn Fn(&mut ClientRepresentation)| {
        let mut rep = ClientRepresentation::new(ClientKey::from(5), 0x81, 508);
        f(&mut rep);
        msg(
            MessageHeader::new(0x80, StreamId::NONE, 0),
            vec![sub(Payload::CreateClient(rep))],
        )
    };
    type Change<'a> = &'a dyn Fn(&mut ClientRepresentation);
    let cases: [(Change, StatusCode); 4] = [
        (
            &|r| r.client_key = ClientKey::from(0),
            StatusCode::ERR_INVALID_DATA,
        ),
        (&|r| r.cookie = *b"XRCF", StatusCode::ERR_INVALID_DATA),
        (&|r| r.version = [2, 0], StatusCode::ERR_INCOMPATIBLE),
        (&|r| r.mtu = 20, StatusCode::ERR_INVALID_DATA),
    ];
    for (i, (f, code)) in cases.into_iter().enumerate() {
        a.handle_input(10 + i as u32, &bad(f), now).unwrap();
        assert_eq!(status_agent_code(&mut a), code);
    }
    assert_eq!(a.clients().count(), 1);
    // the session with the key in its header
    a.handle_input(2, &create_client(0x2222_0002, 0x01), now)
        .unwrap();
    let (_, m) = a.poll_transmit().unwrap();
    assert_eq!(m[..12], [0x01, 0, 0, 0, 0x22, 0x22, 0, 2, 4, 1, 11, 0]);
}

#[test]
fn sessions_are_kept_replaced_or_dropped_as_the_eprosima_agent_does() {
    let (mut a, now) = agent();
    let events = |a: &mut Agent<u32>| {
        while a.poll_transmit().is_some() {}
        std::iter::from_fn(|| a.poll_event()).collect::<Vec<_>>()
    };
    let key = ClientKey::from(0xAB);
    a.handle_input(1, &create_client(0xAB, 0x81), now).unwrap();
    a.handle_input(1, &create_client(0xAB, 0x81), now).unwrap();
    a.handle_input(1, &create_client(0xAB, 0x82), now).unwrap();
    let created = |session_id, kept| AgentEvent::ClientCreated {
        client: key,
        session_id,
        properties: None,
        kept,
    };
    assert_eq!(
        events(&mut a),
        [
            created(0x81, false),
            created(0x81, true),
            AgentEvent::ClientDeleted { client: key },
            created(0x82, false)
        ]
    );
    // another key from the same address takes it over
    a.handle_input(1, &create_client(0xCD, 0x81), now).unwrap();
    let ev = events(&mut a);
    assert_eq!(ev[0], AgentEvent::ClientDeleted { client: key });
    assert_eq!(a.clients().collect::<Vec<_>>(), [ClientKey::from(0xCD)]);
}

#[test]
fn the_agent_limits_clients_and_streams() {
    let now = Instant::now();
    let cfg = AgentConfig {
        max_clients: 8,
        max_streams: 2,
        ..AgentConfig::default()
    };
    let mut a: Agent<u32> = Agent::new(cfg, now, UNIX_EPOCH);
    let mut codes = Vec::new();
    for k in 1..=20u32 {
        a.handle_input(k, &create_client(k, 0x81), now).unwrap();
        codes.push(status_agent_code(&mut a));
    }
    assert_eq!(codes.iter().filter(|c| **c == StatusCode::OK).count(), 8);
    assert_eq!(codes[8..], [StatusCode::ERR_RESOURCES; 12]);
    // client 1 uses reliable streams 0x80, 0x81, then 0x82 is one too many
    let write = |s: u8| {
        msg(
            h(s, 0),
            vec![sub(Payload::WriteData(Data {
                request: BaseObjectRequest::new(10, ObjectId::new(1, ObjectKind::DataWriter)),
                data: vec![1],
            }))],
        )
    };
    a.handle_input(1, &write(0x80), now).unwrap();
    a.handle_input(1, &write(0x81), now).unwrap();
    assert_eq!(
        a.handle_input(1, &write(0x82), now),
        Err(InputError::TooManyStreams(0x82))
    );
    // reliable messages far ahead are not held
    for seq in (100u16..30_000).step_by(11) {
        let m = msg(
            h(0x80, seq),
            vec![sub(Payload::WriteData(Data {
                request: BaseObjectRequest::new(10, ObjectId::new(1, ObjectKind::DataWriter)),
                data: vec![0; 1000],
            }))],
        );
        a.handle_input(1, &m, now).unwrap();
        while a.poll_transmit().is_some() {}
    }
    assert!(a.buffered_bytes() < 1024, "{}", a.buffered_bytes());
}

#[test]
fn unknown_clients_get_errors_pings_and_their_delete_confirmed() {
    let (mut a, now) = agent();
    let stray = msg(h(0x80, 0), vec![sub(Payload::Reset)]);
    assert_eq!(
        a.handle_input(9, &stray, now),
        Err(InputError::UnknownClient { session_id: 0x81 })
    );
    // DELETE of the session after an agent restart: STATUS OK anyway (§6)
    let delete = [0x81, 0, 0, 0, 3, 1, 4, 0, 0, 2, 0xFF, 0xFE];
    a.handle_input(9, &delete, now).unwrap();
    assert_eq!(
        a.poll_transmit(),
        Some((9, vec![0x81, 0, 0, 0, 5, 1, 6, 0, 0, 2, 0xFF, 0xFE, 0, 0]))
    );
    // pings outside and inside a session: udp_ping #2 and #6
    let ping = |id: u8| vec![id, 0, 0, 0, 2, 1, 8, 0, 0, 0x0A, 0xFF, 0xFD, 2, 0, 0, 0];
    let pong = |id: u8, in_session: u8| {
        vec![
            id, 0, 0, 0, 6, 1, 0x1C, 0, 0, 0x0A, 0xFF, 0xFD, 0, in_session, 1, 0x0D, b'X', b'R',
            b'C', b'E', 1, 0, 1, 0x0F, 0, 1, 0x0D, 0, 1, 0, 0, 0, 0, 0, 0, 0,
        ]
    };
    a.handle_input(9, &ping(0x80), now).unwrap();
    assert_eq!(a.poll_transmit(), Some((9, pong(0x80, 0))));
    a.handle_input(9, &create_client(0xAAAA_BBBB, 0x81), now)
        .unwrap();
    a.poll_transmit().unwrap();
    a.handle_input(9, &ping(0x81), now).unwrap();
    assert_eq!(a.poll_transmit(), Some((9, pong(0x81, 1))));
    // an unknown client's ping inside "its" session is answered as unknown
    a.handle_input(10, &ping(0x81), now).unwrap();
    assert_eq!(a.poll_transmit(), Some((10, pong(0x81, 0))));
}

#[test]
fn the_agent_stamps_timestamp_replies_from_its_anchor() {
    let (mut a, now) = agent();
    a.handle_input(1, &create_client(1, 0x81), now).unwrap();
    a.poll_transmit().unwrap();
    let ts = [
        0x81, 0, 0, 0, 0x0E, 1, 8, 0, 0x98, 0xD8, 0x02, 0x6B, 0xBD, 0xA4, 0x14, 0x32,
    ];
    a.handle_input(1, &ts, now + Duration::from_millis(1500))
        .unwrap();
    let (_, m) = a.poll_transmit().unwrap();
    let secs = (1_700_000_001u32).to_le_bytes();
    let nanos = 500_000_000u32.to_le_bytes();
    let mut want = vec![0x81, 0, 0, 0, 0x0F, 1, 24, 0];
    for _ in 0..2 {
        want.extend_from_slice(&secs);
        want.extend_from_slice(&nanos);
    }
    want.extend_from_slice(&ts[8..]);
    assert_eq!(m, want);
}

#[test]
fn host_commands_fail_with_reasons() {
    let (mut a, now) = agent();
    let req = BaseObjectRequest::new(10, reader());
    assert_eq!(
        a.reply_status(
            ClientKey::from(3),
            req,
            StatusCode::OK,
            StreamId::RELIABLE,
            now
        ),
        Err(AgentCommandError::UnknownClient(3))
    );
    a.handle_input(1, &create_client(3, 0x81), now).unwrap();
    assert!(matches!(
        a.send_data(
            ClientKey::from(3),
            req,
            StreamId::BEST_EFFORT,
            &[0; 600],
            now
        ),
        Err(AgentCommandError::Queue(QueueError::Stream(
            StreamError::TooLarge { .. }
        )))
    ));
    a.send_data(ClientKey::from(3), req, StreamId::RELIABLE, &[0; 600], now)
        .unwrap();
}

#[test]
fn replaced_objects_keep_their_place_and_writes_in_flight_are_capped() {
    let mut cfg = no_keepalive(1);
    cfg.max_pending = 100;
    let (mut c, now) = connected(cfg);
    let p = ObjectId::new(1, ObjectKind::Participant);
    let t = ObjectId::new(1, ObjectKind::Topic);
    let xml = |s: &str| Representation::Xml(s.into());
    let part = |s: &str| ObjectVariant::Participant {
        representation: xml(s),
        domain_id: 0,
    };
    c.create(p, part("a"), CreationMode::REPLACE, now).unwrap();
    c.create(
        t,
        ObjectVariant::Topic {
            representation: xml("t"),
            participant_id: p,
        },
        CreationMode::REPLACE,
        now,
    )
    .unwrap();
    c.create(p, part("b"), CreationMode::REPLACE, now).unwrap();
    let ids: Vec<_> = c.objects().iter().map(|d| d.id).collect();
    assert_eq!(
        ids,
        [p, t],
        "the participant is still created before its topic"
    );
    assert_eq!(c.objects()[0].variant, part("b"));
    // tiny reliable writes: at most max_pending wait for their ACKNACK
    let w = ObjectId::new(1, ObjectKind::DataWriter);
    let mut n = 0;
    let err = loop {
        match c.write(w, StreamId::RELIABLE, &[n as u8], now) {
            Ok(_) => n += 1,
            Err(e) => break e,
        }
        drain(&mut c);
    };
    assert_eq!(n, 100);
    assert_eq!(err, CommandError::TooManyRequests(100));
}

fn heartbeat(first: u16, last: u16) -> Submessage {
    sub(Payload::Heartbeat(Heartbeat {
        first_unacked: first,
        last_unacked: last,
        stream_id: StreamId::RELIABLE,
    }))
}

/// A HEARTBEAT whose first is after last + 1 (audit 22 F7: first 500, last
/// 3) is an error and changes nothing; taken as "500 is the first the
/// sender holds", it skipped every DATA below 500 without a word.
#[test]
fn a_heartbeat_with_first_after_last_is_refused_and_skips_nothing() {
    let (mut c, now) = connected(no_keepalive(1));
    c.handle_input(&msg(h(0x80, 0), vec![data(10, reader(), b"hello")]), now)
        .unwrap();
    assert_eq!(drain(&mut c).1.len(), 1);
    assert_eq!(
        c.handle_input(&msg(h(0x00, 0), vec![heartbeat(500, 3)]), now),
        Err(InputError::BadHeartbeat {
            stream: 0x80,
            first: 500,
            last: 3
        })
    );
    assert_eq!(
        InputError::BadHeartbeat {
            stream: 0x80,
            first: 500,
            last: 3
        }
        .to_string(),
        "malformed XRCE HEARTBEAT on stream 0x80: first 500 is after last 3 + 1 (ignored)"
    );
    for seq in 1u16..=5 {
        c.handle_input(&msg(h(0x80, seq), vec![data(10, reader(), b"late")]), now)
            .unwrap();
    }
    let (_, ev) = drain(&mut c);
    assert_eq!(ev.len(), 5, "{ev:?}");
    // a well-formed one across the wrap-around still moves the window
    c.handle_input(&msg(h(0x00, 0), vec![heartbeat(9, 0xFFF0)]), now)
        .unwrap_err();
    c.handle_input(&msg(h(0x00, 0), vec![heartbeat(0xFFF0, 9)]), now)
        .unwrap();
    c.handle_input(&msg(h(0x00, 0), vec![heartbeat(8, 9)]), now)
        .unwrap();
    c.handle_input(&msg(h(0x80, 8), vec![data(10, reader(), b"after")]), now)
        .unwrap();
    let (_, ev) = drain(&mut c);
    assert_eq!(ev.len(), 1, "{ev:?}");

    // the agent's input streams are the same: no ACKNACK from 500 on
    let (mut a, now) = agent();
    a.handle_input(1, &create_client(1, 0x81), now).unwrap();
    while a.poll_transmit().is_some() {}
    assert_eq!(
        a.handle_input(1, &msg(h(0x00, 0), vec![heartbeat(500, 3)]), now),
        Err(InputError::BadHeartbeat {
            stream: 0x80,
            first: 500,
            last: 3
        })
    );
    assert_eq!(a.poll_transmit(), None);
    a.handle_input(1, &msg(h(0x00, 0), vec![heartbeat(0, 3)]), now)
        .unwrap();
    let (_, m) = a.poll_transmit().expect("an ACKNACK");
    let m = Message::decode(&m).unwrap();
    let Payload::AckNack(ack) = &m.submessages[0].payload else {
        panic!("{m:?}")
    };
    assert_eq!(ack.first_unacked, 0);
}

/// An agent whose host does not keep input positions notes no client for
/// them (audit 23: every client key ever seen stayed in that set, about 10
/// bytes each, since nothing took the notes without `--state`); one whose
/// host keeps them reports what moved.
#[test]
fn positions_are_noted_only_for_a_host_that_keeps_them() {
    for keeps in [false, true] {
        let (mut a, now) = agent();
        if keeps {
            a.hold_acks_until_saved();
        }
        for key in 1..=50u32 {
            a.handle_input(key, &create_client(key, 0x81), now).unwrap();
            // a reliable message moves its input position
            let m = msg(h(0x80, 0), vec![data(10, reader(), b"x")]);
            let _ = a.handle_input(key, &m, now);
        }
        let moved = a.take_moved_positions();
        if keeps {
            assert_eq!(moved.len(), 50, "{moved:?}");
        } else {
            assert!(moved.is_empty(), "{moved:?}");
        }
    }
}
