//! `courier list`: what is there (like `ros2 topic list -v`, `cyclonedds
//! ls`).
//!
//! On DDS, the participants and their publications and subscriptions that
//! discovery finds, with types and QoS: once (what came within
//! `--duration`), or every change as it comes (`--watch`).
//!
//! On IPC, what a module can ask central: whether modules are connected
//! (`--module`), a message's format and handlers (`--message`), and,
//! with `--watch`, modules connecting and disconnecting. Central (the C
//! one, and Courier's so far) has no request that lists its modules or
//! messages: that needs an introspection interface in Courier's central.

use std::cell::Cell;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use courier::{EndpointInfo, Guid, ParticipantInfo, Session, SessionEvent};
use futures::StreamExt;

use crate::cli::{kind, Kind, ListArgs};
use crate::connect::{connect, target};
use crate::spy::discovery_line;
use crate::stop::{run_session, Ended, Stop};
use crate::text::{endpoint_text, err, out, participant_text, word};
use crate::Result;

pub async fn run(o: ListArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let started = Instant::now();
    let seen = Cell::new(0u64);
    let what = || {
        if o.watch {
            format!("after watching {} s", started.elapsed().as_secs())
        } else {
            "while listening for discovery".to_string()
        }
    };
    let body = async {
        match kind(&o.url) {
            Kind::Dds => dds(&s, &o, &seen).await,
            Kind::Ipc => ipc(&s, &o).await,
        }
    };
    run_session(&s, &mut stop, body, what).await
}

/// Sleeps until `until`, for ever without one.
async fn sleep_until(until: Option<Instant>) {
    match until {
        Some(t) => tokio::time::sleep_until(t.into()).await,
        None => std::future::pending().await,
    }
}

async fn dds(s: &Session, o: &ListArgs, seen: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    let secs = o.duration.unwrap_or(if o.watch { 0 } else { 2 });
    let until = (secs > 0).then(|| Instant::now() + Duration::from_secs(secs));
    if o.watch {
        out("ready");
        loop {
            tokio::select! {
                _ = sleep_until(until) => return Ok(()),
                e = ev.next() => match e {
                    Some(e) => {
                        seen.set(seen.get() + 1);
                        discovery_line(e);
                    }
                    None => return Err("the session ended".into()),
                }
            }
        }
    }
    let mut parts: BTreeMap<[u8; 12], ParticipantInfo> = BTreeMap::new();
    let mut eps: BTreeMap<Guid, (&'static str, EndpointInfo)> = BTreeMap::new();
    loop {
        tokio::select! {
            _ = sleep_until(until) => break,
            e = ev.next() => match e {
                Some(SessionEvent::ParticipantFound(p) | SessionEvent::ParticipantChanged(p)) => {
                    parts.insert(p.guid.prefix(), *p);
                }
                Some(SessionEvent::ParticipantLost { guid, .. }) => {
                    parts.remove(&guid.prefix());
                    eps.retain(|g, _| !g.is_of(guid.prefix()));
                }
                Some(SessionEvent::PublicationFound(e) | SessionEvent::PublicationChanged(e)) => {
                    eps.insert(e.guid, ("publication", *e));
                }
                Some(SessionEvent::SubscriptionFound(e) | SessionEvent::SubscriptionChanged(e)) => {
                    eps.insert(e.guid, ("subscription", *e));
                }
                Some(SessionEvent::PublicationLost(g) | SessionEvent::SubscriptionLost(g)) => {
                    eps.remove(&g);
                }
                Some(_) => {}
                None => return Err("the session ended".into()),
            }
        }
    }
    // participants by name, each with its endpoints by topic; endpoints
    // of a participant found before this session listened (its
    // announcement came while connecting) under its GUID prefix
    let mut prefixes: Vec<[u8; 12]> = parts.keys().copied().collect();
    for e in eps.values() {
        let p = e.1.guid.prefix();
        if !prefixes.contains(&p) {
            prefixes.push(p);
        }
    }
    if prefixes.is_empty() {
        // stderr: stdout stays the (empty) list, for scripts
        err(format_args!(
            "courier: no participant found in {secs} s on {} (another domain, peers=, or --duration longer?)",
            target(&o.url)
        ));
        return Ok(());
    }
    prefixes.sort_by_key(|p| (parts.get(p).map(|i| i.name.clone()), *p));
    for prefix in prefixes {
        match parts.get(&prefix) {
            Some(p) => out(format_args!("participant {}", participant_text(p))),
            None => out(format_args!(
                "participant {} name=? (announced before this listing began)",
                prefix
                    .iter()
                    .map(|b| format!("{b:02x}"))
                    .collect::<String>()
            )),
        }
        let mut mine: Vec<&(&str, EndpointInfo)> =
            eps.values().filter(|(_, e)| e.guid.is_of(prefix)).collect();
        mine.sort_by(|a, b| (&a.1.topic, a.0).cmp(&(&b.1.topic, b.0)));
        for (k, e) in mine {
            out(format_args!("  {k} {}", endpoint_text(e)));
        }
    }
    Ok(())
}

/// `list ipc://` without --module / --message: every module and every
/// message with what central holds of it (formats, class, handlers, the
/// first handler's module) from Courier's central, or on stderr that there
/// is none (as on an empty DDS domain); from the C central,
/// which has no module list, the message names and then each message as
/// `--message` looks it up. (C's `x_ipc_getMessageInfo` dereferences
/// what a message subscribed but never defined lacks, and crashes that
/// central: it is only asked of Courier's.) Returns the messages left to
/// look up one by one.
async fn everything(ipc: &courier::Ipc<'_>, o: &ListArgs) -> Result<Vec<String>> {
    let mut modules_found = 0;
    let courier_central = match ipc.modules().await {
        Ok(modules) => {
            let me = crate::connect::module_name(&o.name);
            for m in modules.iter().filter(|m| m.name != me) {
                modules_found += 1;
                out(format_args!(
                    "module {} host={} handlers={} waiting={}",
                    word(&m.name),
                    word(&m.host),
                    m.handlers,
                    m.waiting
                ));
            }
            true
        }
        Err(e) if unknown_to_central(&e) => {
            err(format_args!(
                "courier: {} has no module list (courier_getModules is Courier's; the C \
                 central has none): name modules with --module, or --watch them connect and \
                 disconnect",
                target(&o.url)
            ));
            false
        }
        Err(e) => return Err(e.into()),
    };
    let names = ipc.messages().await?;
    if names.is_empty() && modules_found == 0 {
        // stderr: stdout stays the (empty) list, for scripts
        let what = if courier_central {
            "no module but this listing and no message"
        } else {
            "no message"
        };
        err(format_args!(
            "courier: {what} found at {} (another central, or the modules not started yet?)",
            target(&o.url)
        ));
    }
    if !courier_central {
        return Ok(names);
    }
    for name in names {
        let d = ipc.message_details(&name).await?;
        let fmt = |f: &Option<String>| f.as_deref().map_or("-".into(), word);
        // IPC_defineMsg registers the user's format as the reply format
        // (the message format is C's byte-array wrapper)
        out(format_args!(
            "message {} class={} format={} handlers={} module={}",
            word(&name),
            class_name(d.class),
            fmt(&d.reply_format),
            d.handlers,
            fmt(&d.resource)
        ));
    }
    Ok(Vec::new())
}

/// Whether central answered that it knows no such request.
fn unknown_to_central(e: &courier::ControlError) -> bool {
    matches!(
        e,
        courier::ControlError::Central {
            source: courier::ipc::module::Error::UnknownMessage(_),
            ..
        }
    )
}

/// A message class as users know it (`IPC_publish`: publish, `IPC_query…`: query).
fn class_name(class: i32) -> String {
    use courier::ipc::frame::MsgClass;
    match u16::try_from(class).ok().and_then(MsgClass::from_u16) {
        Some(MsgClass::Broadcast) => "publish".into(),
        Some(MsgClass::Query) => "query".into(),
        Some(MsgClass::Inform) => "inform".into(),
        Some(MsgClass::Unknown) => "-".into(),
        Some(c) => format!("{c:?}").to_lowercase(),
        None => class.to_string(),
    }
}

async fn ipc(s: &Session, o: &ListArgs) -> Result<()> {
    let ipc = s.ipc()?;
    // events first: central reports (dis)connections from then on
    let mut ev = s.events();
    let mut messages = o.message.clone();
    if o.module.is_empty() && o.message.is_empty() {
        messages = everything(&ipc, o).await?;
    }
    for m in &o.module {
        let up = s.is_module_connected(m).await?;
        out(format_args!(
            "module {} {}",
            word(m),
            if up { "connected" } else { "not-connected" }
        ));
    }
    for m in &messages {
        crate::connect::watch_if_known(&ipc, m).await?;
    }
    for m in &messages {
        // the num_handlers answers after the lookup watch_handlers made
        let n = s.num_handlers(m).await?;
        match ipc.message_info(m).await? {
            Some(i) => out(format_args!(
                "message {} format={} handlers={n}",
                word(m),
                i.res_format.map_or("-".into(), |f| word(&f.to_string()))
            )),
            None => out(format_args!("message {} unknown", word(m))),
        }
    }
    if !o.watch {
        return Ok(());
    }
    out("ready");
    let until = o
        .duration
        .map(|d| courier_wire::time::later(Instant::now(), Duration::from_secs(d)));
    loop {
        tokio::select! {
            _ = sleep_until(until) => return Ok(()),
            e = ev.next() => match e {
                Some(SessionEvent::ModuleConnected(m)) => {
                    out(format_args!("module {} connected", word(&m)))
                }
                Some(SessionEvent::ModuleDisconnected(m)) => {
                    out(format_args!("module {} disconnected", word(&m)))
                }
                Some(SessionEvent::HandlersChanged { msg, count }) => {
                    out(format_args!("message {} handlers={count}", word(&msg)))
                }
                Some(_) => {}
                None => return Err("the session ended".into()),
            }
        }
    }
}
