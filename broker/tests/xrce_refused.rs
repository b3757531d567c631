//! An XRCE session whose agent no longer has its data writer is told so,
//! and its publishes fail naming the refusal, instead of returning `Ok`
//! for samples that vanish (confirmed ones included):
//! - the agent came back in another DDS domain and refused the entities
//!   when the session re-created them;
//! - the agent restored the session from `--state` but could not make the
//!   writer again, and answers the client's writes with
//!   `ERR_UNKNOWN_REFERENCE`.
//!
//! Every DDS participant is on `lo`, unicast to 127.0.0.1, multicast off,
//! in a domain leased machine-wide; every XRCE socket binds 127.0.0.1.

use std::net::SocketAddr;
use std::time::Duration;

use courier::{IpcMessage, PublishError, Session, SessionEvent};
use courier_broker::xrce_agent::{Transport, XrceAgent};
use futures::StreamExt;

mod xrce_client;
use xrce_client::{rtps, runtime, T};

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Count")]
struct Count {
    n: u32,
}

/// Fast loss detection and re-creation.
const FAST: &str = "keepalive_ms=100&lost_ms=500&attempt_ms=100&attempts=50";

async fn agent(domain: u32, port: u16, state: Option<&std::path::Path>) -> XrceAgent {
    let addr = SocketAddr::from(([127, 0, 0, 1], port));
    let mut b = XrceAgent::builder()
        .rtps(rtps(domain))
        .transport(Transport::Udp(addr));
    if let Some(s) = state {
        b = b.state(s);
    }
    b.spawn().await.unwrap()
}

/// A session publishing on `count` through an agent in domain `d`, then
/// that agent stopped and another started on its port in domain `other`
/// (with the same `state`, if any).
async fn moved(
    d: u32,
    other: u32,
    state: Option<&std::path::Path>,
) -> (
    Session,
    courier::Events,
    courier::Publisher<Count>,
    XrceAgent,
) {
    let a = agent(d, 0, state).await;
    let addr = a.udp_addrs()[0];
    let url = format!("xrce+udp://{addr}?domain={d}&{FAST}");
    let s = Session::builder(url).name("w").connect().await.unwrap();
    let ev = s.events();
    let p = s.publisher::<Count>("count").build().await.unwrap();
    p.publish(&Count { n: 0 }).confirmed().await.unwrap();
    a.shutdown().await;
    let b = agent(other, addr.port(), state).await;
    (s, ev, p, b)
}

/// Publishes (confirmed) until a publish fails, within `T`; the error.
async fn publish_until_refused(p: &courier::Publisher<Count>) -> PublishError {
    let r = tokio::time::timeout(T, async {
        for n in 0.. {
            match p.publish(&Count { n }).confirmed().await {
                Ok(()) => tokio::time::sleep(Duration::from_millis(50)).await,
                Err(e) => return e,
            }
        }
        unreachable!()
    });
    r.await
        .expect("a publish fails once the agent refused the writer")
}

fn assert_refused(e: &PublishError) {
    assert!(
        matches!(
            e,
            PublishError::AgentRefused {
                entity: "data writer",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string().starts_with(
            "cannot publish count: the XRCE agent refused its data writer (STATUS_ERR_"
        ),
        "{e}"
    );
}

#[test]
fn a_writer_refused_when_the_session_is_re_created_fails_its_publishes() {
    let (d, other) = (
        courier_tests::domains::lease(20),
        courier_tests::domains::lease(21),
    );
    let rt = runtime();
    rt.block_on(async {
        // the agent comes back on the same port, in another domain
        let (s, mut ev, p, b) = moved(d, other, None).await;
        let recreated = tokio::time::timeout(T, async {
            let mut refused = Vec::new();
            while let Some(e) = ev.next().await {
                match e {
                    SessionEvent::EntityError { entity, .. } => refused.push(entity),
                    SessionEvent::SessionRecreated { entities } => return (entities, refused),
                    _ => {}
                }
            }
            panic!("the session ended")
        });
        let (entities, refused) = recreated.await.expect("the session is re-created");
        assert!(refused.contains(&"data writer"), "{refused:?}");
        assert_eq!(
            entities, 0,
            "none of the entities was made again: {refused:?}"
        );
        let e = p.publish(&Count { n: 1 }).await.unwrap_err();
        assert_refused(&e);
        s.close().await;
        b.shutdown().await;
    });
}

#[test]
fn a_writer_a_restored_agent_could_not_make_again_fails_its_publishes() {
    let (d, other) = (
        courier_tests::domains::lease(22),
        courier_tests::domains::lease(23),
    );
    let dir = std::env::temp_dir().join(format!("xrce-refused-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let state = dir.join("agent.redb");
    let rt = runtime();
    rt.block_on(async {
        // restored in another domain: the session is kept, its entities
        // cannot be made again
        let (s, mut ev, p, b) = moved(d, other, Some(&state)).await;
        let e = publish_until_refused(&p).await;
        assert_refused(&e);
        let told = tokio::time::timeout(T, async {
            while let Some(e) = ev.next().await {
                if let SessionEvent::EntityError { entity, topic, .. } = e {
                    return (entity, topic);
                }
            }
            panic!("the session ended")
        });
        assert_eq!(told.await.unwrap(), ("data writer", "count".to_string()));
        s.close().await;
        b.shutdown().await;
    });
    let _ = std::fs::remove_dir_all(dir);
}

/// With `representation=reference`, a refusal names the profile the agent
/// lacks; QoS a reference cannot carry is refused before anything goes to
/// the agent (the topic went first, and its refusal came later as a stray
/// `EntityError`); a refused open leaves no stray event behind.
#[test]
fn a_missing_reference_names_the_profile_and_leaves_no_stray_events() {
    use courier_wire::xrce::bridge::Profiles;
    let d = courier_tests::domains::lease(24);
    let profiles = Profiles::parse(
        r#"<profiles>
          <participant profile_name="default_xrce_participant"><rtps><name>p</name></rtps></participant>
        </profiles>"#,
    )
    .unwrap();
    let rt = runtime();
    rt.block_on(async {
        let addr = SocketAddr::from(([127, 0, 0, 1], 0));
        let a = XrceAgent::builder()
            .rtps(rtps(d))
            .transport(Transport::Udp(addr))
            .profiles(profiles)
            .spawn()
            .await
            .unwrap();
        let url = format!(
            "xrce+udp://{}?domain={d}&representation=reference",
            a.udp_addrs()[0]
        );
        let s = Session::builder(url).name("r").connect().await.unwrap();
        let mut ev = s.events();
        let e = s
            .publisher::<Count>("q1")
            .deadline(Duration::from_millis(100))
            .build()
            .await
            .unwrap_err();
        assert!(e.to_string().contains("representation=reference"), "{e}");
        let e = s.publisher::<Count>("count").build().await.unwrap_err();
        assert_eq!(
            e.to_string(),
            "the XRCE agent refused the topic of count: STATUS_ERR_UNKNOWN_REFERENCE (0x84) \
             (representation=reference: the agent's -r file has no topic profile named \
             \"count_topic\", or it names something the agent refused)"
        );
        // nothing else was said meanwhile
        tokio::time::sleep(Duration::from_millis(300)).await;
        use futures::FutureExt;
        let mut stray = Vec::new();
        while let Some(Some(e)) = ev.next().now_or_never() {
            stray.push(e);
        }
        assert!(stray.is_empty(), "{stray:?}");
        s.close().await;
        a.shutdown().await;
    });
}
