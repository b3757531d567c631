//! `courier call <url> <query> <request>`: one query (IPC) or service call
//! (DDS, ROS 2 style), the reply printed decoded (like `ros2 service
//! call`, `z_get`). On DDS the types are ones Courier knows (default
//! `courier::Ping`), or any laid out as an IPC format (`--format`,
//! `--reply-format`, see `cdr_value`): of the request's and the reply's
//! bodies only, the ROS 2 request/reply header (sample identity) being the
//! session's to add and take off (RTPS URL option `services=`).
//!
//! A REQUEST that does not fit its type is a usage error (exit 2): checked
//! before connecting when the command line gives the type, else once
//! central has said the query's format ([`crate::cli::LateUsage`]).

use std::cell::Cell;
use std::time::{Duration, Instant};

use courier::format::Format;
use courier::{Handle, QueryError, Session};

use crate::cli::{kind, CallArgs, Kind, LateUsage};
use crate::connect::connect;
use crate::dds_type::{default_type_note, DdsType};
use crate::stop::{run_session, Ended, Stop};
use crate::text::out;
use crate::values::{parse_value, Decoded, Style};
use crate::Result;

pub async fn run(o: CallArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let asked = Cell::new(None::<Instant>);
    let what = || match asked.get() {
        Some(t) => format!(
            "while waiting for the reply to {:?} ({:.1} s)",
            o.query,
            t.elapsed().as_secs_f64()
        ),
        None => format!("before calling {:?}", o.query),
    };
    run_session(&s, &mut stop, call(&s, &o, &asked), what).await
}

async fn call(s: &Session, o: &CallArgs, asked: &Cell<Option<Instant>>) -> Result<()> {
    let style = if o.json { Style::Json } else { Style::Text };
    let timeout = Duration::from_millis(o.timeout);
    let reply = match kind(&o.url) {
        Kind::Ipc => ipc_call(s, o, timeout, asked).await?,
        Kind::Dds => dds_call(s, o, timeout, asked).await?,
    };
    out(reply.print(style));
    Ok(())
}

/// Why a query failed, said for the command line.
fn failed(o: &CallArgs, e: QueryError, timeout: Duration) -> crate::Error {
    match e {
        QueryError::Timeout { .. } => {
            format!("no reply to {:?} within {timeout:?} (--timeout)", o.query).into()
        }
        QueryError::CentralSilent { asked, .. } => format!(
            "no reply to {:?} within {timeout:?} (--timeout), and central did not answer \
             either (asked who serves it {asked:?} before the end): is it stopped or overloaded?",
            o.query
        )
        .into(),
        QueryError::NoResponder { .. } => format!(
            "nobody serves {:?} (waited {timeout:?} for a server{})",
            o.query,
            match kind(&o.url) {
                Kind::Ipc => "; central keeps the query until one subscribes",
                Kind::Dds => " to be discovered",
            }
        )
        .into(),
        e => e.into(),
    }
}

/// The request's bytes when the command line alone gives its type (all but
/// IPC without `--format`, whose format central holds), or why the types
/// or the REQUEST do not do (a usage error).
pub fn request_offline(o: &CallArgs) -> Option<std::result::Result<Vec<u8>, String>> {
    match kind(&o.url) {
        Kind::Ipc => o.format.as_ref().map(|f| ipc_request(f, &o.request)),
        Kind::Dds => Some(dds_types(o).and_then(|(req, _)| {
            req.encode(&o.request)
                .map_err(|e| format!("{e}{}", default_type_note(o.type_name.as_deref())))
        })),
    }
}

/// A REQUEST of format `f` in IPC marshalling, or why it does not fit.
fn ipc_request(f: &Format, request: &str) -> std::result::Result<Vec<u8>, String> {
    parse_value(f, request)?
        .to_ipc_bytes(f)
        .map_err(|e| e.to_string())
}

/// The request's and the reply's DDS types.
fn dds_types(o: &CallArgs) -> std::result::Result<(DdsType, DdsType), String> {
    let req = DdsType::new(o.format.as_ref(), o.type_name.as_deref())
        .map_err(|e| format!("{e}: give its layout with --format"))?;
    let resp = match (&o.reply_format, &o.reply_type) {
        (None, None) if o.format.is_none() => DdsType::new(None, o.type_name.as_deref()),
        (f, t) => DdsType::new(f.as_ref(), t.as_deref().or(o.type_name.as_deref())),
    }
    .map_err(|e| format!("{e}: give the reply's layout with --reply-format"))?;
    Ok((req, resp))
}

async fn ipc_call(
    s: &Session,
    o: &CallArgs,
    timeout: Duration,
    asked: &Cell<Option<Instant>>,
) -> Result<Decoded> {
    let ipc = s.ipc()?;
    let format = match &o.format {
        Some(f) => f.clone(),
        None => {
            let info = ipc.look_up(&o.query).await?.ok_or_else(|| {
                format!(
                    "central knows no message {:?} (is its server running?)",
                    o.query
                )
            })?;
            if s.num_handlers(&o.query).await? == 0 {
                crate::text::progress(format_args!(
                    "nobody serves {:?} yet; central keeps the query until somebody does",
                    o.query
                ));
            }
            info.res_format.ok_or_else(|| {
                format!(
                    "message {:?} has no format in central; give one with --format",
                    o.query
                )
            })?
        }
    };
    // checked before connecting when --format gave the format
    let data = ipc_request(&format, &o.request).map_err(|msg| LateUsage { sub: "call", msg })?;
    asked.set(Some(Instant::now()));
    let (reply_msg, data, order) = s
        .query_raw(&o.query, &data, timeout)
        .await
        .map_err(|e| failed(o, e, timeout))?;
    // the session looked the reply's message up to unwrap it
    let reply_format: Option<Format> = match &o.reply_format {
        Some(f) => Some(f.clone()),
        None => ipc
            .message_info(&reply_msg)
            .await?
            .and_then(|i| i.res_format),
    };
    Ok(Decoded::ipc(reply_format.as_ref(), &data, order)
        .map_err(|e| format!("the reply ({reply_msg}) {e}"))?)
}

async fn dds_call(
    s: &Session,
    o: &CallArgs,
    timeout: Duration,
    asked: &Cell<Option<Instant>>,
) -> Result<Decoded> {
    // both checked before connecting
    let (req, resp) = dds_types(o)?;
    let data = req.encode(&o.request)?;
    let b = s.backend();
    let client = b
        .open_client(&o.query, &req.type_info(), &resp.type_info())
        .await?;
    asked.set(Some(Instant::now()));
    let r = b.query(client, data, timeout).await;
    b.close_handle(Handle::Client(client));
    let (_, data, _) = r.map_err(|e| failed(o, e, timeout))?;
    resp.decode(&data).map_err(|e| reply_body_note(e, o))
}

/// A reply that does not decode, said with what its type describes: the
/// reply's body, Courier having taken the request/reply header off.
fn reply_body_note(e: crate::Error, o: &CallArgs) -> crate::Error {
    let what = if o.reply_format.is_some() {
        "--reply-format"
    } else {
        "the reply type"
    };
    format!(
        "the reply {e} ({what} describes the reply's body only: Courier took the \
         request/reply header off)"
    )
    .into()
}
