//! What the test files share: the RTPS interop peers' types (IDL
//! `courier::test::Msg` and `Keyed` in tests/peers/rtps/types.idl), loopback
//! sessions, bounded waits, and what losing central must do.

#![allow(dead_code)] // each test file uses its own part

use std::time::Duration;

use courier::{IpcMessage, RecvError, Session};
use futures::StreamExt;

/// The bound on every wait.
pub const T: Duration = Duration::from_secs(20);

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Msg")]
pub struct Msg {
    pub seq: u32,
    pub text: String,
    pub payload: Vec<u8>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Keyed")]
pub struct Keyed {
    #[ipc(key)]
    pub id: i32,
    pub seq: u32,
    pub text: String,
}

/// Loopback only, unicast discovery.
pub fn url(domain: u32) -> String {
    format!("rtps://{domain}?interface=lo&peers=127.0.0.1")
}

pub async fn session(domain: u32, name: &str) -> Session {
    tokio::time::timeout(T, Session::builder(url(domain)).name(name).connect())
        .await
        .expect("connect in time")
        .expect("connect")
}

/// Waits until `s` sees `n` handlers of `topic` (readers matched with its writer).
pub async fn await_handlers(s: &Session, topic: &str, n: i32) {
    tokio::time::timeout(T, async {
        while s.num_handlers(topic).await.unwrap() < n {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{topic}: {n} reader(s) never matched"));
}

pub async fn next<M: IpcMessage>(
    sub: &mut courier::Subscriber<M>,
) -> Result<courier::Sample<M>, RecvError> {
    tokio::time::timeout(T, sub.next())
        .await
        .expect("a sample in time")
        .expect("stream open")
}

/// CPU time of the calling thread.
pub fn thread_cpu() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid clock id and a pointer to a live timespec.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(r, 0);
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Over 300 ms of sleep, this thread (a current-thread runtime running
/// `what`) uses under a quarter of the time: nothing spins.
pub async fn assert_quiet(what: &str) {
    let (cpu, wall) = (thread_cpu(), std::time::Instant::now());
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (cpu, wall) = (thread_cpu() - cpu, wall.elapsed());
    assert!(cpu < wall / 4, "{what} used {cpu:?} of CPU in {wall:?}");
}

/// A publisher of `topic` on `a` and a keep-all subscriber of `depth` on
/// `b`, matched.
pub async fn keep_all_pair(
    a: &Session,
    b: &Session,
    topic: &str,
    depth: usize,
) -> (courier::Publisher<Msg>, courier::Subscriber<Msg>) {
    let p = a.publisher::<Msg>(topic).build().await.unwrap();
    let sub = b
        .subscriber::<Msg>(topic)
        .queue(courier::QueuePolicy::KeepAll(depth))
        .build()
        .await
        .unwrap();
    await_handlers(a, topic, 1).await;
    (p, sub)
}

/// `a` publishes `n` 1000-byte samples on `flood` to `b`'s keep-all
/// subscriber of 8, which stops reading for 50 ms every 500: back-pressure
/// holds the publisher, and every sample arrives once, in order.
pub async fn slow_keep_all_subscriber(a: &Session, b: &Session, n: u32) {
    let (p, mut sub) = keep_all_pair(a, b, "flood", 8).await;
    let writer = tokio::spawn(async move {
        for i in 0..n {
            p.publish(&Msg {
                seq: i,
                text: String::new(),
                payload: vec![0; 1000],
            })
            .await
            .unwrap();
        }
    });
    for i in 0..n {
        let s = next(&mut sub).await.unwrap();
        assert_eq!(s.value.seq, i);
        if i % 500 == 0 {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    writer.await.unwrap();
    assert_eq!(sub.dropped(), 0);
}

/// Central stopped at `since`: the subscriber ends with `Disconnected`
/// (after what was already in flight, if anything) and the pending query
/// fails, at once rather than at its timeout.
pub async fn ended_by_central(
    sub: &mut courier::Subscriber<i32>,
    query: tokio::task::JoinHandle<Result<i32, courier::QueryError>>,
    since: std::time::Instant,
) {
    let first = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert!(
        matches!(first, Some(Err(RecvError::Disconnected)) | Some(Ok(_))),
        "{first:?}"
    );
    let e = tokio::time::timeout(T, query)
        .await
        .unwrap()
        .unwrap()
        .unwrap_err();
    assert!(matches!(e, courier::QueryError::Disconnected(_)), "{e}");
    assert!(since.elapsed() < Duration::from_secs(5), "failed at once");
}
