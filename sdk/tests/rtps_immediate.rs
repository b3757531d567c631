//! Immediate delivery on RTPS (ORTE's IMMEDIATE mode, DDS listeners):
//! `SubscriberBuilder::listen` callbacks, `Publisher::try_publish`, and the
//! participant's receive thread (`receive_thread=true`). Courier against
//! Courier on loopback only, with unicast discovery; each test has its own
//! domain id. Every wait is bounded.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use futures::StreamExt;

use courier::{
    Handle, PublicationQos, PublishError, RecvError, Sample, Session, TypeInfo, WriteOptions,
};

mod common;
use common::{await_handlers, next, session, url, Msg, T};

fn msg(seq: u32) -> Msg {
    Msg {
        seq,
        text: format!("hello {seq}"),
        payload: Vec::new(),
    }
}

/// A session with the receive thread on.
async fn threaded(domain: u32, name: &str) -> Session {
    tokio::time::timeout(
        T,
        Session::builder(url(domain))
            .name(name)
            .receive_thread(true)
            .connect(),
    )
    .await
    .expect("connect in time")
    .expect("connect")
}

type Got = Result<Sample<Msg>, RecvError>;

/// A callback that forwards what it gets to a channel.
fn forward() -> (impl FnMut(Got) + Send + 'static, mpsc::Receiver<Got>) {
    let (tx, rx) = mpsc::channel();
    (move |s| drop(tx.send(s)), rx)
}

async fn recv(rx: &mpsc::Receiver<Got>) -> Got {
    let t0 = std::time::Instant::now();
    loop {
        if let Ok(s) = rx.try_recv() {
            return s;
        }
        assert!(t0.elapsed() < T, "no callback within {T:?}");
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}

/// The names of this process's threads.
fn thread_names() -> Vec<String> {
    std::fs::read_dir("/proc/self/task")
        .map(|d| {
            d.filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("comm")).ok())
                .map(|s| s.trim().to_string())
                .collect()
        })
        .unwrap_or_default()
}

/// Receive threads of sessions named `name` (`rtps-rx <name>`, cut to
/// the 15 bytes Linux keeps).
fn receive_threads(name: &str) -> usize {
    let want: String = format!("rtps-rx {name}").chars().take(15).collect();
    thread_names().iter().filter(|n| **n == want).count()
}

/// Every sample reaches the callback once, in order, and a `close()` is
/// no error it is called with: with the receive thread and with the
/// driver task reading.
#[tokio::test]
async fn callbacks_get_every_sample_in_order_then_the_end() {
    for (domain, on_thread) in [(140, true), (141, false)] {
        let a = session(domain, "a").await;
        let b = if on_thread {
            threaded(domain, "b").await
        } else {
            session(domain, "b").await
        };
        let p = a.publisher::<Msg>("chatter").build().await.unwrap();
        let (f, rx) = forward();
        let l = b.subscriber::<Msg>("chatter").listen(f).await.unwrap();
        assert_eq!(l.msg(), "chatter");
        await_handlers(&a, "chatter", 1).await;
        for i in 0..500 {
            p.publish(&msg(i)).await.unwrap();
        }
        for i in 0..500 {
            let s = recv(&rx).await.unwrap();
            assert_eq!(s.value, msg(i), "receive thread: {on_thread}");
            assert_eq!(s.msg, "chatter");
            assert!(s.source.is_some() && s.source_time.is_some());
        }
        b.close().await;
        drop((l, b));
        // a close asked for is no error: the callback is dropped uncalled
        assert_eq!(
            ended(rx).await,
            Err(mpsc::RecvTimeoutError::Disconnected),
            "receive thread: {on_thread}"
        );
        a.close().await;
    }
}

/// What the callback sends once its samples are read: nothing before it
/// is dropped (`Err(Disconnected)`), or the item it sent.
async fn ended(rx: mpsc::Receiver<Got>) -> Result<Got, mpsc::RecvTimeoutError> {
    tokio::task::spawn_blocking(move || rx.recv_timeout(T))
        .await
        .unwrap()
}

/// A callback answers on the spot with `try_publish` (the receive thread
/// sends the answer itself): every request is echoed, in order.
#[tokio::test]
async fn a_callback_answers_at_once_with_try_publish() {
    let server = threaded(142, "server").await;
    let client = session(142, "client").await;
    let answers = server.publisher::<Msg>("pong").build().await.unwrap();
    let echo = {
        let answers = answers.clone();
        move |s: Got| {
            if let Ok(s) = s {
                let mut v = s.value;
                v.text = format!("echo {}", v.seq);
                answers.try_publish(&v).expect("try_publish in a callback");
            }
        }
    };
    let _l = server.subscriber::<Msg>("ping").listen(echo).await.unwrap();
    let ask = client.publisher::<Msg>("ping").build().await.unwrap();
    let mut pongs = client.subscribe::<Msg>("pong").await.unwrap();
    await_handlers(&client, "ping", 1).await;
    await_handlers(&server, "pong", 1).await;
    for i in 0..200 {
        ask.publish(&msg(i)).await.unwrap();
        // one at a time, as a ping does
        let s = next(&mut pongs).await.unwrap();
        assert_eq!(s.value.seq, i);
        assert_eq!(s.value.text, format!("echo {i}"));
    }
    // and a burst: the answers of one callback batch share datagrams
    for i in 200..1200 {
        ask.publish(&msg(i)).await.unwrap();
    }
    for i in 200..1200 {
        assert_eq!(next(&mut pongs).await.unwrap().value.seq, i);
    }
    client.close().await;
    server.close().await;
}

/// `try_publish` from a task comes after the `publish().await`s before it,
/// and says clearly why it cannot publish.
#[tokio::test]
async fn try_publish_keeps_order_and_refuses_clearly() {
    let a = session(143, "a").await;
    let b = session(143, "b").await;
    let p = a.publisher::<Msg>("mixed").build().await.unwrap();
    let mut sub = b.subscribe::<Msg>("mixed").await.unwrap();
    await_handlers(&a, "mixed", 1).await;
    for i in 0..300 {
        if i % 3 == 0 {
            p.try_publish(&msg(i)).unwrap();
        } else {
            p.publish(&msg(i)).await.unwrap();
        }
    }
    for i in 0..300 {
        assert_eq!(next(&mut sub).await.unwrap().value.seq, i);
    }
    // a publication this session has closed
    let backend = b.backend();
    let closed = backend
        .open_publication("nobody", &TypeInfo::of::<Msg>(), &PublicationQos::default())
        .await
        .unwrap();
    backend.close_handle(Handle::Publication(closed));
    let err = backend
        .try_write(closed, vec![0, 1, 0, 0], WriteOptions::default())
        .unwrap_err();
    match err {
        PublishError::Closed(p) => assert_eq!(p, closed),
        e => panic!("unexpected {e:?}"),
    }
    a.close().await;
    let err = p.try_publish(&msg(0)).unwrap_err();
    assert!(
        matches!(err, PublishError::Disconnected(_)),
        "after close: {err:?}"
    );
    b.close().await;
}

/// Dropping the `Listener` deletes the reader: the writer sees no handler.
#[tokio::test]
async fn dropping_a_listener_unsubscribes() {
    let a = session(144, "a").await;
    let b = threaded(144, "b").await;
    let p = a.publisher::<Msg>("gone").build().await.unwrap();
    let count = Arc::new(AtomicU32::new(0));
    let l = {
        let count = count.clone();
        b.subscriber::<Msg>("gone")
            .listen(move |_| {
                count.fetch_add(1, Ordering::SeqCst);
            })
            .await
            .unwrap()
    };
    await_handlers(&a, "gone", 1).await;
    p.publish(&msg(1)).await.unwrap();
    tokio::time::timeout(T, async {
        while count.load(Ordering::SeqCst) == 0 {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    })
    .await
    .expect("the first sample");
    drop(l);
    tokio::time::timeout(T, async {
        while a.num_handlers("gone").await.unwrap() > 0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("the reader is deleted");
    let before = count.load(Ordering::SeqCst);
    p.publish(&msg(2)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(
        count.load(Ordering::SeqCst),
        before,
        "no callback after drop"
    );
    a.close().await;
    b.close().await;
}

/// A callback that panics loses the sample it was given, not the
/// subscription, and not the receive thread.
#[tokio::test]
async fn a_panicking_callback_loses_its_sample_not_the_subscription() {
    let a = session(145, "a").await;
    let b = threaded(145, "b").await;
    let p = a.publisher::<Msg>("fragile").build().await.unwrap();
    let (tx, rx) = mpsc::channel();
    let _l = b
        .subscriber::<Msg>("fragile")
        .listen(move |s: Got| {
            let s = s.unwrap();
            assert_ne!(s.value.seq, 3, "the test's deliberate panic");
            let _ = tx.send(Ok(s));
        })
        .await
        .unwrap();
    await_handlers(&a, "fragile", 1).await;
    for i in 0..6 {
        p.publish(&msg(i)).await.unwrap();
    }
    let mut got = Vec::new();
    while got.len() < 5 {
        got.push(recv(&rx).await.unwrap().value.seq);
    }
    assert_eq!(got, [0, 1, 2, 4, 5]);
    a.close().await;
    b.close().await;
}

/// The receive thread ends with its session, and a keep-all `Subscriber`
/// fed by it is back-pressured without loss.
#[tokio::test]
async fn the_receive_thread_feeds_streams_and_ends_with_the_session() {
    let a = session(146, "a").await;
    let b = threaded(146, "rx176").await;
    // (a new thread names itself once it runs)
    tokio::time::timeout(T, async {
        while receive_threads("rx176") != 1 {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no receive thread: {:?}", thread_names()));
    common::slow_keep_all_subscriber(&a, &b, 2000).await;
    b.close().await;
    tokio::time::timeout(T, async {
        while receive_threads("rx176") > 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("the receive thread ended");
    a.close().await;
}

/// A runtime dropped without closing its session takes the driver task
/// with it; the receive thread still ends.
#[test]
fn the_receive_thread_ends_when_the_runtime_goes_away() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let s = rt.block_on(threaded(147, "rx177"));
    let wait_for = |n: usize| {
        let t0 = std::time::Instant::now();
        while receive_threads("rx177") != n {
            assert!(t0.elapsed() < T, "{:?}", thread_names());
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    wait_for(1);
    drop(rt);
    wait_for(0);
    drop(s);
}

/// A receive thread that stopped reading because a keep-all `Subscriber`
/// is full still ends when the session closes.
#[tokio::test]
async fn a_receive_thread_held_by_a_full_queue_ends_with_the_session() {
    let a = session(149, "a").await;
    let b = threaded(149, "rx178").await;
    let (p, mut sub) = common::keep_all_pair(&a, &b, "held", 2).await;
    for i in 0..50 {
        p.publish(&msg(i)).await.unwrap();
    }
    // the queue fills; nobody reads
    assert_eq!(next(&mut sub).await.unwrap().value.seq, 0);
    tokio::time::sleep(Duration::from_millis(100)).await;
    b.close().await;
    tokio::time::timeout(T, async {
        while receive_threads("rx178") > 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("the receive thread is still there: {:?}", thread_names()));
    a.close().await;
}

/// A callback that closes its own session, blocking on the close (the
/// docs say never to block there), does not hang the session for ever:
/// the close goes on once the callback returns, with the receive thread
/// and with the driver task reading (on the test's own runtime: a hang
/// there fails the test rather than hanging it).
#[test]
fn a_callback_closing_its_own_session_does_not_hang() {
    common::on_own_runtime(4 * T, closing_inside_a_callback);
}

async fn closing_inside_a_callback() {
    for (domain, on_thread) in [(150, true), (151, false)] {
        let a = session(domain, "a").await;
        let b = if on_thread {
            threaded(domain, "b").await
        } else {
            session(domain, "b").await
        };
        common::close_inside_own_callback(&a, &b, "closer").await;
        // and the session is closed
        let mut events = b.events();
        let e = tokio::time::timeout(T, events.next()).await.unwrap();
        assert!(
            matches!(e, None | Some(courier::SessionEvent::Disconnected)),
            "{e:?}"
        );
        a.close().await;
    }
}

/// A callback on a topic its own session publishes gets each sample as
/// it is written, with the driver task reading and with the receive
/// thread (audit 15: each sample waited for the next write, or for ever).
#[tokio::test]
async fn a_callback_gets_what_its_own_session_publishes_at_once() {
    for (domain, on_thread) in [(152, false), (153, true)] {
        let a = if on_thread {
            threaded(domain, "own").await
        } else {
            session(domain, "own").await
        };
        let p = a.publisher::<Msg>("own").build().await.unwrap();
        let (f, rx) = forward();
        let l = a.subscriber::<Msg>("own").listen(f).await.unwrap();
        await_handlers(&a, "own", 1).await;
        for i in 0..5 {
            p.publish(&msg(i)).await.unwrap();
            // nothing else is written until it came
            let s = recv(&rx).await.unwrap();
            assert_eq!(s.value, msg(i), "receive thread: {on_thread}");
        }
        // and so does a write that does not wait
        p.try_publish(&msg(5)).unwrap();
        assert_eq!(recv(&rx).await.unwrap().value, msg(5));
        drop(l);
        a.close().await;
    }
}
