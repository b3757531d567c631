//! The sans-I/O DDS domain on the shared simulated network: exclusive
//! ownership and its hand-over, lifespan, time-based filter, deadlines,
//! request/reply correlation, pattern subscriptions, confirmed writes,
//! keep-all back-pressure and type mismatches. Deterministic: seeded
//! faults, simulated time.

use std::time::Duration;

use courier_wire::cdr::Version;
use courier_wire::dds::{
    ConfirmFailure, Domain, DropReason, Endpoint, Event, InstanceKeys, QueryFailure, ReaderId,
    ServiceConfig, WriterId,
};
use courier_wire::rtps::discovery::{
    Durability, Duration as RtpsDuration, EndpointQos, History, Reliability,
};
use courier_wire::rtps::participant::{
    guid_prefix, Change, Config, EndpointConfig, KeyHash, WriteError,
};
use courier_wire::sim::{self, Faults};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

fn config(i: usize) -> Config {
    Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9)
}

/// `n` domains on a network with `loss` % loss.
fn new_net(n: usize, seed: u64, loss: u32) -> Net {
    let mut net = Net::new(seed, Faults::lossy(loss));
    for i in 0..n {
        let d = Domain::new(config(i), net.now(), net.wall());
        net.add(d);
    }
    net
}

fn reliable() -> Reliability {
    Reliability::Reliable(RtpsDuration::ZERO)
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn writer_qos() -> EndpointQos {
    let mut q = EndpointQos::writer_default();
    q.history = History::KeepAll;
    q
}

fn reader_qos() -> EndpointQos {
    let mut q = EndpointQos::reader_default();
    q.reliability = reliable();
    q.history = History::KeepAll;
    q
}

/// A CDR_LE sample holding `n`.
/// A reliable writer of `topic` and `ty` on node `i`.
fn writer(net: &mut Net, i: usize, topic: &str, ty: &str) -> WriterId {
    let now = net.now();
    net.node(i)
        .create_writer(EndpointConfig::writer(topic, ty).qos(writer_qos()), now)
        .unwrap()
}

/// A reliable reader of `topic` and `ty` on node `i`.
fn reader(net: &mut Net, i: usize, topic: &str, ty: &str) -> ReaderId {
    let now = net.now();
    net.node(i)
        .create_reader(EndpointConfig::reader(topic, ty).qos(reader_qos()), now)
        .unwrap()
}

fn sample(n: u32) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&n.to_le_bytes());
    b
}

fn value(data: &[u8]) -> u32 {
    u32::from_le_bytes(data[4..8].try_into().unwrap())
}

/// The values reader `r` of host `i` received, in order.
fn received(net: &Net, i: usize, r: ReaderId) -> Vec<u32> {
    net.hosts[i]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if *reader == r => Some(value(sample.data())),
            _ => None,
        })
        .collect()
}

fn matched(net: &Net, i: usize, r: ReaderId, writers: usize) -> bool {
    net.hosts[i]
        .events
        .iter()
        .filter(|e| matches!(e, Event::ReaderMatched { reader, .. } if *reader == r))
        .count()
        >= writers
}

fn writer_matched(net: &Net, i: usize, w: WriterId) -> bool {
    net.has(
        i,
        |e| matches!(e, Event::WriterMatched { writer, .. } if *writer == w),
    )
}

fn write(net: &mut Net, i: usize, w: WriterId, n: u32) {
    let now = net.now();
    net.node(i)
        .write(w, Change::alive_owned(sample(n)), now)
        .unwrap();
}

#[test]
fn exclusive_ownership_goes_to_the_strongest_writer_then_to_the_next_when_it_is_deleted_or_lost() {
    // 0: strong writer (10), 1: weak writer (1), 2: exclusive reader; short
    // leases so that a crashed owner is lost soon
    let mut net = Net::new(5, Faults::lossy(10));
    for i in 0..3 {
        let mut cfg = config(i);
        cfg.lease_duration = Duration::from_secs(1);
        cfg.announce_period = ms(250);
        let d = Domain::new(cfg, net.now(), net.wall());
        net.add(d);
    }
    let now = net.now();
    let mut strong = writer_qos();
    strong.exclusive_ownership = true;
    strong.ownership_strength = 10;
    let mut weak = strong.clone();
    weak.ownership_strength = 1;
    let mut rq = reader_qos();
    rq.exclusive_ownership = true;
    let s = net
        .node(0)
        .create_writer(EndpointConfig::writer("Own", "T").qos(strong.clone()), now)
        .unwrap();
    let w = net
        .node(1)
        .create_writer(EndpointConfig::writer("Own", "T").qos(weak), now)
        .unwrap();
    let r = net
        .node(2)
        .create_reader(EndpointConfig::reader("Own", "T").qos(rq), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 2, r, 2)));
    // the strong one writes first, and owns the instance once its sample
    // is in (a weak sample that comes while the strong one's first is
    // being repaired is taken: the weak writer owns it until then)
    write(&mut net, 0, s, 0);
    assert!(net.run_until(Duration::from_secs(10), |n| received(n, 2, r) == [0]));
    // both write (strong: even values, weak: odd ones); only the strong is taken
    write(&mut net, 1, w, 1);
    net.run_for(ms(20));
    for k in 1..20 {
        write(&mut net, 0, s, 2 * k);
        write(&mut net, 1, w, 2 * k + 1);
        net.run_for(ms(20));
    }
    net.run_for(ms(500));
    let got = received(&net, 2, r);
    assert_eq!(
        got,
        (0..20).map(|k| 2 * k).collect::<Vec<_>>(),
        "only the strong writer's"
    );
    // the strong writer is deleted: the weak one's samples are taken
    let now = net.now();
    assert!(net.node(0).delete_writer(s, now));
    net.run_for(ms(500));
    write(&mut net, 1, w, 1001);
    net.run_for(ms(500));
    assert_eq!(
        received(&net, 2, r).last(),
        Some(&1001),
        "hand-over on deletion"
    );

    // again with a new strong writer, which then crashes: the weak
    // writer's samples are taken once the strong one's lease has ended
    let now = net.now();
    let s2 = net
        .node(0)
        .create_writer(EndpointConfig::writer("Own", "T").qos(strong), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 2, r, 3)));
    net.run_for(ms(200));
    write(&mut net, 0, s2, 2000);
    net.run_for(ms(300));
    assert_eq!(received(&net, 2, r).last(), Some(&2000));
    write(&mut net, 1, w, 2001);
    net.run_for(ms(300));
    assert_eq!(
        received(&net, 2, r).last(),
        Some(&2000),
        "the strong writer still owns it"
    );
    net.hosts[0].up = false;
    let crash = net.now();
    let mut k = 3001;
    while received(&net, 2, r).last() != Some(&(k - 2)) {
        write(&mut net, 1, w, k);
        k += 2;
        net.run_for(ms(100));
        assert!(net.now() - crash < Duration::from_secs(5), "no hand-over");
    }
    let after = net.now() - crash;
    assert!(
        after >= ms(900),
        "taken over only after the lease: {after:?}"
    );
}

/// An owner that goes silent past the reader's deadline loses the
/// instance (DDS 2.2.3.9): the weaker writer's next samples are taken.
/// The strong writer kept it for ever while alive and silent.
#[test]
fn an_exclusive_owner_that_misses_the_deadline_hands_the_instance_over() {
    let mut net = new_net(3, 41, 0);
    let now = net.now();
    let mut strong = writer_qos();
    strong.exclusive_ownership = true;
    strong.ownership_strength = 5;
    strong.deadline = RtpsDuration::from_std(ms(100));
    let mut weak = strong.clone();
    weak.ownership_strength = 1;
    let mut rq = reader_qos();
    rq.exclusive_ownership = true;
    rq.deadline = RtpsDuration::from_std(ms(100));
    let s = net
        .node(0)
        .create_writer(EndpointConfig::writer("Own2", "T").qos(strong), now)
        .unwrap();
    let w = net
        .node(1)
        .create_writer(EndpointConfig::writer("Own2", "T").qos(weak), now)
        .unwrap();
    let r = net
        .node(2)
        .create_reader(EndpointConfig::reader("Own2", "T").qos(rq), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 2, r, 2)));
    // both write every 20 ms: the strong one's are taken
    for k in 0..5 {
        write(&mut net, 0, s, 2 * k);
        write(&mut net, 1, w, 2 * k + 1);
        net.run_for(ms(20));
    }
    // the strong one goes silent; the weak one goes on
    for k in 5..30 {
        write(&mut net, 1, w, 2 * k + 1);
        net.run_for(ms(20));
    }
    net.run_for(ms(100));
    let got = received(&net, 2, r);
    assert_eq!(&got[..5], &[0, 2, 4, 6, 8], "the strong writer's first");
    assert_eq!(
        got.last(),
        Some(&59),
        "the weak writer's once the owner missed the deadline"
    );
    assert!(got.iter().skip(5).all(|v| v % 2 == 1));
}

#[test]
fn samples_older_than_their_writers_lifespan_are_dropped() {
    let mut net = new_net(1, 7, 20);
    // a writer whose clock is 2 s behind: its samples look 2 s old
    let wall = net.wall() - Duration::from_secs(2);
    let late = Domain::new(config(1), net.now(), wall);
    net.add(late);
    let now = net.now();
    let mut wq = writer_qos();
    wq.lifespan = RtpsDuration::from_std(Duration::from_secs(1));
    let fresh = net
        .node(0)
        .create_writer(EndpointConfig::writer("Life", "T").qos(wq.clone()), now)
        .unwrap();
    let stale = net
        .node(1)
        .create_writer(EndpointConfig::writer("Life", "T").qos(wq), now)
        .unwrap();
    let r = net
        .node(0)
        .create_reader(EndpointConfig::reader("Life", "T").qos(reader_qos()), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, r, 2)));
    for k in 0..10 {
        write(&mut net, 0, fresh, k);
        write(&mut net, 1, stale, 100 + k);
        net.run_for(ms(10));
    }
    net.run_for(Duration::from_secs(1));
    assert_eq!(received(&net, 0, r), (0..10).collect::<Vec<_>>());
    let dropped = net.hosts[0]
        .events
        .iter()
        .filter(|e| matches!(e, Event::SampleDropped { reader, reason: DropReason::Lifespan } if *reader == r))
        .count();
    assert_eq!(dropped, 10, "every stale sample, counted");
}

/// The key hash of a test sample: its value is its key (in either version).
fn instance_of(data: &[u8], _key_only: bool, _: Version) -> Option<[u8; 16]> {
    let mut h = [0; 16];
    h[..4].copy_from_slice(data.get(4..8)?);
    Some(h)
}

/// The test samples' instance keys: the hash is the key, in either version.
fn instance_keys() -> InstanceKeys {
    InstanceKeys {
        hash_in: instance_of,
        translate: |h, _, _| Some(*h),
    }
}

/// A keyed writer that sends no key hash (Cyclone DDS 11): a reader told
/// how to find the instance of a sample keeps its instances apart; without
/// it they are one, and a time-based filter drops the other instances.
#[test]
fn instances_of_a_writer_without_key_hashes_are_told_apart() {
    for (keys, want) in [(true, 3), (false, 1)] {
        let mut net = new_net(2, 13, 0);
        let now = net.now();
        let w = net
            .node(0)
            .create_writer(
                EndpointConfig::writer("Nokh", "T")
                    .keyed(true)
                    .qos(writer_qos()),
                now,
            )
            .unwrap();
        let mut rq = reader_qos();
        rq.time_based_filter = RtpsDuration::from_std(ms(1000));
        let r = net
            .node(1)
            .create_reader(EndpointConfig::reader("Nokh", "T").keyed(true).qos(rq), now)
            .unwrap();
        if keys {
            assert!(net.node(1).set_instance_keys(r, instance_keys()));
        }
        assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 1, r, 1)));
        // three instances, one sample each, no key hash
        for k in 0..3 {
            write(&mut net, 0, w, k);
        }
        net.run_for(ms(300));
        let taken = net
            .take_events(1)
            .into_iter()
            .filter(|e| matches!(e, Event::Sample { .. }))
            .count();
        assert_eq!(taken, want, "instances told apart: {keys}");
    }
}

#[test]
fn a_minimum_separation_takes_one_sample_per_period() {
    let mut net = new_net(2, 9, 0);
    let now = net.now();
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Tbf", "T").qos(writer_qos()), now)
        .unwrap();
    let mut rq = reader_qos();
    rq.time_based_filter = RtpsDuration::from_std(ms(100));
    let r = net
        .node(1)
        .create_reader(EndpointConfig::reader("Tbf", "T").qos(rq), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 1, r, 1)));
    // a sample every 10 ms for 1 s; the time each one is taken
    let mut taken = Vec::new();
    for k in 0..100 {
        write(&mut net, 0, w, k);
        for _ in 0..10 {
            net.step();
            for e in net.take_events(1) {
                if let Event::Sample { .. } = e {
                    taken.push(net.now());
                }
            }
        }
    }
    assert!((9..=11).contains(&taken.len()), "{} taken", taken.len());
    for p in taken.windows(2) {
        assert!(p[1] - p[0] >= ms(100), "{:?} apart", p[1] - p[0]);
    }
}

#[test]
fn a_missed_deadline_is_an_event_per_period_until_a_sample_comes() {
    let mut net = new_net(2, 11, 10);
    let now = net.now();
    let mut wq = writer_qos();
    wq.deadline = RtpsDuration::from_std(ms(100));
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Dl", "T").qos(wq), now)
        .unwrap();
    let mut rq = reader_qos();
    rq.deadline = RtpsDuration::from_std(ms(100));
    let r = net
        .node(1)
        .create_reader(EndpointConfig::reader("Dl", "T").qos(rq), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 1, r, 1)));
    let misses = |net: &Net| {
        net.hosts[1]
            .events
            .iter()
            .filter(|e| matches!(e, Event::DeadlineMissed { reader, .. } if *reader == r))
            .count()
    };
    // every 30 ms for 1 s (lost samples are repaired within the period)
    write(&mut net, 0, w, 0);
    net.run_for(ms(50));
    let before = misses(&net);
    for k in 1..33 {
        write(&mut net, 0, w, k);
        net.run_for(ms(30));
    }
    net.run_for(ms(50));
    assert_eq!(misses(&net), before, "no miss while samples come");
    // silence for 1 s: about one miss per 100 ms
    net.run_for(Duration::from_secs(1));
    let silent = misses(&net) - before;
    assert!((9..=11).contains(&silent), "{silent} misses");
    let last = net.hosts[1].events.iter().rev().find_map(|e| match e {
        Event::DeadlineMissed { total, .. } => Some(*total),
        _ => None,
    });
    assert_eq!(last, Some(misses(&net) as u64));
    // the writer offered the same deadline and missed it as often
    let offered = |net: &Net| {
        net.hosts[0]
            .events
            .iter()
            .filter(|e| matches!(e, Event::OfferedDeadlineMissed { writer, .. } if *writer == w))
            .count()
    };
    assert!(
        (9..=11).contains(&offered(&net)),
        "{} offered misses",
        offered(&net)
    );
    // a sample stops them: the reader's period restarts when it arrives
    // (up to 20 ms of delay, and a repair if it was lost), so nothing is
    // missed until 100 ms after the write at the earliest
    write(&mut net, 0, w, 99);
    net.run_for(ms(60));
    let (now_misses, now_offered) = (misses(&net), offered(&net));
    net.run_for(ms(30));
    assert_eq!(misses(&net), now_misses);
    // the writer's period restarts at the write: 100 ms later
    net.run_for(ms(30));
    assert_eq!(offered(&net), now_offered + 1);
}

#[test]
fn an_offered_deadline_holds_for_live_instances_only() {
    let mut net = new_net(1, 12, 0);
    let now = net.now();
    let mut wq = writer_qos();
    wq.deadline = RtpsDuration::from_std(ms(100));
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Od", "T").qos(wq).keyed(true), now)
        .unwrap();
    let missed = |net: &Net| -> Vec<[u8; 16]> {
        net.hosts[0]
            .events
            .iter()
            .filter_map(|e| match e {
                Event::OfferedDeadlineMissed { instance, .. } => Some(instance.0),
                _ => None,
            })
            .collect()
    };
    // nothing written, nothing promised
    net.run_for(ms(250));
    assert!(missed(&net).is_empty());
    let (a, b) = (KeyHash([1; 16]), KeyHash([2; 16]));
    for k in [a, b] {
        let now = net.now();
        let c = Change::alive_owned(sample(0)).with_key_hash(k);
        net.node(0).write(w, c, now).unwrap();
    }
    // b unregistered: only a misses, once per period
    let now = net.now();
    net.node(0)
        .write(w, Change::unregister(&[], b), now)
        .unwrap();
    net.run_for(ms(350));
    let m = missed(&net);
    assert!((3..=4).contains(&m.len()), "{m:?}");
    assert!(m.iter().all(|i| *i == a.0), "{m:?}");
    // a disposed: no more
    let now = net.now();
    net.node(0).write(w, Change::dispose(&[], a), now).unwrap();
    let before = missed(&net).len();
    net.run_for(ms(300));
    assert_eq!(missed(&net).len(), before);
}

#[test]
fn two_clients_of_one_service_each_get_only_their_own_replies() {
    for seed in [1u64, 2, 3] {
        let mut net = new_net(3, seed, 20);
        let now = net.now();
        let svc = ServiceConfig::new("add_one", "Req", "Rep");
        let s = net.node(0).create_service(&svc, now).unwrap();
        let a = net.node(1).create_client(&svc, now).unwrap();
        let b = net.node(2).create_client(&svc, now).unwrap();
        // a third client in the same domain as a
        let c = net.node(1).create_client(&svc, now).unwrap();
        let mut asked = Vec::new();
        for k in 0..5u32 {
            for (host, client, base) in [(1, a, 1000), (2, b, 2000), (1, c, 3000)] {
                let now = net.now();
                let q = net
                    .node(host)
                    .query(client, sample(base + k), Duration::from_secs(20), now)
                    .unwrap();
                asked.push((host, client, q, base + k));
            }
        }
        // the service answers every request with its value + 1
        let end = net.now() + Duration::from_secs(20);
        let mut replies = 0;
        while net.now() < end && replies < asked.len() {
            net.step();
            for e in net.take_events(0) {
                if let Event::Request {
                    service,
                    request,
                    sample: req,
                } = e
                {
                    assert_eq!(service, s);
                    let now = net.now();
                    let v = value(req.data());
                    net.node(0).reply(s, request, sample(v + 1), now).unwrap();
                }
            }
            replies = [1, 2]
                .iter()
                .map(|h| {
                    net.hosts[*h]
                        .events
                        .iter()
                        .filter(|e| matches!(e, Event::Reply { .. }))
                        .count()
                })
                .sum();
        }
        for (host, client, query, v) in &asked {
            let got: Vec<u32> = net.hosts[*host]
                .events
                .iter()
                .filter_map(|e| match e {
                    Event::Reply {
                        client: c,
                        query: q,
                        sample,
                    } if c == client && q == query => Some(value(sample.data())),
                    _ => None,
                })
                .collect();
            assert_eq!(
                got,
                vec![v + 1],
                "seed {seed}: query {query:?} of {client:?}"
            );
        }
        assert_eq!(
            replies,
            asked.len(),
            "seed {seed}: one reply per query, no more"
        );
    }
}

#[test]
fn a_query_nobody_serves_fails_as_unserved() {
    let mut net = new_net(1, 3, 0);
    let now = net.now();
    let c = net
        .node(0)
        .create_client(&ServiceConfig::new("none", "Req", "Rep"), now)
        .unwrap();
    let q = net.node(0).query(c, sample(1), ms(300), now).unwrap();
    net.run_for(ms(299));
    assert!(!net.has(0, |e| matches!(e, Event::QueryFailed { .. })));
    net.run_for(ms(2));
    assert!(net.has(0, |e| matches!(e, Event::QueryFailed { client, query, reason: QueryFailure::NoService(t) } if *client == c && *query == q && *t == ms(300))));
}

#[test]
fn a_query_a_matched_service_leaves_unanswered_times_out() {
    let mut net = new_net(2, 4, 0);
    let now = net.now();
    let cfg = ServiceConfig::new("silent", "Req", "Rep");
    net.node(1).create_service(&cfg, now).unwrap();
    let c = net.node(0).create_client(&cfg, now).unwrap();
    // the request goes out once both sides are matched, then nothing comes
    let q = net.node(0).query(c, sample(1), ms(3000), now).unwrap();
    net.run_for(ms(3001));
    assert!(
        net.has(1, |e| matches!(e, Event::Request { .. })),
        "the service got the request"
    );
    assert!(net.has(0, |e| matches!(e, Event::QueryFailed { client, query, reason: QueryFailure::Timeout(t) } if *client == c && *query == q && *t == ms(3000))));
}

/// A cancelled query is forgotten: neither a failure nor its reply is
/// reported, whether it waited for a service (unsent) or was sent.
#[test]
fn a_cancelled_query_is_neither_answered_nor_failed() {
    let mut net = new_net(2, 4, 0);
    let now = net.now();
    let cfg = ServiceConfig::new("cancel", "Req", "Rep");
    let c = net.node(0).create_client(&cfg, now).unwrap();
    // unsent: no service yet
    let waiting = net.node(0).query(c, sample(1), ms(300), now).unwrap();
    assert!(net.node(0).cancel_query(waiting));
    assert!(!net.node(0).cancel_query(waiting), "once");
    net.run_for(ms(400));
    assert!(!net.has(0, |e| matches!(e, Event::QueryFailed { .. })));
    // sent, and answered after the cancel
    let now = net.now();
    let s = net.node(1).create_service(&cfg, now).unwrap();
    let sent = net.node(0).query(c, sample(2), ms(3000), now).unwrap();
    net.run_until(ms(3000), |n| {
        n.has(1, |e| matches!(e, Event::Request { .. }))
    });
    assert!(net.node(0).cancel_query(sent));
    let request = net.hosts[1].events.iter().find_map(|e| match e {
        Event::Request { request, .. } => Some(*request),
        _ => None,
    });
    // another query, which the service leaves unanswered, is in flight
    // when the cancelled one's reply comes
    let now = net.now();
    let silent = net.node(0).query(c, sample(4), ms(1000), now).unwrap();
    net.node(1)
        .reply(s, request.unwrap(), sample(3), now)
        .unwrap();
    net.run_for(ms(1100));
    assert!(!net.has(0, |e| matches!(e, Event::Reply { .. })));
    assert!(!net.has(
        0,
        |e| matches!(e, Event::QueryFailed { query, .. } if *query == sent)
    ));
    // the late reply answered a query given up, not no query: the other
    // times out as such, not as one whose replies did not match (which
    // says "the other RPC style?")
    assert!(net.has(0, |e| matches!(e, Event::QueryFailed { query, reason: QueryFailure::Timeout(_), .. } if *query == silent)));
}

#[test]
fn a_pattern_subscription_reads_every_matching_topic_and_type() {
    let mut net = new_net(2, 13, 10);
    let pose = writer(&mut net, 0, "robot/pose", "Pose");
    let vel = writer(&mut net, 0, "robot/vel", "Twist");
    let other = writer(&mut net, 0, "camera/pose", "Pose");
    let wrong_type = writer(&mut net, 0, "robot/img", "Image");
    let now = net.now();
    let p = net
        .node(1)
        .create_pattern("robot/*", "[PT]*", reader_qos(), now);
    assert!(net.run_until(Duration::from_secs(10), |n| {
        n.hosts[1]
            .events
            .iter()
            .filter(|e| matches!(e, Event::PatternMatched { .. }))
            .count()
            >= 2
            && n.hosts[1]
                .events
                .iter()
                .filter(|e| matches!(e, Event::ReaderMatched { .. }))
                .count()
                >= 2
    }));
    net.run_for(ms(200));
    for (w, v) in [(pose, 1), (vel, 2), (other, 3), (wrong_type, 4)] {
        write(&mut net, 0, w, v);
    }
    net.run_for(ms(500));
    let readers: Vec<(ReaderId, String)> = net.hosts[1]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::PatternMatched {
                pattern,
                reader,
                topic,
                ..
            } if *pattern == p => Some((*reader, topic.clone())),
            _ => None,
        })
        .collect();
    let mut topics: Vec<&str> = readers.iter().map(|(_, t)| t.as_str()).collect();
    topics.sort();
    assert_eq!(topics, ["robot/pose", "robot/vel"]);
    let mut got: Vec<u32> = readers
        .iter()
        .flat_map(|(r, _)| received(&net, 1, *r))
        .collect();
    got.sort();
    assert_eq!(got, [1, 2]);
    // deleting the pattern deletes its readers
    let now = net.now();
    assert!(net.node(1).delete_pattern(p, now));
    net.run_for(ms(500));
    assert_eq!(
        net.hosts[1]
            .node
            .participant()
            .matched_writers(readers[0].0.guid())
            .len(),
        0
    );
}

/// A pattern reader asks what its publication offers: a transient-local
/// publication's history reaches a pattern made after it was written (a
/// recorder missed latched data). A best-effort publication of the same
/// topic found later gets the reader replaced by a best-effort volatile
/// one, which takes both publications' new samples.
#[test]
fn a_pattern_reader_takes_a_latched_history_and_gives_way_to_a_weaker_publication() {
    // no loss: the reader that replaces it is best effort
    let mut net = new_net(2, 21, 0);
    let now = net.now();
    let mut q = writer_qos();
    q.durability = Durability::TransientLocal;
    let latched = net
        .node(0)
        .create_writer(EndpointConfig::writer("map", "Map").qos(q), now)
        .unwrap();
    for v in 1..=3 {
        write(&mut net, 0, latched, v);
    }
    net.run_for(ms(300));
    let now = net.now();
    let p = net.node(1).create_pattern("*", "*", reader_qos(), now);
    let first_reader = |net: &Net| {
        net.hosts[1].events.iter().find_map(|e| match e {
            Event::PatternMatched {
                pattern, reader, ..
            } if *pattern == p => Some(*reader),
            _ => None,
        })
    };
    assert!(net.run_until(Duration::from_secs(10), |n| first_reader(n)
        .is_some_and(|r| received(n, 1, r).len() == 3)));
    let r1 = first_reader(&net).unwrap();
    assert_eq!(received(&net, 1, r1), [1, 2, 3], "the history");
    // a best-effort publication of the same topic
    let now = net.now();
    let mut be = writer_qos();
    be.reliability = Reliability::BestEffort;
    let weak = net
        .node(0)
        .create_writer(EndpointConfig::writer("map", "Map").qos(be), now)
        .unwrap();
    let replaced = |net: &Net| {
        net.hosts[1].events.iter().find_map(|e| match e {
            Event::PatternMatched {
                reader,
                replaces: Some(old),
                ..
            } if *old == r1 => Some(*reader),
            _ => None,
        })
    };
    assert!(net.run_until(Duration::from_secs(10), |n| replaced(n)
        .is_some_and(|r| matched(n, 1, r, 2))));
    let r2 = replaced(&net).unwrap();
    // and both writers know it
    let knows = |n: &Net, w: WriterId| {
        n.has(0, |e| {
            matches!(e, Event::WriterMatched { writer, reader } if *writer == w && *reader == r2.guid())
        })
    };
    assert!(net.run_until(Duration::from_secs(10), |n| knows(n, latched)
        && knows(n, weak)));
    write(&mut net, 0, latched, 4);
    write(&mut net, 0, weak, 5);
    assert!(net.run_until(Duration::from_secs(10), |n| {
        let mut got = received(n, 1, r2);
        got.sort();
        got == [4, 5]
    }));
    assert!(!net.hosts[1]
        .events
        .iter()
        .any(|e| matches!(e, Event::IncompatibleQos { .. })));
}

#[test]
fn a_confirmed_write_resolves_only_once_every_reliable_reader_has_acknowledged_it() {
    let mut net = new_net(2, 17, 30);
    let now = net.now();
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Conf", "T").qos(writer_qos()), now)
        .unwrap();
    let r = net
        .node(1)
        .create_reader(EndpointConfig::reader("Conf", "T").qos(reader_qos()), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 1, r, 1)
            && writer_matched(n, 0, w))
    );
    net.run_for(ms(100));
    // the reader's host stops reading for a while
    net.hosts[1].up = false;
    let now = net.now();
    let sn = net
        .node(0)
        .write_confirmed(
            w,
            Change::alive_owned(sample(7)),
            Duration::from_secs(5),
            now,
        )
        .unwrap();
    let confirmed = |n: &Net| {
        n.has(0, |e| matches!(e, Event::WriteConfirmed { writer, sequence_number } if *writer == w && *sequence_number == sn))
    };
    net.run_for(ms(500));
    assert!(!confirmed(&net), "not before the reader has it");
    net.hosts[1].up = true;
    assert!(net.run_until(Duration::from_secs(4), |n| confirmed(n)));
    assert_eq!(received(&net, 1, r), [7], "the reader has it");
    assert!(net.hosts[0]
        .node
        .participant()
        .is_acked_by_all(w.guid(), sn));
    // without the reader, the confirmation times out
    net.hosts[1].up = false;
    let now = net.now();
    let sn = net
        .node(0)
        .write_confirmed(w, Change::alive_owned(sample(8)), ms(500), now)
        .unwrap();
    net.run_for(ms(600));
    assert!(net.has(0, |e| matches!(e, Event::ConfirmFailed { writer, sequence_number, reason: ConfirmFailure::Timeout(_) } if *writer == w && *sequence_number == sn)));
    // with no reader matched, a confirmed write is confirmed at once
    let now = net.now();
    let lone = net
        .node(0)
        .create_writer(EndpointConfig::writer("Nobody", "T").qos(writer_qos()), now)
        .unwrap();
    let sn = net
        .node(0)
        .write_confirmed(lone, Change::alive_owned(sample(9)), ms(500), now)
        .unwrap();
    net.pump();
    assert!(net.has(0, |e| matches!(e, Event::WriteConfirmed { writer, sequence_number } if *writer == lone && *sequence_number == sn)));
}

#[test]
fn a_full_keep_all_reader_holds_back_a_reliable_writer_until_it_has_room() {
    let mut net = Net::new(19, Faults::lossy(5));
    let mut cfg = config(0);
    cfg.max_unacked_bytes = 16 << 10;
    let d = Domain::new(cfg, net.now(), net.wall());
    net.add(d);
    let d = Domain::new(config(1), net.now(), net.wall());
    net.add(d);
    let now = net.now();
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Bp", "T").qos(writer_qos()), now)
        .unwrap();
    let r = net
        .node(1)
        .create_reader(EndpointConfig::reader("Bp", "T").qos(reader_qos()), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 1, r, 1)
            && writer_matched(n, 0, w))
    );
    net.run_for(ms(100));
    // the shell's queue is full: user data is not read
    net.node(1).set_reader_full(r, true);
    assert_eq!(net.hosts[1].node.paused_reader(), Some(r));
    let big = |n: u32| {
        let mut b = sample(n);
        b.resize(2048, 0);
        b
    };
    let mut written = 0u32;
    let mut blocked = false;
    for _ in 0..200 {
        let now = net.now();
        if !net.node(0).has_room(w, 2048) {
            blocked = true;
            break;
        }
        net.node(0)
            .write(w, Change::alive_owned(big(written)), now)
            .unwrap();
        written += 1;
        net.run_for(ms(5));
    }
    assert!(blocked, "the writer's history filled up");
    let now = net.now();
    assert!(matches!(
        net.node(0).write(w, Change::alive_owned(big(written)), now),
        Err(WriteError::HistoryFull(_))
    ));
    assert!(written < 20, "{written} written");
    assert!(received(&net, 1, r).is_empty());
    net.run_for(Duration::from_secs(1));
    assert!(!net.has(0, |e| matches!(e, Event::Writable { .. })));
    // room again: everything arrives and the writer may go on
    net.node(1).set_reader_full(r, false);
    assert!(net.run_until(Duration::from_secs(5), |n| n.has(
        0,
        |e| matches!(e, Event::Writable { writer } if *writer == w)
    )));
    let now = net.now();
    net.node(0)
        .write(w, Change::alive_owned(big(written)), now)
        .unwrap();
    written += 1;
    assert!(
        net.run_until(Duration::from_secs(5), |n| received(n, 1, r).len()
            == written as usize)
    );
    assert_eq!(received(&net, 1, r), (0..written).collect::<Vec<_>>());
}

#[test]
fn a_remote_endpoint_of_another_type_on_our_topic_is_reported_with_both_type_names() {
    let mut net = new_net(2, 23, 0);
    let w = writer(&mut net, 0, "Shared", "TypeA");
    let r = reader(&mut net, 1, "Shared", "TypeB");
    let reported = |n: &Net| {
        n.has(0, |e| matches!(e, Event::TypeMismatch { local, remote, topic, local_type, remote_type }
            if *local == Endpoint::Writer(w) && *remote == r.guid() && topic == "Shared" && local_type == "TypeA" && remote_type == "TypeB"))
            && n.has(1, |e| matches!(e, Event::TypeMismatch { local, remote, local_type, remote_type, .. }
            if *local == Endpoint::Reader(r) && *remote == w.guid() && local_type == "TypeB" && remote_type == "TypeA"))
    };
    assert!(net.run_until(Duration::from_secs(10), reported));
    assert!(!matched(&net, 1, r, 1));
    // once, as a type mismatch: not also as an incompatible QoS
    for node in [0, 1] {
        assert!(
            !net.has(node, |e| matches!(e, Event::IncompatibleQos { .. })),
            "node {node}"
        );
    }
}

#[test]
fn two_local_endpoints_of_different_types_on_one_topic_are_reported_both_ways() {
    // an XRCE agent hosts every client's endpoints in one participant, so
    // a mismatch between two of them is never discovered, only local
    let mut net = new_net(1, 31, 0);
    let w = writer(&mut net, 0, "Shared", "TypeA");
    let r = reader(&mut net, 0, "Shared", "TypeB");
    // a pattern takes every type: no mismatch for it
    let now = net.now();
    net.node(0).create_pattern("Shared", "*", reader_qos(), now);
    let same = reader(&mut net, 0, "Shared", "TypeA");
    net.run_for(ms(50));
    assert!(net.has(0, |e| matches!(e, Event::TypeMismatch { local, remote, topic, local_type, remote_type }
        if *local == Endpoint::Writer(w) && *remote == r.guid() && topic == "Shared" && local_type == "TypeA" && remote_type == "TypeB")));
    assert!(net.has(0, |e| matches!(e, Event::TypeMismatch { local, remote, local_type, remote_type, .. }
        if *local == Endpoint::Reader(r) && *remote == w.guid() && local_type == "TypeB" && remote_type == "TypeA")));
    let mismatches = net.hosts[0]
        .events
        .iter()
        .filter(|e| matches!(e, Event::TypeMismatch { .. }))
        .count();
    assert_eq!(mismatches, 2, "only the writer and the TypeB reader");
    assert!(matched(&net, 0, same, 1));
    assert!(!matched(&net, 0, r, 1));
}

#[test]
fn payloads_are_padded_to_four_bytes() {
    let mut net = new_net(1, 29, 0);
    let now = net.now();
    let w = net
        .node(0)
        .create_writer(EndpointConfig::writer("Pad", "T").qos(writer_qos()), now)
        .unwrap();
    let r = net
        .node(0)
        .create_reader(EndpointConfig::reader("Pad", "T").qos(reader_qos()), now)
        .unwrap();
    net.node(0)
        .write(w, Change::alive(&[0, 1, 0, 0, 9]), now)
        .unwrap();
    net.pump();
    let data: Vec<Vec<u8>> = net.hosts[0]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if *reader == r => Some(sample.data().to_vec()),
            _ => None,
        })
        .collect();
    assert_eq!(data, [vec![0, 1, 0, 0, 9, 0, 0, 0]]);
}

// ---------------------------------------------------------------------------
// The two ROS 2 request/reply styles (rmw_fastrtps: related sample identity;
// rmw_cyclonedds: a header before the body). The peer of the other style is
// played by a plain writer and reader on the service's topics, writing and
// checking the bytes rmw_cyclonedds puts on the wire.

use courier_wire::dds::{RequestHeader, RpcStyle};

/// rmw_cyclonedds's layout: encapsulation, client id (u64), request number
/// (i64), body; little-endian here.
fn with_header(client: u64, seq: i64, body: u32) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&client.to_le_bytes());
    b.extend_from_slice(&seq.to_le_bytes());
    b.extend_from_slice(&body.to_le_bytes());
    b
}

/// A plain writer of `topic` and reader of `other` on host `i`.
fn raw_pair(
    net: &mut Net,
    i: usize,
    topic: &str,
    ty: &str,
    other: &str,
    other_ty: &str,
) -> (WriterId, ReaderId) {
    let now = net.now();
    let mut wq = writer_qos();
    wq.reliability = reliable();
    let w = net
        .node(i)
        .create_writer(EndpointConfig::writer(topic, ty).qos(wq), now)
        .unwrap();
    let r = net
        .node(i)
        .create_reader(
            EndpointConfig::reader(other, other_ty).qos(reader_qos()),
            now,
        )
        .unwrap();
    (w, r)
}

fn samples_of(
    net: &mut Net,
    i: usize,
    r: ReaderId,
) -> Vec<courier_wire::rtps::participant::ReceivedSample> {
    net.take_events(i)
        .into_iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if reader == r => Some(sample),
            _ => None,
        })
        .collect()
}

#[test]
fn a_service_answers_a_request_header_client_by_header() {
    let mut net = new_net(2, 21, 0);
    let now = net.now();
    let svc = ServiceConfig::new("add", "Req", "Rep").with_style(RpcStyle::RequestHeader);
    let s = net.node(0).create_service(&svc, now).unwrap();
    let (w, r) = raw_pair(&mut net, 1, "rq/addRequest", "Req", "rr/addReply", "Rep");
    // the plain writer is matched with the service's request reader
    assert!(net.run_until(ms(5000), |n| n.has(
        1,
        |e| matches!(e, Event::WriterMatched { writer, .. } if *writer == w)
    )));
    let now = net.now();
    net.node(1)
        .write(w, Change::alive_owned(with_header(0xfeed, 41, 7)), now)
        .unwrap();
    let mut got = None;
    assert!(net.run_until(ms(5000), |n| n
        .has(0, |e| matches!(e, Event::Request { .. }))));
    for e in net.take_events(0) {
        if let Event::Request {
            request,
            sample: req,
            ..
        } = e
        {
            // the service sees the body alone
            assert_eq!(req.data(), sample(7));
            assert_eq!(request.style(), RpcStyle::RequestHeader);
            assert_eq!(
                request.request_header(),
                Some(RequestHeader {
                    client: 0xfeed,
                    seq: 41
                })
            );
            assert_eq!(request.related_identity(), None);
            got = Some(request);
        }
    }
    let request = got.expect("the request");
    let now = net.now();
    net.node(0).reply(s, request, sample(8), now).unwrap();
    assert!(net.run_until(ms(5000), |n| n.has(
        1,
        |e| matches!(e, Event::Sample { reader, .. } if *reader == r)
    )));
    let replies = samples_of(&mut net, 1, r);
    assert_eq!(replies.len(), 1);
    // the reply echoes the header, as rmw_cyclonedds's client expects
    assert_eq!(replies[0].data(), with_header(0xfeed, 41, 8));
    assert_eq!(replies[0].related_sample_identity, None);
}

#[test]
fn a_client_asks_a_request_header_service_and_takes_only_its_own_replies() {
    let mut net = new_net(2, 22, 0);
    let now = net.now();
    let svc = ServiceConfig::new("add", "Req", "Rep").with_style(RpcStyle::RequestHeader);
    let c = net.node(0).create_client(&svc, now).unwrap();
    let (w, r) = raw_pair(&mut net, 1, "rr/addReply", "Rep", "rq/addRequest", "Req");
    let now = net.now();
    let q = net.node(0).query(c, sample(5), ms(10_000), now).unwrap();
    assert!(net.run_until(ms(5000), |n| n.has(
        1,
        |e| matches!(e, Event::Sample { reader, .. } if *reader == r)
    )));
    let reqs = samples_of(&mut net, 1, r);
    assert_eq!(reqs.len(), 1);
    let h = RequestHeader::peek(reqs[0].data()).expect("a header");
    assert_eq!(h.seq, 1, "the client's first request");
    assert_eq!(
        reqs[0].data(),
        with_header(h.client, 1, 5),
        "header, then the body"
    );
    let now = net.now();
    // another client's reply first (ignored), then ours
    net.node(1)
        .write(
            w,
            Change::alive_owned(with_header(h.client ^ 1, 1, 99)),
            now,
        )
        .unwrap();
    net.node(1)
        .write(w, Change::alive_owned(with_header(h.client, 1, 6)), now)
        .unwrap();
    assert!(net.run_until(ms(5000), |n| n.has(0, |e| matches!(e, Event::Reply { .. }))));
    let replies: Vec<_> = net
        .take_events(0)
        .into_iter()
        .filter_map(|e| match e {
            Event::Reply {
                client,
                query,
                sample,
            } => Some((client, query, sample.data().to_vec())),
            _ => None,
        })
        .collect();
    assert_eq!(replies, vec![(c, q, sample(6))]);
}

#[test]
fn replies_that_answer_no_query_are_counted_and_named_when_the_query_times_out() {
    let mut net = new_net(2, 23, 0);
    let now = net.now();
    // the client asks by related sample identity; the service answers by
    // header (the other style): its replies match nothing
    let svc = ServiceConfig::new("add", "Req", "Rep").with_style(RpcStyle::SampleIdentity);
    let c = net.node(0).create_client(&svc, now).unwrap();
    let (w, r) = raw_pair(&mut net, 1, "rr/addReply", "Rep", "rq/addRequest", "Req");
    let now = net.now();
    let q = net.node(0).query(c, sample(5), ms(3000), now).unwrap();
    assert!(net.run_until(ms(2000), |n| n.has(
        1,
        |e| matches!(e, Event::Sample { reader, .. } if *reader == r)
    )));
    let now = net.now();
    // a reply without identity and too short for a header
    net.node(1)
        .write(w, Change::alive_owned(sample(6)), now)
        .unwrap();
    net.run_for(ms(3001));
    assert!(net.has(0, |e| matches!(e, Event::QueryFailed { client, query, reason: QueryFailure::Unmatched { replies: 1, .. } } if *client == c && *query == q)));
}
