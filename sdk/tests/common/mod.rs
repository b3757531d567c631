//! What the test files share: the RTPS interop peers' types (IDL
//! `courier::test::Msg`, `Keyed` and `Stamped` in tests/peers/rtps/types.idl), loopback
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

/// `courier::test::Stamped` (`@key long id; @key long long stamp;
/// unsigned long seq; string text;`): a key whose XCDR1 and XCDR2 key
/// hashes differ (XCDR1 aligns `stamp` to 8, XCDR2 to 4).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Stamped")]
pub struct Stamped {
    #[ipc(key)]
    pub id: i32,
    #[ipc(key)]
    pub stamp: i64,
    pub seq: u32,
    pub text: String,
}

/// Loopback only, unicast discovery, on the DDS domain leased to `key`
/// (a number naming the test's domain within its test binary; see
/// `courier_tests::domains`).
pub fn url(key: u32) -> String {
    let domain = courier_tests::domains::lease(key);
    format!("rtps://{domain}?interface=lo&peers=127.0.0.1")
}

/// A session on the domain leased to `key`.
pub async fn session(key: u32, name: &str) -> Session {
    tokio::time::timeout(T, Session::builder(url(key)).name(name).connect())
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

pub async fn next<M: IpcMessage, D: courier::Delivery<M>>(
    sub: &mut courier::Subscriber<M, D>,
) -> Result<D::Item, RecvError> {
    tokio::time::timeout(T, sub.next())
        .await
        .expect("a sample in time")
        .expect("stream open")
}

/// Within the bound, every busy poller of this process stops spinning
/// (`what` has gone idle): a state check, not a CPU-time measurement
/// (what idle busy polling costs is a benchmark's business).
pub async fn await_quiet(what: &str) {
    tokio::time::timeout(T, async {
        while courier::busy_poll::spinning() > 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{what}: still spinning after {T:?} idle"));
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

/// Central stopped: the subscriber ends with `Disconnected` (after what
/// was already in flight, if anything) and the pending query fails with
/// `Disconnected`, not with its timeout.
pub async fn ended_by_central(
    sub: &mut courier::Subscriber<i32>,
    query: tokio::task::JoinHandle<Result<i32, courier::QueryError>>,
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
}

/// Courier's central with configuration `cfg`, built further by `more`,
/// embedded on a free port of 127.0.0.1, and its `ipc://` URL. With
/// `CENTRAL_LOG` set, its message log (`-lmsr`) goes to stderr.
pub async fn central_with(
    mut cfg: courier_broker::Config,
    more: impl FnOnce(courier_broker::Builder) -> courier_broker::Builder,
) -> (courier_broker::CentralHandle, String) {
    let mut b = courier_broker::CentralServer::builder();
    if std::env::var_os("CENTRAL_LOG").is_some() {
        cfg.terminal_log = courier_broker::LogOptions::parse("msr", false).unwrap();
        b = b.log_sink(courier_broker::LogSink::new(|_, l: &str| {
            eprintln!("central| {l}")
        }));
    }
    let c = more(b.config(cfg))
        .bind("127.0.0.1".parse().unwrap())
        .port(0)
        .spawn()
        .await
        .unwrap();
    let url = format!("ipc://{}", c.local_addr());
    (c, url)
}

/// Courier's central with C's defaults (see [`central_with`]).
pub async fn central() -> (courier_broker::CentralHandle, String) {
    central_with(courier_broker::Config::default(), |b| b).await
}

/// A session named `name` on `url`, connected within the bound.
pub async fn connect(url: &str, name: &str) -> Session {
    tokio::time::timeout(T, Session::builder(url).name(name).connect())
        .await
        .expect("connect in time")
        .expect("connect")
}

/// Closes `s`, which holds a `listen` callback that holds a publisher of
/// `s` itself (as `listen`'s example answers), and checks that the
/// callback is dropped: the session, its sockets and its tasks must not
/// keep each other alive for ever.
pub async fn close_lets_go_of_a_callback(s: Session) {
    let answer = s.publisher::<i32>("answer").build().await.unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<()>();
    let l = s
        .subscriber::<i32>("ask")
        .listen(move |_| {
            let _ = (&answer, &tx);
        })
        .await
        .unwrap();
    s.close().await;
    drop((l, s));
    // `tx` goes when the callback does
    let end = tokio::task::spawn_blocking(move || rx.recv_timeout(T))
        .await
        .unwrap();
    assert_eq!(
        end,
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected),
        "the callback outlived its session"
    );
}

/// Runs `scenario` on a current-thread runtime of a thread of its own and
/// fails if it has not finished within `bound`: for scenarios whose bug is
/// a hang of the runtime itself, which must fail a test, not hang it.
pub fn on_own_runtime<F, Fut>(bound: Duration, scenario: F)
where
    F: FnOnce() -> Fut + Send + 'static,
    Fut: std::future::Future<Output = ()>,
{
    let (done, finished) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(scenario());
        let _ = done.send(());
    });
    finished
        .recv_timeout(bound)
        .expect("the scenario finished (it hung, or failed above)");
}

/// `b`'s `listen` callback closes `b` itself, blocking on the close; the
/// callback must get out of it (the close goes on once it returns). A
/// sample published by `a` on `topic` calls it.
pub async fn close_inside_own_callback(a: &Session, b: &Session, topic: &str) {
    let p = a.publisher::<i32>(topic).build().await.unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let mut own = Some(b.clone());
    let _l = b
        .subscriber::<i32>(topic)
        .listen(move |_| {
            if let Some(s) = own.take() {
                futures::executor::block_on(s.close());
                let _ = tx.send(());
            }
        })
        .await
        .unwrap();
    // (XRCE counts no handlers: its agent delivers a new writer's first
    // sample to the readers it already has)
    if a.xrce().is_err() {
        await_handlers(a, topic, 1).await;
    }
    p.publish(&1).await.unwrap();
    let returned = tokio::task::spawn_blocking(move || rx.recv_timeout(T))
        .await
        .unwrap();
    assert_eq!(returned, Ok(()), "the callback got out of close()");
}

/// The log lines of this thread (the test's runtime is current-thread, so
/// the sessions' tasks log here too) while the guard lives.
pub fn capture_logs() -> (
    std::sync::Arc<std::sync::Mutex<Vec<u8>>>,
    tracing::subscriber::DefaultGuard,
) {
    let buf = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let sink = buf.clone();
    let sub = tracing_subscriber::fmt()
        .with_ansi(false)
        .with_writer(move || LogSink(sink.clone()))
        .finish();
    (buf, tracing::subscriber::set_default(sub))
}

struct LogSink(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for LogSink {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Polls `f` once, lets the session's tasks run `turns` times, and drops
/// it: an operation cancelled at every stage (a `timeout` or `select!`
/// would drop it anywhere).
pub async fn cancel_after<F: std::future::Future>(f: F, turns: usize) {
    let mut f = std::pin::pin!(f);
    let _ = futures::poll!(&mut f);
    for _ in 0..turns {
        tokio::task::yield_now().await;
    }
}
