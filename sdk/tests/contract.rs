//! What the Session API promises a newcomer, including when it is used the
//! wrong way: typed calls define what they need, a topic keeps one type,
//! options a backend cannot honour are refused by name, unknown URL schemes
//! list the known ones. Against Courier's own central, embedded on a free
//! port of 127.0.0.1; every wait is bounded.

use std::future::IntoFuture;
use std::time::Duration;

use courier::{ConnectError, IpcMessage, OpenError, PublishError, QueryError, Session};
use futures::StreamExt;

mod common;

const T: Duration = Duration::from_secs(20);

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Ask {
    a: i32,
    b: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Sum {
    total: i32,
    note: String,
}

use common::{central, connect as session};

/// The crate-root example's order: `serve` and `query` with no `define`
/// anywhere. Both define their messages themselves (on the old code the
/// query failed with "query  refused", and a reply to an undefined reply
/// message was dropped).
#[tokio::test]
async fn typed_query_and_serve_define_what_they_need() {
    let (c, url) = central().await;
    let server = session(&url, "adder").await;
    let client = session(&url, "asker").await;
    let mut reqs = server.serve::<Ask, Sum>("add", "add_result").await.unwrap();
    let srv = tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let sum = Sum {
                total: r.value.a + r.value.b,
                note: "ok".into(),
            };
            r.reply(&sum).await.unwrap();
        }
    });
    let r: Sum = client
        .query("add", &Ask { a: 2, b: 40 })
        .timeout(T)
        .await
        .unwrap();
    assert_eq!(r.total, 42);
    client.close().await;
    server.close().await;
    tokio::time::timeout(T, srv).await.unwrap().unwrap();
    c.shutdown().await;
}

/// `publish` alone, never `define`d, reaches a subscriber.
#[tokio::test]
async fn typed_publish_defines_its_message() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut sub = b.subscribe::<Sum>("sums").await.unwrap();
    common::await_handlers(&a, "sums", 1).await;
    let v = Sum {
        total: 7,
        note: "seven".into(),
    };
    a.publish("sums", &v).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap().unwrap();
    assert_eq!(got.unwrap().value, v);
    a.close().await;
    b.close().await;
    c.shutdown().await;
}

/// Another type on a topic this session already uses is an error naming
/// both types, for every typed operation; the subscriber never sees bytes
/// it cannot decode (the old code returned Ok and the subscriber got
/// `Decode { "count 1072693248 at byte 4 …" }`).
#[tokio::test]
async fn a_topic_keeps_one_type_per_session() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    a.define::<Sum>("sums").await.unwrap();
    let mismatch = |e: OpenError| match e {
        OpenError::TypeMismatch { msg, bound, given } => {
            assert_eq!(msg, "sums");
            assert!(bound.ends_with("Sum"), "{bound}");
            given
        }
        other => panic!("expected a type mismatch, got {other:?}"),
    };
    let given = match a.publish("sums", &1.5f64).await.unwrap_err() {
        PublishError::Open(e) => mismatch(e),
        other => panic!("expected a type mismatch, got {other:?}"),
    };
    assert_eq!(given, "f64");
    mismatch(a.define::<Ask>("sums").await.unwrap_err());
    mismatch(a.subscribe::<i32>("sums").await.err().unwrap());
    mismatch(a.publisher::<Ask>("sums").build().await.err().unwrap());
    mismatch(a.serve::<Ask, Sum>("sums", "other").await.err().unwrap());
    let e = a
        .query::<Ask, Sum>("sums", &Ask { a: 1, b: 2 })
        .timeout(T)
        .await
        .unwrap_err();
    match e {
        QueryError::Open { msg, source } => {
            assert_eq!(msg, "sums");
            let detail = source.to_string();
            assert!(detail.contains("Sum") && detail.contains("Ask"), "{detail}");
            mismatch(source);
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    // the same type again is fine
    a.publish(
        "sums",
        &Sum {
            total: 1,
            note: String::new(),
        },
    )
    .await
    .unwrap();
    a.close().await;
    c.shutdown().await;
}

/// DDS settings on an IPC session fail, naming the setting, instead of
/// being ignored; settings IPC has (keep-last as the local queue, best
/// effort, which reliable delivery satisfies) are accepted.
#[tokio::test]
async fn dds_settings_on_an_ipc_session_are_refused_by_name() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let unsupported = |e: OpenError, what: &str| match e {
        OpenError::Unsupported { what: w, backend } => {
            assert!(w.contains(what), "{w}");
            assert_eq!(backend, "ipc://");
        }
        other => panic!("expected {what} refused, got {other:?}"),
    };
    let e = a.subscriber::<i32>("m1").deadline(T).build().await;
    unsupported(e.err().unwrap(), "deadline");
    let e = a.subscriber::<i32>("m2").exclusive().build().await;
    unsupported(e.err().unwrap(), "exclusive");
    let e = a
        .subscriber::<i32>("m3")
        .minimum_separation(T)
        .build()
        .await;
    unsupported(e.err().unwrap(), "minimum separation");
    let e = a.publisher::<i32>("m4").strength(3).build().await;
    unsupported(e.err().unwrap(), "strength");
    let e = a.publisher::<i32>("m5").deadline(T).build().await;
    unsupported(e.err().unwrap(), "deadline");
    let e = a.publisher::<i32>("m6").transient_local().build().await;
    unsupported(e.err().unwrap(), "transient-local");
    let _m7 = a
        .subscriber::<i32>("m7")
        .keep_last(4)
        .best_effort()
        .build()
        .await
        .unwrap();
    a.close().await;

    let e = Session::builder(&url)
        .interface("lo")
        .connect()
        .await
        .err()
        .unwrap();
    let text = e.to_string();
    assert!(
        matches!(
            &e,
            ConnectError::Unsupported {
                option: "interface",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(text.contains("rtps://"), "{text}");
    c.shutdown().await;
}

/// IPC-only builder options on an RTPS session fail at connect.
#[tokio::test]
async fn ipc_settings_on_an_rtps_session_are_refused_by_name() {
    let e = Session::builder(common::url(1))
        .no_listen()
        .connect()
        .await
        .err()
        .unwrap();
    assert!(
        matches!(&e, ConnectError::Unsupported { option: "no_listen", scheme, .. } if scheme == "rtps"),
        "{e:?}"
    );
    // connect_timeout too (it was silently ignored there)
    let e = Session::builder(common::url(1))
        .connect_timeout(std::time::Duration::from_secs(1))
        .connect()
        .await
        .err()
        .unwrap();
    assert!(
        matches!(
            &e,
            ConnectError::Unsupported {
                option: "connect_timeout",
                ..
            }
        ),
        "{e:?}"
    );
    // and a message size of 0 on any backend
    let e = Session::builder(common::url(1))
        .max_message_bytes(0)
        .connect()
        .await
        .err()
        .unwrap();
    assert_eq!(
        e.to_string(),
        "bad SessionBuilder::max_message_bytes: 0 bytes is no message"
    );
    // and a busy-polling window that would hold a CPU for nothing (10 s
    // after each message)
    let e = Session::builder(common::url(1))
        .busy_poll(std::time::Duration::from_secs(10))
        .connect()
        .await
        .err()
        .unwrap();
    assert!(
        e.to_string()
            .starts_with("bad SessionBuilder::busy_poll: a window of 10s is longer than 1s"),
        "{e}"
    );
    let e = courier::central::CentralServer::builder()
        .port(0)
        .busy_poll(std::time::Duration::from_secs(10))
        .spawn()
        .await
        .err()
        .unwrap();
    assert!(
        e.to_string()
            .starts_with("bad Builder::busy_poll: a window of 10s is longer than 1s"),
        "{e}"
    );
}

/// A URL with a scheme nobody registered names the known schemes (the old
/// code sent every non-`rtps:` URL to IPC: "expected ipc://host:port").
#[tokio::test]
async fn an_unknown_scheme_lists_the_known_ones() {
    for url in ["zenoh://127.0.0.1:7447", "localhost:1381"] {
        let e = Session::builder(url).connect().await.err().unwrap();
        let text = e.to_string();
        assert!(
            matches!(e, ConnectError::UnknownScheme { .. }),
            "{url}: {e:?}"
        );
        assert!(
            text.contains("ipc, rtps, xrce+udp, xrce+tcp, xrce+serial"),
            "{text}"
        );
    }
}

/// A reply whose message central does not know fails with an error naming
/// it, and the server keeps receiving (on the old code `reply` returned Ok,
/// the reply vanished and the module's capacity slot in central stayed
/// taken: it never received another message).
#[tokio::test]
async fn a_failed_reply_is_an_error_and_the_server_keeps_receiving() {
    let (c, url) = central().await;
    let server = session(&url, "server").await;
    let client = session(&url, "client").await;
    let mut reqs = server.serve_raw("ask").await.unwrap();
    client.define::<i32>("ask").await.unwrap();
    client.define::<i32>("answer").await.unwrap();
    common::await_handlers(&client, "ask", 1).await;
    let first = tokio::spawn({
        let client = client.clone();
        async move {
            client
                .query::<i32, i32>("ask", &1)
                .timeout(Duration::from_millis(500))
                .await
        }
    });
    let r = tokio::time::timeout(T, reqs.recv()).await.unwrap().unwrap();
    let e = r
        .respond
        .reply("never_defined", 7i32.to_le_bytes().to_vec())
        .await
        .unwrap_err();
    assert!(e.to_string().contains("never_defined"), "{e}");
    let e = first.await.unwrap().unwrap_err();
    assert!(matches!(e, QueryError::Timeout { .. }), "{e}");
    // the slot is free again: the next query is delivered and answered
    let second = tokio::spawn({
        let client = client.clone();
        async move { client.query::<i32, i32>("ask", &2).timeout(T).await }
    });
    let r = tokio::time::timeout(T, reqs.recv()).await.unwrap().unwrap();
    r.respond
        .reply("answer", 40i32.to_le_bytes().to_vec())
        .await
        .unwrap();
    assert_eq!(second.await.unwrap().unwrap(), 40);
    client.close().await;
    server.close().await;
    c.shutdown().await;
}

/// A `Request` dropped without a reply is declined: the asker times out and
/// the server keeps receiving (on the old code the module was wedged).
#[tokio::test]
async fn a_dropped_request_is_declined_and_the_server_keeps_receiving() {
    let (c, url) = central().await;
    let server = session(&url, "server").await;
    let client = session(&url, "client").await;
    let mut reqs = server.serve::<Ask, Sum>("add", "").await.unwrap();
    common::await_handlers(&client, "add", 1).await;
    let first = tokio::spawn({
        let client = client.clone();
        async move {
            client
                .query::<Ask, Sum>("add", &Ask { a: 1, b: 1 })
                .timeout(Duration::from_millis(500))
                .await
        }
    });
    let r = tokio::time::timeout(T, reqs.next()).await.unwrap().unwrap();
    drop(r.unwrap());
    let e = first.await.unwrap().unwrap_err();
    assert!(matches!(e, QueryError::Timeout { .. }), "{e}");
    let second = tokio::spawn({
        let client = client.clone();
        async move {
            client
                .query::<Ask, Sum>("add", &Ask { a: 20, b: 22 })
                .timeout(T)
                .await
        }
    });
    let r = tokio::time::timeout(T, reqs.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let total = r.value.a + r.value.b;
    r.reply(&Sum {
        total,
        note: String::new(),
    })
    .await
    .unwrap();
    assert_eq!(second.await.unwrap().unwrap().total, 42);
    client.close().await;
    server.close().await;
    c.shutdown().await;
}

/// Two publications of one message in one session share its definition in
/// central, and both reach the subscriber.
#[tokio::test]
async fn two_ipc_publications_of_one_message_share_its_definition() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let b = session(&url, "b").await;
    let mut sub = b.subscribe::<i32>("shared").await.unwrap();
    let p1 = a.publisher::<i32>("shared").build().await.unwrap();
    let p2 = a.publisher::<i32>("shared").build().await.unwrap();
    common::await_handlers(&a, "shared", 1).await;
    p1.publish(&1).await.unwrap();
    p2.publish(&2).await.unwrap();
    drop(p1);
    p2.publish(&3).await.unwrap();
    for want in [1, 2, 3] {
        let got = tokio::time::timeout(T, sub.next()).await.unwrap().unwrap();
        assert_eq!(got.unwrap().value, want);
    }
    a.close().await;
    b.close().await;
    c.shutdown().await;
}

/// Dropping the stream of `serve` unsubscribes its handler in central.
#[tokio::test]
async fn a_dropped_requests_stream_unsubscribes() {
    let (c, url) = central().await;
    let server = session(&url, "server").await;
    let client = session(&url, "client").await;
    let reqs = server.serve::<Ask, Sum>("add", "").await.unwrap();
    common::await_handlers(&client, "add", 1).await;
    drop(reqs);
    tokio::time::timeout(T, async {
        while client.num_handlers("add").await.unwrap() != 0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("the handler is gone from central");
    client.close().await;
    server.close().await;
    c.shutdown().await;
}

/// `keep_last(0)` keeps nothing: refused when built, on every backend (it
/// was taken as 1, silently).
#[tokio::test]
async fn keep_last_of_nothing_is_refused() {
    let (c, url) = central().await;
    let a = session(&url, "a").await;
    let e = a
        .publisher::<i32>("t")
        .keep_last(0)
        .build()
        .await
        .unwrap_err();
    assert_eq!(
        e.to_string(),
        "QoS of t: keep_last(0) keeps nothing: give 1 or more (or keep_all)"
    );
    let e = a
        .subscriber::<i32>("t")
        .keep_last(0)
        .build()
        .await
        .err()
        .unwrap();
    assert!(matches!(e, OpenError::Qos { .. }), "{e:?}");
    // and the topic is not bound by the refused attempt
    let _t = a.subscriber::<f64>("t").keep_last(1).build().await.unwrap();
    a.close().await;
    c.shutdown().await;
}

/// Sessions without a name get names of their own within the process
/// (`courier-<pid>`, `courier-<pid>-2`, …): central refuses a second module
/// of one name, so the second unnamed session of a process was refused.
#[tokio::test]
async fn unnamed_sessions_of_one_process_each_connect() {
    let (c, url) = central().await;
    let connect = || Session::builder(url.as_str()).connect();
    let a = tokio::time::timeout(T, connect()).await.unwrap().unwrap();
    let b = tokio::time::timeout(T, connect()).await.unwrap().unwrap();
    let mut sub = b.subscribe::<i32>("both").await.unwrap();
    a.publish("both", &7).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await;
    assert_eq!(got.unwrap().unwrap().unwrap().value, 7);
    a.close().await;
    b.close().await;
    c.shutdown().await;
}

/// The handles are `Debug` whatever their message type: a program that
/// keeps a `Publisher<T>` in a `#[derive(Debug)]` struct needs no `T:
/// Debug` (the derived impls asked for it).
#[test]
fn handles_are_debug_whatever_their_type() {
    #[derive(courier::IpcMessage)]
    struct NotDebug {
        _x: i32,
    }
    fn debug<T: std::fmt::Debug>() {}
    debug::<courier::Publisher<NotDebug>>();
    debug::<courier::PublisherBuilder<NotDebug>>();
    debug::<courier::Subscriber<NotDebug>>();
    debug::<courier::SubscriberBuilder<NotDebug>>();
    debug::<courier::Requests<NotDebug, NotDebug>>();
}

/// A `close()` asked for ends the session's streams with `None`, without
/// an error (`s?` in a loop over them ends cleanly), whichever clone of the
/// session closed it; on IPC and DDS. Its events end too, without a
/// `Disconnected` (which says the connection was lost).
#[tokio::test]
async fn a_close_ends_streams_without_an_error() {
    let (c, url) = central().await;
    for url in [url, common::url(2)] {
        let s = session(&url, "closing").await;
        let mut sub = s.subscribe::<i32>("t").await.unwrap();
        let mut reqs = s.serve::<Ask, Sum>("add", "").await.unwrap();
        let events = s.events();
        let seen = tokio::spawn(events.collect::<Vec<_>>());
        let run = tokio::spawn(async move {
            let mut n = 0;
            // (recv: next() without StreamExt)
            while let Some(s) = sub.recv().await {
                s?;
                n += 1;
            }
            while let Some(r) = reqs.recv().await {
                r?;
                n += 1;
            }
            Ok::<_, courier::RecvError>(n)
        });
        let clone = s.clone();
        tokio::time::timeout(T, clone.close()).await.unwrap();
        let n = tokio::time::timeout(T, run).await.unwrap().unwrap();
        assert_eq!(n, Ok(0), "{url}");
        let seen = tokio::time::timeout(T, seen).await.unwrap().unwrap();
        assert!(
            !seen.contains(&courier::SessionEvent::Disconnected),
            "{url}: {seen:?}"
        );
    }
    c.shutdown().await;
}

/// A callback that holds its own session (to answer with a publisher of
/// it, as `listen`'s example does) is dropped at `close()`: the session,
/// its sockets and its tasks do not keep each other alive for ever.
#[tokio::test]
async fn a_closed_session_lets_go_of_its_callbacks() {
    let (c, url) = central().await;
    for url in [url, common::url(3)] {
        common::close_lets_go_of_a_callback(session(&url, "callbacks").await).await;
    }
    c.shutdown().await;
}

/// `Duration::MAX` as a bound means "as long as it takes": a query, a
/// confirmed publish, `wait_for_handlers` and IPC's `connect_timeout`
/// given it work (they panicked adding it to the clock; on DDS inside the
/// session's driver, which killed the session).
#[tokio::test]
async fn duration_max_as_a_bound_waits_as_long_as_it_takes() {
    let (c, url) = central().await;
    let forever = Duration::MAX;
    for url in [url, common::url(4)] {
        let builder = Session::builder(url.as_str()).name("forever");
        let builder = if url.starts_with("ipc") {
            builder.connect_timeout(forever)
        } else {
            builder
        };
        let s = tokio::time::timeout(T, builder.connect())
            .await
            .unwrap()
            .unwrap();
        let mut reqs = s.serve::<Ask, Sum>("add", "").await.unwrap();
        let srv = tokio::spawn(async move {
            while let Some(Ok(r)) = reqs.next().await {
                let total = r.value.a + r.value.b;
                let _ = r
                    .reply(&Sum {
                        total,
                        note: String::new(),
                    })
                    .await;
            }
        });
        let mut sub = s.subscribe::<i32>("t").await.unwrap();
        let p = s.publisher::<i32>("t").build().await.unwrap();
        let n = tokio::time::timeout(T, s.wait_for_handlers("t", 1, forever)).await;
        assert_eq!(n.unwrap(), Ok(1), "{url}");
        let sum: Sum =
            tokio::time::timeout(T, s.query("add", &Ask { a: 1, b: 2 }).timeout(forever))
                .await
                .unwrap()
                .unwrap();
        assert_eq!(sum.total, 3, "{url}");
        if !url.starts_with("ipc") {
            tokio::time::timeout(T, p.publish(&5).confirmed_within(forever))
                .await
                .unwrap()
                .unwrap();
            let got = tokio::time::timeout(T, sub.next()).await.unwrap();
            assert_eq!(got.unwrap().unwrap().value, 5);
        }
        s.close().await;
        tokio::time::timeout(T, srv).await.unwrap().unwrap();
    }
    c.shutdown().await;
}

/// Names DDS cannot carry are refused by the session, naming what is
/// wrong, and a long one is not repeated whole.
#[tokio::test]
async fn names_dds_cannot_carry_are_refused_clearly() {
    let s = session(&common::url(5), "names").await;
    let e = s.subscribe::<i32>("a\0b").await.err().unwrap();
    assert_eq!(
        e.to_string(),
        "bad name \"a\\0b\": DDS names cannot hold a NUL"
    );
    let e = s.publisher::<i32>("").build().await.unwrap_err();
    assert_eq!(e.to_string(), "bad name \"\": a topic needs a name");
    let long = "x".repeat(70_000);
    let e = s.serve::<i32, i32>(&long, "").await.err().unwrap();
    assert_eq!(
        e.to_string(),
        format!(
            "bad name \"{}\"… (70000 bytes): DDS names are at most 256 bytes",
            "x".repeat(64)
        )
    );
    s.close().await;
}

/// A burst of `publish().await`s right before `close()` is not lost: the
/// close sends what the session still holds before it goes (IPC: what
/// waits to be written to central or, direct, to the other module; DDS:
/// the writer's linger, while the
/// reader reads). Each of the 2000 samples returned `Ok`, so each must
/// arrive.
#[tokio::test]
async fn a_burst_published_right_before_close_arrives() {
    let (c, url) = central().await;
    let mut direct = courier_broker::Config::default();
    direct.direct = true;
    let (d, direct_url) = common::central_with(direct, |b| b).await;
    for url in [url, direct_url, common::url(6)] {
        let a = session(&url, "burst").await;
        let b = session(&url, "count").await;
        let mut sub = b.subscribe::<Sum>("burst").await.unwrap();
        let p = a.publisher::<Sum>("burst").build().await.unwrap();
        tokio::time::timeout(T, a.wait_for_handlers("burst", 1, T))
            .await
            .unwrap()
            .unwrap();
        let reader = tokio::spawn(async move {
            let mut got = Vec::new();
            while got.len() < 2000 {
                match tokio::time::timeout(T, sub.next()).await {
                    Ok(Some(Ok(s))) => got.push(s.value.total),
                    _ => break,
                }
            }
            got
        });
        let note = "x".repeat(500);
        for total in 0..2000 {
            let s = Sum {
                total,
                note: note.clone(),
            };
            p.publish(&s).await.unwrap();
        }
        drop(p);
        tokio::time::timeout(T, a.close()).await.unwrap();
        let got = reader.await.unwrap();
        assert_eq!(got, (0..2000).collect::<Vec<_>>(), "{url}");
        b.close().await;
    }
    c.shutdown().await;
    d.shutdown().await;
}

/// Cancelled `subscribe` and `serve` calls leave nothing behind: no
/// subscription nobody reads (its full queue held every other delivery to
/// the session, and its publishers still counted it), no service that
/// keeps its name (a second `serve` was refused for ever). IPC, IPC direct
/// and RTPS.
#[tokio::test]
async fn cancelled_opens_leave_nothing_behind() {
    let (c, url) = central().await;
    let mut direct = courier_broker::Config::default();
    direct.direct = true;
    let (d, direct_url) = common::central_with(direct, |b| b).await;
    for url in [url, direct_url, common::url(7)] {
        let a = session(&url, "cancelling").await;
        let b = session(&url, "publishing").await;
        b.define::<i32>("leak").await.unwrap();
        for turns in 0..40 {
            common::cancel_after(a.subscribe::<i32>("leak"), turns % 8).await;
            common::cancel_after(a.serve::<Ask, Sum>("svc", ""), turns % 8).await;
        }
        // every subscription of `leak` is gone (central or matching says)
        let gone = tokio::time::timeout(T, async {
            while b.num_handlers("leak").await.unwrap() != 0 {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await;
        assert!(
            gone.is_ok(),
            "{url}: cancelled subscriptions still count: {:?}",
            b.num_handlers("leak").await
        );
        // the service can be served again
        let served = tokio::time::timeout(T, a.serve::<Ask, Sum>("svc", "")).await;
        assert!(matches!(served, Ok(Ok(_))), "{url}: {served:?}");
        // and a subscription of the session still gets what is published,
        // after a flood of the topic the cancelled ones named
        let mut other = a.subscribe::<i32>("other").await.unwrap();
        let p = b.publisher::<i32>("other").build().await.unwrap();
        tokio::time::timeout(T, b.wait_for_handlers("other", 1, T))
            .await
            .unwrap()
            .unwrap();
        for i in 0..2000 {
            b.publish("leak", &i).await.unwrap();
        }
        p.publish(&7).await.unwrap();
        let got = tokio::time::timeout(T, other.next()).await;
        assert!(
            matches!(got, Ok(Some(Ok(ref s))) if s.value == 7),
            "{url}: {got:?}"
        );
        a.close().await;
        b.close().await;
    }
    c.shutdown().await;
    d.shutdown().await;
}

/// A first typed use that is cancelled (or a publish never awaited) does
/// not hold its topic to its type: another type may use the topic after
/// (it got `TypeMismatch` for the session's life). IPC and RTPS.
#[tokio::test]
async fn a_cancelled_first_use_does_not_bind_the_topic() {
    let (c, url) = central().await;
    for url in [url, common::url(8)] {
        let s = session(&url, "binder").await;
        common::cancel_after(s.subscribe::<Ask>("sub_topic"), 0).await;
        let sub = tokio::time::timeout(T, s.subscribe::<Sum>("sub_topic")).await;
        assert!(matches!(sub, Ok(Ok(_))), "{url}: {sub:?}");
        drop(s.publish("pub_topic", &Ask { a: 1, b: 2 }));
        let sum = Sum {
            total: 3,
            note: String::new(),
        };
        let p = tokio::time::timeout(T, s.publish("pub_topic", &sum)).await;
        assert!(matches!(p, Ok(Ok(()))), "{url}: {p:?}");
        common::cancel_after(
            s.query::<Ask, Sum>("q_topic", &Ask { a: 1, b: 2 })
                .into_future(),
            0,
        )
        .await;
        let d = tokio::time::timeout(T, s.define::<Sum>("q_topic")).await;
        assert!(matches!(d, Ok(Ok(()))), "{url}: {d:?}");
        s.close().await;
    }
    c.shutdown().await;
}

/// Liveliness where a backend cannot keep it is refused when the handle is
/// built, naming what and where (IPC has no liveliness; a plain
/// `assert_liveliness` there is refused too).
#[tokio::test]
async fn liveliness_on_ipc_is_refused_by_name() {
    use courier::qos::LivelinessKind;
    let (c, url) = central().await;
    let a = session(&url, "lively").await;
    let e = a
        .publisher::<i32>("beat")
        .liveliness(LivelinessKind::ManualByTopic, Duration::from_secs(1))
        .build()
        .await
        .err()
        .unwrap();
    assert!(
        matches!(&e, OpenError::Unsupported { what, .. } if what.contains("liveliness")),
        "{e:?}"
    );
    let e = a
        .subscriber::<i32>("beat")
        .liveliness(LivelinessKind::Automatic, Duration::from_secs(1))
        .build()
        .await
        .err()
        .unwrap();
    assert!(matches!(e, OpenError::Unsupported { .. }), "{e:?}");
    let p = a.publisher::<i32>("beat").build().await.unwrap();
    let e = p.assert_liveliness().await.unwrap_err();
    assert!(matches!(e, PublishError::Unsupported { .. }), "{e:?}");
    let e = a.assert_liveliness().await.unwrap_err();
    assert!(
        matches!(&e, PublishError::Unsupported { what, backend: "ipc://" }
            if what.contains("Session::assert_liveliness")),
        "{e:?}"
    );
    a.close().await;
    c.shutdown().await;
}
