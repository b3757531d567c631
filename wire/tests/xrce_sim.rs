//! The XRCE client and agent machines talking on the shared simulated
//! network (seeded loss, duplication and reordering, simulated time): a
//! publisher client writes through the agent to a subscriber client, the
//! agent's host (this file) relaying every written sample to every reader
//! as a DDS domain would.

use std::collections::VecDeque;
use std::time::{Duration, SystemTime};

use courier_wire::sim::{self, Faults};
use courier_wire::xrce::sim::{Peer, PeerEvent};
use courier_wire::xrce::{
    Agent, AgentCommandError, AgentConfig, AgentEvent, BaseObjectRequest, Client, ClientConfig,
    ClientKey, CreationMode, DeliveryControl, Event, Keepalive, LostReason, Message, ObjectId,
    ObjectKind, ObjectVariant, QueueError, ReadData, Representation, State, StatusCode,
    StreamConfig, StreamError, StreamId, SubmessageId,
};

type Net = sim::Net<Peer<u16>>;

const AGENT: u16 = 1;
const R: StreamId = StreamId::RELIABLE;
const BE: StreamId = StreamId::BEST_EFFORT;

fn oid(kind: ObjectKind) -> ObjectId {
    ObjectId::new(1, kind)
}

/// The agent's host: answers every CREATE and DELETE with OK and sends
/// every sample written to every reader that is reading.
#[derive(Default)]
struct Host {
    reads: Vec<(ClientKey, ReadData)>,
    /// Samples waiting for a reader or for room in the agent's stream.
    queue: VecDeque<Vec<u8>>,
    out: VecDeque<(ClientKey, BaseObjectRequest, StreamId, Vec<u8>)>,
    writes_seen: Vec<Vec<u8>>,
}

impl Host {
    fn serve(&mut self, net: &mut Net, agent: usize) {
        let now = net.now();
        for e in net.take_events(agent) {
            let PeerEvent::Agent(e) = e else { continue };
            let a = net.node(agent).as_agent().unwrap();
            match e {
                AgentEvent::Create {
                    client,
                    request,
                    reply_stream,
                    ..
                }
                | AgentEvent::Delete {
                    client,
                    request,
                    reply_stream,
                } => a
                    .reply_status(client, request, StatusCode::OK, reply_stream, now)
                    .unwrap(),
                AgentEvent::Read { client, read } => {
                    self.reads.retain(|(c, r)| {
                        (*c, r.request.object_id) != (client, read.request.object_id)
                    });
                    self.reads.push((client, read));
                }
                AgentEvent::Write { data, .. } => {
                    self.writes_seen.push(data.clone());
                    self.queue.push_back(data);
                }
                AgentEvent::ClientDeleted { client } => self.reads.retain(|(c, _)| *c != client),
                _ => {}
            }
        }
        if !self.reads.is_empty() {
            while let Some(d) = self.queue.pop_front() {
                for (c, r) in &self.reads {
                    self.out
                        .push_back((*c, r.request, r.preferred_stream_id, d.clone()));
                }
            }
        }
        let a = net.node(agent).as_agent().unwrap();
        while let Some((c, req, stream, d)) = self.out.pop_front() {
            match a.send_data(c, req, stream, &d, now) {
                Ok(()) => {}
                Err(AgentCommandError::Queue(QueueError::Stream(StreamError::Backlog {
                    ..
                }))) => {
                    self.out.push_front((c, req, stream, d));
                    break;
                }
                Err(e) => panic!("{e}"),
            }
        }
    }
}

struct World {
    net: Net,
    host: Host,
    agent: usize,
    publisher: usize,
    subscriber: usize,
}

fn client_config(key: u32, session_id: u8) -> ClientConfig {
    ClientConfig {
        session_id,
        streams: streams(StreamConfig::client()),
        keepalive: Some(Keepalive {
            interval: Duration::from_secs(1),
            timeout: Duration::from_secs(3),
        }),
        ..ClientConfig::new(key)
    }
}

fn agent_config() -> AgentConfig {
    let mut c = AgentConfig::default();
    c.streams = streams(c.streams);
    c.streams.max_backlog = 64 * 1024;
    c
}

thread_local! {
    /// Courier's delayed acknowledgement on both sides (else eProsima's:
    /// an ACKNACK per message).
    static DELAYED_ACKS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn streams(c: StreamConfig) -> StreamConfig {
    if DELAYED_ACKS.with(|d| d.get()) {
        c.delayed_acks()
    } else {
        c
    }
}

fn world(seed: u64, faults: Faults, session_id: u8) -> World {
    let mut net = Net::new(seed, faults);
    let agent = net.add(Peer::agent(
        AGENT,
        Agent::new(agent_config(), net.now(), SystemTime::UNIX_EPOCH),
    ));
    let publisher = net.add(Peer::client(
        10,
        AGENT,
        Client::new(client_config(0xAAAA_0001, session_id)),
    ));
    let subscriber = net.add(Peer::client(
        11,
        AGENT,
        Client::new(client_config(0xBBBB_0002, session_id)),
    ));
    World {
        net,
        host: Host::default(),
        agent,
        publisher,
        subscriber,
    }
}

impl World {
    fn client(&mut self, i: usize) -> &mut Client {
        self.net.node(i).as_client().unwrap()
    }

    fn step(&mut self) {
        self.net.step();
        self.host.serve(&mut self.net, self.agent);
    }

    fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&mut Self) -> bool) -> bool {
        let end = self.net.elapsed() + limit;
        while self.net.elapsed() < end {
            if done(self) {
                return true;
            }
            self.step();
        }
        done(self)
    }

    fn has(&self, i: usize, f: impl Fn(&Event) -> bool) -> bool {
        self.net
            .has(i, |e| matches!(e, PeerEvent::Client(e) if f(e)))
    }

    fn count(&self, i: usize, f: impl Fn(&Event) -> bool) -> usize {
        self.net.hosts[i]
            .events
            .iter()
            .filter(|e| matches!(e, PeerEvent::Client(e) if f(e)))
            .count()
    }

    /// Connects both clients and creates their entities; the subscriber
    /// reads on `data_stream`.
    fn setup(&mut self, data_stream: StreamId) {
        for i in [self.publisher, self.subscriber] {
            let now = self.net.now();
            self.client(i).connect(now);
        }
        let (p, s) = (self.publisher, self.subscriber);
        assert!(self.run_until(Duration::from_secs(30), |w| {
            w.has(p, |e| matches!(e, Event::Connected { .. }))
                && w.has(s, |e| matches!(e, Event::Connected { .. }))
        }));
        let now = self.net.now();
        create_entities(self.client(p), false, now);
        create_entities(self.client(s), true, now);
        assert!(self.run_until(Duration::from_secs(30), |w| {
            w.count(p, is_ok_status) == 4 && w.count(s, is_ok_status) == 4
        }));
        let unlimited = Some(DeliveryControl {
            max_samples: 0xFFFF,
            ..Default::default()
        });
        let now = self.net.now();
        self.client(s)
            .read(oid(ObjectKind::DataReader), R, data_stream, unlimited, now)
            .unwrap();
        assert!(self.run_until(Duration::from_secs(30), |w| !w.host.reads.is_empty()));
    }

    fn received(&self) -> Vec<Vec<u8>> {
        self.net.hosts[self.subscriber]
            .events
            .iter()
            .filter_map(|e| match e {
                PeerEvent::Client(Event::Data { data, .. }) => Some(data.clone()),
                _ => None,
            })
            .collect()
    }
}

fn is_ok_status(e: &Event) -> bool {
    matches!(e, Event::Status { result: Ok(_), .. })
}

fn create_entities(c: &mut Client, reader: bool, now: std::time::Instant) {
    let xml = |s: &str| Representation::Xml(s.into());
    let p = oid(ObjectKind::Participant);
    let m = CreationMode::REPLACE;
    c.create(
        p,
        ObjectVariant::Participant {
            representation: xml("<p/>"),
            domain_id: 0,
        },
        m,
        now,
    )
    .unwrap();
    c.create(
        oid(ObjectKind::Topic),
        ObjectVariant::Topic {
            representation: xml("<t/>"),
            participant_id: p,
        },
        m,
        now,
    )
    .unwrap();
    if reader {
        let s = oid(ObjectKind::Subscriber);
        c.create(
            s,
            ObjectVariant::Subscriber {
                representation: xml(""),
                participant_id: p,
            },
            m,
            now,
        )
        .unwrap();
        c.create(
            oid(ObjectKind::DataReader),
            ObjectVariant::DataReader {
                representation: xml("<r/>"),
                subscriber_id: s,
            },
            m,
            now,
        )
        .unwrap();
    } else {
        let s = oid(ObjectKind::Publisher);
        c.create(
            s,
            ObjectVariant::Publisher {
                representation: xml(""),
                participant_id: p,
            },
            m,
            now,
        )
        .unwrap();
        c.create(
            oid(ObjectKind::DataWriter),
            ObjectVariant::DataWriter {
                representation: xml("<w/>"),
                publisher_id: s,
            },
            m,
            now,
        )
        .unwrap();
    }
}

/// Sample `i`, `len` bytes long (at least 4): the index, then a pattern.
fn sample(i: u32, len: usize) -> Vec<u8> {
    let mut v = i.to_le_bytes().to_vec();
    v.extend((4..len).map(|k| (k as u32 ^ i) as u8));
    v
}

fn index(d: &[u8]) -> u32 {
    u32::from_le_bytes(d[..4].try_into().unwrap())
}

/// Writes `n` samples of `len` bytes reliably, a few per millisecond as
/// the stream accepts them; returns once the subscriber has all of them.
fn reliable_transfer(seed: u64, n: u32, len: usize, session_id: u8) {
    let mut w = world(seed, Faults::lossy(30), session_id);
    w.setup(R);
    let mut next = 0u32;
    let writer = oid(ObjectKind::DataWriter);
    let (p, s) = (w.publisher, w.subscriber);
    let done = w.run_until(Duration::from_secs(600), |w| {
        while next < n {
            let now = w.net.now();
            match w.client(p).write(writer, R, &sample(next, len), now) {
                Ok(_) => next += 1,
                Err(_) => break, // backlog full: later
            }
        }
        w.received().len() >= n as usize
    });
    let got = w.received();
    assert!(
        done,
        "seed {seed}: {} of {n} samples after 600 s",
        got.len()
    );
    // complete, in order, no duplicates, intact: subscriber side ...
    let want: Vec<Vec<u8>> = (0..n).map(|i| sample(i, len)).collect();
    assert_eq!(got.len(), want.len(), "seed {seed}");
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(
            g == w,
            "seed {seed}: sample {i} is sample {} ({} bytes)",
            index(g),
            g.len()
        );
    }
    // ... and on the way in (client to agent)
    assert_eq!(w.host.writes_seen, want, "seed {seed}: what the agent got");
    // every write was acknowledged to the publisher
    assert!(w.run_until(Duration::from_secs(30), |w| {
        w.count(p, |e| matches!(e, Event::WriteAcked(_))) == n as usize
    }));
    let _ = s;
}

#[test]
fn reliable_both_directions_complete_and_in_order_at_30_percent_loss() {
    for seed in 1..=5 {
        reliable_transfer(seed, 150, 40, 0x81);
    }
}

#[test]
fn delayed_acks_reliable_complete_and_in_order_at_30_percent_loss() {
    DELAYED_ACKS.with(|d| d.set(true));
    for seed in 31..=35 {
        reliable_transfer(seed, 150, 40, 0x81);
    }
    reliable_transfer(36, 6, 20_000, 0x81);
}

/// ACKNACKs sent while 128 samples go through reliably, two written per
/// millisecond (the simulator's latency is at least 1 ms a hop, so a
/// one-at-a-time ping-pong would be slower than the delay), without loss.
fn acknacks_for_a_steady_stream() -> usize {
    let n = 128u32;
    let mut w = world(41, Faults::none(), 0x81);
    w.setup(R);
    w.net.tapping = true;
    let writer = oid(ObjectKind::DataWriter);
    let p = w.publisher;
    for i in (0..n).step_by(2) {
        for k in i..i + 2 {
            let now = w.net.now();
            w.client(p).write(writer, R, &sample(k, 16), now).unwrap();
        }
        w.step();
    }
    assert!(w.run_until(Duration::from_secs(5), |w| {
        w.received().len() == n as usize
            && w.count(p, |e| matches!(e, Event::WriteAcked(_))) == n as usize
    }));
    assert_eq!(
        w.received(),
        (0..n).map(|i| sample(i, 16)).collect::<Vec<_>>()
    );
    w.net
        .tap
        .iter()
        .filter_map(|pk| Message::decode(&pk.payload).ok())
        .flat_map(|m| m.submessages)
        .filter(|s| s.id() == SubmessageId::AckNack)
        .count()
}

#[test]
fn delayed_acks_cover_several_messages_with_one_acknack() {
    let every = acknacks_for_a_steady_stream();
    DELAYED_ACKS.with(|d| d.set(true));
    let delayed = acknacks_for_a_steady_stream();
    // eProsima's way: one per message and hop (the client packs two
    // samples a message, the agent sends one a message): 64 + 128
    assert!(every >= 192, "{every} ACKNACKs without delay");
    assert!(
        delayed * 2 <= every,
        "{delayed} ACKNACKs with delayed acknowledgement, {every} without"
    );
}

#[test]
fn reliable_with_the_client_key_in_every_header_at_30_percent_loss() {
    for seed in 11..=12 {
        reliable_transfer(seed, 60, 40, 0x01);
    }
}

#[test]
fn fragmented_20000_byte_samples_both_directions_at_30_percent_loss() {
    for seed in 21..=23 {
        reliable_transfer(seed, 6, 20_000, 0x81);
    }
}

#[test]
fn best_effort_delivers_only_in_order_and_without_duplicates() {
    for seed in 31..=34 {
        let mut w = world(seed, Faults::lossy(30), 0x81);
        w.setup(BE);
        let writer = oid(ObjectKind::DataWriter);
        let p = w.publisher;
        for i in 0..300u32 {
            let now = w.net.now();
            w.client(p).write(writer, BE, &sample(i, 16), now).unwrap();
            w.step();
            w.step();
        }
        w.run_until(Duration::from_secs(2), |_| false);
        let got: Vec<u32> = w.received().iter().map(|d| index(d)).collect();
        assert!(
            got.windows(2).all(|p| p[0] < p[1]),
            "seed {seed}: out of order or duplicated: {got:?}"
        );
        // 30 % loss on each of two hops, and what is overtaken is dropped
        assert!(
            got.len() > 30 && got.len() < 200,
            "seed {seed}: {}",
            got.len()
        );
    }
    // without faults, everything arrives
    let mut w = world(35, Faults::none(), 0x81);
    w.setup(BE);
    for i in 0..100u32 {
        let now = w.net.now();
        w.client(w.publisher)
            .write(oid(ObjectKind::DataWriter), BE, &sample(i, 16), now)
            .unwrap();
        w.step();
    }
    w.run_until(Duration::from_secs(1), |_| false);
    let got: Vec<u32> = w.received().iter().map(|d| index(d)).collect();
    assert_eq!(got, (0..100).collect::<Vec<_>>());
}

#[test]
fn agent_restart_is_detected_and_the_session_recreated_without_losing_writes() {
    let mut w = world(41, Faults::lossy(10), 0x81);
    w.setup(R);
    let (p, s, a) = (w.publisher, w.subscriber, w.agent);
    let writer = oid(ObjectKind::DataWriter);
    for i in 0..20u32 {
        let now = w.net.now();
        w.client(p).write(writer, R, &sample(i, 8), now).unwrap();
    }
    assert!(w.run_until(Duration::from_secs(30), |w| w.received().len() == 20));
    // the agent dies; the publisher goes on writing
    w.net.hosts[a].up = false;
    for i in 20..40u32 {
        let now = w.net.now();
        w.client(p).write(writer, R, &sample(i, 8), now).unwrap();
        w.step();
    }
    assert!(w.run_until(Duration::from_secs(10), |w| {
        w.has(p, |e| *e == Event::AgentLost(LostReason::Silent))
            && w.has(s, |e| *e == Event::AgentLost(LostReason::Silent))
    }));
    assert_eq!(w.client(p).state(), State::Lost);
    // it comes back empty: a new process
    let now = w.net.now();
    *w.net.node(a) = Peer::agent(
        AGENT,
        Agent::new(agent_config(), now, SystemTime::UNIX_EPOCH),
    );
    w.net.hosts[a].up = true;
    w.host = Host::default();
    // the pings are answered, but outside any session
    assert!(w.run_until(Duration::from_secs(10), |w| {
        w.has(p, |e| {
            matches!(
                e,
                Event::Pong {
                    in_session: false,
                    ..
                }
            )
        })
    }));
    // what the SDK will do: create the session again, then the objects
    for i in [p, s] {
        w.net.take_events(i);
        let now = w.net.now();
        w.client(i).connect(now);
    }
    assert!(w.run_until(Duration::from_secs(30), |w| {
        w.has(p, |e| matches!(e, Event::Connected { .. }))
            && w.has(s, |e| matches!(e, Event::Connected { .. }))
    }));
    for i in [s, p] {
        let now = w.net.now();
        let ids = w.client(i).recreate_objects(now).unwrap();
        assert_eq!(ids.len(), 4);
    }
    assert!(
        w.run_until(Duration::from_secs(60), |w| {
            let got: Vec<u32> = w.received().iter().map(|d| index(d)).collect();
            (20..40).all(|i| got.contains(&i))
        }),
        "writes made while the agent was down arrive after the session is created again"
    );
    assert_eq!(w.count(p, is_ok_status), 4);
    assert_eq!(w.count(s, is_ok_status), 4);
}

/// A client that gives up while connecting (its application dropped the
/// connect) deletes the session the agent may have made already: the agent
/// does not keep it for a client that is gone.
#[test]
fn a_client_that_gives_up_connecting_leaves_no_session_at_the_agent() {
    let mut made_before_the_delete = 0;
    for seed in 0..12 {
        let mut w = world(seed, Faults::lossy(20), 0x81);
        let (p, a) = (w.publisher, w.agent);
        let now = w.net.now();
        w.client(p).connect(now);
        // even seeds: give up at once; odd ones: once the agent made the
        // session, before its answer arrives
        if seed % 2 == 1 {
            w.run_until(Duration::from_secs(2), |w| match &w.net.hosts[a].node {
                Peer::Agent { agent, .. } => agent.clients().count() > 0,
                _ => false,
            });
        }
        if !matches!(w.client(p).state(), State::Connecting { .. }) {
            continue; // connected already: the ordinary delete
        }
        made_before_the_delete += w.net.node(a).as_agent().unwrap().clients().count();
        let now = w.net.now();
        w.client(p).disconnect(now).unwrap();
        w.run_until(Duration::from_secs(30), |_| false);
        let left = w.net.node(a).as_agent().unwrap().clients().count();
        assert_eq!(left, 0, "seed {seed}: the agent kept the session");
    }
    assert!(
        made_before_the_delete > 0,
        "no seed tested a session the agent had made"
    );
}
