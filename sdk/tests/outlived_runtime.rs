//! Handles that outlive the tokio runtime their session ran on (a runtime
//! dropped while a `Session`, `Publisher` or `Subscriber` is kept, then
//! used from another runtime): every call fails with `Disconnected` and
//! every stream ends, on each backend. They waited for ever, and an RTPS
//! `Publisher::publish` said `Ok` for a sample nobody would send.

mod common;
mod xrce_agent;

use std::time::Duration;

use courier::Session;
use futures::StreamExt;

/// Makes a session on a runtime of its own, drops that runtime, then uses
/// the handles on another one.
fn outlive(connect: impl std::future::Future<Output = Session>) {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (s, sub, p) = rt.block_on(async {
        let s = connect.await;
        let sub = s.subscribe::<i32>("x").await.unwrap();
        let p = s.publisher::<i32>("x").build().await.unwrap();
        (s, sub, p)
    });
    drop(rt);
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let e = within("publish", s.publish("x", &1i32)).await.unwrap_err();
        assert!(e.to_string().contains("isconnected"), "{e}");
        let e = within("Publisher::publish", p.publish(&1)).await;
        assert!(
            matches!(e, Err(courier::PublishError::Disconnected(_))),
            "{e:?}"
        );
        let e = within("subscribe", s.subscribe::<i32>("y")).await;
        assert!(
            matches!(e, Err(courier::OpenError::Disconnected(_))),
            "{:?}",
            e.map(|_| ())
        );
        let mut sub = sub;
        within("the subscriber's stream", async {
            while let Some(r) = sub.next().await {
                assert!(r.is_err(), "no sample after the end");
            }
        })
        .await;
        within("close", s.close()).await;
    });
}

/// `f`'s output; panics if it takes 10 s.
async fn within<F: std::future::IntoFuture>(what: &str, f: F) -> F::Output {
    match tokio::time::timeout(Duration::from_secs(10), f).await {
        Ok(v) => v,
        Err(_) => panic!("{what} waited 10 s after its runtime was gone"),
    }
}

#[test]
fn ipc_handles_outliving_their_runtime_fail_at_once() {
    let central_rt = tokio::runtime::Runtime::new().unwrap();
    let (_c, url) = central_rt.block_on(common::central());
    outlive(async move { common::connect(&url, "a").await });
}

#[test]
fn rtps_handles_outliving_their_runtime_fail_at_once() {
    outlive(common::session(1, "a"));
}

#[test]
fn xrce_handles_outliving_their_runtime_fail_at_once() {
    let agent_rt = tokio::runtime::Runtime::new().unwrap();
    let agent = agent_rt.block_on(xrce_agent::udp(0));
    let url = format!("xrce+udp://{}", agent.addr);
    outlive(async move { Session::builder(url).connect().await.unwrap() });
}
