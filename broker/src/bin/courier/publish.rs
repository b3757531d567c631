//! `courier pub <url> <topic> <value>`: publishes a value given as JSON
//! (or plain text for a `string`), typed by an IPC format (like `ros2
//! topic pub`, `z_pub`).
//!
//! The type: on IPC `--format`, else the format central holds for the
//! message; on DDS (RTPS and XRCE alike) `--type` with `--format` (any
//! type, laid out as the derive lays out that format), or a type Courier
//! knows (`--type`, default `courier::Ping`, documented in `pub --help`).
//!
//! A VALUE that does not fit the type is a usage error (exit 2): checked
//! before connecting when the command line gives the type, else once
//! central has said the message's format ([`crate::cli::LateUsage`]). So is
//! a `--format` that central's format of the message does not fit (see
//! [`crate::central_format`]; `--redefine` replaces central's).

use std::cell::Cell;
use std::time::{Duration, Instant};

use courier::format::Format;
use courier::ipc::Value;
use courier::{Incompatible, PublicationQos, Session, SessionEvent, TypeInfo, WriteOptions};
use futures::StreamExt;

use crate::cli::{kind, Kind, LateUsage, PubArgs};
use crate::connect::{connect, target, PROGRESS_EVERY};
use crate::dds_type::{default_type_note, DEFAULT_TYPE};
use crate::ping::{Matched, LAST_ACK_BOUND};
use crate::reader_kind::{kind_word, Publication};
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{err, incompatible_line, out, progress, type_mismatch_line};
use crate::values::{known_names, known_type, parse_value, Known};
use crate::wait::Discovery;
use crate::Result;

pub async fn run(o: PubArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let sent = Cell::new(0u64);
    let waiting = Cell::new(true);
    let what = || {
        if waiting.get() {
            format!("while waiting for subscribers of {:?}", o.topic)
        } else {
            format!("after {} sent", count(sent.get(), "sample"))
        }
    };
    run_session(&s, &mut stop, publish(&s, &o, &sent, &waiting), what).await
}

/// What a sample's bytes are made from.
pub enum Encoder {
    /// IPC marshalling through the format.
    Ipc(Format),
    /// A DDS type Courier knows.
    Known(&'static Known),
    /// CDR laid out as the derive lays out this format.
    Cdr(Format),
}

impl Encoder {
    fn format(&self) -> Format {
        match self {
            Encoder::Ipc(f) | Encoder::Cdr(f) => f.clone(),
            Encoder::Known(k) => k.parsed(),
        }
    }

    fn encode(&self, v: &Value) -> Result<Vec<u8>> {
        Ok(match self {
            Encoder::Ipc(f) => v.to_ipc_bytes(f)?,
            Encoder::Known(k) => k.encode(v)?,
            Encoder::Cdr(f) => crate::cdr_value::encode(f, v)?,
        })
    }
}

/// Leaks a string: type information lives as long as the process.
fn leak(s: String) -> &'static str {
    Box::leak(s.into_boxed_str())
}

/// The type of the topic and the publication's type information when the
/// command line alone gives them: all but IPC without `--format`, whose
/// format central holds. `Err`: `--type` names no type Courier knows (and
/// no `--format` lays it out).
pub fn encoder_offline(o: &PubArgs) -> Option<std::result::Result<(Encoder, TypeInfo), String>> {
    match kind(&o.url) {
        Kind::Ipc => o.format.as_ref().map(|f| {
            let ty = TypeInfo::dynamic(Some(leak(f.to_string())), "");
            Ok((Encoder::Ipc(f.clone()), ty))
        }),
        Kind::Dds => {
            if let (Some(f), Some(name)) = (&o.format, &o.type_name) {
                let ty = TypeInfo::dynamic(Some(leak(f.to_string())), leak(name.clone()));
                return Some(Ok((Encoder::Cdr(f.clone()), ty)));
            }
            let name = o.type_name.as_deref().unwrap_or(DEFAULT_TYPE);
            Some(match known_type(name) {
                Some(k) => Ok((
                    Encoder::Known(k),
                    TypeInfo::dynamic(Some(k.format), k.type_name),
                )),
                None => Err(format!(
                    "type {name:?} is not one Courier knows ({}): give its layout with --format",
                    known_names()
                )),
            })
        }
    }
}

/// The sample's bytes: VALUE read as the type and encoded, or why it does
/// not fit (a usage error). Without `--type` on DDS the type is the
/// default, and the error says so.
pub fn sample(enc: &Encoder, o: &PubArgs) -> std::result::Result<Vec<u8>, String> {
    let note = match kind(&o.url) {
        Kind::Dds => default_type_note(o.type_name.as_deref()),
        Kind::Ipc => "",
    };
    parse_value(&enc.format(), &o.value)
        .map_err(|e| e.to_string())
        .and_then(|v| enc.encode(&v).map_err(|e| e.to_string()))
        .map_err(|e| format!("{e}{note}"))
}

/// The type of the topic, and the publication's type information.
async fn encoder(s: &Session, o: &PubArgs) -> Result<(Encoder, TypeInfo)> {
    if let Some(r) = encoder_offline(o) {
        return Ok(r?);
    }
    // IPC without --format: the one central holds
    let info = s.ipc()?.look_up(&o.topic).await?.ok_or_else(|| {
        format!(
            "central knows no message {:?}: give its format with --format",
            o.topic
        )
    })?;
    let f = info.res_format.ok_or_else(|| {
        format!(
            "message {:?} has no format in central (raw bytes); give one with --format",
            o.topic
        )
    })?;
    Ok((Encoder::Ipc(f), TypeInfo::untyped()))
}

async fn publish(s: &Session, o: &PubArgs, sent: &Cell<u64>, waiting: &Cell<bool>) -> Result<()> {
    let (enc, ty) = encoder(s, o).await?;
    redefines(s, o).await?;
    // checked before connecting unless the format came from central
    let data = sample(&enc, o).map_err(|msg| LateUsage { sub: "pub", msg })?;
    // listening before the publication exists: a reader of another type
    // already discovered is reported as the writer is created
    let ev = s.events();
    let mut pb = Publication::open(s, &o.topic, ty, &PublicationQos::default()).await?;
    let r = publish_on(s, o, &mut pb, &data, sent, waiting, ev).await;
    pb.close(s);
    r
}

/// IPC: refuses to define the message with a `--format` that central's
/// format of it does not fit (its subscribers would fail to decode), unless
/// `--redefine`: a usage error, as a VALUE that does not fit central's
/// format is.
async fn redefines(s: &Session, o: &PubArgs) -> Result<()> {
    let (Kind::Ipc, Some(f), false) = (kind(&o.url), &o.format, o.redefine) else {
        return Ok(());
    };
    crate::central_format::check(s, &o.topic, f, &format!("--format {f}"))
        .await?
        .map_err(|msg| LateUsage { sub: "pub", msg }.into())
}

/// Opens `pb` again if the topic's readers all want the other kind
/// (keyed or not: DDS matches only writers of their kind), and says so.
async fn key_as_readers(s: &Session, o: &PubArgs, pb: &mut Publication) -> Result<()> {
    if let Some(keyed) = pb.key_as_readers(s).await? {
        out(format_args!(
            "{}, as the readers of {:?} are",
            kind_word(keyed),
            o.topic
        ));
    }
    Ok(())
}

/// A topic-kind incompatibility with a reader of the kind `pb` has now:
/// it concerned the writer that `pb` replaced to match that reader (see
/// [`key_as_readers`]), not the user's (its event can come after the
/// replacement, even once samples go out).
fn replaced_kind(pb: &Publication, remote: &courier::Guid, reason: &Incompatible) -> bool {
    matches!(reason, Incompatible::TopicKind { .. }) && remote.is_keyed() == pb.ty.keyed
}

async fn publish_on(
    s: &Session,
    o: &PubArgs,
    pb: &mut Publication,
    data: &[u8],
    sent: &Cell<u64>,
    waiting: &Cell<bool>,
    mut ev: courier::Events,
) -> Result<()> {
    // an XRCE agent tells its clients nothing of the readers matched: the
    // wait cannot be, and the samples go out at once (as ping's do)
    let xrce = s.xrce().is_ok();
    if xrce && o.wait > 0 {
        err(format_args!(
            "courier: an XRCE agent does not say who reads {:?}: publishing without waiting \
             for --wait {}",
            o.topic, o.wait
        ));
    }
    if !xrce {
        s.watch_handlers(&o.topic).await?;
    }
    out("ready");
    let mut matched = Matched(None);
    key_as_readers(s, o, pb).await?;
    let wait = if xrce { 0 } else { o.wait };
    let mut n = if xrce {
        0
    } else {
        s.num_handlers(&o.topic).await?.unsigned_abs()
    };
    if n > 0 {
        matched.set(n as usize);
    }
    // wait for the subscribers asked for: a sample nobody subscribes is
    // not sent (IPC) or reaches nobody (DDS)
    let started = Instant::now();
    let mut found = Discovery::default();
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    while n < wait {
        tokio::select! {
            Some(e) = ev.next() => {
                found.update(&e);
                match e {
                    SessionEvent::HandlersChanged { msg, count } if msg == o.topic => {
                        n = count.unsigned_abs();
                        matched.set(n as usize);
                    }
                    SessionEvent::IncompatibleQos { msg, remote, reason } if msg == o.topic => {
                        key_as_readers(s, o, pb).await?;
                        if !replaced_kind(pb, &remote, &reason) {
                            out(incompatible_line(remote, &reason))
                        }
                    }
                    SessionEvent::TypeMismatch { topic, remote, local_type, remote_type } if topic == o.topic => {
                        out(type_mismatch_line(remote, &local_type, &remote_type))
                    }
                    SessionEvent::SubscriptionFound(r) | SessionEvent::SubscriptionChanged(r)
                        if r.topic == o.topic =>
                    {
                        key_as_readers(s, o, pb).await?
                    }
                    _ => {}
                }
            }
            _ = tick.tick() => {
                // readers found before the events began have no event
                key_as_readers(s, o, pb).await?;
                let secs = started.elapsed().as_secs();
                let seen = match kind(&o.url) {
                    Kind::Dds => format!(": {}", found.summary(&o.topic, false)),
                    Kind::Ipc => format!(" at {}", target(&o.url)),
                };
                progress(format_args!(
                    "waiting for {} of {:?} for {secs} s (--wait 0 publishes at once){seen}",
                    count(u64::from(o.wait), "subscriber"),
                    o.topic,
                ));
            }
        }
    }
    waiting.set(false);
    let period = Duration::from_secs_f64(1.0 / o.rate);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let b = s.backend();
    loop {
        tokio::select! {
            _ = tick.tick() => {
                let last = o.count != 0 && sent.get() + 1 >= o.count;
                let mut opts = WriteOptions::default();
                let confirm = last && kind(&o.url) == Kind::Dds;
                if confirm {
                    // exiting right after the write could leave a reader
                    // without the last sample: wait for its acknowledgement
                    opts.confirm = Some(LAST_ACK_BOUND);
                }
                match b.write(pb.id, data.to_vec(), opts).await {
                    // (on XRCE the agent acknowledges, not the readers)
                    Err(courier::PublishError::Timeout { after, .. }) if confirm => err(format_args!(
                        "courier: the last sample was not acknowledged by {} within {after:?}",
                        if crate::cli::is_xrce(&o.url) { "the XRCE agent" } else { "every reader" }
                    )),
                    r => r?,
                }
                sent.set(sent.get() + 1);
                out(format_args!("sent {}", sent.get()));
                if last {
                    break;
                }
            }
            Some(e) = ev.next() => match e {
                SessionEvent::HandlersChanged { msg, count } if msg == o.topic => {
                    matched.set(count.unsigned_abs() as usize)
                }
                SessionEvent::IncompatibleQos { msg, remote, reason } if msg == o.topic
                    && !replaced_kind(pb, &remote, &reason) =>
                {
                    out(incompatible_line(remote, &reason))
                }
                SessionEvent::TypeMismatch { topic, remote, local_type, remote_type } if topic == o.topic => {
                    out(type_mismatch_line(remote, &local_type, &remote_type))
                }
                _ => {}
            },
        }
    }
    out("done");
    Ok(())
}
