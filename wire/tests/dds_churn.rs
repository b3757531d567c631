//! A long-lived domain participant while others come and go: each newcomer
//! makes writers and readers (on a shared topic and on topics of its own),
//! writes, and then leaves, cleanly or by crashing (its lease expires).
//! Once they are all gone, the long-lived one must hold nothing of them:
//! the state that grows with every participant, endpoint, topic or key
//! that ever existed is a leak in a process that runs for weeks.
//! Deterministic: seeded network, simulated time.

use std::time::Duration;

use courier_wire::dds::{Domain, Event, PatternId, ReaderId};
use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, Reliability};
use courier_wire::rtps::participant::{guid_prefix, Change, Config, EndpointConfig, KeyHash};
use courier_wire::sim::{self, Faults};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

/// Participant `i` (index `i`, a GUID prefix of its own), with a short
/// lease so that crashed ones expire soon.
fn config(i: usize) -> Config {
    let id = [0xc4, (i >> 8) as u8, i as u8, 1, 2, 3, 4, 5, 6, 7];
    let mut c = Config::udpv4(0, i as u32, guid_prefix(id), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 1);
    c.lease_duration = Duration::from_secs(2);
    c
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn reliable(mut q: EndpointQos) -> EndpointQos {
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q
}

fn sample(n: u32) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&n.to_le_bytes());
    b
}

/// A newcomer joins, lives `life`, and leaves: cleanly (`close`) or not
/// (it stops: its lease expires).
fn leave(net: &mut Net, h: usize, cleanly: bool) {
    if cleanly {
        let now = net.now();
        net.node(h).close(now);
        net.run_for(ms(20));
    }
    net.hosts[h].up = false;
}

/// The pattern readers host `i` was told of, made and deleted.
fn pattern_readers(net: &Net, i: usize, p: PatternId) -> (Vec<(ReaderId, String)>, Vec<ReaderId>) {
    let mut made = Vec::new();
    let mut deleted = Vec::new();
    for e in &net.hosts[i].events {
        match e {
            Event::PatternMatched {
                pattern,
                reader,
                topic,
                replaces,
                ..
            } if *pattern == p => {
                made.push((*reader, topic.clone()));
                deleted.extend(*replaces);
            }
            Event::PatternUnmatched {
                pattern, reader, ..
            } if *pattern == p => deleted.push(*reader),
            _ => {}
        }
    }
    (made, deleted)
}

/// 40 participants come and go past a long-lived one that reads a shared
/// topic and records every topic with a pattern subscription ("*", as
/// `courier spy` and `courier record` do). Afterwards it knows no remote
/// participant or endpoint, and the pattern holds a reader only for the
/// topic a participant that stayed still publishes: each other one was
/// deleted once the last publication of its topic was gone. Before, the
/// pattern kept a reader for every topic ever published, each announced
/// to every participant that joined later.
#[test]
fn participants_that_come_and_go_leave_no_trace() {
    let mut net = Net::new(17, Faults::lossy(5));
    let now = net.now();
    let mut d = Domain::new(config(0), now, net.wall());
    let shared = EndpointConfig::reader("shared", "T").qos(reliable(EndpointQos::reader_default()));
    d.create_reader(shared, now).unwrap();
    let p = d.create_pattern("*", "*", EndpointQos::reader_default(), now);
    net.add(d);
    // one that stays, with a topic of its own
    let now = net.now();
    let mut d = Domain::new(config(1), now, net.wall());
    d.create_writer(EndpointConfig::writer("kept", "T"), now)
        .unwrap();
    net.add(d);
    for i in 2..42usize {
        let now = net.now();
        let mut d = Domain::new(config(i), now, net.wall());
        let topic = if i % 2 == 0 {
            "shared".to_string()
        } else {
            format!("own/{i}")
        };
        let w = d
            .create_writer(EndpointConfig::writer(&topic, "T"), now)
            .unwrap();
        d.create_reader(EndpointConfig::reader(&format!("in/{i}"), "T"), now)
            .unwrap();
        let h = net.add(d);
        net.run_for(ms(300));
        let now = net.now();
        net.node(h)
            .write(w, Change::alive_owned(sample(i as u32)), now)
            .unwrap();
        net.run_for(ms(100));
        leave(&mut net, h, i % 3 != 0);
    }
    // the crashed ones' leases run out
    net.run_for(Duration::from_secs(5));
    let d = &net.hosts[0].node;
    let remote: Vec<_> = d
        .participant()
        .participants()
        .map(|p| p.guid_prefix)
        .collect();
    assert_eq!(remote, [config(1).guid_prefix], "only the one that stayed");
    let pubs: Vec<&str> = d
        .participant()
        .publications()
        .map(|e| e.topic_name.as_str())
        .collect();
    assert_eq!(pubs, ["kept"]);
    assert_eq!(d.participant().subscriptions().count(), 0);
    let (made, deleted) = pattern_readers(&net, 0, p);
    let mut live: Vec<&str> = made
        .iter()
        .filter(|(r, _)| !deleted.contains(r))
        .map(|(_, t)| t.as_str())
        .collect();
    live.sort_unstable();
    assert_eq!(live, ["kept"], "a reader for the topic still published");
    assert!(made.len() >= 21, "{} pattern readers made", made.len());
    for r in &deleted {
        assert!(d.local_endpoint(r.guid()).is_none(), "deleted for good");
    }
    // a topic published again gets a reader again
    let now = net.now();
    let mut d = Domain::new(config(50), now, net.wall());
    let w = d
        .create_writer(EndpointConfig::writer("own/3", "T"), now)
        .unwrap();
    let h = net.add(d);
    let again = |net: &Net| {
        let (made, deleted) = pattern_readers(net, 0, p);
        made.into_iter()
            .find(|(r, t)| t == "own/3" && !deleted.contains(r))
            .map(|(r, _)| r)
    };
    assert!(net.run_until(Duration::from_secs(5), |n| again(n).is_some()));
    net.run_for(ms(300));
    let now = net.now();
    net.node(h)
        .write(w, Change::alive_owned(sample(99)), now)
        .unwrap();
    let r = again(&net).unwrap();
    let sample_99 = sample(99);
    assert!(
        net.run_until(Duration::from_secs(5), |n| n.has(0, |e| matches!(
            e,
            Event::Sample { reader, sample } if *reader == r && sample.data() == sample_99
        )))
    );
}

/// A keyed reader with a deadline while writers come and go, each with a
/// key of its own, and crash: once their participants' leases have
/// expired, the reader misses no deadline for their keys any more (DDS:
/// an instance without writers is not alive). Before, each crashed
/// writer's key missed its deadline every period for ever: a reader that
/// had seen 1000 such keys got 1000 events a period, and kept them all.
#[test]
fn deadlines_stop_for_keys_whose_writers_are_lost() {
    let mut net = Net::new(23, Faults::lossy(5));
    let mut rq = reliable(EndpointQos::reader_default());
    rq.deadline = RtpsDuration::from_std(ms(100));
    let now = net.now();
    let mut d = Domain::new(config(0), now, net.wall());
    let r = d
        .create_reader(EndpointConfig::reader("K", "T").keyed(true).qos(rq), now)
        .unwrap();
    net.add(d);
    let misses = |net: &Net| {
        net.hosts[0]
            .events
            .iter()
            .filter(|e| matches!(e, Event::DeadlineMissed { reader, .. } if *reader == r))
            .count()
    };
    let mut wq = reliable(EndpointQos::writer_default());
    wq.deadline = RtpsDuration::from_std(ms(100));
    for i in 1..=10usize {
        let now = net.now();
        let mut d = Domain::new(config(i), now, net.wall());
        let w = d
            .create_writer(
                EndpointConfig::writer("K", "T").keyed(true).qos(wq.clone()),
                now,
            )
            .unwrap();
        let h = net.add(d);
        assert!(
            net.run_until(Duration::from_secs(5), |n| n.has(h, |e| matches!(
                e,
                Event::WriterMatched { writer, .. } if *writer == w
            )))
        );
        let now = net.now();
        let mut key = [0; 16];
        key[0] = i as u8;
        let change = Change::alive_owned(sample(i as u32)).with_key_hash(KeyHash(key));
        net.node(h).write(w, change, now).unwrap();
        net.run_for(ms(200));
        leave(&mut net, h, false);
    }
    assert!(misses(&net) > 0, "crashed writers' keys missed deadlines");
    // leases (2 s) expire
    net.run_for(Duration::from_secs(3));
    let before = misses(&net);
    net.run_for(Duration::from_secs(2));
    assert_eq!(misses(&net), before, "no key left to miss a deadline");
}
