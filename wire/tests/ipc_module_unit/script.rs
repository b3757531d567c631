//! Central's side, written by hand: the frames a test sends the module
//! (from the C demo capture's handshake, and built), and the scripted
//! network the module runs on.

use std::time::{Duration, Instant};

use courier_wire::format::{encode_formatter, parse};
use courier_wire::ipc::frame::{ClassId, Deframer, Frame, Header, MsgClass};
use courier_wire::ipc::module::{Connection, Event, ModuleConfig};
use courier_wire::ipc::Writer;
use courier_wire::sim::{Faults, IpcEvent, ModuleNode, Net, StreamFaults, StreamId};

const MODULE2: &str = include_str!("../fixtures/ipc-module/demo-central-module2.txt");

/// The seeds each scripted test runs with.
pub const SEEDS: std::ops::RangeInclusive<u64> = 1..=6;

const CENTRAL: &str = "central:1381";

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// Central's frames of module2's handshake, up to and including the waitMsg reply.
pub fn handshake_stream() -> Vec<u8> {
    let mut out = Vec::new();
    for l in MODULE2.lines().filter(|l| l.starts_with("C ")) {
        let h = l.split_whitespace().nth(1).unwrap();
        out.extend(hex(h));
        if l.contains("x_ipc_waitMsg REPLY") {
            break;
        }
    }
    out
}

pub fn frame(
    intent: i32,
    class: MsgClass,
    dispatch: i32,
    msg_ref: i32,
    cd: &[u8],
    data: &[u8],
) -> Vec<u8> {
    Frame {
        header: Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: 0,
            intent,
            class_id: ClassId::native(class),
            dispatch_ref: dispatch,
            msg_ref,
        },
        class_data: cd.to_vec(),
        data: data.to_vec(),
    }
    .encode()
}

pub fn str_data(s: &str) -> Vec<u8> {
    let mut w = Writer::new();
    w.write_str(s);
    w.into_vec()
}

/// Central's reply to a msgInfo lookup.
pub fn msg_info_reply(
    msg_ref: i32,
    id: i32,
    name: &str,
    class: i32,
    msg_fmt: &str,
    res_fmt: &str,
) -> Vec<u8> {
    let mut w = Writer::new();
    w.write_ptr_flag(true);
    w.write_i32(id);
    w.write_str(name);
    w.write_i32(class);
    let m = parse(msg_fmt).unwrap();
    encode_formatter(Some(&m), &mut w);
    let r = parse(res_fmt).unwrap();
    encode_formatter(Some(&r), &mut w);
    reply_frame(msg_ref, &w.into_vec())
}

/// Central's reply (intent -4) to the query `msg_ref`, carrying `data`.
pub fn reply_frame(msg_ref: i32, data: &[u8]) -> Vec<u8> {
    frame(-4, MsgClass::Unknown, 0, msg_ref, &[], data)
}

/// The message name a msgInfo lookup asks about.
pub fn lookup_name(f: &Frame) -> String {
    let mut r = courier_wire::ipc::Reader::native(&f.data);
    r.read_str().unwrap().to_string()
}

/// A module2 on the network whose central is the test: what the test
/// writes reaches the module in pieces of 1 to 16 bytes, 0 to 3 ms late.
pub struct Scripted {
    pub net: Net<ModuleNode>,
    /// The test's end of the module's connection to central.
    pub central: StreamId,
    deframer: Deframer,
}

impl Scripted {
    /// The module, connected to the test (no handshake yet).
    pub fn new(seed: u64, listen: bool) -> Scripted {
        let mut net = Net::new(seed, Faults::none());
        net.stream_faults = StreamFaults::rough(16);
        net.listen_raw(CENTRAL.into());
        let mut cfg = ModuleConfig::new("module2", "127.1");
        cfg.listen = listen;
        let node = ModuleNode::new(cfg, CENTRAL, 0, net.now());
        net.add(node);
        assert!(net.run_until_quiet(Duration::from_secs(1)));
        let [(central, _)] = net.take_accepted()[..] else {
            panic!("the module did not connect");
        };
        Scripted {
            net,
            central,
            deframer: Deframer::new(u64::MAX),
        }
    }

    /// A module2 after its handshake, everything it sent discarded.
    pub fn connected(seed: u64, listen: bool) -> Scripted {
        let mut s = Scripted::new(seed, listen);
        s.send(&handshake_stream());
        s.frames();
        assert_eq!(s.event(), Some(Event::Connected));
        s
    }

    /// The module machine, for its API.
    pub fn c(&mut self) -> &mut Connection {
        &mut self.net.node(0).conn
    }

    /// Runs the network until nothing moves.
    pub fn run(&mut self) {
        assert!(self.net.run_until_quiet(Duration::from_secs(60)));
    }

    /// The module's next event, if any.
    pub fn event(&mut self) -> Option<Event> {
        self.run();
        let events = &mut self.net.hosts[0].events;
        if events.is_empty() {
            return None;
        }
        match events.remove(0) {
            IpcEvent::Module(e) => Some(e),
            other => panic!("a module reported {other:?}"),
        }
    }
}

impl Central for Scripted {
    /// The test writes `bytes`; the network runs until they are handled.
    fn send(&mut self, bytes: &[u8]) {
        self.net.write(self.central, bytes);
        self.run();
    }

    fn frames(&mut self) -> Vec<Frame> {
        self.run();
        let bytes = self.net.read(self.central);
        let mut input = &bytes[..];
        let mut out = Vec::new();
        while let Some(f) = self.deframer.next(&mut input).unwrap() {
            out.push(f);
        }
        out
    }
}

/// A module connection fed by hand: what the test sends is received at
/// once, whole; every buffer it writes is one frame.
impl Central for Connection {
    fn send(&mut self, bytes: &[u8]) {
        self.receive(bytes, Instant::now());
    }

    fn frames(&mut self) -> Vec<Frame> {
        let mut v = Vec::new();
        while let Some(b) = self.poll_transmit() {
            let h = Header::decode(&b).unwrap();
            v.push(Frame::from_parts(h, &b[28..]).unwrap());
        }
        v
    }
}

/// The test as central: it sends the module bytes and reads its frames.
pub trait Central {
    /// Central writes `bytes` to the module.
    fn send(&mut self, bytes: &[u8]);

    /// The frames the module wrote since last asked.
    fn frames(&mut self) -> Vec<Frame>;

    /// Takes what the module wrote, checks that it starts with the msgInfo
    /// lookup of `name`, and answers it as central would (`id`, `class`,
    /// formats). Returns what the module had written.
    fn answer_lookup(
        &mut self,
        name: &str,
        id: i32,
        class: i32,
        msg_fmt: &str,
        res_fmt: &str,
    ) -> Vec<Frame> {
        let f = self.frames();
        assert_eq!(lookup_name(&f[0]), name);
        self.send(&msg_info_reply(
            f[0].header.msg_ref,
            id,
            name,
            class,
            msg_fmt,
            res_fmt,
        ));
        f
    }

    /// Takes what the module wrote, checks that it starts with the msgInfo
    /// lookup of `name`, and answers as central does for a name it does
    /// not know.
    fn answer_unknown(&mut self, name: &str) {
        let f = self.frames();
        assert_eq!(lookup_name(&f[0]), name);
        self.send(&frame(
            -4,
            MsgClass::Unknown,
            0,
            f[0].header.msg_ref,
            &[],
            &[0],
        ));
    }

    /// Answers the msgInfo lookup of `x_ipc_directMsgQuery` (id 147) that
    /// num_handlers and direct sends start with; returns what follows it.
    fn answer_direct_msg_query_lookup(&mut self) -> Vec<Frame> {
        self.answer_lookup("x_ipc_directMsgQuery", 147, 3, "string", "int");
        self.frames()
    }

    /// Answers the msgInfo lookup a first publish of message9 starts with
    /// (id 106, a broadcast).
    fn answer_message9_lookup(&mut self) {
        let f = self.answer_lookup("message9", 106, 15, "{int, <byte:1>}", "string");
        assert_eq!(f.len(), 1);
    }

    /// Takes the registration a first subscribe writes (the module knows
    /// `x_ipc_registerHandlerMsg` from its handshake) and answers it, as
    /// these tests always have, with that message's msgInfo: a reply to no
    /// query of the module's, which it ignores.
    fn take_registration(&mut self) {
        let f = self.frames();
        self.send(&msg_info_reply(
            f[0].header.msg_ref,
            166,
            "x_ipc_registerHandlerMsg",
            6,
            "{int, string, string}",
            "",
        ));
        self.frames();
    }
}

/// A module2 connection after its handshake, fed by hand, everything it
/// sent discarded.
pub fn by_hand(listen: bool) -> Connection {
    let mut cfg = ModuleConfig::new("module2", "127.1");
    cfg.listen = listen;
    by_hand_with(cfg)
}

/// [`by_hand`] with a configuration of the test's.
pub fn by_hand_with(cfg: ModuleConfig) -> Connection {
    let mut c = Connection::new(cfg, Instant::now());
    c.send(&handshake_stream());
    c.frames();
    assert_eq!(c.poll_event(), Some(Event::Connected));
    c
}
