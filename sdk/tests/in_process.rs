//! A module in the process that hosts central, on an in-process link
//! (`CentralHandle::session`), among modules on sockets: it must be an
//! ordinary module to all of them. Central is embedded on a free port of
//! 127.0.0.1; every wait is bounded.

use std::time::Duration;

use courier::{ConnectError, IpcMessage, RecvError, Session, Subscriber};
use courier_broker::{CentralHandle, CentralServer, Config};
use futures::StreamExt;

mod common;
use common::T;

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: i32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

fn blob(len: usize, seed: u8) -> Blob {
    Blob {
        n: len as i32,
        data: (0..len)
            .map(|i| (i as u8).wrapping_mul(31) ^ seed)
            .collect(),
    }
}

async fn central(direct: bool) -> CentralHandle {
    let mut cfg = Config::default();
    cfg.direct = direct;
    central_with(cfg).await
}

async fn central_with(cfg: Config) -> CentralHandle {
    CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(0)
        .config(cfg)
        .log_sink(courier_broker::LogSink::discard())
        .spawn()
        .await
        .unwrap()
}

async fn on_tcp(c: &CentralHandle, name: &str) -> Session {
    let url = format!("ipc://{}", c.local_addr());
    tokio::time::timeout(T, Session::builder(url).name(name).connect())
        .await
        .unwrap()
        .unwrap()
}

async fn in_process(c: &CentralHandle, name: &str) -> Session {
    tokio::time::timeout(T, c.session(name).connect())
        .await
        .unwrap()
        .unwrap()
}

async fn handlers(s: &Session, msg: &str, n: i32) {
    tokio::time::timeout(T, async {
        while s.num_handlers(msg).await.unwrap() < n {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("handlers within 20 s");
}

/// Publishes until `sub` has the value: the publisher learns of the new
/// subscriber through the broadcast list it watches (as in C), so the
/// first publications may be filtered out.
async fn publish_until_received(
    p: &Session,
    msg: &str,
    v: &Blob,
    sub: &mut courier::Subscriber<Blob>,
) {
    let deadline = tokio::time::Instant::now() + T;
    loop {
        p.publish(msg, v).await.unwrap();
        if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await {
            let s = s.unwrap();
            assert_eq!(s.value, *v);
            return;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "{msg} never arrived"
        );
    }
}

/// Once `msg` has a subscriber, publishes `value(0..n)` on a task of its
/// own.
async fn publish_when_subscribed<V: IpcMessage + Send + 'static>(
    p: &Session,
    msg: &'static str,
    n: usize,
    value: impl Fn(usize) -> V + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    handlers(p, msg, 1).await;
    // The publisher's broadcast list may lag its num_handlers answer.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let p = p.clone();
    tokio::spawn(async move {
        for i in 0..n {
            p.publish(msg, &value(i)).await.unwrap();
        }
    })
}

async fn serve_echo(s: &Session, ask: &str, answer: &str) -> tokio::task::JoinHandle<()> {
    let mut reqs = s.serve::<Blob, Blob>(ask, answer).await.unwrap();
    tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let mut v = r.value.clone();
            v.data.reverse();
            r.reply(&v).await.unwrap();
        }
    })
}

/// Messages and queries of 4 B and 1 MiB (larger than the link's buffer)
/// both ways between an in-process module and one on TCP, routed.
#[tokio::test]
async fn in_process_and_socket_modules_exchange_messages_and_queries() {
    let c = central(false).await;
    let a = in_process(&c, "inproc").await;
    let b = on_tcp(&c, "tcp").await;
    for m in ["to_b", "to_a", "ask_a", "ask_b", "answer"] {
        a.define::<Blob>(m).await.unwrap();
    }
    assert!(b.is_module_connected("inproc").await.unwrap());
    assert!(a.is_module_connected("tcp").await.unwrap());

    let mut at_b = b.subscribe::<Blob>("to_b").await.unwrap();
    let mut at_a = a.subscribe::<Blob>("to_a").await.unwrap();
    let sa = serve_echo(&a, "ask_a", "answer").await;
    let sb = serve_echo(&b, "ask_b", "answer").await;
    for len in [4, 1 << 20] {
        publish_until_received(&a, "to_b", &blob(len, 1), &mut at_b).await;
        publish_until_received(&b, "to_a", &blob(len, 2), &mut at_a).await;
        let q = blob(len, 3);
        let mut want = q.clone();
        want.data.reverse();
        let r: Blob = a.query("ask_b", &q).timeout(T).await.unwrap();
        assert_eq!(r, want, "{len} B query from the in-process module");
        let r: Blob = b.query("ask_a", &q).timeout(T).await.unwrap();
        assert_eq!(r, want, "{len} B query to the in-process module");
    }
    a.close().await;
    b.close().await;
    c.shutdown().await;
    sa.await.unwrap();
    sb.await.unwrap();
}

/// Capacity 1 keeps its meaning on an in-process link: central hands the
/// module one message at a time, each after the acknowledgement of the one
/// before, and every message arrives, in order.
#[tokio::test]
async fn a_capacity_one_in_process_subscriber_gets_everything_in_order() {
    let c = central(false).await;
    let sub_side = in_process(&c, "sub").await;
    let pub_side = on_tcp(&c, "pub").await;
    sub_side.ipc().unwrap().set_capacity(1).await.unwrap();
    pub_side.define::<i32>("seq").await.unwrap();
    let mut sub = sub_side.subscribe::<i32>("seq").await.unwrap();
    const N: i32 = 5000;
    let publisher = publish_when_subscribed(&pub_side, "seq", N as usize, |i| i as i32).await;
    for want in 0..N {
        let got = tokio::time::timeout(T, sub.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(got.value, want);
        assert_eq!(got.msg, "seq");
    }
    publisher.await.unwrap();
    let stats = c.stats().await.unwrap();
    assert_eq!(stats.modules, 2, "{stats:?}");
    sub_side.close().await;
    pub_side.close().await;
    c.shutdown().await;
}

/// Direct mode (`central -c`): the in-process module still listens for
/// direct links and links to the others itself, so messages and queries
/// go module to module.
#[tokio::test]
async fn an_in_process_module_links_directly_in_direct_mode() {
    let c = central(true).await;
    let a = in_process(&c, "direct-inproc").await;
    let b = on_tcp(&c, "direct-tcp").await;
    for m in ["d_to_b", "d_to_a", "d_ask", "d_answer"] {
        a.define::<Blob>(m).await.unwrap();
    }
    let mut at_b = b.subscribe::<Blob>("d_to_b").await.unwrap();
    let mut at_a = a.subscribe::<Blob>("d_to_a").await.unwrap();
    let sb = serve_echo(&b, "d_ask", "d_answer").await;
    handlers(&a, "d_to_b", 1).await;
    handlers(&b, "d_to_a", 1).await;
    publish_until_received(&a, "d_to_b", &blob(64, 4), &mut at_b).await;
    publish_until_received(&b, "d_to_a", &blob(64, 5), &mut at_a).await;
    let r: Blob = a.query("d_ask", &blob(8, 6)).timeout(T).await.unwrap();
    let mut want = blob(8, 6);
    want.data.reverse();
    assert_eq!(r, want);
    a.close().await;
    b.close().await;
    c.shutdown().await;
    sb.await.unwrap();
}

/// Central stopping ends the in-process module as a dying central ends a
/// socket module: subscribers end with `Disconnected`, a pending query
/// fails at once; a later connect says central has stopped.
/// `a` subscribed to `m` with a query of it pending when `c` stops: both
/// end at once; the subscriber is returned for what the test checks next.
async fn stop_under_a_subscriber_and_a_query(c: CentralHandle, a: &Session) -> Subscriber<i32> {
    a.define::<i32>("m").await.unwrap();
    let mut sub = a.subscribe::<i32>("m").await.unwrap();
    let q = {
        let a = a.clone();
        tokio::spawn(async move { a.query::<i32, i32>("m", &1).timeout(T).await })
    };
    tokio::time::sleep(Duration::from_millis(100)).await;
    c.shutdown().await;
    common::ended_by_central(&mut sub, q).await;
    sub
}

#[tokio::test]
async fn central_stopping_disconnects_in_process_modules() {
    let c = central(false).await;
    let a = in_process(&c, "a").await;
    // Longer than the test allows: a stopped central must not be retried.
    let late = c.session("late").connect_timeout(Duration::from_secs(60));
    let _sub = stop_under_a_subscriber_and_a_query(c, &a).await;
    match tokio::time::timeout(T, late.connect()).await.unwrap() {
        Err(e @ ConnectError::Unreachable { attempts, .. }) => {
            assert_eq!(attempts, 1, "a stopped central is not retried: {e}");
            // the OS error is the source, not repeated in the message
            let source = std::error::Error::source(&e)
                .expect("the last error")
                .to_string();
            assert!(source.contains("central has stopped"), "{source}");
            assert!(!e.to_string().contains(&source), "{e}");
        }
        Err(e) => panic!("unexpected error: {e}"),
        Ok(_) => panic!("connected to a stopped central"),
    }
}

/// A hosted session with `reconnect` does not retry a central that has
/// stopped (it cannot come back): its subscriber and pending query end as
/// without reconnect, and later calls fail instead of waiting.
#[tokio::test]
async fn a_reconnecting_in_process_module_ends_with_its_stopped_central() {
    let c = central(false).await;
    let a = tokio::time::timeout(
        T,
        c.session("a")
            .reconnect(Duration::from_millis(10))
            .connect(),
    )
    .await
    .unwrap()
    .unwrap();
    let mut sub = stop_under_a_subscriber_and_a_query(c, &a).await;
    // Retrying would leave the stream open (it stays open across reconnects).
    let end = tokio::time::timeout(T, async {
        while let Some(item) = sub.next().await {
            assert!(matches!(item, Err(RecvError::Disconnected)), "{item:?}");
        }
    })
    .await;
    assert!(
        end.is_ok(),
        "the subscriber stayed open: the session is still retrying"
    );
    assert!(a.publish("m", &2).await.is_err());
}

/// A hosted subscriber that stops reading: its keep-all queue fills, it
/// holds its acknowledgement, and central queues for it only up to
/// `max_queued_bytes` before it stops reading the publisher (the rest
/// waits in the publisher's socket: TCP back-pressure). Memory stays
/// bounded; once the subscriber reads again, every message arrives, in
/// order.
#[tokio::test]
async fn a_stalled_in_process_subscriber_bounds_central_and_loses_nothing() {
    const LIMIT: usize = 256 << 10;
    let mut cfg = Config::default();
    cfg.max_queued_bytes = LIMIT;
    let c = central_with(cfg).await;
    let sub_side = in_process(&c, "stalled").await;
    let pub_side = on_tcp(&c, "flooder").await;
    pub_side.define::<Blob>("flood").await.unwrap();
    let mut sub = sub_side
        .subscribe_with::<Blob>("flood", courier::QueuePolicy::KeepAll(2))
        .await
        .unwrap();
    const N: usize = 2000;
    let publisher = publish_when_subscribed(&pub_side, "flood", N, |i| blob(1024, i as u8)).await;
    // Not reading: 2 MiB are published against a 256 KiB limit. The
    // messages wait in central (the subscriber holds its acknowledgement),
    // not in the subscriber's process.
    tokio::time::timeout(T, async {
        while c.stats().await.unwrap().queued_bytes < LIMIT / 2 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("central queues for the stalled subscriber");
    tokio::time::sleep(Duration::from_millis(300)).await;
    let stats = c.stats().await.unwrap();
    assert!(
        stats.peak_queued_bytes <= LIMIT + 64 * 1024,
        "central queued {} bytes for a stalled subscriber (limit {LIMIT} plus one read)",
        stats.peak_queued_bytes
    );
    for i in 0..N {
        let got = tokio::time::timeout(T, sub.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(got.value, blob(1024, i as u8), "message {i}");
    }
    tokio::time::timeout(T, publisher).await.unwrap().unwrap();
    let stats = c.stats().await.unwrap();
    assert_eq!(stats.dropped, 0);
    println!("peak queued in central: {} bytes", stats.peak_queued_bytes);
    sub_side.close().await;
    pub_side.close().await;
    c.shutdown().await;
}
