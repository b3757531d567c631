//! `courier replay FILE.mcap <url>`: plays a recording back onto any
//! backend (like `ros2 bag play`), at the recorded rate or `--rate`
//! times it, once or `--loop`ing, every channel or those `--topic` names.
//!
//! Samples are re-encoded for the target: IPC bytes are decoded through
//! their channel's format and written as CDR onto DDS (laid out as the
//! derive lays out that format), and CDR back to IPC bytes the same way;
//! a channel recorded on IPC needs `--type TOPIC=TYPE` for DDS, whose
//! readers match on type names. A recording does not say whether a DDS
//! type is keyed, and DDS readers match only writers of their own kind: a
//! topic is written keyed when the readers of it that discovery finds
//! (before playing, and while `--wait`ing) all are, and says so.
//!
//! On IPC a channel's format is not defined over one central holds that
//! it does not fit (its subscribers would fail to decode) unless
//! `--redefine`. On DDS, `--type` naming another type than the recorded
//! one writes the CDR unchanged: refused when both layouts are known and
//! differ, else with a warning. Offsets count from the first message of
//! the channels replayed.
//!
//! The file is read twice, in a thread of its own: once to count what is
//! intact (and report what is damaged, with where), once to play it.
//! A damaged file replays what is intact and exits 1 at the end.

use std::cell::Cell;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use courier::format::Format;
use courier::ipc::{ByteOrder, Value};
use courier::{Durability, History, PublicationQos, Session, SessionEvent, TypeInfo, WriteOptions};
use futures::StreamExt;

use crate::bar::Bar;
use crate::cli::{kind, Kind, ProgressMode, ReplayArgs};
use crate::connect::{connect, PROGRESS_EVERY};
use crate::ping::LAST_ACK_BOUND;
use crate::reader_kind::{kind_word, Publication};
use crate::recording::{
    parse_order, ros2_dds_name, ENC_CDR, ENC_IPC, META_FORMAT, META_TYPE, SCHEMA_IPC_FORMAT,
    SCHEMA_ROS2MSG,
};
use crate::scan::{self, Chan, Event, Msg, Survey};
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{err, out, progress, type_mismatch_line, word};
use crate::values::known_type;
use crate::Result;

/// Messages read ahead of the one being played.
const READ_AHEAD: usize = 256;

pub async fn run(o: ReplayArgs, progress_mode: ProgressMode, mut stop: Stop) -> Result<Ended> {
    let path = o.file.clone();
    let survey = tokio::task::spawn_blocking(move || scan::survey(&path))
        .await
        .map_err(|e| format!("reading {}: {e}", o.file.display()))??;
    for d in &survey.damage {
        err(format_args!("courier: {}: {d}", o.file.display()));
    }
    // every channel's way onto the target, before anything connects
    let chosen = choose(&o, &survey)?;
    let plans = chosen
        .iter()
        .map(|&c| {
            plan(&o, c)
                .map(|p| (c, p))
                .map_err(|e| channel_error(c, &chosen, &e))
        })
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    if let Err(e) = central_fits(&s, &o, &plans).await {
        s.close().await;
        return Err(e);
    }
    let sent = Cell::new(0u64);
    let what = || format!("after {} replayed", count(sent.get(), "message"));
    let body = replay(&s, &o, progress_mode, &survey, plans, &sent);
    let ended = run_session(&s, &mut stop, body, what).await?;
    if !survey.damage.is_empty() {
        return Err(format!(
            "{} is damaged ({}, said above): what is intact was replayed",
            o.file.display(),
            count(survey.damage.len() as u64, "problem")
        )
        .into());
    }
    Ok(ended)
}

/// Why channel `c` cannot be replayed (`why`), and, when other channels
/// were chosen with it, that `--topic` can replay those without it: one
/// channel that cannot be replayed stops the whole replay before it
/// begins.
fn channel_error(c: &Chan, chosen: &[&Chan], why: &str) -> String {
    let mut others: Vec<&str> = chosen
        .iter()
        .filter(|o| o.topic != c.topic)
        .map(|o| o.topic.as_str())
        .collect();
    others.sort_unstable();
    others.dedup();
    let hint = if others.is_empty() {
        String::new()
    } else {
        format!(
            "; or leave it out: --topic {} replays the others only",
            others.join(" --topic ")
        )
    };
    format!("channel {:?} ({}): {why}{hint}", c.topic, c.id)
}

/// IPC: that central's format of each channel's message fits the format
/// the replay defines it with (see [`crate::central_format`]), unless
/// `--redefine`.
async fn central_fits(s: &Session, o: &ReplayArgs, plans: &[(&Chan, Plan)]) -> Result<()> {
    if kind(&o.url) != Kind::Ipc || o.redefine {
        return Ok(());
    }
    let chosen: Vec<&Chan> = plans.iter().map(|(c, _)| *c).collect();
    for (c, (_, ty, _)) in plans {
        let Some(f) = ty.format.and_then(|f| courier::format::parse(f).ok()) else {
            continue;
        };
        let ours = format!("the recorded format {f}");
        if let Err(e) = crate::central_format::check(s, &c.topic, &f, &ours).await? {
            return Err(channel_error(c, &chosen, &e).into());
        }
    }
    Ok(())
}

/// The channels to replay: all, or those `--topic` names (each must name
/// one).
fn choose<'a>(o: &ReplayArgs, survey: &'a Survey) -> Result<Vec<&'a Chan>> {
    for t in &o.topic {
        if !survey.channels.values().any(|c| &c.topic == t) {
            let mut have: Vec<&str> = survey.channels.values().map(|c| c.topic.as_str()).collect();
            have.sort_unstable();
            have.dedup();
            return Err(format!(
                "--topic {t:?}: {} has no channel of that topic (it has: {})",
                o.file.display(),
                if have.is_empty() {
                    "none".into()
                } else {
                    have.join(", ")
                }
            )
            .into());
        }
    }
    for (t, _) in &o.types {
        if !survey.channels.values().any(|c| &c.topic == t) {
            return Err(format!(
                "--type {t}=…: {} has no channel of that topic",
                o.file.display()
            )
            .into());
        }
    }
    Ok(survey
        .channels
        .values()
        .filter(|c| o.topic.is_empty() || o.topic.contains(&c.topic))
        .collect())
}

/// What a channel's samples are, as recorded.
enum Source {
    Ipc {
        format: Option<Format>,
        order: ByteOrder,
    },
    Cdr {
        format: Option<Format>,
        type_name: Option<String>,
    },
}

fn parse(text: &str) -> std::result::Result<Format, String> {
    courier::format::parse(text).map_err(|e| format!("its IPC format {text:?} does not parse: {e}"))
}

impl Source {
    fn of(c: &Chan) -> std::result::Result<Source, String> {
        let schema = c.schema.as_ref();
        match c.encoding.as_str() {
            ENC_IPC => {
                let text = c.metadata.get(META_FORMAT).cloned().or_else(|| {
                    schema
                        .filter(|s| s.encoding == SCHEMA_IPC_FORMAT)
                        .map(|s| String::from_utf8_lossy(&s.data).into_owned())
                });
                Ok(Source::Ipc {
                    format: text.as_deref().map(parse).transpose()?,
                    order: parse_order(&c.metadata)?,
                })
            }
            ENC_CDR => {
                let type_name = c.metadata.get(META_TYPE).cloned().or_else(|| {
                    schema.map(|s| {
                        if s.encoding == SCHEMA_ROS2MSG {
                            ros2_dds_name(&s.name).unwrap_or_else(|| s.name.clone())
                        } else {
                            s.name.clone()
                        }
                    })
                });
                let format = match c.metadata.get(META_FORMAT) {
                    Some(t) => Some(parse(t)?),
                    None => type_name
                        .as_deref()
                        .and_then(known_type)
                        .map(|k| k.parsed()),
                };
                Ok(Source::Cdr { format, type_name })
            }
            e => Err(format!(
                "its message encoding {e:?} is not one courier replays ({ENC_IPC}, {ENC_CDR})"
            )),
        }
    }
}

/// How a recorded sample becomes one for the target.
enum Convert {
    Pass,
    /// IPC bytes of the other byte order to ours.
    Reorder(Format, ByteOrder),
    IpcToCdr(Format, ByteOrder),
    CdrToIpc(Format),
}

impl Convert {
    fn apply(&self, data: &[u8]) -> std::result::Result<Vec<u8>, String> {
        let from_ipc = |f: &Format, o: ByteOrder| {
            Value::from_ipc_bytes(f, data, o).map_err(|e| format!("does not decode as {f}: {e}"))
        };
        match self {
            Convert::Pass => Ok(data.to_vec()),
            Convert::Reorder(f, o) => from_ipc(f, *o)?.to_ipc_bytes(f).map_err(|e| e.to_string()),
            Convert::IpcToCdr(f, o) => crate::cdr_value::encode(f, &from_ipc(f, *o)?),
            Convert::CdrToIpc(f) => crate::cdr_value::decode(f, data)
                .map_err(|e| format!("does not decode as {f}: {e}"))?
                .to_ipc_bytes(f)
                .map_err(|e| e.to_string()),
        }
    }
}

/// Leaks a string: type information lives as long as the process.
fn leak(s: String) -> &'static str {
    Box::leak(s.into_boxed_str())
}

/// How a channel goes onto the target: the conversion, the publication's
/// type, and how that is said.
type Plan = (Convert, TypeInfo, String);

/// How channel `c` goes onto the target: the conversion and the
/// publication's type, or why it cannot.
fn plan(o: &ReplayArgs, c: &Chan) -> std::result::Result<Plan, String> {
    let src = Source::of(c)?;
    let wanted = o
        .types
        .iter()
        .find(|(t, _)| t == &c.topic)
        .map(|(_, ty)| ty.clone());
    let dynamic = |f: Option<&Format>, ty: &str| {
        TypeInfo::dynamic(f.map(|f| leak(f.to_string())), leak(ty.to_string()))
    };
    match (kind(&o.url), src) {
        (Kind::Ipc, Source::Ipc { format, order }) => {
            let ty = format
                .as_ref()
                .map_or(TypeInfo::untyped(), |f| dynamic(Some(f), ""));
            let shown = format.as_ref().map_or("raw".to_string(), Format::to_string);
            let conv = match (order == ByteOrder::NATIVE, format) {
                (true, _) => Convert::Pass,
                (false, Some(f)) => Convert::Reorder(f, order),
                (false, None) => {
                    return Err("its IPC bytes are of the other byte order, and it has no \
                                format to convert them by"
                        .into())
                }
            };
            Ok((conv, ty, format!("ipc {}", word(&shown))))
        }
        (Kind::Ipc, Source::Cdr { format, type_name }) => {
            let f = format.ok_or_else(|| {
                format!(
                    "Courier does not know the layout of its DDS type {}, so it cannot write \
                     it as IPC",
                    type_name.as_deref().unwrap_or("?")
                )
            })?;
            crate::cdr_value::check(&f)?;
            let ty = dynamic(Some(&f), "");
            let shown = format!("cdr->ipc {}", word(&f.to_string()));
            Ok((Convert::CdrToIpc(f), ty, shown))
        }
        (Kind::Dds, Source::Ipc { format, order }) => {
            let ty_name = wanted.ok_or_else(|| {
                format!(
                    "it was recorded on IPC, and DDS readers match on a type name: give one \
                     with --type {}=TYPE",
                    c.topic
                )
            })?;
            let f = format.ok_or(
                "it has no IPC format (central held none when it was recorded), so its bytes \
                 cannot be written as CDR",
            )?;
            crate::cdr_value::check(&f)?;
            let ty = dynamic(Some(&f), &ty_name);
            let shown = format!("ipc->cdr {}", word(&ty_name));
            Ok((Convert::IpcToCdr(f, order), ty, shown))
        }
        (Kind::Dds, Source::Cdr { format, type_name }) => {
            let recorded = type_name.clone();
            let ty_name = wanted.or(type_name).ok_or_else(|| {
                format!(
                    "it names no DDS type: give one with --type {}=TYPE",
                    c.topic
                )
            })?;
            let mut shown = format!("cdr {}", word(&ty_name));
            if let Some(rec) = recorded.filter(|r| *r != ty_name) {
                relabel(c, &rec, format.as_ref(), &ty_name)?;
                shown.push_str(&format!(" (recorded as {})", word(&rec)));
            }
            let ty = dynamic(format.as_ref(), &ty_name);
            Ok((Convert::Pass, ty, shown))
        }
    }
}

/// `--type` naming another DDS type than the one channel `c` was recorded
/// as (`recorded`, laid out as `format` when known): its CDR is written
/// unchanged, since DDS types carry no field names to convert by. Refused
/// when both layouts are known and the recorded one does not read as the
/// other; else a warning, since readers of `wanted` decode the samples
/// only if it is laid out as `recorded` (a type renamed, say).
fn relabel(
    c: &Chan,
    recorded: &str,
    format: Option<&Format>,
    wanted: &str,
) -> std::result::Result<(), String> {
    let target = known_type(wanted).map(|k| k.parsed());
    if let (Some(f), Some(t)) = (format, &target) {
        return courier::format::fits(f, t).map_err(|m| {
            format!(
                "it was recorded as DDS type {recorded} ({f}), whose samples do not read as \
                 {wanted} ({t}) of --type {}={wanted}: {m}; replay writes a channel's CDR \
                 unchanged, it does not convert between DDS types",
                c.topic
            )
        });
    }
    let layout = format.map_or(String::new(), |f| format!(" ({f})"));
    err(format_args!(
        "courier: channel {:?}: recorded as DDS type {recorded}, written unchanged as {wanted} \
         (--type): readers of {wanted} decode its samples only if {wanted} is laid out as \
         {recorded}{layout}",
        c.topic
    ));
    Ok(())
}

/// A channel being replayed.
struct Playing {
    /// Its publication (keyed or not as the topic's readers are), with
    /// its topic.
    pb: Publication,
    conv: Convert,
    /// Its intact messages in the file, and how many of them were played
    /// in this pass (the last is written confirmed on DDS).
    total: u64,
    played: u64,
}

/// What the reading thread sends.
enum Item {
    Msg(Msg),
    /// The end of one pass over the file.
    End,
}

/// Reads the chosen channels' messages in a thread (again and again with
/// `--loop`) while the receiver wants them.
fn reader(file: PathBuf, ids: Vec<u16>, looping: bool) -> tokio::sync::mpsc::Receiver<Item> {
    let (tx, rx) = tokio::sync::mpsc::channel(READ_AHEAD);
    std::thread::spawn(move || loop {
        let mut open = true;
        // the damage was reported by the first reading
        let r = scan::walk(&file, &mut |e| match e {
            Event::Message(m) if ids.contains(&m.channel) => {
                open = tx.blocking_send(Item::Msg(m)).is_ok();
                open
            }
            _ => true,
        });
        if r.is_err() || !open || tx.blocking_send(Item::End).is_err() || !looping {
            break;
        }
    });
    rx
}

async fn replay(
    s: &Session,
    o: &ReplayArgs,
    mode: ProgressMode,
    survey: &Survey,
    plans: Vec<(&Chan, Plan)>,
    sent: &Cell<u64>,
) -> Result<()> {
    let mut qos = PublicationQos::default();
    if o.transient_local {
        qos.durability = Durability::TransientLocal;
        qos.history = History::KeepLast(o.depth);
    }
    let mut playing: HashMap<u16, Playing> = HashMap::new();
    let mut topics = BTreeMap::new();
    // listening before the publications exist: a reader of another type
    // already discovered is reported as its writer is created
    let ev = s.events();
    let r: Result<()> = async {
        for (c, (conv, ty, shown)) in plans {
            let pb = Publication::open(s, &c.topic, ty, &qos).await?;
            out(format_args!("channel {} {shown}", word(&c.topic)));
            topics.insert(c.topic.clone(), ());
            playing.insert(
                c.id,
                Playing {
                    pb,
                    conv,
                    total: survey.counts.get(&c.id).copied().unwrap_or(0),
                    played: 0,
                },
            );
        }
        out("ready");
        key_as_readers(s, &mut playing).await?;
        wait_for(s, o, topics.keys(), &mut playing, ev).await?;
        play(s, o, mode, survey, &mut playing, sent).await
    }
    .await;
    for p in playing.values() {
        p.pb.close(s);
    }
    r?;
    out(format_args!("replayed {}", count(sent.get(), "message")));
    out("done");
    Ok(())
}

/// Opens again, as their readers want, the publications whose topic's
/// readers are all of the other kind (keyed or not), and says so.
async fn key_as_readers(s: &Session, playing: &mut HashMap<u16, Playing>) -> Result<()> {
    for p in playing.values_mut() {
        if let Some(keyed) = p.pb.key_as_readers(s).await? {
            out(format_args!(
                "channel {} {}, as its readers are",
                word(&p.pb.topic),
                kind_word(keyed)
            ));
        }
    }
    Ok(())
}

/// Waits until each topic has `--wait` subscribers (a sample nobody
/// subscribes is not sent on IPC and reaches nobody on DDS), keying the
/// DDS publications as their readers are found to be.
async fn wait_for<'a>(
    s: &Session,
    o: &ReplayArgs,
    topics: impl Iterator<Item = &'a String>,
    playing: &mut HashMap<u16, Playing>,
    mut ev: courier::Events,
) -> Result<()> {
    if o.wait == 0 {
        return Ok(());
    }
    let mut have = BTreeMap::new();
    for t in topics {
        s.watch_handlers(t).await?;
        have.insert(t.clone(), s.num_handlers(t).await?.unsigned_abs());
    }
    let started = Instant::now();
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    while have.values().any(|&n| n < o.wait) {
        tokio::select! {
            Some(e) = ev.next() => match e {
                SessionEvent::HandlersChanged { msg, count } => {
                    if let Some(n) = have.get_mut(&msg) {
                        *n = count.unsigned_abs();
                    }
                }
                SessionEvent::SubscriptionFound(r) | SessionEvent::SubscriptionChanged(r)
                    if have.contains_key(&r.topic) =>
                {
                    key_as_readers(s, playing).await?;
                }
                // a reader of another type never matches: say so, as
                // `pub` does, rather than only waiting
                SessionEvent::TypeMismatch { topic, remote, local_type, remote_type }
                    if have.contains_key(&topic) =>
                {
                    out(format_args!(
                        "channel {} {}",
                        word(&topic),
                        type_mismatch_line(remote, &local_type, &remote_type)
                    ));
                }
                _ => {}
            },
            _ = tick.tick() => {
                // readers found before this wait began have no event
                key_as_readers(s, playing).await?;
                let missing: Vec<&str> = have
                    .iter()
                    .filter(|(_, &n)| n < o.wait)
                    .map(|(t, _)| t.as_str())
                    .collect();
                progress(format_args!(
                    "waiting for {} of {} for {} s (--wait 0 replays at once)",
                    count(u64::from(o.wait), "subscriber"),
                    missing.join(", "),
                    started.elapsed().as_secs()
                ));
            }
        }
    }
    Ok(())
}

/// Plays the messages at their recorded pace (times `--rate`).
async fn play(
    s: &Session,
    o: &ReplayArgs,
    mode: ProgressMode,
    survey: &Survey,
    playing: &mut HashMap<u16, Playing>,
    sent: &Cell<u64>,
) -> Result<()> {
    let dds = kind(&o.url) == Kind::Dds;
    let b = s.backend();
    let per_pass: u64 = playing.values().map(|p| p.total).sum();
    // offsets count from the first message replayed, not from the file's
    // first on any channel: a channel left out leaves no idle gap
    let (first, last) = survey.span(playing.keys()).unwrap_or((0, 0));
    let span = last.saturating_sub(first) as f64 / 1e9 / o.rate;
    let mut bar = Bar::new(mode, per_pass, "messages");
    let mut rx = reader(o.file.clone(), playing.keys().copied().collect(), o.r#loop);
    let mut start = tokio::time::Instant::now();
    let mut in_pass = 0u64;
    let mut bad = 0u64;
    while let Some(item) = rx.recv().await {
        let m = match item {
            Item::Msg(m) => m,
            Item::End => {
                bar.finish(in_pass, span);
                start = tokio::time::Instant::now();
                in_pass = 0;
                for p in playing.values_mut() {
                    p.played = 0;
                }
                continue;
            }
        };
        let Some(p) = playing.get_mut(&m.channel) else {
            continue;
        };
        // (a file's times can be anything: at most 31 years, which the
        // clock holds)
        let offset = (m.log_time.saturating_sub(first) as f64 / 1e9 / o.rate).min(1e9);
        tokio::time::sleep_until(start + Duration::from_secs_f64(offset)).await;
        p.played += 1;
        in_pass += 1;
        let data = match p.conv.apply(&m.data) {
            Ok(d) => d,
            Err(e) => {
                bad += 1;
                err(format_args!(
                    "courier: a message of {:?} (log time {}) {e}: skipped",
                    p.pb.topic, m.log_time
                ));
                continue;
            }
        };
        let mut opts = WriteOptions::default();
        let confirm = dds && p.played == p.total;
        if confirm {
            // the last of its channel: wait for every reader to have it
            opts.confirm = Some(LAST_ACK_BOUND);
        }
        match b.write(p.pb.id, data, opts).await {
            Err(courier::PublishError::Timeout { after, .. }) if confirm => err(format_args!(
                "courier: the last sample of {:?} was not acknowledged by every reader within \
                 {after:?}",
                p.pb.topic
            )),
            r => r?,
        }
        sent.set(sent.get() + 1);
        bar.update(in_pass, offset);
    }
    if bad > 0 {
        return Err(format!("{} did not decode (said above)", count(bad, "message")).into());
    }
    Ok(())
}
