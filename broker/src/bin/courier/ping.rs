//! `courier ping --publish | --subscribe`: like ORTE's `orteping`.

use std::cell::Cell;
use std::collections::HashSet;
use std::time::{Duration, SystemTime};

use courier::{RecvError, Session, SessionEvent};
use futures::{FutureExt, StreamExt};

use crate::cli::{kind, Kind, PingArgs};
use crate::connect::connect;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{err, incompatible_line, out, type_mismatch_line};
use crate::values::Ping;
use crate::Result;

pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

pub async fn run(o: PingArgs, mut stop: Stop) -> Result<Ended> {
    if o.rtt {
        return crate::pong::rtt(o, stop).await;
    }
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let mut ev = s.events();
    let n = Cell::new(0u64);
    if o.publish {
        let what = || format!("after {} sent", count(n.get(), "sample"));
        run_session(&s, &mut stop, publish(&s, &o, &mut ev, &n), what).await
    } else {
        let what = || format!("after {} received", count(n.get(), "sample"));
        run_session(&s, &mut stop, subscribe(&s, &o, &mut ev, &n), what).await
    }
}

/// How long the last of `--count` samples may wait for every matched
/// reliable reader to acknowledge it.
pub const LAST_ACK_BOUND: Duration = Duration::from_secs(5);

/// Publishes `v`. When `last` (the last write of a reliable DDS
/// publication), it waits up to [`LAST_ACK_BOUND`] for every matched reader
/// to acknowledge it: leaving right after the write could cost a reader the
/// tail. A timeout is said on stderr (`what` names the sample), not failed.
pub async fn publish_acked<T: courier::IpcMessage>(
    p: &courier::Publisher<T>,
    v: &T,
    last: bool,
    what: impl std::fmt::Display,
) -> Result<()> {
    if !last {
        p.publish(v).await?;
        return Ok(());
    }
    match p.publish(v).confirmed_within(LAST_ACK_BOUND).await {
        Err(courier::PublishError::Timeout { after, .. }) => {
            err(format_args!(
                "courier: {what} not acknowledged by every reader within {after:?}"
            ));
            Ok(())
        }
        r => Ok(r?),
    }
}

/// How long `ping --subscribe` lets discovery settle before it counts the
/// publications it matches.
const SETTLE: Duration = Duration::from_millis(50);

/// Prints `matched <n>` when `n` differs from what was printed last.
pub struct Matched(pub Option<usize>);

impl Matched {
    pub fn set(&mut self, n: usize) {
        if self.0 != Some(n) {
            self.0 = Some(n);
            out(format_args!("matched {n}"));
        }
    }
}

async fn publish(
    s: &Session,
    o: &PingArgs,
    ev: &mut courier::Events,
    sent: &Cell<u64>,
) -> Result<()> {
    let mut b = s.publisher::<Ping>(&o.topic);
    if o.qos.best_effort {
        b = b.best_effort();
    }
    if let Some(n) = o.qos.strength {
        b = b.strength(n);
    }
    if let Some(d) = o.qos.deadline {
        b = b.deadline(Duration::from_millis(d));
    }
    if let Some(l) = o.qos.liveliness() {
        b = b.liveliness(l.kind, l.lease);
    }
    let p = b.build().await?;
    // an XRCE agent tells its clients nothing of the readers matched
    let xrce = s.xrce().is_ok();
    if !xrce {
        s.watch_handlers(&o.topic).await?;
    }
    out("ready");
    // readers already matched when the publication was created (DDS: the
    // readers matched with our writer; IPC: the modules subscribing)
    let mut matched = Matched(None);
    let n = if xrce {
        0
    } else {
        s.num_handlers(&o.topic).await?
    };
    if n > 0 {
        matched.set(n.unsigned_abs() as usize);
    }
    let mut tick = tokio::time::interval(Duration::from_millis(o.period.unwrap_or(1000)));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut seq = 0u32;
    loop {
        tokio::select! {
            _ = tick.tick() => {
                seq = seq.wrapping_add(1);
                let v = Ping { seq, stamp_ns: now_ns(), text: "x".repeat(o.size as usize) };
                let last = o.count.is_some_and(|n| u64::from(seq) >= n);
                let acked = last && kind(&o.url) == Kind::Dds && !o.qos.best_effort;
                publish_acked(&p, &v, acked, format!("sample {seq}")).await?;
                sent.set(sent.get() + 1);
                out(format_args!("sent {seq}"));
                if last {
                    break;
                }
            }
            Some(e) = ev.next() => match e {
                SessionEvent::HandlersChanged { msg, count } if msg == o.topic => {
                    matched.set(count.unsigned_abs() as usize)
                }
                SessionEvent::IncompatibleQos { msg, remote, reason } if msg == o.topic => {
                    out(incompatible_line(remote, &reason))
                }
                SessionEvent::TypeMismatch { topic, remote, local_type, remote_type } if topic == o.topic => {
                    out(type_mismatch_line(remote, &local_type, &remote_type))
                }
                SessionEvent::OfferedDeadlineMissed { msg, total } if msg == o.topic => {
                    out(format_args!("offered deadline missed {total}"))
                }
                SessionEvent::LivelinessLost { msg, total } if msg == o.topic => {
                    out(format_args!("liveliness lost {total}"))
                }
                _ => {}
            },
        }
    }
    out("done");
    Ok(())
}

async fn subscribe(
    s: &Session,
    o: &PingArgs,
    ev: &mut courier::Events,
    received: &Cell<u64>,
) -> Result<()> {
    let mut b = s.subscriber::<Ping>(&o.topic);
    if o.qos.best_effort {
        b = b.best_effort();
    }
    if let Some(d) = o.qos.deadline {
        b = b.deadline(Duration::from_millis(d));
    }
    if let Some(l) = o.qos.liveliness() {
        b = b.liveliness(l.kind, l.lease);
    }
    if let Some(d) = o.qos.min_separation {
        b = b.minimum_separation(Duration::from_millis(d));
    }
    if o.qos.exclusive || o.qos.strength.is_some() {
        b = b.exclusive();
    }
    let mut sub = b.build().await?;
    out("ready");
    let dds = kind(&o.url) == Kind::Dds;
    // DDS: publications of our topic and type, less those whose QoS does not
    // match ours (the SDK reports no reader matches, only mismatches)
    let mut found = HashSet::new();
    let mut refused = HashSet::new();
    let mut matched = Matched(None);
    let mut recount: Option<tokio::time::Instant> = None;
    loop {
        tokio::select! {
            r = sub.next() => match r {
                None | Some(Err(RecvError::Disconnected)) => return Err("the session ended".into()),
                Some(Ok(smp)) => {
                    // a sample shows its publication matched: take the
                    // discovery events already in and count before printing
                    // it, so that `matched` comes first
                    while let Some(Some(e)) = ev.next().now_or_never() {
                        if pub_event(e, o, &mut found, &mut refused) && dds {
                            recount.get_or_insert_with(|| tokio::time::Instant::now() + SETTLE);
                        }
                    }
                    if recount.take().is_some() {
                        matched.set(found.difference(&refused).count());
                    }
                    received.set(received.get() + 1);
                    out(format_args!(
                        "received {} from {} {} B",
                        smp.value.seq,
                        smp.source.map_or("?".into(), |g| g.to_string()),
                        smp.value.text.len()
                    ));
                    if o.count.is_some_and(|c| received.get() >= c) {
                        break;
                    }
                }
                Some(Err(e)) => out(format_args!("skipped {e}")),
            },
            Some(e) = ev.next() => {
                if pub_event(e, o, &mut found, &mut refused) && dds {
                    // a publication's mismatch comes right after its
                    // discovery: count once both are in, not to print a
                    // match that is none
                    recount.get_or_insert_with(|| tokio::time::Instant::now() + SETTLE);
                }
            }
            _ = async { tokio::time::sleep_until(recount.unwrap()).await }, if recount.is_some() => {
                recount = None;
                matched.set(found.difference(&refused).count());
            }
        }
    }
    out("done");
    Ok(())
}

/// A session event for `ping --subscribe`: prints deadline misses and QoS
/// mismatches, follows the publications of the topic; whether the number of
/// matched publications may have changed.
fn pub_event(
    e: SessionEvent,
    o: &PingArgs,
    found: &mut HashSet<courier::Guid>,
    refused: &mut HashSet<courier::Guid>,
) -> bool {
    match e {
        SessionEvent::DeadlineMissed { msg, total } if msg == o.topic => {
            out(format_args!("deadline missed {total}"));
            false
        }
        SessionEvent::LivelinessChanged {
            msg,
            writer,
            alive,
            alive_count,
            not_alive_count,
        } if msg == o.topic => {
            let now = if alive { "alive" } else { "not-alive" };
            out(format_args!(
                "liveliness {writer} {now} alive={alive_count} not-alive={not_alive_count}"
            ));
            false
        }
        SessionEvent::IncompatibleQos {
            msg,
            remote,
            reason,
        } if msg == o.topic => {
            refused.insert(remote);
            out(incompatible_line(remote, &reason));
            true
        }
        SessionEvent::TypeMismatch {
            topic,
            remote,
            local_type,
            remote_type,
        } if topic == o.topic => {
            refused.insert(remote);
            out(type_mismatch_line(remote, &local_type, &remote_type));
            true
        }
        SessionEvent::PublicationFound(e) | SessionEvent::PublicationChanged(e)
            if e.topic == o.topic && e.type_name == <Ping as courier::IpcMessage>::TYPE_NAME =>
        {
            // a change is matched anew: a mismatch is reported again
            refused.remove(&e.guid);
            found.insert(e.guid);
            true
        }
        SessionEvent::PublicationLost(g) => found.remove(&g) | refused.remove(&g),
        _ => false,
    }
}
