//! `courier spy`: like ORTE's `ortespy`, every discovered participant and
//! endpoint, and every sample of the matching topics (DDS); on IPC every
//! message named, decoded, and modules coming and going.

use std::cell::Cell;
use std::collections::HashMap;
use std::time::{Duration, Instant};

use courier::{Session, SessionEvent};
use futures::StreamExt;

use crate::cli::{is_xrce, kind, Kind, SpyArgs};
use crate::connect::connect;
use crate::dds_type::DdsType;
use crate::echo::SampleDecoder;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{
    encapsulation_text, endpoint_line, hex, incompatible_line, out, participant_line, prefix_hex,
    word,
};
use crate::values::{sample_text, Decoded, Style};
use crate::Result;

pub async fn run(o: SpyArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let n = Cell::new(0u64);
    let what = || format!("after {}", count(n.get(), "sample"));
    match kind(&o.url) {
        Kind::Dds if is_xrce(&o.url) => {
            run_session(&s, &mut stop, spy_named(&s, &o, &n), what).await
        }
        Kind::Dds => run_session(&s, &mut stop, spy(&s, &o, &n), what).await,
        Kind::Ipc => run_session(&s, &mut stop, spy_named(&s, &o, &n), what).await,
    }
}

/// On IPC: the messages named, each decoded through the format central
/// holds for it, and modules connecting and disconnecting. (A module sees
/// only what it subscribes, and a pattern would miss the messages defined
/// after it was matched.) On XRCE: the topics named, as the type named
/// (the client learns nothing of DDS discovery).
async fn spy_named(s: &Session, o: &SpyArgs, n: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    let mut subs = Vec::new();
    let mut decoders = HashMap::new();
    // XRCE: the agent creates typed readers (cli.rs checked --type names one)
    let typed = if is_xrce(&o.url) {
        Some(DdsType::new(None, Some(&o.type_name))?)
    } else {
        None
    };
    for t in &o.topic {
        let sub = match &typed {
            Some(ty) => s.subscribe_raw_as(t, &ty.type_info()).await?,
            None => s.subscribe_raw(t).await?,
        };
        subs.push(Box::pin(futures::stream::unfold(
            sub,
            |mut sub| async move { sub.recv().await.map(|smp| (smp, sub)) },
        )));
        decoders.insert(t.clone(), SampleDecoder::new(&o.url, t, None));
    }
    let mut samples = futures::stream::select_all(subs);
    out("ready");
    let until = o
        .duration
        .map(|d| courier_wire::time::later(Instant::now(), Duration::from_secs(d)));
    loop {
        let sleep = async {
            match until {
                Some(t) => tokio::time::sleep_until(t.into()).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = sleep => break,
            smp = samples.next() => {
                let Some(smp) = smp else { break }; // the session ended
                let Some(dec) = decoders.get_mut(&smp.msg) else { continue };
                let decoded = match &typed {
                    Some(t) => t.decode(&smp.data),
                    None => dec.decode(s, &smp).await,
                };
                let (ty, value) = match decoded {
                    Ok(d) if typed.is_some() => (o.type_name.clone(), d.print(Style::Text)),
                    Ok(Decoded::Value(f, v)) => (word(&f.to_string()), Decoded::Value(f, v).print(Style::Text)),
                    Ok(d) => ("?".to_string(), d.print(Style::Text)),
                    Err(e) => ("?".to_string(), format!("{} ({e})", hex(&smp.data))),
                };
                out(format_args!("sample {} {ty} from ? {} B: {value}", smp.msg, smp.data.len()));
                n.set(n.get() + 1);
                if o.count.is_some_and(|c| n.get() >= c) {
                    break;
                }
            }
            Some(e) = ev.next() => match e {
                SessionEvent::ModuleConnected(m) => out(format_args!("module {} connected", word(&m))),
                SessionEvent::ModuleDisconnected(m) => {
                    out(format_args!("module {} disconnected", word(&m)))
                }
                _ => {}
            },
        }
    }
    Ok(())
}

async fn spy(s: &Session, o: &SpyArgs, n: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    let topic = o.topic.first().map_or("*", String::as_str);
    let mut samples = s
        .subscribe_pattern(topic, &o.type_name)
        .await
        .map_err(|e| format!("spy needs pattern subscriptions: {e}"))?;
    out("ready");
    let until = o
        .duration
        .map(|d| courier_wire::time::later(Instant::now(), Duration::from_secs(d)));
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
                    "sample {} {ty} from {} {} B {}{state}: {}",
                    smp.msg,
                    smp.source.map_or("?".into(), |g| g.to_string()),
                    smp.data.len(),
                    encapsulation_text(&smp.data),
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
