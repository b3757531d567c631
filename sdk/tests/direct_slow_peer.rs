//! Direct mode (`central -c`) with a receiving module that stops reading:
//! only the publishes that go to it wait (back-pressure); the session goes
//! on serving everything else, and once that module is gone the waiting
//! publishes finish. The stuck module is a sans-I/O `Connection` on a
//! blocking socket that registers its handler and then reads nothing.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use courier::ipc::module::{Connection, Event, ModuleConfig};
use courier::IpcMessage;
use futures::StreamExt;

mod common;

const T: Duration = Duration::from_secs(20);

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: i32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

/// A module that connects to central in direct mode, subscribes `msg` and
/// then reads nothing: not its direct link, not central.
struct Stuck {
    _central: std::net::TcpStream,
    listener: std::net::TcpListener,
}

impl Stuck {
    /// Waits (bounded) for the publisher's direct link and keeps it,
    /// unread.
    fn take_link(&self) -> std::net::TcpStream {
        self.listener.set_nonblocking(true).unwrap();
        let deadline = Instant::now() + T;
        loop {
            match self.listener.accept() {
                Ok((s, _)) => return s,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    assert!(
                        Instant::now() < deadline,
                        "no direct link to the stuck module"
                    );
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(e) => panic!("accept: {e}"),
            }
        }
    }
}

fn stuck_module(central: std::net::SocketAddr, msg: &str) -> Stuck {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let mut sock = std::net::TcpStream::connect(central).unwrap();
    sock.set_read_timeout(Some(T)).unwrap();
    let mut conn = Connection::new(ModuleConfig::new("stuck", "localhost"), Instant::now());
    let mut buf = vec![0u8; 1 << 16];
    let deadline = Instant::now() + T;
    let mut subscribed = false;
    loop {
        assert!(
            Instant::now() < deadline,
            "the stuck module's handshake timed out"
        );
        while let Some(b) = conn.poll_transmit() {
            sock.write_all(&b).unwrap();
        }
        match conn.poll_event() {
            Some(Event::DirectListenRequested) => conn.announce_direct_port(i32::from(port)),
            Some(Event::Connected) => {
                conn.subscribe(msg, "stuck_handler").unwrap();
                // asked after the subscription, answered once central has it
                conn.num_handlers(msg).unwrap();
            }
            Some(Event::NumHandlers { count, .. }) => {
                assert!(count >= 1, "central lists the stuck module handler");
                subscribed = true;
            }
            Some(Event::Closed(e)) => panic!("central closed the stuck module: {e:?}"),
            Some(_) => {}
            None if subscribed => {
                while let Some(b) = conn.poll_transmit() {
                    sock.write_all(&b).unwrap();
                }
                return Stuck {
                    _central: sock,
                    listener,
                };
            }
            None => {
                let n = sock.read(&mut buf).unwrap();
                assert!(n > 0, "central closed the stuck module's connection");
                conn.receive(&buf[..n], Instant::now());
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_direct_receiver_that_stops_reading_holds_up_only_the_publishes_to_it() {
    let mut cfg = courier_broker::Config::default();
    cfg.direct = true;
    let (c, url) = common::central_with(cfg, |b| b).await;
    // the messages are defined before anybody subscribes them
    let publisher = common::connect(&url, "publisher").await;
    publisher.define::<Blob>("to_both").await.unwrap();
    publisher.define::<i32>("to_good").await.unwrap();
    let good = common::connect(&url, "good").await;
    let mut both = good.subscribe::<Blob>("to_both").await.unwrap();
    let mut only_good = good.subscribe::<i32>("to_good").await.unwrap();
    let addr = c.local_addr();
    let stuck = tokio::task::spawn_blocking(move || stuck_module(addr, "to_both"))
        .await
        .unwrap();
    common::await_handlers(&publisher, "to_both", 2).await;
    common::await_handlers(&publisher, "to_good", 1).await;

    // 16 MiB to both receivers: far more than the stuck one's socket
    // buffers and its link's queue take
    let flood = tokio::spawn({
        let p = publisher.clone();
        async move {
            let blob = Blob {
                n: 64 << 10,
                data: vec![7; 64 << 10],
            };
            for _ in 0..256 {
                p.publish("to_both", &blob).await.unwrap();
            }
        }
    });
    let (stuck, link) = tokio::task::spawn_blocking(move || {
        let link = stuck.take_link();
        (stuck, link)
    })
    .await
    .unwrap();
    let drain = tokio::spawn(async move {
        let mut n = 0;
        while n < 256 {
            if tokio::time::timeout(T, both.next()).await.is_err() {
                break;
            }
            n += 1;
        }
        n
    });
    // Give the flood time to fill the stuck module's socket buffers (a few
    // MiB, well under a millisecond's work each): a wait, not a measured
    // bound; too short would only make this test weaker, never fail it.
    tokio::time::sleep(Duration::from_millis(500)).await;
    // meanwhile the session goes on: publishes elsewhere, calls to central
    for i in 0..20 {
        tokio::time::timeout(T, publisher.publish("to_good", &i))
            .await
            .expect("a publish to another module is not held up")
            .unwrap();
        let got = tokio::time::timeout(T, only_good.next())
            .await
            .expect("delivered")
            .unwrap()
            .unwrap();
        assert_eq!(got.value, i);
    }
    tokio::time::timeout(T, publisher.num_handlers("to_good"))
        .await
        .expect("central still answers")
        .unwrap();
    assert!(
        !flood.is_finished(),
        "the publishes to the stuck module wait (back-pressure)"
    );
    // the stuck module goes: its link fails and the publishes finish
    drop((stuck, link));
    tokio::time::timeout(T, flood)
        .await
        .expect("the waiting publishes finish once the stuck module is gone")
        .unwrap();
    assert_eq!(
        tokio::time::timeout(T, drain).await.unwrap().unwrap(),
        256,
        "the module that reads got every message"
    );
    publisher.close().await;
    good.close().await;
    c.shutdown().await;
}

/// The receiving side of the same: a Courier subscriber whose
/// application stops taking samples keeps only a bounded amount of what its
/// direct link brings (the link's reader waits for the subscriber's queue,
/// so TCP holds the sender back), and once the application reads again it
/// gets every message, in order. Before the bound, the receiving session
/// read the link to its end, parking each sample it could not queue in a
/// task of its own: the sender never waited, and memory grew with the
/// flood.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscriber_that_stops_reading_holds_back_its_direct_sender_and_loses_nothing() {
    const N: usize = 1024;
    let mut cfg = courier_broker::Config::default();
    cfg.direct = true;
    let (c, url) = common::central_with(cfg, |b| b).await;
    let publisher = common::connect(&url, "publisher").await;
    publisher.define::<Blob>("flood").await.unwrap();
    let reader = common::connect(&url, "reader").await;
    let mut sub = reader
        .subscriber::<Blob>("flood")
        .queue(courier::QueuePolicy::KeepAll(4))
        .build()
        .await
        .unwrap();
    common::await_handlers(&publisher, "flood", 1).await;

    // 16 MiB: far more than the socket buffers, the sender's link queue
    // (1 MiB) and the reader's bound together
    let flood = tokio::spawn({
        let p = publisher.clone();
        async move {
            for i in 0..N {
                let mut data = vec![7; 64 << 10];
                data[..4].copy_from_slice(&(i as u32).to_le_bytes());
                let blob = Blob { n: 64 << 10, data };
                p.publish("flood", &blob).await.unwrap();
            }
        }
    });
    // Time for the flood to go through if nothing held it back (16 MiB on
    // loopback is well under a second's work): a wait, not a measured bound.
    let mut flood = flood;
    let finished = tokio::time::timeout(Duration::from_secs(3), &mut flood).await;
    assert!(
        finished.is_err(),
        "the sender waits while the subscriber does not read (back-pressure)"
    );
    for i in 0..N {
        let got = tokio::time::timeout(T, sub.next())
            .await
            .unwrap_or_else(|_| panic!("message {i} of {N} arrives"))
            .expect("the stream goes on")
            .unwrap();
        let seq = u32::from_le_bytes(got.value.data[..4].try_into().unwrap());
        assert_eq!(seq as usize, i, "every message, in order");
    }
    tokio::time::timeout(T, flood)
        .await
        .expect("the sender finishes once the subscriber reads")
        .unwrap();
    publisher.close().await;
    reader.close().await;
    c.shutdown().await;
}
