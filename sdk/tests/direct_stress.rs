//! Direct mode (`central -c`) under stress: many short serve/query rounds,
//! each on fresh message names as `session-bench` runs them, while other
//! threads keep both cores busy. Every query must be answered: a lost one
//! fails the test with the round and query that got no reply.
//!
//! `DIRECT_STRESS_ROUNDS` (default 60) × `DIRECT_STRESS_QUERIES` (default
//! 300) queries; raise them for a long run.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use courier::IpcMessage;
use futures::StreamExt;

mod common;

/// The bound on one reply (a loaded 2-core machine answers in well under
/// a millisecond).
const REPLY: Duration = Duration::from_secs(10);

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: i32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Threads that spin until dropped: the CPU hog.
struct Hog {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Hog {
    fn start(n: usize) -> Hog {
        let stop = Arc::new(AtomicBool::new(false));
        let threads = (0..n)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
                    }
                })
            })
            .collect();
        Hog { stop, threads }
    }
}

impl Drop for Hog {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_direct_query_is_answered_under_load() {
    if let Some(filter) = std::env::var("RUST_LOG")
        .ok()
        .and_then(|f| f.parse::<tracing_subscriber::filter::Targets>().ok())
    {
        use tracing_subscriber::layer::SubscriberExt;
        use tracing_subscriber::util::SubscriberInitExt;
        let fmt = tracing_subscriber::fmt::layer().with_test_writer();
        let _ = tracing_subscriber::registry()
            .with(fmt)
            .with(filter)
            .try_init();
    }
    let rounds = env("DIRECT_STRESS_ROUNDS", 60);
    let queries = env("DIRECT_STRESS_QUERIES", 300);
    let mut cfg = courier_broker::Config::default();
    cfg.direct = true;
    let (c, url) = common::central_with(cfg, |b| b).await;
    let a = common::connect(&url, "stress-a").await;
    let b = common::connect(&url, "stress-b").await;
    let _hog = Hog::start(2);
    let payload = Blob {
        n: 4,
        data: vec![7; 4],
    };
    for round in 0..rounds {
        let (ask, answer) = (format!("ask{round}"), format!("answer{round}"));
        let mut reqs = b.serve::<Blob, Blob>(&ask, &answer).await.unwrap();
        a.num_handlers(&ask).await.unwrap();
        let srv = tokio::spawn(async move {
            for _ in 0..queries {
                let r = reqs.next().await.unwrap().unwrap();
                let v = r.value.clone();
                r.reply(&v).await.unwrap();
            }
        });
        for q in 0..queries {
            let r = a.query::<Blob, Blob>(&ask, &payload).timeout(REPLY).await;
            match r {
                Ok(r) => assert_eq!(r, payload),
                Err(e) => panic!("round {round}, query {q} of {ask}: {e}"),
            }
        }
        tokio::time::timeout(REPLY, srv)
            .await
            .expect("server done")
            .unwrap();
    }
    a.close().await;
    b.close().await;
    c.shutdown().await;
}
