//! IPC: what a module is told when its type does not fit the format
//! central holds for a message, as a definer (define, publish) and as a
//! subscriber; and the wording of a query's unmatched replies. Every wait
//! is bounded.

use std::time::Duration;

use courier::{IpcMessage, OpenError, QueryError, RecvError};
use futures::StreamExt;

mod common;

use common::{central, connect as session, T};

/// What the robot's motor module sends on `m`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Cmd {
    seq: u64,
    mode: i64,
    v: f64,
    w: f64,
}

/// What the planner thinks `m` is.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Odom {
    seq: u64,
    x: f64,
    y: f64,
    theta: f64,
}

const CMD: &str = "{ulong, long, double, double}";
const ODOM: &str = "{ulong, double, double, double}";

fn odom() -> &'static str {
    std::any::type_name::<Odom>()
}

/// A definer whose type does not fit is told that central holds the other
/// format and what its own type's format is, not that it is a reader.
#[tokio::test]
async fn a_definer_whose_type_does_not_fit_is_told_both_formats_as_the_writer() {
    let (c, url) = central().await;
    let a = session(&url, "motor").await;
    let b = session(&url, "planner").await;
    a.define::<Cmd>("m").await.unwrap();
    let e = tokio::time::timeout(T, b.define::<Odom>("m"))
        .await
        .expect("define in time")
        .unwrap_err();
    assert!(matches!(e, OpenError::FormatMismatch { .. }), "{e:?}");
    let ty = odom();
    assert_eq!(
        e.to_string(),
        format!(
            "central holds the format {CMD} for m (defined by another module, or an earlier \
             run of this one), which {ty} does not fit: {ty}'s format is {ODOM}; at field 2, \
             {ty} has double where central's format has long"
        )
    );
    // a publish of the misfit says the same
    let odo = Odom {
        seq: 1,
        x: 0.0,
        y: 0.0,
        theta: 0.0,
    };
    let b2 = session(&url, "planner2").await;
    let e = tokio::time::timeout(T, b2.publish("m", &odo))
        .await
        .expect("publish in time")
        .unwrap_err();
    assert!(
        e.to_string().contains(&format!(
            "{ty}'s format is {ODOM}; at field 2, {ty} has double where central's format has long"
        )),
        "{e}"
    );
    c.shutdown().await;
}

/// A subscriber whose type does not fit the format central already holds
/// is refused at once, naming both formats (it was `Ok`, and then every
/// message was a `FormatMismatch`); the message is not subscribed, and the
/// session may still subscribe with the right type.
#[tokio::test]
async fn a_subscriber_whose_type_does_not_fit_a_known_format_is_refused_up_front() {
    let (c, url) = central().await;
    let a = session(&url, "motor").await;
    let b = session(&url, "planner").await;
    a.define::<Cmd>("cmd").await.unwrap();
    let r = tokio::time::timeout(T, b.subscribe::<Odom>("cmd"))
        .await
        .expect("subscribe in time");
    let e = match r {
        Err(e) => e,
        Ok(_) => panic!("subscribed to cmd as Odom although central holds {CMD}"),
    };
    let OpenError::FormatMismatch {
        msg,
        ty,
        central: held,
        detail,
    } = &e
    else {
        panic!("{e:?}")
    };
    assert_eq!((msg.as_str(), *ty, held.as_str()), ("cmd", odom(), CMD));
    let t = odom();
    assert_eq!(
        *detail,
        format!("{t}'s format is {ODOM}; at field 2, the data has long where {t} has double")
    );
    assert!(
        e.to_string().contains(CMD) && e.to_string().contains(ODOM),
        "{e}"
    );
    // nothing was subscribed
    let n = tokio::time::timeout(T, a.num_handlers("cmd"))
        .await
        .unwrap();
    assert_eq!(n.unwrap(), 0);
    // the right type is taken (the refused one left no binding behind)
    let mut sub = tokio::time::timeout(T, b.subscribe::<Cmd>("cmd"))
        .await
        .expect("subscribe in time")
        .unwrap();
    let want = Cmd {
        seq: 3,
        mode: 1,
        v: 0.5,
        w: 0.0,
    };
    let got = tokio::time::timeout(T, async {
        loop {
            a.publish("cmd", &want).await.unwrap();
            if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(100), sub.next()).await
            {
                break s.unwrap().value;
            }
        }
    })
    .await
    .expect("a message in time");
    assert_eq!(got, want);
    c.shutdown().await;
}

/// A subscription made before anyone defines the message is taken, and
/// each message of a format that its type does not fit is a
/// `FormatMismatch` saying the data's format and the subscriber's type.
#[tokio::test]
async fn a_subscriber_before_the_definer_is_taken_and_told_message_by_message() {
    let (c, url) = central().await;
    let a = session(&url, "motor").await;
    let b = session(&url, "planner").await;
    let mut sub = tokio::time::timeout(T, b.subscribe::<Odom>("later"))
        .await
        .expect("subscribe in time")
        .expect("central does not know the message yet: nothing to refuse");
    a.define::<Cmd>("later").await.unwrap();
    let msg = Cmd {
        seq: 1,
        mode: 2,
        v: 0.1,
        w: 0.2,
    };
    let e = tokio::time::timeout(T, async {
        loop {
            a.publish("later", &msg).await.unwrap();
            if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(100), sub.next()).await
            {
                break s;
            }
        }
    })
    .await
    .expect("a message in time");
    let t = odom();
    match e {
        Err(RecvError::FormatMismatch {
            msg,
            ty,
            central,
            detail,
        }) => {
            assert_eq!((msg.as_str(), ty, central.as_str()), ("later", t, CMD));
            assert_eq!(
                detail,
                format!(
                    "{t}'s format is {ODOM}; at field 2, the data has long where {t} has double"
                )
            );
        }
        other => panic!("{other:?}"),
    }
    c.shutdown().await;
}

/// Two subscriptions made before anyone defines the message both get its
/// values (the README's Appendix A: module2 and module3 subscribe to
/// `message1` before module1 defines it). The second subscriber's format
/// lookup found central's placeholder for the first one's handler and
/// kept it as the message's definition, so it took C's `{int, <byte:1>}`
/// wrapper for the data: "8 unexpected trailing byte(s)" (audit 21).
#[tokio::test]
async fn subscribers_before_the_definer_all_get_its_values() {
    let (c, url) = central().await;
    let a = session(&url, "module1").await;
    let b = session(&url, "module2").await;
    let d = session(&url, "module3").await;
    let mut subs = Vec::new();
    for s in [&d, &b] {
        let sub = tokio::time::timeout(T, s.subscribe::<i32>("message1"))
            .await
            .expect("subscribe in time")
            .expect("subscribe");
        subs.push(sub);
    }
    a.define::<i32>("message1").await.unwrap();
    a.wait_for_handlers("message1", 2, T).await.unwrap();
    a.publish("message1", &42i32).await.unwrap();
    for (i, sub) in subs.iter_mut().enumerate() {
        let got = tokio::time::timeout(T, sub.next())
            .await
            .expect("a message in time")
            .expect("open");
        assert_eq!(got.map(|s| s.value), Ok(42), "subscriber {i}");
    }
    c.shutdown().await;
}

/// Replies that answered no open query are named for both causes, the
/// late replies of a stalled server first.
#[test]
fn unmatched_replies_name_late_replies_and_the_other_service_style() {
    let e = QueryError::Unmatched {
        msg: "plan".into(),
        timeout: Duration::from_millis(300),
        replies: 1,
    };
    let s = e.to_string();
    let late = s.find("late replies to earlier queries that had timed out");
    let style = s.find("a ROS 2 service of the other request/reply style");
    assert!(
        matches!((late, style), (Some(l), Some(r)) if l < r),
        "both causes, late replies first: {s}"
    );
    assert!(
        s.starts_with("no reply to plan within 300ms; 1 reply(ies)"),
        "{s}"
    );
}
