//! The Session API against Courier's own central, embedded on a free port
//! of 127.0.0.1. Every wait is bounded.

use std::time::Duration;

use courier::{IpcMessage, QueryError, RecvError, Session, SessionEvent};
use courier_broker::{CentralHandle, CentralServer};
use futures::StreamExt;

mod common;

const T: Duration = Duration::from_secs(20);

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Point {
    x: f64,
    y: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Path {
    name: String,
    n: i32,
    #[ipc(len = "n")]
    points: Vec<Point>,
}

use common::{central, connect as session};

#[tokio::test]
async fn publish_subscribe_typed() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    a.define::<Path>("path").await.unwrap();
    let mut sub = b.subscribe::<Path>("path").await.unwrap();
    // Central confirms b's subscription reached it before a publishes.
    assert_eq!(
        tokio::time::timeout(T, b.num_handlers("path"))
            .await
            .unwrap()
            .unwrap(),
        1
    );
    // a learns the new subscriber through the broadcast list it watches.
    let p = Path {
        name: "square".into(),
        n: 2,
        points: vec![Point { x: 0.0, y: 1.0 }, Point { x: 2.0, y: 3.0 }],
    };
    let deadline = tokio::time::Instant::now() + T;
    let got = loop {
        a.publish("path", &p).await.unwrap();
        if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await {
            break s.unwrap();
        }
        assert!(tokio::time::Instant::now() < deadline);
    };
    assert_eq!(got.value, p);
    assert_eq!(got.msg, "path");
    // Raw bytes both ways.
    let mut raw = b.subscribe_raw("path").await.unwrap();
    a.publish_raw("path", &courier::ipc::to_vec(&p))
        .await
        .unwrap();
    let r = tokio::time::timeout(T, raw.recv()).await.unwrap().unwrap();
    assert_eq!(courier::ipc::from_slice::<Path>(&r.data).unwrap(), p);
    // a raw subscription is a Stream too, ending with the connection
    a.publish_raw("path", &courier::ipc::to_vec(&p))
        .await
        .unwrap();
    let r = tokio::time::timeout(T, raw.next()).await.unwrap().unwrap();
    assert_eq!(courier::ipc::from_slice::<Path>(&r.data).unwrap(), p);
    b.close().await;
    assert!(tokio::time::timeout(T, raw.next()).await.unwrap().is_none());
    drop(raw);
    a.close().await;
    c.shutdown().await;
}

/// Immediate subscriptions work on IPC too: the session runs the callback
/// on a task of its own, in order, and ends it with the connection.
/// Publishing without waiting is refused with the way to do it.
#[tokio::test]
async fn listen_callbacks_on_ipc_and_try_publish_refused() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let (tx, rx) = std::sync::mpsc::channel();
    let l = b
        .subscriber::<Point>("point")
        .listen(move |s| drop(tx.send(s)))
        .await
        .unwrap();
    assert_eq!(l.msg(), "point");
    let p = a.publisher::<Point>("point").build().await.unwrap();
    tokio::time::timeout(T, async {
        while a.num_handlers("point").await.unwrap() < 1 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .unwrap();
    for i in 0..100 {
        p.publish(&Point {
            x: f64::from(i),
            y: 0.0,
        })
        .await
        .unwrap();
    }
    let got = tokio::task::spawn_blocking(move || {
        let mut got = Vec::new();
        while got.len() < 100 {
            let s = rx.recv_timeout(T).expect("a callback in time");
            got.push(s.unwrap().value.x as i32);
        }
        (got, rx)
    })
    .await
    .unwrap();
    assert_eq!(got.0, (0..100).collect::<Vec<_>>());
    let e = p.try_publish(&Point { x: 0.0, y: 0.0 }).unwrap_err();
    assert!(e.to_string().contains("publish().await"), "{e}");
    // a close asked for is no error: the callback is dropped uncalled
    let d = session(&url, "d").await;
    let (tx, rx) = std::sync::mpsc::channel();
    let l2 = d
        .subscriber::<Point>("point")
        .listen(move |s| drop(tx.send(s)))
        .await
        .unwrap();
    d.close().await;
    drop(l2);
    let end = tokio::task::spawn_blocking(move || rx.recv_timeout(T))
        .await
        .unwrap();
    assert_eq!(
        end.unwrap_err(),
        std::sync::mpsc::RecvTimeoutError::Disconnected
    );
    // a lost connection is
    c.shutdown().await;
    let end = tokio::task::spawn_blocking(move || got.1.recv_timeout(T))
        .await
        .unwrap()
        .expect("the end of the connection reaches the callback");
    assert_eq!(end.unwrap_err(), RecvError::Disconnected);
    a.close().await;
    b.close().await;
}

#[tokio::test]
async fn query_serve_with_delayed_reply_and_many_concurrent_queries() {
    let (c, url) = central().await;
    let server = session(&url, "server").await;
    let client = session(&url, "client").await;
    server.define::<i32>("square").await.unwrap();
    server.define::<i64>("squared").await.unwrap();
    let mut reqs = server.serve::<i32, i64>("square", "squared").await.unwrap();
    // Central hands a module at most `capacity` queries at once.
    server.ipc().unwrap().set_capacity(20).await.unwrap();
    assert_eq!(
        tokio::time::timeout(T, client.num_handlers("square"))
            .await
            .unwrap()
            .unwrap(),
        1
    );
    // The server answers from other tasks, in reverse order of arrival.
    let srv = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Some(r) = reqs.next().await {
            held.push(r.unwrap());
            if held.len() == 20 {
                break;
            }
        }
        let mut tasks = Vec::new();
        for r in held.into_iter().rev() {
            tasks.push(tokio::spawn(async move {
                let v = r.value as i64;
                r.reply(&(v * v)).await.unwrap();
            }));
        }
        for t in tasks {
            t.await.unwrap();
        }
        reqs
    });
    let mut qs = Vec::new();
    for i in 0..20i32 {
        let client = client.clone();
        qs.push(tokio::spawn(async move {
            let r: i64 = client.query("square", &i).timeout(T).await.unwrap();
            assert_eq!(r, (i as i64) * (i as i64));
        }));
    }
    for q in qs {
        tokio::time::timeout(T, q).await.unwrap().unwrap();
    }
    let mut reqs = tokio::time::timeout(T, srv).await.unwrap().unwrap();
    // A reply of the wrong type is an error, not a panic.
    let bad = tokio::spawn(async move {
        let r = reqs.next().await.unwrap().unwrap();
        r.reply(&1i64).await.unwrap();
    });
    let e = client
        .query::<i32, String>("square", &3)
        .timeout(T)
        .await
        .unwrap_err();
    assert!(matches!(e, QueryError::Decode { .. }), "{e}");
    bad.await.unwrap();
    client.close().await;
    server.close().await;
    c.shutdown().await;
}

#[tokio::test]
async fn query_timeout_and_events() {
    let (c, url) = central().await;
    let a = session(&url, "watcher").await;
    a.define::<i32>("nobody_serves").await.unwrap();
    let e = a
        .query::<i32, i32>("nobody_serves", &1)
        .timeout(Duration::from_millis(200))
        .await
        .unwrap_err();
    // nobody serves it: said so (central holds it until a server comes)
    assert!(matches!(e, QueryError::NoResponder { .. }), "{e}");
    assert_eq!(e.to_string(), "nobody serves nobody_serves (waited 200ms)");
    assert!(a.is_module_connected("watcher").await.unwrap());
    assert!(!a.is_module_connected("ghost").await.unwrap());
    a.ipc().unwrap().set_capacity(2).await.unwrap();
    a.ipc()
        .unwrap()
        .set_priority("nobody_serves", 3)
        .await
        .unwrap();
    a.ipc()
        .unwrap()
        .set_queue_length("nobody_serves", 5)
        .await
        .unwrap();
    c.shutdown().await;
}

#[tokio::test]
async fn central_dying_ends_subscribers_and_fails_queries_at_once() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    a.define::<i32>("m").await.unwrap();
    let mut sub = a.subscribe::<i32>("m").await.unwrap();
    let mut events = a.events();
    let q = {
        let a = a.clone();
        tokio::spawn(async move { a.query::<i32, i32>("m", &1).timeout(T).await })
    };
    tokio::time::sleep(Duration::from_millis(100)).await;
    c.shutdown().await;
    common::ended_by_central(&mut sub, q).await;
    loop {
        match tokio::time::timeout(T, events.next()).await.unwrap() {
            Some(SessionEvent::Disconnected) | None => break,
            Some(_) => {}
        }
    }
    assert!(a.publish("m", &1).await.is_err());
}

#[tokio::test(start_paused = true)]
async fn timers_tick_on_schedule() {
    let (c, url) = central().await;
    let a = session(&url, "timers").await;
    let start = tokio::time::Instant::now();
    let ticks: Vec<_> = a.times(3, Duration::from_millis(100)).collect().await;
    assert_eq!(ticks.len(), 3);
    for (i, t) in ticks.iter().enumerate() {
        assert_eq!(
            t.scheduled,
            start + Duration::from_millis(100 * (i as u64 + 1))
        );
        assert!(t.fired >= t.scheduled);
    }
    let once: Vec<_> = a.after(Duration::from_secs(5)).collect().await;
    assert_eq!(once.len(), 1);
    let mut every = a.every(Duration::from_secs(1));
    for _ in 0..5 {
        every.next().await.unwrap();
    }
    // closing the session ends its timers, also one waiting for a tick
    let mut hourly = a.every(Duration::from_secs(3600));
    let waiting = tokio::spawn(async move { hourly.next().await });
    a.close().await;
    assert_eq!(waiting.await.unwrap(), None);
    assert_eq!(every.next().await, None);
    c.shutdown().await;
}

#[tokio::test]
async fn bad_url_and_unreachable_central_say_where() {
    let e = Session::builder("tcp://x").connect().await.unwrap_err();
    assert!(e.to_string().contains("unknown URL scheme \"tcp\""), "{e}");
    let e = Session::builder("ipc://x:notaport")
        .connect()
        .await
        .unwrap_err();
    assert!(e.to_string().contains("bad session URL"), "{e}");
    // A port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let e = Session::builder(format!("ipc://127.0.0.1:{port}"))
        .connect_timeout(Duration::from_millis(500))
        .connect()
        .await
        .unwrap_err();
    assert!(e.to_string().contains(&format!("127.0.0.1:{port}")), "{e}");
}

#[tokio::test]
async fn connect_disconnect_and_handler_events() {
    let (c, url) = central().await;
    let a = session(&url, "observer").await;
    a.define::<i32>("topic").await.unwrap();
    let mut ev = a.events();
    a.watch_handlers("topic").await.unwrap();
    // Make sure central has the subscriptions before the newcomer arrives.
    a.is_module_connected("x").await.unwrap();
    let b = session(&url, "newcomer").await;
    let sub = b.subscribe::<i32>("topic").await.unwrap();
    b.num_handlers("topic").await.unwrap();
    drop(sub);
    b.close().await;
    let mut seen = Vec::new();
    while !seen.contains(&SessionEvent::ModuleDisconnected("newcomer".into())) {
        let e = tokio::time::timeout(T, ev.next()).await.unwrap().unwrap();
        seen.push(e);
    }
    assert!(
        seen.contains(&SessionEvent::ModuleConnected("newcomer".into())),
        "{seen:?}"
    );
    assert!(
        seen.contains(&SessionEvent::HandlersChanged {
            msg: "topic".into(),
            count: 1
        }),
        "{seen:?}"
    );
    a.close().await;
    c.shutdown().await;
}

/// Direct mode (`central -c`): messages go module to module over links
/// the sessions open themselves; the first message after the subscriber
/// appears is not lost.
#[tokio::test]
async fn direct_mode_publish_and_query() {
    let mut cfg = courier_broker::Config::default();
    cfg.direct = true;
    let c = CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(0)
        .config(cfg)
        .spawn()
        .await
        .unwrap();
    let url = format!("ipc://{}", c.local_addr());
    // (the only direct-mode test of this binary: the /tmp/x_ipc files that
    // appear are these two sessions')
    let before = x_ipc_direct_files();
    let a = session(&url, "direct-a").await;
    let b = session(&url, "direct-b").await;
    let ours: Vec<String> = x_ipc_direct_files()
        .into_iter()
        .filter(|f| !before.contains(f))
        .collect();
    assert_eq!(
        ours.len(),
        2,
        "each module listens at /tmp/x_ipc/<its direct port>, as C does: {ours:?}"
    );
    a.define::<i32>("d_msg").await.unwrap();
    a.define::<i32>("d_ask").await.unwrap();
    a.define::<i32>("d_answer").await.unwrap();
    let mut sub = b.subscribe::<i32>("d_msg").await.unwrap();
    let mut reqs = b.serve::<i32, i32>("d_ask", "d_answer").await.unwrap();
    assert_eq!(b.num_handlers("d_msg").await.unwrap(), 1);
    let srv = tokio::spawn(async move {
        let r = reqs.next().await.unwrap().unwrap();
        let v = r.value;
        r.reply(&(v + 1)).await.unwrap();
        reqs
    });
    a.publish("d_msg", &7).await.unwrap();
    let got = tokio::time::timeout(T, sub.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(got.value, 7);
    let r: i32 = a.query("d_ask", &41).timeout(T).await.unwrap();
    assert_eq!(r, 42);
    let _served = tokio::time::timeout(T, srv).await.unwrap().unwrap();
    // the link a -> b is a UNIX socket: /proc/net/unix lists the accepted
    // end under the listener's path besides the two listeners
    let unix_ends = unix_sockets_at(&ours);
    assert!(
        unix_ends >= 3,
        "{unix_ends} UNIX sockets at {ours:?}: the direct link is not over the UNIX socket"
    );
    a.close().await;
    b.close().await;
    // closing removes the socket files
    let gone = tokio::time::timeout(T, async {
        while ours.iter().any(|f| std::path::Path::new(f).exists()) {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(gone.is_ok(), "{ours:?} left behind after close");

    // a stale socket file (its process died) at the port the next module
    // will take does not stop it: it is replaced by a live listener
    let port = (8000..9000u16)
        .find(|p| std::net::TcpListener::bind(("127.0.0.1", *p)).is_ok())
        .unwrap();
    let stale = format!("/tmp/x_ipc/{port}");
    let _ = std::fs::remove_file(&stale);
    drop(std::os::unix::net::UnixListener::bind(&stale).unwrap());
    assert!(std::os::unix::net::UnixStream::connect(&stale).is_err());
    let d = session(&url, "direct-d").await;
    assert!(
        std::os::unix::net::UnixStream::connect(&stale).is_ok(),
        "the stale {stale} was not replaced by the module's listener"
    );
    d.close().await;
    c.shutdown().await;
}

/// `/tmp/x_ipc/<port>` files of the direct-link port range.
fn x_ipc_direct_files() -> Vec<String> {
    let Ok(dir) = std::fs::read_dir("/tmp/x_ipc") else {
        return Vec::new();
    };
    dir.filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.parse::<u16>().is_ok_and(|p| (8000..9000).contains(&p)))
        .map(|n| format!("/tmp/x_ipc/{n}"))
        .collect()
}

/// How many UNIX sockets (listening or connected) carry one of `paths`.
fn unix_sockets_at(paths: &[String]) -> usize {
    std::fs::read_to_string("/proc/net/unix")
        .unwrap()
        .lines()
        .filter(|l| {
            l.split_whitespace()
                .nth(7)
                .is_some_and(|p| paths.iter().any(|x| x == p))
        })
        .count()
}

/// With the host given as this machine's name, the session prefers the UNIX
/// socket `/tmp/x_ipc/<port>`, as the C library does.
#[tokio::test]
async fn unix_socket_when_central_is_this_host() {
    let c = CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(0)
        .unix_socket(true)
        .spawn()
        .await
        .unwrap();
    let port = c.local_addr().port();
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .unwrap()
        .trim()
        .to_string();
    // The TCP port is bound to 127.0.0.1 only, so reaching central through
    // the host name works only over the UNIX socket (or loopback).
    let a = session(&format!("ipc://{host}:{port}"), "unix-a").await;
    a.define::<i32>("u").await.unwrap();
    let mut sub = a.subscribe::<i32>("u").await.unwrap();
    a.num_handlers("u").await.unwrap();
    a.publish("u", &5).await.unwrap();
    assert_eq!(
        tokio::time::timeout(T, sub.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap()
            .value,
        5
    );
    a.close().await;
    c.shutdown().await;
}

#[tokio::test]
async fn raw_query_and_serve() {
    let (c, url) = central().await;
    let a = session(&url, "raw-a").await;
    let b = session(&url, "raw-b").await;
    b.define::<i32>("raw_q").await.unwrap();
    b.define::<i32>("raw_r").await.unwrap();
    let mut reqs = b.serve_raw("raw_q").await.unwrap();
    a.num_handlers("raw_q").await.unwrap();
    let srv = tokio::spawn(async move {
        let r = reqs.recv().await.unwrap();
        assert_eq!(r.data, courier::ipc::to_vec(&9i32));
        r.respond
            .reply("raw_r", courier::ipc::to_vec(&10i32))
            .await
            .unwrap();
        reqs
    });
    let (reply, data, _) = a
        .query_raw("raw_q", &courier::ipc::to_vec(&9i32), T)
        .await
        .unwrap();
    assert_eq!(reply, "raw_r");
    assert_eq!(courier::ipc::from_slice::<i32>(&data).unwrap(), 10);
    let _served = srv.await.unwrap();
    c.shutdown().await;
}

/// A central, a publisher, and a subscriber (with `policy`, and central's
/// queue length for it when given) that 0..10 were published to before it
/// read anything.
async fn flood_a_subscriber(
    msg: &str,
    policy: courier::QueuePolicy,
    central_limit: Option<i32>,
) -> (CentralHandle, [Session; 2], courier::Subscriber<i32>) {
    let (c, url) = central().await;
    let p = session(&url, &format!("{msg}-pub")).await;
    let s = session(&url, &format!("{msg}-sub")).await;
    p.define::<i32>(msg).await.unwrap();
    let sub = s.subscribe_with::<i32>(msg, policy).await.unwrap();
    if let Some(n) = central_limit {
        s.ipc().unwrap().set_queue_length(msg, n).await.unwrap();
    }
    p.num_handlers(msg).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    for i in 0..10 {
        p.publish(msg, &i).await.unwrap();
    }
    (c, [p, s], sub)
}

/// A subscriber that does not read: keep-last keeps the newest and counts
/// what it dropped.
#[tokio::test]
async fn keep_last_drops_the_oldest_and_counts() {
    let (c, _sessions, mut sub) =
        flood_a_subscriber("kl", courier::QueuePolicy::KeepLast(3), None).await;
    let deadline = tokio::time::Instant::now() + T;
    while sub.dropped() < 7 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "dropped {}",
            sub.dropped()
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut got = Vec::new();
    for _ in 0..3 {
        got.push(
            tokio::time::timeout(T, sub.next())
                .await
                .unwrap()
                .unwrap()
                .unwrap()
                .value,
        );
    }
    assert_eq!(got, vec![7, 8, 9]);
    assert_eq!(sub.dropped(), 7);
    c.shutdown().await;
}

/// A slow keep-all subscriber holds its acknowledgement, so central queues
/// the rest and its queue length limit (IPC_setMsgQueueLength) applies.
#[tokio::test]
async fn slow_keep_all_subscriber_with_central_queue_limit() {
    let (c, [p, _s], mut sub) =
        flood_a_subscriber("ql", courier::QueuePolicy::KeepAll(2), Some(3)).await;
    // Everything published has reached central once this is answered.
    p.is_module_connected("nobody").await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let mut got = Vec::new();
    while let Ok(Some(v)) = tokio::time::timeout(Duration::from_millis(500), sub.next()).await {
        got.push(v.unwrap().value);
    }
    // Which middle ones survive depends on how the publishes and the
    // acknowledgements interleave in central; the newest three always do,
    // and at most 2 queued + 1 held + 3 limited ones arrive.
    assert!(got.len() <= 6 && got.len() >= 4, "{got:?}");
    assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
    assert_eq!(got[got.len() - 3..], [7, 8, 9], "{got:?}");
    assert_eq!(got[0], 0, "{got:?}");
    c.shutdown().await;
}

/// With reconnect on, a session survives central restarting on the same
/// port: it defines and subscribes again and the same Subscriber goes on.
#[tokio::test]
async fn reconnects_and_resubscribes_after_central_restarts() {
    let (c, url) = central().await;
    let port = c.local_addr().port();
    let s = tokio::time::timeout(
        T,
        Session::builder(&url)
            .name("survivor")
            .reconnect(Duration::from_millis(50))
            .connect(),
    )
    .await
    .unwrap()
    .unwrap();
    s.define::<i32>("again").await.unwrap();
    let mut sub = s.subscribe::<i32>("again").await.unwrap();
    let mut ev = s.events();
    c.shutdown().await;
    loop {
        match tokio::time::timeout(T, ev.next()).await.unwrap().unwrap() {
            SessionEvent::Disconnected => break,
            _ => continue,
        }
    }
    let c2 = CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(port)
        .spawn()
        .await
        .unwrap();
    loop {
        match tokio::time::timeout(T, ev.next()).await.unwrap().unwrap() {
            SessionEvent::Reconnected => break,
            _ => continue,
        }
    }
    let p = session(&url, "publisher").await;
    assert_eq!(p.num_handlers("again").await.unwrap(), 1, "re-subscribed");
    p.publish("again", &5).await.unwrap();
    let v = tokio::time::timeout(T, sub.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(v.value, 5);
    s.close().await;
    c2.shutdown().await;
}

/// Busy-polling sessions and a busy-polling central answer queries like any
/// other, and their busy pollers stop spinning once traffic stops.
#[tokio::test(flavor = "current_thread")]
async fn busy_polling_answers_queries_and_goes_quiet_when_idle() {
    let window = Duration::from_millis(20);
    let (c, url) =
        common::central_with(courier_broker::Config::default(), |b| b.busy_poll(window)).await;
    let connect = |name: &'static str| {
        Session::builder(url.clone())
            .name(name)
            .busy_poll(window)
            .connect()
    };
    let a = tokio::time::timeout(T, connect("spin-a"))
        .await
        .unwrap()
        .unwrap();
    let b = tokio::time::timeout(T, connect("spin-b"))
        .await
        .unwrap()
        .unwrap();
    a.define::<i32>("spin_q").await.unwrap();
    a.define::<i32>("spin_r").await.unwrap();
    let mut reqs = b.serve::<i32, i32>("spin_q", "spin_r").await.unwrap();
    let srv = tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let v = r.value;
            r.reply(&(v * 2)).await.unwrap();
        }
    });
    for i in 0..200 {
        let r: i32 = a.query("spin_q", &i).timeout(T).await.unwrap();
        assert_eq!(r, i * 2);
    }
    // Idle: after the window nothing spins.
    tokio::time::sleep(window * 3).await;
    common::await_quiet("an idle busy-polling central and sessions").await;
    // Traffic again: still answered.
    let r: i32 = a.query("spin_q", &21).timeout(T).await.unwrap();
    assert_eq!(r, 42);
    a.close().await;
    b.close().await;
    srv.await.unwrap();
    c.shutdown().await;
}

/// A module learns a message's format from central, as C's `msgInfo`
/// does: tools that meet a message at run time decode it through that.
#[tokio::test]
async fn message_info_gives_the_format_central_holds() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    a.define::<Path>("path").await.unwrap();
    let ipc = b.ipc().unwrap();
    // not looked up yet
    assert_eq!(ipc.message_info("path").await.unwrap(), None);
    // watch_handlers looks it up; the num_handlers after it answers once
    // the lookup is done (a message nobody defined: an error, as in C)
    ipc.watch_handlers("path").await.unwrap();
    assert!(ipc.watch_handlers("nobody-defined-this").await.is_err());
    tokio::time::timeout(T, b.num_handlers("path"))
        .await
        .unwrap()
        .unwrap();
    let info = ipc.message_info("path").await.unwrap().expect("looked up");
    assert_eq!(info.name, "path");
    // named formats come expanded (Path::FORMAT names Point)
    assert_eq!(
        info.res_format.map(|f| f.to_string()).as_deref(),
        Some("{string, int, <{double, double}:2>}")
    );
    assert_eq!(ipc.message_info("nobody-defined-this").await.unwrap(), None);
    a.close().await;
    b.close().await;
    c.shutdown().await;
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: u32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

/// `max_message_bytes`: a message above a session's limit is refused when
/// sent (nothing goes out, the session goes on); one above it from central
/// ends the receiving session visibly: a `Disconnected` event, its
/// subscriptions end. Before, the receiver stopped reading without a word
/// and its subscribers waited forever.
#[tokio::test]
async fn messages_above_the_limit_are_refused_and_end_a_receiver_visibly() {
    let (c, url) = central().await;
    let small = |name: &'static str| {
        tokio::time::timeout(
            T,
            Session::builder(&url)
                .name(name)
                .max_message_bytes(100_000)
                .connect(),
        )
    };
    let a = session(&url, "a").await;
    let b = small("b").await.unwrap().unwrap();
    let mut sub = b.subscribe::<Blob>("blob").await.unwrap();
    let mut small_sub = b.subscribe::<i32>("small").await.unwrap();
    assert_eq!(b.num_handlers("blob").await.unwrap(), 1);
    assert_eq!(b.num_handlers("small").await.unwrap(), 1);
    let big = Blob {
        n: 0,
        data: vec![7; 200_000],
    };
    // the sender with the small limit refuses it, naming sizes
    match b.publish("blob", &big).await {
        Err(courier::PublishError::TooLarge { msg, len, max }) => {
            let bytes = courier::ipc::to_vec(&big).len();
            assert_eq!((msg.as_str(), len, max), ("blob", bytes, 100_000))
        }
        other => panic!("{other:?}"),
    }
    // and goes on
    a.num_handlers("small").await.unwrap();
    a.publish("small", &1).await.unwrap();
    let s = tokio::time::timeout(T, small_sub.next()).await.unwrap();
    assert_eq!(s.unwrap().unwrap().value, 1);
    // the default limit sends it; the receiver cannot take it
    let mut events = b.events();
    a.publish("blob", &big).await.unwrap();
    let first = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert!(
        matches!(first, Some(Err(RecvError::Disconnected))),
        "{first:?}"
    );
    assert!(tokio::time::timeout(T, sub.next()).await.unwrap().is_none());
    loop {
        match tokio::time::timeout(T, events.next()).await.unwrap() {
            Some(SessionEvent::Disconnected) => break,
            Some(_) => {}
            None => panic!("events ended without Disconnected"),
        }
    }
    assert!(b.publish("small", &2).await.is_err());
    // central let it go: its name is free again
    let b2 = small("b").await.unwrap();
    assert!(b2.is_ok(), "{:?}", b2.err());
    c.shutdown().await;
}

/// A subscriber whose type does not fit the format central holds for the
/// message (its definer's) gets `FormatMismatch` for each such message
/// instead of wrong values: the C library decodes by the sender's format,
/// so an `int` read as `f32` used to come out as a plausible number. A
/// type that reads the same bytes as the same kind (`u32` for `int`) fits.
/// (The subscription comes before the definition: one after it is refused
/// at once, see tests/ipc_formats.rs.)
#[tokio::test]
async fn a_subscriber_whose_type_does_not_fit_central_s_format_is_told() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut wrong = b.subscribe::<f32>("speed").await.unwrap();
    a.define::<i32>("speed").await.unwrap();
    // one type per topic and session: another session reads it as u32
    let b2 = session(&url, "b2").await;
    let mut right = b2.subscribe::<u32>("speed").await.unwrap();
    assert_eq!(a.num_handlers("speed").await.unwrap(), 2);
    for v in [1_078_530_011, 7] {
        a.publish("speed", &v).await.unwrap();
    }
    for _ in 0..2 {
        match tokio::time::timeout(T, wrong.next()).await.unwrap() {
            Some(Err(RecvError::FormatMismatch {
                msg,
                central,
                detail,
                ..
            })) => {
                assert_eq!((msg.as_str(), central.as_str()), ("speed", "int"));
                assert_eq!(detail, "f32's format is float");
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(wrong.decode_errors(), 2);
    for want in [1_078_530_011u32, 7] {
        let s = tokio::time::timeout(T, right.next()).await.unwrap();
        assert_eq!(s.unwrap().unwrap().value, want);
    }
    c.shutdown().await;
}

/// A `Vec` without `#[ipc(len)]` is a DDS sequence: its IPC format `<T:0>`
/// names no count field, so neither central nor a C module could read it.
/// An IPC session refuses such a type when it is first used, saying what to
/// add, instead of registering a format nobody can read.
#[tokio::test]
async fn a_type_ipc_cannot_carry_is_refused_naming_the_fix() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Route {
        name: String,
        waypoints: Vec<f64>,
    }
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let want = "a Vec field needs #[ipc(len = \"count\")]";
    let e = a.subscribe::<Route>("route").await.unwrap_err().to_string();
    assert!(
        e.contains("{string, <double:0>}") && e.contains(want),
        "{e}"
    );
    let b = session(&url, "b").await;
    let e = b.define::<Route>("route").await.unwrap_err().to_string();
    assert!(e.contains(want), "{e}");
    let e = b
        .query::<Route, i32>(
            "plan",
            &Route {
                name: "r".into(),
                waypoints: vec![],
            },
        )
        .timeout(Duration::from_secs(1))
        .await
        .unwrap_err();
    assert_eq!(e.to_string(), "query plan could not be opened");
    let cause = std::error::Error::source(&e)
        .expect("the cause")
        .to_string();
    assert!(cause.contains(want), "{cause}");
    c.shutdown().await;
}

/// A `char` a byte cannot carry is refused by publish, naming the field,
/// instead of arriving as `'?'`; a Latin-1 one arrives.
#[tokio::test]
async fn a_char_above_latin1_is_refused_not_sent_as_a_question_mark() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Grade {
        student: i32,
        grade: char,
    }
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut sub = b.subscribe::<Grade>("grade").await.unwrap();
    assert_eq!(a.num_handlers("grade").await.unwrap(), 1);
    let e = a
        .publish(
            "grade",
            &Grade {
                student: 1,
                grade: '€',
            },
        )
        .await
        .unwrap_err();
    assert!(matches!(e, courier::PublishError::Length { .. }), "{e:?}");
    assert!(
        e.to_string()
            .starts_with("cannot publish grade: field `grade` holds '€' (U+20AC)"),
        "{e}"
    );
    let ok = Grade {
        student: 2,
        grade: 'é',
    };
    a.publish("grade", &ok).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert_eq!(got.unwrap().unwrap().value, ok, "nothing before it");
    c.shutdown().await;
}

/// A value with a `Vec` longer than its length field can say is refused
/// by publish, query and reply, naming the field, instead of going out
/// cut short.
#[tokio::test]
async fn a_vec_its_length_field_cannot_say_is_refused_not_cut_short() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Obstacles {
        n: u8,
        #[ipc(len = "n")]
        xs: Vec<f32>,
    }
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut sub = b.subscribe::<Obstacles>("obstacles").await.unwrap();
    assert_eq!(a.num_handlers("obstacles").await.unwrap(), 1);
    let long = Obstacles {
        n: 0,
        xs: vec![1.0; 300],
    };
    let want = "field `xs` has 300 elements, more than its length field `n` (u8) can say (255)";
    let e = a.publish("obstacles", &long).await.unwrap_err();
    assert!(matches!(e, courier::PublishError::Length { .. }), "{e:?}");
    assert_eq!(e.to_string(), format!("cannot publish obstacles: {want}"));
    let p = a.publisher::<Obstacles>("obstacles").build().await.unwrap();
    assert!(p.try_publish(&long).is_err());
    // nothing went out; what fits does
    let fits = Obstacles {
        n: 0,
        xs: vec![2.0; 255],
    };
    p.publish(&fits).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert_eq!(got.unwrap().unwrap().value.xs.len(), 255);
    // a query's request, and a reply
    let e = a
        .query::<Obstacles, i32>("count", &long)
        .timeout(Duration::from_secs(1))
        .await
        .unwrap_err();
    assert!(matches!(e, QueryError::Refused { .. }), "{e:?}");
    let mut reqs = b.serve::<i32, Obstacles>("obstacles_of", "").await.unwrap();
    let server = tokio::spawn(async move {
        let r = reqs.next().await.unwrap().unwrap();
        r.reply(&Obstacles {
            n: 0,
            xs: vec![0.0; 256],
        })
        .await
    });
    let q = a
        .query::<i32, Obstacles>("obstacles_of", &1)
        .timeout(Duration::from_secs(1))
        .await;
    // no reply came (the server, done, may have stopped serving by then)
    assert!(
        matches!(
            q,
            Err(QueryError::Timeout { .. } | QueryError::NoResponder { .. })
        ),
        "{q:?}"
    );
    let e = server.await.unwrap().unwrap_err();
    assert!(e.to_string().contains("`xs` has 256 elements"), "{e}");
    c.shutdown().await;
}

/// A bounded `String` (`#[ipc(bound = N)]`, IDL `string<N>`) over its
/// bound is refused by publish, and a subscriber of the bounded type
/// refuses one that a peer with the unbounded type sent.
#[tokio::test]
async fn a_string_over_its_bound_is_refused_on_both_sides() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "Name")]
    struct Name {
        #[ipc(bound = 4)]
        text: String,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "Name")]
    struct AnyName {
        text: String,
    }
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut sub = b.subscribe::<Name>("name").await.unwrap();
    assert_eq!(a.num_handlers("name").await.unwrap(), 1);
    let e = a
        .publish(
            "name",
            &Name {
                text: "robot".into(),
            },
        )
        .await
        .unwrap_err();
    assert_eq!(
        e.to_string(),
        "cannot publish name: field `text` has 5 bytes, more than its bound of 4"
    );
    a.publish(
        "name",
        &AnyName {
            text: "robot".into(),
        },
    )
    .await
    .unwrap();
    a.publish("name", &AnyName { text: "bot".into() })
        .await
        .unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap().unwrap();
    let e = got.unwrap_err();
    assert!(matches!(e, courier::RecvError::Decode { .. }), "{e:?}");
    assert!(e.to_string().contains("more than its bound of 4"), "{e}");
    let got = tokio::time::timeout(T, sub.next()).await.unwrap().unwrap();
    assert_eq!(got.unwrap().value.text, "bot");
    c.shutdown().await;
}

/// A typed first use that fails does not hold the topic to its type: the
/// next attempt may use another (before, it failed with `TypeMismatch`
/// naming the type of the attempt that never worked). A use that worked
/// keeps the type.
#[tokio::test]
async fn a_failed_first_use_does_not_bind_the_topic_to_its_type() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Route {
        name: String,
        waypoints: Vec<f64>,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Route2 {
        name: String,
        n: i32,
        #[ipc(len = "n")]
        waypoints: Vec<f64>,
    }
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    // IPC refuses the type without a length field
    assert!(a.subscribe::<Route>("r1").await.is_err());
    assert!(a.define::<Route>("r2").await.is_err());
    assert!(a.serve::<Route, i32>("r3", "").await.is_err());
    assert!(a
        .publish(
            "r4",
            &Route {
                name: "r".into(),
                waypoints: vec![]
            }
        )
        .await
        .is_err());
    // the fixed type takes each topic, and keeps it
    for t in ["r1", "r2", "r3", "r4"] {
        let _s = a.subscribe::<Route2>(t).await.unwrap();
        let e = a.define::<i32>(t).await.unwrap_err();
        assert!(e.to_string().contains("Route2"), "{e}");
    }
    // on a closed session each call says it is closed, not a type mismatch
    let b = session(&url, "b").await;
    b.close().await;
    let e = b.serve::<String, i32>("q", "").await.unwrap_err();
    assert!(matches!(e, courier::OpenError::Disconnected(_)), "{e:?}");
    let e = b.publish("q", &1i32).await.unwrap_err();
    assert!(
        matches!(
            e,
            courier::PublishError::Open(courier::OpenError::Disconnected(_))
        ),
        "{e:?}"
    );
    c.shutdown().await;
}

/// One server per message and session on IPC, as on DDS: a second `serve`
/// is refused (it would have shared the queries with the first at random);
/// once the first is dropped, the message may be served again.
#[tokio::test]
async fn a_message_is_served_once_per_session() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let first = a.serve::<i32, i32>("double", "").await.unwrap();
    let e = a.serve::<i32, i32>("double", "").await.unwrap_err();
    assert!(
        matches!(e, courier::OpenError::AlreadyServed(ref m) if m == "double"),
        "{e:?}"
    );
    drop(first);
    let mut again = a.serve::<i32, i32>("double", "").await.unwrap();
    let b = session(&url, "b").await;
    tokio::spawn(async move {
        while let Some(Ok(r)) = again.next().await {
            let v = r.value * 2;
            let _ = r.reply(&v).await;
        }
    });
    let n: i32 = b.query("double", &21).timeout(T).await.unwrap();
    assert_eq!(n, 42);
    c.shutdown().await;
}

/// `close()` returns at once although a publish waits for room that
/// central will not make (its subscriber reads nothing, so central stops
/// reading the publisher): the waiting publish fails. It hung before.
#[tokio::test]
async fn close_returns_while_a_publish_waits_for_central_to_read() {
    #[derive(IpcMessage, Debug, Clone)]
    #[allow(dead_code)]
    struct Blob {
        n: i32,
        #[ipc(len = "n")]
        data: Vec<u8>,
    }
    let (c, url) = central().await;
    let p = session(&url, "pub").await;
    let s = session(&url, "sub").await;
    let _unread = s.subscribe::<Blob>("blob").await.unwrap();
    assert_eq!(p.num_handlers("blob").await.unwrap(), 1);
    let publisher = {
        let p = p.clone();
        tokio::spawn(async move {
            let blob = Blob {
                n: 0,
                data: vec![0; 1 << 20],
            };
            let mut sent = 0u64;
            loop {
                if let Err(e) = p.publish("blob", &blob).await {
                    return (sent, e);
                }
                sent += 1;
            }
        })
    };
    // until the publisher is held up (central keeps 64 MiB for a module)
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(!publisher.is_finished());
    tokio::time::timeout(Duration::from_secs(5), p.close())
        .await
        .expect("close() returns");
    let (sent, e) = tokio::time::timeout(Duration::from_secs(5), publisher)
        .await
        .expect("the waiting publish fails")
        .unwrap();
    assert!(sent > 0);
    assert!(matches!(e, courier::PublishError::Disconnected(_)), "{e:?}");
    s.close().await;
    c.shutdown().await;
}

/// A subscriber (or a server's `Requests`) keeps its session connected
/// after the `Session` value is dropped, as a `Publisher` does
/// (`connect().await?.subscribe(..)` is a whole program's subscription);
/// the session disconnects when the handle goes too.
#[tokio::test]
async fn a_handle_keeps_its_session_connected() {
    let (c, url) = central().await;
    let p = session(&url, "p").await;
    let mut sub = session(&url, "only_sub")
        .await
        .subscribe::<i32>("n")
        .await
        .unwrap();
    let mut reqs = session(&url, "only_srv")
        .await
        .serve::<i32, i32>("double", "")
        .await
        .unwrap();
    assert!(p.is_module_connected("only_sub").await.unwrap());
    assert!(p.is_module_connected("only_srv").await.unwrap());
    assert_eq!(p.num_handlers("n").await.unwrap(), 1);
    p.publish("n", &5).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert_eq!(got.unwrap().unwrap().value, 5);
    let server = tokio::spawn(async move {
        let r = reqs.next().await.unwrap().unwrap();
        let v = r.value * 2;
        r.reply(&v).await.unwrap();
        reqs
    });
    let q = p.query::<i32, i32>("double", &21).timeout(T).await;
    assert_eq!(q.unwrap(), 42);
    let reqs = server.await.unwrap();
    drop(sub);
    drop(reqs);
    let gone = async {
        while p.is_module_connected("only_sub").await.unwrap()
            || p.is_module_connected("only_srv").await.unwrap()
        {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    };
    tokio::time::timeout(T, gone).await.unwrap();
    c.shutdown().await;
}

/// A periodic publication whose function panicked says so when stopped.
#[tokio::test]
async fn a_periodic_publication_whose_function_panicked_says_so() {
    let (c, url) = central().await;
    let p = session(&url, "p").await;
    let pub_ = p.publisher::<i32>("tick").build().await.unwrap();
    let job = pub_.send_every(Duration::from_millis(5), |_| -> Option<i32> {
        panic!("sensor unplugged")
    });
    tokio::time::sleep(Duration::from_millis(100)).await;
    let e = job.stop().await.unwrap_err();
    assert!(matches!(e, courier::PublishError::Panicked { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "the periodic publication of tick ended: its function panicked: sensor unplugged"
    );
    // stopped while running: Ok
    let job = pub_.send_every(Duration::from_millis(5), |_| Some(1));
    tokio::time::sleep(Duration::from_millis(20)).await;
    assert_eq!(job.stop().await, Ok(()));
    c.shutdown().await;
}

/// Types that disagree with central's format are refused, not read as
/// wrong values: a query whose request type does not fit the message
/// another module defined, a reply that does not fit the type the query
/// reads, a publish of a misfit, and a server of a misfit; and two types
/// of one session that name different formats alike.
#[tokio::test]
async fn queries_servers_and_publishers_that_do_not_fit_central_s_format_are_refused() {
    let (c, url) = central().await;
    let srv = session(&url, "srv").await;
    let a = session(&url, "a").await;
    let mut reqs = srv.serve::<i32, i32>("work", "").await.unwrap();
    let server = tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let v = r.value * 2;
            r.reply(&v).await.unwrap();
        }
    });
    // the right types work
    assert_eq!(a.query::<i32, i32>("work", &3).timeout(T).await.unwrap(), 6);
    // a reply read as f32 (1.7e-44 before)
    let e = a
        .query::<i32, f32>("work", &3)
        .timeout(T)
        .await
        .unwrap_err();
    assert!(matches!(e, QueryError::Decode { .. }), "{e:?}");
    assert!(
        e.to_string()
            .contains("workReply is sent as int (central's format)"),
        "{e}"
    );
    // a request of f32 (the server read 1069547520 before)
    let b = session(&url, "b").await;
    let e = b
        .query::<f32, i32>("work", &1.5)
        .timeout(T)
        .await
        .unwrap_err();
    let chain = format!(
        "{e} / {}",
        std::error::Error::source(&e)
            .map(|s| s.to_string())
            .unwrap_or_default()
    );
    assert!(
        chain.contains(
            "central holds the format int for work (defined by another module, or an earlier \
             run of this one), which f32 does not fit"
        ),
        "{chain}"
    );
    // a publish of a misfit, and a server of one
    let e = b.publish("workReply", &2.5f64).await.unwrap_err();
    assert!(
        e.to_string().ends_with(
            "central holds the format int for workReply (defined by another module, or an \
             earlier run of this one), which f64 does not fit: f64's format is double"
        ),
        "{e}"
    );
    let e = b.serve::<f32, i32>("work", "").await.unwrap_err();
    assert!(
        matches!(e, courier::OpenError::FormatMismatch { .. }),
        "{e:?}"
    );
    // one session, two types named alike
    mod one {
        #[derive(courier::IpcMessage, Debug, Clone, PartialEq)]
        pub struct Pos {
            pub x: i32,
            pub y: i32,
        }
    }
    mod two {
        #[derive(courier::IpcMessage, Debug, Clone, PartialEq)]
        pub struct Pos {
            pub lat: f64,
        }
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct A {
        p: one::Pos,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct B {
        p: two::Pos,
    }
    b.define::<A>("msg_a").await.unwrap();
    let e = b.define::<B>("msg_b").await.unwrap_err();
    assert!(
        matches!(e, courier::OpenError::NamedFormatConflict { .. }),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .starts_with("the named format Pos is {int, int} in this session, not {double}"),
        "{e}"
    );
    // one type carrying both: IPC would send one `Pos` format for the two
    // (it was defined with `{Pos, Pos}` and `Pos = {int, int}`)
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Both {
        a: one::Pos,
        b: two::Pos,
    }
    let fresh = session(&url, "fresh").await;
    let e = fresh.define::<Both>("msg_both").await.unwrap_err();
    assert!(
        e.to_string()
            .starts_with("the named format Pos is {int, int} in this session, not {double}"),
        "{e}"
    );
    let e = fresh
        .ipc()
        .unwrap()
        .define_formats::<Both>()
        .await
        .unwrap_err();
    assert!(
        matches!(e, courier::OpenError::NamedFormatConflict { .. }),
        "{e:?}"
    );
    fresh.close().await;
    server.abort();
    c.shutdown().await;
}

/// `subscribe().await` returns once central has the subscription: another
/// module that asks `num_handlers` right after counts it, and its publish
/// arrives (the quick start's pattern). It returned when the registration
/// was queued, and 4 % of such publishes went nowhere.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_is_at_central_when_subscribe_returns() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    for i in 0..100 {
        let msg = format!("m{i}");
        a.define::<i32>(&msg).await.unwrap();
        let mut sub = b.subscribe::<i32>(&msg).await.unwrap();
        assert_eq!(a.num_handlers(&msg).await.unwrap(), 1, "{msg}");
        a.publish(&msg, &i).await.unwrap();
        let got = tokio::time::timeout(Duration::from_secs(2), sub.next()).await;
        assert_eq!(got.expect(&msg).unwrap().unwrap().value, i);
    }
    c.shutdown().await;
}

/// `watch_handlers` on a message central does not know fails, as C's
/// `IPC_subscribeHandlerChange` does (it returned Ok and never reported);
/// once the message is defined, the watch works.
#[tokio::test]
async fn watching_the_handlers_of_an_undefined_message_fails_until_it_is_defined() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let e = a.watch_handlers("later").await.unwrap_err();
    assert!(matches!(e, courier::ControlError::Central { .. }), "{e:?}");
    assert!(
        format!("{e}: {}", std::error::Error::source(&e).unwrap())
            .contains("watch_handlers(later): define the message first: message \"later\" is not defined in central"),
        "{e}"
    );
    a.define::<i32>("later").await.unwrap();
    let mut ev = a.events();
    a.watch_handlers("later").await.unwrap();
    let _sub = b.subscribe::<i32>("later").await.unwrap();
    let changed = async {
        loop {
            if let Some(SessionEvent::HandlersChanged { msg, count }) = ev.next().await {
                if msg == "later" && count == 1 {
                    return;
                }
            }
        }
    };
    tokio::time::timeout(T, changed).await.unwrap();
    c.shutdown().await;
}

/// C's argument checks: a capacity or queue length below 1, a negative
/// priority and an empty message name are refused, naming the call (they
/// returned Ok).
#[tokio::test]
async fn out_of_range_arguments_and_empty_names_are_refused() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let ipc = a.ipc().unwrap();
    for (e, want) in [
        (
            ipc.set_capacity(0).await.unwrap_err(),
            "set_capacity: 0 is out of range, it must be at least 1",
        ),
        (
            ipc.set_queue_length("m", -5).await.unwrap_err(),
            "set_queue_length(m): -5 is out of range, it must be at least 1",
        ),
        (
            ipc.set_priority("m", -1).await.unwrap_err(),
            "set_priority(m): -1 is out of range, it must be at least 0",
        ),
    ] {
        assert_eq!(e.to_string(), want);
    }
    ipc.set_capacity(2).await.unwrap();
    let e = a.publish("", &1).await.unwrap_err();
    assert_eq!(
        e.to_string(),
        "bad name \"\": a message needs a name (C: IPC_Null_Argument)"
    );
    let e = a.subscribe::<i32>("").await.unwrap_err();
    assert!(
        matches!(&e, courier::OpenError::BadName { name, .. } if name.is_empty()),
        "{e}"
    );
    c.shutdown().await;
}

/// A keep-all subscription nobody reads holds the whole session back (IPC
/// delivers a module's messages one by one): the session says so once,
/// naming the message, instead of going silent.
#[tokio::test]
async fn a_full_subscription_that_holds_the_session_back_is_reported() {
    let (c, url) = central().await;
    let p = session(&url, "p").await;
    let s = session(&url, "s").await;
    let mut ev = s.events();
    let _unread = s
        .subscribe_with::<i32>("status", courier::QueuePolicy::KeepAll(5))
        .await
        .unwrap();
    assert_eq!(p.num_handlers("status").await.unwrap(), 1);
    for i in 0..20 {
        p.publish("status", &i).await.unwrap();
    }
    let full = async {
        loop {
            match ev.next().await {
                Some(SessionEvent::SubscriberFull { msg, queued }) => return (msg, queued),
                Some(_) => continue,
                None => panic!("events ended"),
            }
        }
    };
    let (msg, queued) = tokio::time::timeout(T, full).await.unwrap();
    assert_eq!((msg.as_str(), queued), ("status", 5));
    c.shutdown().await;
}

/// A reconnecting in-process session whose embedded central stops for
/// good reports `Disconnected` once (it came twice: from the reconnect
/// that gave up, then from the end).
#[tokio::test]
async fn a_reconnecting_session_whose_central_stops_reports_disconnected_once() {
    let (c, _url) = central().await;
    let s = c
        .session("recon")
        .reconnect(Duration::from_millis(50))
        .connect()
        .await
        .unwrap();
    let mut ev = s.events();
    c.shutdown().await;
    let mut seen = Vec::new();
    while let Ok(Some(e)) = tokio::time::timeout(Duration::from_secs(2), ev.next()).await {
        seen.push(e);
    }
    let downs = seen
        .iter()
        .filter(|e| matches!(e, SessionEvent::Disconnected))
        .count();
    assert_eq!(downs, 1, "{seen:?}");
}

/// `define().await` returns once central has the definition: a module that
/// defines a message right after another defined it with a format that
/// does not fit is refused, as when it comes later (both were `Ok`, and the
/// first module's data then failed everywhere: define returned when the
/// definition was only queued, before the second module's check).
#[tokio::test]
async fn a_definition_that_follows_another_at_once_is_checked_against_it() {
    #[derive(IpcMessage, Debug)]
    struct PoseA {
        x: f64,
        y: f64,
    }
    #[derive(IpcMessage, Debug)]
    struct PoseB {
        x: f64,
        y: f64,
        theta: f64,
    }
    let (c, url) = central().await;
    for round in 0..5 {
        let msg = format!("pose{round}");
        let a = session(&url, "old").await;
        let b = session(&url, "new").await;
        a.define::<PoseA>(&msg).await.unwrap();
        let e = b.define::<PoseB>(&msg).await.unwrap_err();
        assert!(
            matches!(e, courier::OpenError::FormatMismatch { .. }),
            "round {round}: {e:?}"
        );
        a.close().await;
        b.close().await;
    }
    c.shutdown().await;
}

/// A subscriber's local queue follows its history however the history is
/// given: `qos()` with keep-last 2 keeps the newest 2, as `keep_last(2)`
/// does (it kept 1000, and on IPC the history was silently ignored). A
/// queue of 0 is refused, as `keep_last(0)` is.
#[tokio::test]
async fn a_keep_last_history_given_through_qos_is_the_local_queue() {
    let (c, url) = central().await;
    let s = session(&url, "q").await;
    let mut qos = courier::SubscriptionQos::default();
    qos.history = courier::History::KeepLast(2);
    let mut sub = s.subscriber::<i32>("q").qos(qos).build().await.unwrap();
    s.num_handlers("q").await.unwrap();
    for i in 0..5 {
        s.publish("q", &i).await.unwrap();
    }
    // the five are in (a publish to oneself comes back through central)
    let deadline = tokio::time::Instant::now() + T;
    while sub.dropped() < 3 && tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert_eq!(sub.dropped(), 3);
    assert_eq!(sub.next().await.unwrap().unwrap().value, 3);
    assert_eq!(sub.next().await.unwrap().unwrap().value, 4);
    for p in [
        courier::QueuePolicy::KeepLast(0),
        courier::QueuePolicy::KeepAll(0),
    ] {
        let e = s
            .subscriber::<i32>("q0")
            .queue(p)
            .build()
            .await
            .unwrap_err();
        assert!(e.to_string().contains("holds nothing"), "{e}");
    }
    s.close().await;
    c.shutdown().await;
}

/// `wait_for_handlers` returns once central lists enough subscribers, and
/// says how many there were when it gives up.
#[tokio::test]
async fn wait_for_handlers_counts_subscribers_and_gives_up_naming_the_count() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    a.define::<i32>("w").await.unwrap();
    let waiting = {
        let a = a.clone();
        tokio::spawn(async move { a.wait_for_handlers("w", 1, T).await })
    };
    let _sub = b.subscribe::<i32>("w").await.unwrap();
    assert_eq!(waiting.await.unwrap().unwrap(), 1);
    let e = a
        .wait_for_handlers("w", 3, Duration::from_millis(100))
        .await
        .unwrap_err();
    assert!(
        e.to_string().contains("3 handler(s) of w (there are 1)"),
        "{e}"
    );
    a.close().await;
    b.close().await;
    c.shutdown().await;
}

/// A message published to a module that serves it (takes queries) and
/// does not subscribe to it is dropped there, as before, but no longer
/// silently: one warning per message says what was wrong.
#[tokio::test]
async fn a_publish_to_a_server_is_warned_of_once() {
    let (logs, _guard) = common::capture_logs();
    let (c, url) = central().await;
    let server = session(&url, "server").await;
    let publisher = session(&url, "publisher").await;
    let _reqs = server.serve::<i32, i32>("svc", "").await.unwrap();
    let mut sync = server.subscribe::<i32>("sync").await.unwrap();
    common::await_handlers(&publisher, "svc", 1).await;
    common::await_handlers(&publisher, "sync", 1).await;
    publisher.publish("svc", &1).await.unwrap();
    publisher.publish("svc", &2).await.unwrap();
    // central hands the server its messages in order: after these two
    publisher.publish("sync", &3).await.unwrap();
    let got = tokio::time::timeout(T, sync.next()).await.unwrap();
    assert_eq!(got.unwrap().unwrap().value, 3);
    let text = String::from_utf8(logs.lock().unwrap().clone()).unwrap();
    let warned = text
        .lines()
        .filter(|l| l.contains("svc was published to this session, which serves it"))
        .count();
    assert_eq!(warned, 1, "{text}");
    server.close().await;
    publisher.close().await;
    c.shutdown().await;
}

/// A callback that closes its own session, blocking on the close (the
/// docs say never to block there), does not hang: the close goes on once
/// the callback returns. On a current-thread runtime, of a thread of its
/// own: a hang there must fail this test, not hang it.
#[test]
fn a_callback_closing_its_own_session_does_not_hang() {
    common::on_own_runtime(2 * T, closing_inside_a_callback);
}

async fn closing_inside_a_callback() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    common::close_inside_own_callback(&a, &b, "closer").await;
    // and b is gone from central
    tokio::time::timeout(T, async {
        while a.is_module_connected("b").await.unwrap() {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("b disconnected");
    a.close().await;
    c.shutdown().await;
}
