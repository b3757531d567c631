//! The simulated network's stream links, with a node that only records
//! what happens to it: bytes arrive whole and in order whatever the
//! faults, cut and joined across writes, late; EOF comes after the last
//! byte; refused connects, back-pressure, holds, crashes and the test's
//! own ends; and one node using datagrams and streams on one clock.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use courier_wire::sim::{Faults, Net, Node, Reads, StreamFaults, StreamId, StreamOp};

#[derive(Debug, Clone, PartialEq, Eq)]
enum Ev {
    Accepted(StreamId, String),
    Connected(u64, Option<StreamId>),
    Data(StreamId, Vec<u8>),
    Eof(StreamId),
    Datagram(String, Vec<u8>),
}

/// Listens at its address if `listen`; does what the test queues in
/// `ops`; reads unless `reading` is false; reports everything.
struct Rec {
    addr: String,
    listen: bool,
    reading: bool,
    ops: VecDeque<StreamOp<String>>,
    datagrams: VecDeque<(String, Vec<u8>)>,
    events: VecDeque<Ev>,
}

impl Rec {
    fn new(addr: &str, listen: bool) -> Rec {
        Rec {
            addr: addr.into(),
            listen,
            reading: true,
            ops: VecDeque::new(),
            datagrams: VecDeque::new(),
            events: VecDeque::new(),
        }
    }
}

impl Node for Rec {
    type Addr = String;
    type Event = Ev;
    fn address(&self) -> String {
        self.addr.clone()
    }
    fn poll_event(&mut self) -> Option<Ev> {
        self.events.pop_front()
    }
    fn owns(&self, to: &String) -> bool {
        *to == self.addr
    }
    fn handle_datagram(&mut self, from: String, bytes: &[u8], _now: Instant) {
        self.events.push_back(Ev::Datagram(from, bytes.to_vec()));
    }
    fn poll_transmit(&mut self) -> Option<(String, Vec<u8>)> {
        self.datagrams.pop_front()
    }
    fn listens(&self, at: &String) -> bool {
        self.listen && *at == self.addr
    }
    fn handle_accept(&mut self, stream: StreamId, from: String, _now: Instant) {
        self.events.push_back(Ev::Accepted(stream, from));
    }
    fn handle_connect(&mut self, token: u64, stream: Option<StreamId>, _now: Instant) {
        self.events.push_back(Ev::Connected(token, stream));
    }
    fn handle_stream(&mut self, stream: StreamId, bytes: &[u8], _now: Instant) {
        self.events.push_back(Ev::Data(stream, bytes.to_vec()));
    }
    fn handle_eof(&mut self, stream: StreamId, _now: Instant) {
        self.events.push_back(Ev::Eof(stream));
    }
    fn reads_stream(&self, _stream: StreamId) -> bool {
        self.reading
    }
    fn poll_stream(&mut self) -> Option<StreamOp<String>> {
        self.ops.pop_front()
    }
}

const QUIET: Duration = Duration::from_secs(60);

/// A client (host 0) connected to a server (host 1): the net and both ends.
fn pair(seed: u64, faults: StreamFaults) -> (Net<Rec>, StreamId, StreamId) {
    let mut net = Net::new(seed, Faults::none());
    net.stream_faults = faults;
    net.add(Rec::new("client", false));
    net.add(Rec::new("server", true));
    net.node(0).ops.push_back(StreamOp::Connect {
        to: "server".into(),
        token: 7,
    });
    assert!(net.run_until_quiet(QUIET));
    let c = match net.take_events(0).as_slice() {
        [Ev::Connected(7, Some(c))] => *c,
        other => panic!("{other:?}"),
    };
    let s = match net.take_events(1).as_slice() {
        [Ev::Accepted(s, from)] if from == "client" => *s,
        other => panic!("{other:?}"),
    };
    assert_eq!(c.peer(), s);
    (net, c, s)
}

/// The pieces read, in these events (on any stream).
fn data(events: &[Ev]) -> Vec<Vec<u8>> {
    events
        .iter()
        .filter_map(|e| match e {
            Ev::Data(_, b) => Some(b.clone()),
            _ => None,
        })
        .collect()
}

/// The pieces host `i` read (on any stream).
fn pieces(net: &mut Net<Rec>, i: usize) -> Vec<Vec<u8>> {
    data(&net.take_events(i))
}

/// `n` writes of 1 to 300 bytes, each byte its position in the stream.
fn writes(seed: u64, n: usize) -> Vec<Vec<u8>> {
    let mut x = seed | 1;
    let mut at = 0u32;
    (0..n)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let len = 1 + (x % 300) as usize;
            (0..len)
                .map(|_| {
                    at += 1;
                    (at % 251) as u8
                })
                .collect()
        })
        .collect()
}

#[test]
fn bytes_arrive_whole_and_in_order_cut_and_joined_across_writes() {
    let (mut split, mut joined) = (0, 0);
    for seed in 1..=20 {
        let (mut net, c, s) = pair(seed, StreamFaults::rough(64));
        let ws = writes(seed, 40);
        // Both ways at once, each write in its own pump.
        for w in &ws {
            net.node(0).ops.push_back(StreamOp::Write {
                stream: c,
                bytes: w.clone(),
            });
            net.node(1).ops.push_back(StreamOp::Write {
                stream: s,
                bytes: w.clone(),
            });
            net.pump();
        }
        assert!(net.run_until_quiet(QUIET));
        let sent: Vec<u8> = ws.concat();
        for host in [0, 1] {
            let got = pieces(&mut net, host);
            assert_eq!(got.concat(), sent, "seed {seed}, host {host}");
            // Where the reads' boundaries fall relative to the writes'.
            let bounds: Vec<usize> = ws
                .iter()
                .scan(0, |at, w| {
                    *at += w.len();
                    Some(*at)
                })
                .collect();
            let mut at = 0;
            for p in &got {
                let (start, end) = (at, at + p.len());
                at = end;
                // A read ending inside a write cut it.
                split += usize::from(!bounds.contains(&end));
                // A read with a write boundary strictly inside joined two.
                joined += usize::from(bounds.iter().any(|b| *b > start && *b < end));
            }
            assert!(got.iter().all(|p| p.len() <= 64), "reads of at most 64");
        }
        assert_eq!(net.unread(c) + net.unread(s), 0);
    }
    assert!(split > 100, "writes were cut: {split}");
    assert!(joined > 100, "writes were joined: {joined}");
}

#[test]
fn faults_are_deterministic_per_seed() {
    let run = |seed| {
        let (mut net, c, _) = pair(seed, StreamFaults::rough(50));
        for w in writes(3, 20) {
            net.write(c, &w);
        }
        assert!(net.run_until_quiet(QUIET));
        let sizes: Vec<usize> = pieces(&mut net, 1).iter().map(Vec::len).collect();
        (sizes, net.elapsed())
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5).0, run(6).0);
}

#[test]
fn perfect_streams_hand_over_writes_whole_at_once() {
    let (mut net, c, _) = pair(1, StreamFaults::none());
    let t = net.elapsed();
    net.write(c, b"abc");
    net.write(c, b"defg");
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(pieces(&mut net, 1), vec![b"abcdefg".to_vec()], "joined");
    assert_eq!(net.elapsed(), t, "no time passed");
    net.stream_faults.reads = Reads::Chunks(3);
    net.write(c, b"0123456");
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(
        pieces(&mut net, 1),
        vec![b"012".to_vec(), b"345".to_vec(), b"6".to_vec()]
    );
}

#[test]
fn segments_take_their_delay_and_never_overtake() {
    let mut f = StreamFaults::rough(10);
    f.min_delay = Duration::from_millis(5);
    f.max_delay = Duration::from_millis(40);
    let (mut net, c, _) = pair(9, f);
    let t = net.elapsed();
    net.write(c, &[1; 100]);
    net.write(c, &[2; 100]);
    assert!(net.run_until_quiet(QUIET));
    let got = pieces(&mut net, 1).concat();
    assert_eq!(got, [[1u8; 100], [2u8; 100]].concat());
    let took = net.elapsed() - t;
    assert!(took >= Duration::from_millis(5), "{took:?}");
    assert!(took <= Duration::from_millis(40), "{took:?}");
}

#[test]
fn eof_comes_after_the_last_byte_and_later_writes_go_nowhere() {
    for seed in 1..=10 {
        let (mut net, c, s) = pair(seed, StreamFaults::rough(16));
        net.write(c, &[7; 200]);
        net.node(0).ops.push_back(StreamOp::Close { stream: c });
        net.pump();
        // Written after the close: dropped.
        net.node(0).ops.push_back(StreamOp::Write {
            stream: c,
            bytes: vec![9; 10],
        });
        net.pump();
        assert!(net.run_until_quiet(QUIET));
        let ev = net.take_events(1);
        let last = ev.iter().rposition(|e| matches!(e, Ev::Data(..)));
        assert_eq!(ev.last(), Some(&Ev::Eof(s)), "seed {seed}: {ev:?}");
        assert_eq!(last, Some(ev.len() - 2), "nothing after EOF");
        assert_eq!(data(&ev).concat(), vec![7; 200]);
        // The closed end reads nothing more.
        net.write(s, b"late");
        assert!(net.run_until_quiet(QUIET));
        assert!(pieces(&mut net, 0).is_empty());
        assert_eq!(net.unread(s), 0, "dropped, not waiting");
    }
}

#[test]
fn a_connect_to_nobody_is_refused() {
    let mut net: Net<Rec> = Net::new(1, Faults::none());
    net.add(Rec::new("client", false));
    net.add(Rec::new("closed", false));
    net.node(0).ops.push_back(StreamOp::Connect {
        to: "closed".into(),
        token: 3,
    });
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(net.take_events(0), vec![Ev::Connected(3, None)]);
    assert!(net.take_events(1).is_empty());
}

#[test]
fn a_node_that_does_not_read_leaves_the_bytes_in_the_network() {
    let (mut net, c, _) = pair(4, StreamFaults::rough(32));
    net.node(1).reading = false;
    net.write(c, &[1; 500]);
    net.close(c);
    assert!(net.run_until_quiet(QUIET), "quiet: nobody will read");
    net.run_for(Duration::from_millis(50));
    assert!(net.take_events(1).is_empty(), "neither bytes nor EOF");
    assert_eq!(net.unread(c), 500);
    assert_eq!(net.pending(c), vec![1; 500]);
    net.node(1).reading = true;
    assert!(net.run_until_quiet(QUIET));
    let ev = net.take_events(1);
    assert!(matches!(ev.last(), Some(Ev::Eof(_))), "{ev:?}");
    assert_eq!(net.unread(c), 0);
}

#[test]
fn held_bytes_wait_and_push_hands_over_exactly_what_is_asked() {
    let (mut net, c, _) = pair(2, StreamFaults::rough(8));
    net.hold(c, true);
    net.write(c, b"0123456789");
    assert!(net.run_until_quiet(QUIET));
    net.run_for(Duration::from_millis(50));
    assert!(pieces(&mut net, 1).is_empty());
    assert_eq!(net.push(c, 4), 4);
    assert_eq!(pieces(&mut net, 1).concat(), b"0123");
    assert_eq!(net.pending(c), b"456789");
    net.hold(c, false);
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(pieces(&mut net, 1).concat(), b"456789");
}

#[test]
fn a_crash_resets_the_connections_of_the_dead_host() {
    let (mut net, c, s) = pair(3, StreamFaults::none());
    net.hold(c, true);
    net.write(c, b"never read");
    net.write(s, b"never read either");
    net.crash(0);
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(net.take_events(1), vec![Ev::Eof(s)], "EOF, and no bytes");
    assert!(net.take_events(0).is_empty(), "the dead read nothing");
    assert_eq!(net.unread(c) + net.unread(s), 0);
}

#[test]
fn the_test_can_be_either_end() {
    let mut net: Net<Rec> = Net::new(8, Faults::none());
    net.stream_faults = StreamFaults::rough(5);
    net.add(Rec::new("server", true));
    net.add(Rec::new("client", false));
    // The test connects to the server...
    let mine = net.connect_raw("tester".into(), &"server".into()).unwrap();
    assert!(
        matches!(&net.take_events(0)[..], [Ev::Accepted(s, f)] if *s == mine.peer() && f == "tester")
    );
    net.write(mine, b"hello server");
    net.write(mine.peer(), b"hello test");
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(pieces(&mut net, 0).concat(), b"hello server");
    assert_eq!(net.read(mine), b"hello test");
    assert!(!net.is_eof(mine));
    net.close(mine.peer());
    assert!(net.run_until_quiet(QUIET));
    assert!(net.is_eof(mine));
    assert_eq!(net.owner(mine), None);
    assert_eq!(net.owner(mine.peer()), Some(0));
    assert!(net.connect_raw("tester".into(), &"nobody".into()).is_none());
    // ... and listens for the client.
    net.listen_raw("scripted".into());
    net.node(1).ops.push_back(StreamOp::Connect {
        to: "scripted".into(),
        token: 1,
    });
    assert!(net.run_until_quiet(QUIET));
    let [(theirs, from)] = &net.take_accepted()[..] else {
        panic!()
    };
    assert_eq!(from, "client");
    assert_eq!(
        net.take_events(1),
        vec![Ev::Connected(1, Some(theirs.peer()))]
    );
    net.write(theirs.peer(), b"to the script");
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(net.read(*theirs), b"to the script");
    // ... or both.
    let a = net.connect_raw("a".into(), &"scripted".into()).unwrap();
    let [(b, from)] = &net.take_accepted()[..] else {
        panic!()
    };
    assert_eq!((b.peer(), from.as_str()), (a, "a"));
    net.write(a, b"to myself");
    assert!(net.run_until_quiet(QUIET));
    assert_eq!(net.read(*b), b"to myself");
}

#[test]
fn datagrams_and_streams_share_one_clock() {
    let (mut net, c, _) = pair(6, StreamFaults::rough(100));
    net.tapping = true;
    net.node(0)
        .datagrams
        .push_back(("server".into(), b"dgram".to_vec()));
    net.write(c, b"stream");
    net.pump();
    assert!(net.run_until_quiet(QUIET));
    let ev = net.take_events(1);
    assert!(ev.contains(&Ev::Datagram("client".into(), b"dgram".to_vec())));
    assert_eq!(data(&ev).concat(), b"stream");
    assert_eq!(net.tap.len(), 1);
    assert_eq!(net.stream_tap, vec![(c, b"stream".to_vec())]);
    assert!(
        net.elapsed() >= Duration::from_millis(1),
        "the datagram took 1 ms"
    );
}
