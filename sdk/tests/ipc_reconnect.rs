//! IPC with `SessionBuilder::reconnect`: while no connection to central
//! exists, operations fail at once with the disconnected error instead of
//! waiting behind the reconnect attempt (a 50 Hz control loop froze for
//! ~4.8 s per attempt: each attempt retried the TCP connect for the whole
//! connect timeout, and the commands queued behind it). Every wait is
//! bounded.

use std::time::Duration;

use courier::{PublishError, QueryError, Session, SessionEvent};
use courier_broker::CentralServer;
use futures::StreamExt;

mod common;

use common::{central, connect as session, T};

/// The bound on one operation while central is away: not a performance
/// figure, a bound on a hang (the bug was a ~5 s wait per call).
const PROMPT: Duration = Duration::from_secs(1);

/// Waits for `want` among the session's events.
async fn await_event(ev: &mut courier::Events, want: SessionEvent) {
    tokio::time::timeout(T, async {
        while let Some(e) = ev.next().await {
            if e == want {
                return;
            }
        }
        panic!("the events ended before {want:?}");
    })
    .await
    .unwrap_or_else(|_| panic!("no {want:?} within {T:?}"));
}

#[tokio::test]
async fn operations_fail_at_once_while_central_is_away_and_work_once_it_is_back() {
    let (c, url) = central().await;
    let port = c.local_addr().port();
    let s = tokio::time::timeout(
        T,
        Session::builder(&url)
            .name("planner")
            .reconnect(Duration::from_millis(50))
            .connect(),
    )
    .await
    .expect("connect in time")
    .expect("connect");
    s.define::<i32>("cmd").await.unwrap();
    s.define::<i32>("plan").await.unwrap();
    s.publish("cmd", &0).await.unwrap();
    let mut ev = s.events();
    c.shutdown().await;
    await_event(&mut ev, SessionEvent::Disconnected).await;

    // central away for a few seconds: reconnect attempts run meanwhile
    let away = tokio::time::Instant::now() + Duration::from_secs(3);
    let (mut publishes, mut queries) = (0, 0);
    while tokio::time::Instant::now() < away {
        let r = tokio::time::timeout(PROMPT, s.publish("cmd", &publishes))
            .await
            .unwrap_or_else(|_| {
                panic!("publish {publishes} while disconnected hung for {PROMPT:?}")
            });
        assert!(
            matches!(r, Err(PublishError::Disconnected(_))),
            "publish {publishes}: {r:?}"
        );
        publishes += 1;
        if publishes % 10 == 0 {
            let q = s
                .query::<i32, i32>("plan", &1)
                .timeout(Duration::from_millis(500));
            let r = tokio::time::timeout(T, q)
                .await
                .unwrap_or_else(|_| panic!("query {queries} hung for {T:?}"));
            match r {
                Err(QueryError::Disconnected(m)) => assert_eq!(m, "plan"),
                other => panic!("query {queries} while disconnected: {other:?}"),
            }
            queries += 1;
            let n = tokio::time::timeout(PROMPT, s.num_handlers("cmd"))
                .await
                .unwrap_or_else(|_| panic!("num_handlers while disconnected hung"));
            assert!(
                matches!(n, Err(courier::ControlError::Disconnected(_))),
                "{n:?}"
            );
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(queries > 0);

    // central back on the same port: the session reconnects and works
    let c2 = CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(port)
        .spawn()
        .await
        .unwrap();
    await_event(&mut ev, SessionEvent::Reconnected).await;
    let robot = session(&url, "robot").await;
    let mut sub = robot.subscribe::<i32>("cmd").await.unwrap();
    let got = tokio::time::timeout(T, async {
        loop {
            // the planner learns of the new subscriber from central
            s.publish("cmd", &42).await.unwrap();
            if let Ok(Some(v)) = tokio::time::timeout(Duration::from_millis(100), sub.next()).await
            {
                break v.unwrap().value;
            }
        }
    })
    .await
    .expect("a publish after the reconnect arrives");
    assert_eq!(got, 42);
    s.close().await;
    robot.close().await;
    c2.shutdown().await;
}

/// Once a new TCP connection is up, operations wait for its handshake, and
/// no longer than the connect timeout: a listener on central's port that
/// accepts and never answers holds a publish that long at most (then it
/// fails as disconnected), and the session still reconnects to the real
/// central afterwards.
#[tokio::test]
async fn a_handshake_that_never_ends_holds_operations_no_longer_than_the_connect_timeout() {
    let (c, url) = central().await;
    let addr = c.local_addr();
    let s = tokio::time::timeout(
        T,
        Session::builder(&url)
            .name("planner")
            .reconnect(Duration::from_millis(50))
            .connect_timeout(Duration::from_millis(500))
            .connect(),
    )
    .await
    .expect("connect in time")
    .expect("connect");
    s.define::<i32>("cmd").await.unwrap();
    let mut ev = s.events();
    c.shutdown().await;
    await_event(&mut ev, SessionEvent::Disconnected).await;
    // a silent peer where central was: connections open, handshakes hang
    let silent = tokio::net::TcpListener::bind(addr).await.unwrap();
    let accepting = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((conn, _)) = silent.accept().await {
            held.push(conn);
        }
    });
    for i in 0..5 {
        let r = tokio::time::timeout(T, s.publish("cmd", &i))
            .await
            .unwrap_or_else(|_| panic!("publish {i} hung for {T:?}"));
        assert!(
            matches!(r, Err(PublishError::Disconnected(_))),
            "{i}: {r:?}"
        );
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    accepting.abort();
    let _ = accepting.await;
    let c2 = CentralServer::builder()
        .bind(addr.ip())
        .port(addr.port())
        .spawn()
        .await
        .unwrap();
    await_event(&mut ev, SessionEvent::Reconnected).await;
    tokio::time::timeout(T, s.publish("cmd", &7))
        .await
        .expect("publish in time")
        .unwrap();
    s.close().await;
    c2.shutdown().await;
}
