//! Two participants after an asymmetric lease expiry: one process is
//! stopped (`SIGSTOP`) for longer than the lease it announced, so its peer
//! drops it, while it never loses its peer (whose lease is longer). When it
//! resumes, it reads what waited in its sockets before its timers run, as
//! a resumed process does. Reliable data must flow again both ways, with
//! nothing delivered twice. Deterministic: seeded faults, simulated time.

use std::time::Duration;

use courier_wire::dds::{Domain, Event, ReaderId, WriterId};
use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History, Reliability};
use courier_wire::rtps::participant::{
    self, guid_prefix, Change, Config, EndpointConfig, LostReason,
};
use courier_wire::sim::{self, Faults};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

fn config(i: usize, lease: Duration) -> Config {
    let mut c = Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9);
    c.lease_duration = lease;
    c
}

fn writer_qos() -> EndpointQos {
    let mut q = EndpointQos::writer_default();
    q.history = History::KeepLast(64);
    q
}

fn reader_qos() -> EndpointQos {
    let mut q = EndpointQos::reader_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepLast(64);
    q
}

fn sample(n: u32) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&n.to_le_bytes());
    b
}

fn received(net: &Net, i: usize, r: ReaderId) -> Vec<u32> {
    net.hosts[i]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if *reader == r => {
                Some(u32::from_le_bytes(sample.data()[4..8].try_into().unwrap()))
            }
            _ => None,
        })
        .collect()
}

fn lost(net: &Net, i: usize) -> usize {
    net.hosts[i]
        .events
        .iter()
        .filter(|e| {
            matches!(
                e,
                Event::Discovery(participant::Event::ParticipantLost {
                    reason: LostReason::LeaseExpired,
                    ..
                })
            )
        })
        .count()
}

struct Pair {
    net: Net,
    /// Writer on 0, reader on 1.
    w0: WriterId,
    r1: ReaderId,
    /// Writer on 1, reader on 0.
    w1: WriterId,
    r0: ReaderId,
}

/// Node 0 announces a 1 s lease, node 1 a 30 s one; a reliable volatile
/// topic each way, matched, with sample 1 delivered both ways.
fn pair(seed: u64, loss: u32) -> Pair {
    let mut net = Net::new(seed, Faults::lossy(loss));
    for (i, lease) in [(0, 1), (1, 30)] {
        let d = Domain::new(config(i, Duration::from_secs(lease)), net.now(), net.wall());
        net.add(d);
    }
    let now = net.now();
    let w0 = net
        .node(0)
        .create_writer(EndpointConfig::writer("ab", "T").qos(writer_qos()), now)
        .unwrap();
    let r0 = net
        .node(0)
        .create_reader(EndpointConfig::reader("ba", "T").qos(reader_qos()), now)
        .unwrap();
    let w1 = net
        .node(1)
        .create_writer(EndpointConfig::writer("ba", "T").qos(writer_qos()), now)
        .unwrap();
    let r1 = net
        .node(1)
        .create_reader(EndpointConfig::reader("ab", "T").qos(reader_qos()), now)
        .unwrap();
    let mut p = Pair {
        net,
        w0,
        r1,
        w1,
        r0,
    };
    let matched = |n: &Net| {
        [(0, r0), (1, r1)].iter().all(|&(i, r)| {
            n.has(
                i,
                |e| matches!(e, Event::ReaderMatched { reader, .. } if *reader == r),
            )
        }) && [(0, w0), (1, w1)].iter().all(|&(i, w)| {
            n.has(
                i,
                |e| matches!(e, Event::WriterMatched { writer, .. } if *writer == w),
            )
        })
    };
    assert!(
        p.net.run_until(Duration::from_secs(10), matched),
        "seed {seed}: no match"
    );
    p.write_both(1);
    assert!(
        p.net
            .run_until(Duration::from_secs(10), |n| received(n, 1, r1) == [1]
                && received(n, 0, r0) == [1]),
        "seed {seed}: sample 1"
    );
    // everything acknowledged: nobody heartbeats any more
    p.net.run_for(Duration::from_secs(2));
    p
}

impl Pair {
    fn write_both(&mut self, n: u32) {
        let now = self.net.now();
        self.net
            .node(0)
            .write(self.w0, Change::alive_owned(sample(n)), now)
            .unwrap();
        self.net
            .node(1)
            .write(self.w1, Change::alive_owned(sample(n)), now)
            .unwrap();
        self.net.pump();
    }
}

/// Node 0 is stopped for `stopped`, then resumed; afterwards samples
/// 100.. are written both ways every 200 ms until both readers have one
/// (or 20 s passed).
fn stop_and_resume(seed: u64, loss: u32, stopped: Duration) -> Pair {
    let mut p = pair(seed, loss);
    p.net.freeze(0);
    p.net.run_for(stopped);
    p.net.thaw(0);
    let (r0, r1) = (p.r0, p.r1);
    for n in 100..200 {
        p.write_both(n);
        let both = |net: &Net| {
            received(net, 0, r0).iter().any(|v| *v >= 100)
                && received(net, 1, r1).iter().any(|v| *v >= 100)
        };
        if p.net.run_until(Duration::from_millis(200), both) {
            // a little longer: what is still on its way arrives, and
            // nothing comes twice
            p.net.run_for(Duration::from_secs(2));
            break;
        }
    }
    p
}

#[test]
fn reliable_data_flows_both_ways_after_the_peer_with_the_short_lease_was_stopped() {
    for seed in 1..=30u64 {
        let loss = [0, 10, 20][seed as usize % 3];
        let p = stop_and_resume(seed, loss, Duration::from_secs(3));
        // the premise: node 1 dropped node 0; node 0 never dropped node 1
        // (with a 1 s lease and loss it may lose it more than once)
        assert!(lost(&p.net, 1) >= 1, "seed {seed}: node 1 lost node 0");
        assert_eq!(lost(&p.net, 0), 0, "seed {seed}: node 0 never lost node 1");
        for (i, r) in [(0, p.r0), (1, p.r1)] {
            let got = received(&p.net, i, r);
            assert!(
                got.iter().any(|v| *v >= 100),
                "seed {seed} loss {loss}: node {i} got nothing after the stop: {got:?}"
            );
            assert_eq!(
                got.iter().filter(|v| **v == 1).count(),
                1,
                "seed {seed}: node {i} got sample 1 twice: {got:?}"
            );
            let mut after: Vec<u32> = got.iter().copied().filter(|v| *v >= 100).collect();
            let n = after.len();
            after.dedup();
            assert_eq!(
                after.len(),
                n,
                "seed {seed}: node {i} got a sample twice: {got:?}"
            );
            assert!(
                after.windows(2).all(|w| w[0] < w[1]),
                "seed {seed}: node {i} out of order: {got:?}"
            );
        }
    }
}

/// A stop shorter than the stopped one's lease: nobody is dropped, and
/// data flows on (what waited is read at once).
#[test]
fn a_stop_shorter_than_the_lease_loses_nothing() {
    for seed in 1..=3u64 {
        let p = stop_and_resume(seed, 0, Duration::from_millis(800));
        assert_eq!(lost(&p.net, 1) + lost(&p.net, 0), 0, "seed {seed}");
        for (i, r) in [(0, p.r0), (1, p.r1)] {
            let got = received(&p.net, i, r);
            assert!(
                got.iter().any(|v| *v >= 100),
                "seed {seed}: node {i}: {got:?}"
            );
        }
    }
}
