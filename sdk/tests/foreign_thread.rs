//! A session awaited from a thread outside any tokio runtime (with
//! `futures::executor::block_on`, as a GUI or a C callback thread would):
//! the calls that make tokio timers or tasks make them on the session's
//! own runtime. Queries (IPC and XRCE), `wait_for_handlers`, `every` and
//! `after`, `send_every`, `listen` and a confirmed XRCE publish panicked
//! in tokio ("there is no reactor running") before.

mod common;
mod xrce_agent;

use std::future::IntoFuture;
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use courier::Session;
use futures::executor::block_on;
use futures::StreamExt;

const T: Duration = Duration::from_secs(20);

/// Runs `f` on a plain thread; its result, or a failure naming `what` if
/// it panicked or took longer than [`T`].
fn on_plain_thread<R: Send + 'static>(what: &str, f: impl FnOnce() -> R + Send + 'static) -> R {
    let (tx, rx) = mpsc::channel();
    let t = std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(T) {
        Ok(r) => {
            t.join().unwrap();
            r
        }
        Err(_) => match t.join() {
            Err(p) => panic!(
                "{what} panicked on a plain thread: {}",
                p.downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| p.downcast_ref::<&str>().copied())
                    .unwrap_or("?")
            ),
            Ok(()) => panic!("{what} took more than {T:?} on a plain thread"),
        },
    }
}

/// `server` answers `x + 1` on `inc` and subscribes `tick`; `user` is
/// used from plain threads only.
fn scenario(rt: &tokio::runtime::Runtime, server: Session, user: Session, handlers: bool) {
    let mut ticks = rt.block_on(async {
        let mut reqs = server.serve::<i32, i32>("inc", "").await.unwrap();
        tokio::spawn(async move {
            while let Some(Ok(r)) = reqs.next().await {
                let x = r.value;
                let _ = r.reply(&(x + 1)).await;
            }
        });
        server.subscribe::<i32>("tick").await.unwrap()
    });
    let user = Arc::new(user);

    let u = user.clone();
    let answer = on_plain_thread("query", move || {
        block_on(async {
            let mut last = None;
            // the server's reader may need a moment to be found (DDS)
            for _ in 0..20 {
                last = Some(
                    u.query::<i32, i32>("inc", &41)
                        .timeout(Duration::from_secs(1))
                        .await,
                );
                if matches!(last, Some(Ok(_))) {
                    break;
                }
            }
            last.unwrap()
        })
    });
    assert_eq!(answer.unwrap(), 42);

    let u = user.clone();
    let unanswered = on_plain_thread("a query nobody serves", move || {
        block_on(
            u.query::<i32, i32>("nobody", &1)
                .timeout(Duration::from_millis(300))
                .into_future(),
        )
    });
    assert!(unanswered.is_err(), "{unanswered:?}");

    if handlers {
        let u = user.clone();
        let p = on_plain_thread("publisher", move || {
            block_on(u.publisher::<i32>("tick").build()).unwrap()
        });
        let u = user.clone();
        let n = on_plain_thread("wait_for_handlers", move || {
            block_on(u.wait_for_handlers("tick", 1, Duration::from_secs(10)))
        });
        assert!(n.unwrap() >= 1);
        drop(p);
    }

    let u = user.clone();
    let ticked = on_plain_thread("every and after", move || {
        let mut every = u.every(Duration::from_millis(10));
        let mut after = u.after(Duration::from_millis(10));
        block_on(async { (every.next().await.is_some(), after.next().await.is_some()) })
    });
    assert_eq!(ticked, (true, true));

    let u = user.clone();
    let periodic = on_plain_thread("send_every", move || {
        let p = block_on(u.publisher::<i32>("tick").build()).unwrap();
        p.send_every(Duration::from_millis(20), |_| Some(7))
    });
    let got = rt.block_on(async { tokio::time::timeout(T, ticks.next()).await });
    assert_eq!(got.expect("a tick in time").unwrap().unwrap().value, 7);
    drop(periodic);

    let u = user.clone();
    let heard = on_plain_thread("listen", move || {
        let (tx, rx) = mpsc::channel();
        let listener = block_on(u.subscriber::<i32>("told").listen(move |v| {
            let _ = tx.send(v);
        }))
        .unwrap();
        (listener, rx)
    });
    let (listener, rx) = heard;
    rt.block_on(async {
        let p = server.publisher::<i32>("told").build().await.unwrap();
        for _ in 0..100 {
            let _ = p.publish(&5).await;
            if let Ok(v) = rx.try_recv() {
                assert_eq!(v.unwrap().value, 5);
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("the listen callback made on a plain thread never ran");
    });
    drop(listener);
    rt.block_on(async {
        server.close().await;
        user.close().await;
    });
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

#[test]
fn ipc_session_from_a_plain_thread() {
    let rt = runtime();
    let (_central, url) = rt.block_on(common::central());
    let (a, b) = rt.block_on(async {
        (
            common::connect(&url, "a").await,
            common::connect(&url, "b").await,
        )
    });
    scenario(&rt, a, b, true);
}

#[test]
fn rtps_session_from_a_plain_thread() {
    let rt = runtime();
    let (a, b) =
        rt.block_on(async { (common::session(1, "a").await, common::session(1, "b").await) });
    scenario(&rt, a, b, true);
}

#[test]
fn xrce_session_from_a_plain_thread() {
    let rt = runtime();
    let agent = rt.block_on(xrce_agent::udp(0));
    let url = format!("xrce+udp://{}", agent.addr);
    let (a, b) = rt.block_on(async {
        (
            Session::builder(url.as_str()).connect().await.unwrap(),
            Session::builder(url.as_str()).connect().await.unwrap(),
        )
    });
    scenario(&rt, a, b, false);
    let u = {
        let url = url.clone();
        rt.block_on(async move { Arc::new(Session::builder(url).connect().await.unwrap()) })
    };
    let confirmed = on_plain_thread("a confirmed publish", move || {
        block_on(
            u.publish("confirmed", &3i32)
                .confirmed_within(Duration::from_secs(5))
                .into_future(),
        )
    });
    confirmed.unwrap();
    drop(agent);
}
