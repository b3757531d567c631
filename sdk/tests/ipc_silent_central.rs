//! A central that stops answering (audit 22: `subscriber().build()`,
//! `courier echo`, `courier list` and a query's first use waited for ever,
//! and `Session::close` never returned). Questions to central fail after
//! `CENTRAL_ANSWER_TIMEOUT` naming what went unanswered, later ones at
//! once, and a close ends. Central here is a real one behind a
//! relay that stops passing central's bytes on. Every wait is bounded.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use courier::{OpenError, QueryError, CENTRAL_ANSWER_TIMEOUT};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

mod common;

use common::{central, connect, T};

/// Copies `from` to `to`; once `mute` is set, reads and drops.
async fn pass(
    mut from: tokio::net::tcp::OwnedReadHalf,
    mut to: tokio::net::tcp::OwnedWriteHalf,
    mute: Option<Arc<AtomicBool>>,
) {
    let mut buf = vec![0u8; 64 << 10];
    loop {
        let n = match from.read(&mut buf).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        if mute.as_ref().is_some_and(|m| m.load(Ordering::Relaxed)) {
            continue;
        }
        if to.write_all(&buf[..n]).await.is_err() {
            return;
        }
    }
}

/// A relay on 127.0.0.1 (port 0) to `central`: its URL, and the switch
/// that silences central.
async fn relay(central: std::net::SocketAddr) -> (String, Arc<AtomicBool>) {
    let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    let mute = Arc::new(AtomicBool::new(false));
    let m = mute.clone();
    tokio::spawn(async move {
        while let Ok((module, _)) = l.accept().await {
            let Ok(c) = TcpStream::connect(central).await else {
                return;
            };
            let (mr, mw) = module.into_split();
            let (cr, cw) = c.into_split();
            tokio::spawn(pass(mr, cw, None));
            tokio::spawn(pass(cr, mw, Some(m.clone())));
        }
    });
    (format!("ipc://127.0.0.1:{}", addr.port()), mute)
}

#[tokio::test]
async fn a_central_that_stops_answering_fails_calls_in_time_and_close_ends() {
    let (c, _) = central().await;
    let (url, mute) = relay(c.local_addr()).await;
    let s = connect(&url, "silenced").await;
    s.define::<i32>("before").await.unwrap();
    mute.store(true, Ordering::Relaxed);

    // a query ends within its own timeout
    let r: Result<i32, QueryError> =
        tokio::time::timeout(T, s.query("ask", &1i32).timeout(Duration::from_secs(2)))
            .await
            .expect("the query returned within the test's bound");
    assert!(
        matches!(
            r,
            Err(QueryError::Timeout { .. } | QueryError::CentralSilent { .. })
        ),
        "{r:?}"
    );

    // a subscription waits for central's answer no longer than the bound
    let r = tokio::time::timeout(T, s.subscriber::<i32>("news").build())
        .await
        .expect("the subscription returned within the test's bound");
    match r {
        Err(OpenError::Timeout { what, after }) => {
            assert_eq!(after, CENTRAL_ANSWER_TIMEOUT);
            assert!(what.contains("news"), "{what}");
        }
        other => panic!("{:?}", other.map(|_| ())),
    }

    // a question after that one fails at once, saying why
    let r = tokio::time::timeout(T, s.num_handlers("later"))
        .await
        .expect("the question returned within the test's bound");
    match r {
        Err(courier::ControlError::Timeout { what, .. }) => assert!(
            what.contains("later") && what.contains("central has sent nothing since"),
            "{what}"
        ),
        other => panic!("{other:?}"),
    }

    // and a close ends
    tokio::time::timeout(T, s.close())
        .await
        .expect("close returned within the test's bound");
    c.shutdown().await;
}
