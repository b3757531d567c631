//! `courier spy`: like ORTE's `ortespy`, every discovered participant and
//! endpoint, and every sample of the matching topics.

use std::cell::Cell;
use std::time::{Duration, Instant};

use courier::{Session, SessionEvent};
use futures::StreamExt;

use crate::cli::{kind, Kind, SpyArgs};
use crate::connect::connect;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{endpoint_line, incompatible_line, out, participant_line, prefix_hex};
use crate::values::sample_text;
use crate::Result;

pub async fn run(o: SpyArgs, mut stop: Stop) -> Result<Ended> {
    // IPC refuses pattern subscriptions: say so without connecting
    // (central need not even run)
    if kind(&o.url) == Kind::Ipc {
        return Err(format!(
            "spy needs pattern subscriptions, which need a DDS session (rtps://...); {} is IPC",
            o.url
        )
        .into());
    }
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let n = Cell::new(0u64);
    let what = || format!("after {}", count(n.get(), "sample"));
    run_session(&s, &mut stop, spy(&s, &o, &n), what).await
}

async fn spy(s: &Session, o: &SpyArgs, n: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    let topic = o.topic.first().map_or("*", String::as_str);
    let mut samples = s
        .subscribe_pattern(topic, &o.type_name)
        .await
        .map_err(|e| format!("spy needs pattern subscriptions: {e}"))?;
    out("ready");
    let until = o.duration.map(|d| Instant::now() + Duration::from_secs(d));
    loop {
        let sleep = async {
            match until {
                Some(t) => tokio::time::sleep_until(t.into()).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = sleep => break,
            smp = samples.recv() => {
                let Some(smp) = smp else { break }; // the session ended
                let ty = smp.type_name.as_deref().unwrap_or("?");
                let state = match smp.state {
                    courier::InstanceState::Alive => "",
                    courier::InstanceState::Disposed => " (disposed)",
                    courier::InstanceState::Unregistered => " (unregistered)",
                };
                out(format_args!(
                    "sample {} {ty} from {} {} B{state}: {}",
                    smp.msg,
                    smp.source.as_deref().unwrap_or("?"),
                    smp.data.len(),
                    sample_text(ty, &smp.data)
                ));
                n.set(n.get() + 1);
                if o.count.is_some_and(|c| n.get() >= c) {
                    break;
                }
            }
            Some(e) = ev.next() => discovery_line(e),
        }
    }
    Ok(())
}

/// Prints a discovery event (shared with `list --watch`).
pub fn discovery_line(e: SessionEvent) {
    match e {
        SessionEvent::ParticipantFound(p) => out(participant_line("found", &p)),
        SessionEvent::ParticipantChanged(p) => out(participant_line("changed", &p)),
        SessionEvent::ParticipantLost { guid, disposed } => out(format_args!(
            "participant lost {} {}",
            prefix_hex(guid),
            if disposed { "goodbye" } else { "lease-expired" }
        )),
        SessionEvent::PublicationFound(e) => out(endpoint_line("publication", "found", &e)),
        SessionEvent::PublicationChanged(e) => out(endpoint_line("publication", "changed", &e)),
        SessionEvent::PublicationLost(g) => out(format_args!("publication lost {g}")),
        SessionEvent::SubscriptionFound(e) => out(endpoint_line("subscription", "found", &e)),
        SessionEvent::SubscriptionChanged(e) => out(endpoint_line("subscription", "changed", &e)),
        SessionEvent::SubscriptionLost(g) => out(format_args!("subscription lost {g}")),
        SessionEvent::IncompatibleQos { remote, reason, .. } => {
            out(incompatible_line(remote, &reason))
        }
        _ => {}
    }
}
