//! `courier echo <url> <topic>`: every sample of one topic, decoded, one a
//! line (like `ros2 topic echo`, `z_sub`).
//!
//! On IPC the format is `--format`, or the one central holds for the
//! message (looked up at its first delivery); on DDS `--format` (the CDR
//! layout the derive gives that format), else the discovered type when
//! Courier knows it. Anything else prints as hex.
//!
//! A dispose or unregister of a keyed DDS instance is no sample: it prints
//! as a line of its own, `(disposed) key=…` ([`instance_change`]), as `spy`
//! marks it `(disposed)`, never as data or a decode failure.

use std::cell::Cell;
use std::time::{Duration, Instant};

use courier::format::Format;
use courier::{InstanceState, RawSample, Session};
use futures::StreamExt;

use crate::cli::{kind, EchoArgs, Kind};
use crate::connect::{connect, target, PROGRESS_EVERY};
use crate::dds_type::DdsType;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{err, out, progress};
use crate::values::{decode_key, known_type, Decoded, Style};
use crate::wait::Discovery;
use crate::Result;

pub async fn run(o: EchoArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let n = Cell::new(0u64);
    let what = || format!("after {}", count(n.get(), "sample"));
    run_session(&s, &mut stop, echo(&s, &o, &n), what).await
}

/// Decodes the samples of one topic: through a format given or learnt
/// once (IPC), or by the sample's type (DDS).
pub struct SampleDecoder {
    topic: String,
    kind: Kind,
    format: Option<Format>,
    /// IPC: the format was asked of the session already.
    asked: bool,
}

impl SampleDecoder {
    pub fn new(url: &str, topic: &str, format: Option<Format>) -> Self {
        SampleDecoder {
            topic: topic.to_string(),
            kind: kind(url),
            asked: format.is_some(),
            format,
        }
    }

    /// The layout of a DDS sample of `type_name`, when one is known: the
    /// format given, or the known type's.
    pub fn dds_format(&self, type_name: Option<&str>) -> Option<Format> {
        match (&self.kind, &self.format) {
            (Kind::Ipc, _) => None,
            (Kind::Dds, Some(f)) => Some(f.clone()),
            (Kind::Dds, None) => type_name.and_then(known_type).map(|k| k.parsed()),
        }
    }

    /// The sample decoded (its bytes when no format is known).
    pub async fn decode(&mut self, s: &Session, smp: &RawSample) -> Result<Decoded> {
        match self.kind {
            Kind::Ipc => {
                if !self.asked {
                    self.asked = true;
                    // the first delivery looked the message up
                    self.format = s
                        .ipc()?
                        .message_info(&self.topic)
                        .await?
                        .and_then(|i| i.res_format);
                }
                Ok(Decoded::ipc(self.format.as_ref(), &smp.data, smp.order)?)
            }
            Kind::Dds => match &self.format {
                Some(f) => Ok(Decoded::cdr(f, &smp.data)?),
                None => Ok(Decoded::dds(smp.type_name.as_deref(), &smp.data)?),
            },
        }
    }
}

async fn echo(s: &Session, o: &EchoArgs, n: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    // a type named: announced (an XRCE agent needs it) and decoded by
    let ty = o
        .type_name
        .as_deref()
        .map(|t| DdsType::new(o.format.as_ref(), Some(t)))
        .transpose()?;
    let mut sub = match &ty {
        Some(t) => s.subscribe_raw_as(&o.topic, &t.type_info()).await?,
        None => s.subscribe_raw(&o.topic).await?,
    };
    let style = if o.json { Style::Json } else { Style::Text };
    let mut dec = SampleDecoder::new(&o.url, &o.topic, o.format.clone());
    let started = Instant::now();
    let until = o
        .duration
        .map(|d| courier_wire::time::later(started, Duration::from_secs(d)));
    let mut found = Discovery::default();
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    loop {
        let sleep = async {
            match until {
                Some(t) => tokio::time::sleep_until(t.into()).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = sleep => break,
            smp = sub.recv() => {
                let Some(smp) = smp else {
                    return Err("the session ended".into());
                };
                if smp.state != InstanceState::Alive {
                    // the one instance of a topic without key (its writer
                    // closed): nothing to say about a key
                    let keyless = smp.data.len() <= 4 && smp.key_hash.is_none_or(|h| h == [0; 16]);
                    if keyless {
                        continue;
                    }
                    // printed, not counted: --count counts samples (a
                    // writer that closes disposes what it leaves)
                    let f = match &ty {
                        Some(t) => Some(t.format()),
                        None => dec.dds_format(smp.type_name.as_deref()),
                    };
                    out(instance_change(&smp, f.as_ref(), style));
                    continue;
                }
                n.set(n.get() + 1);
                let decoded = match &ty {
                    Some(t) => t.decode(&smp.data),
                    None => dec.decode(s, &smp).await,
                };
                let d = match decoded {
                    Ok(d) => d,
                    Err(e) => {
                        err(format_args!("courier: sample {} of {:?} {e}", n.get(), o.topic));
                        Decoded::Bytes(smp.data.clone())
                    }
                };
                out(d.print(style));
                if o.count.is_some_and(|c| n.get() >= c) {
                    break;
                }
            }
            Some(e) = ev.next() => found.update(&e),
            _ = tick.tick(), if n.get() == 0 => {
                let secs = started.elapsed().as_secs();
                match kind(&o.url) {
                    Kind::Dds => progress(format_args!(
                        "no sample of {:?} for {secs} s: {}",
                        o.topic,
                        found.summary(&o.topic, true)
                    )),
                    Kind::Ipc => progress(format_args!(
                        "no message {:?} from {} for {secs} s",
                        o.topic,
                        target(&o.url)
                    )),
                }
            }
        }
    }
    Ok(())
}

/// How `echo` prints a dispose or unregister: what happened and to which
/// instance. Text: `(disposed) key={1}` (the key decoded through `fmt`, see
/// [`decode_key`]), `(disposed) key=<hex>` (the key's bytes, encapsulation
/// header first, when it does not decode), `(disposed) key_hash=<hex>`
/// (only the 16-byte key hash came), `(disposed) key=-` (nothing came);
/// `unregistered` alike. JSON: `{"disposed":true,"key":[1]}`,
/// `{"disposed":true,"key":{"hex":"…"}}`, `{"disposed":true,"key_hash":"…"}`,
/// `{"disposed":true,"key":null}`.
pub fn instance_change(smp: &RawSample, fmt: Option<&Format>, style: Style) -> String {
    let what = match smp.state {
        InstanceState::Disposed => "disposed",
        InstanceState::Unregistered => "unregistered",
        InstanceState::Alive => "alive",
    };
    let key = if smp.data.is_empty() {
        None
    } else {
        Some(
            fmt.and_then(|f| decode_key(f, &smp.data))
                .unwrap_or_else(|| Decoded::Bytes(smp.data.clone())),
        )
    };
    let hash = |h: &[u8; 16]| h.iter().map(|b| format!("{b:02x}")).collect::<String>();
    match (style, key, &smp.key_hash) {
        (Style::Text, Some(k), _) => format!("({what}) key={}", k.print(Style::Text)),
        (Style::Text, None, Some(h)) => format!("({what}) key_hash={}", hash(h)),
        (Style::Text, None, None) => format!("({what}) key=-"),
        (Style::Json, Some(k), _) => {
            format!("{{\"{what}\":true,\"key\":{}}}", k.print(Style::Json))
        }
        (Style::Json, None, Some(h)) => format!("{{\"{what}\":true,\"key_hash\":\"{}\"}}", hash(h)),
        (Style::Json, None, None) => format!("{{\"{what}\":true,\"key\":null}}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn change(state: InstanceState, data: &[u8], key_hash: Option<[u8; 16]>) -> RawSample {
        let mut s = RawSample::new("k", data.to_vec());
        s.state = state;
        s.key_hash = key_hash;
        s
    }

    #[test]
    fn instance_changes_say_what_happened_to_which_key() {
        // Cyclone DDS's dispose of {int, string} keyed on the int: the key only
        let f = crate::values::parse_format("{int, string}").unwrap();
        let key = [0x00, 0x01, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00];
        let d = change(InstanceState::Disposed, &key, None);
        assert_eq!(
            instance_change(&d, Some(&f), Style::Text),
            "(disposed) key={1}"
        );
        assert_eq!(
            instance_change(&d, Some(&f), Style::Json),
            r#"{"disposed":true,"key":[1]}"#
        );
        // no layout, or one the key does not fit: its bytes
        assert_eq!(
            instance_change(&d, None, Style::Text),
            "(disposed) key=0001000001000000"
        );
        let s = crate::values::parse_format("string").unwrap();
        assert_eq!(
            instance_change(&d, Some(&s), Style::Json),
            r#"{"disposed":true,"key":{"hex":"0001000001000000"}}"#
        );
        // a whole sample decodes as one
        let u = change(InstanceState::Unregistered, &[0, 1, 0, 0, 7, 0, 0, 0], None);
        let i = crate::values::parse_format("int").unwrap();
        assert_eq!(
            instance_change(&u, Some(&i), Style::Text),
            "(unregistered) key=7"
        );
        // only a key hash, or nothing
        let h = change(InstanceState::Disposed, &[], Some([0xab; 16]));
        assert_eq!(
            instance_change(&h, Some(&f), Style::Text),
            format!("(disposed) key_hash={}", "ab".repeat(16))
        );
        assert_eq!(
            instance_change(&h, None, Style::Json),
            format!(r#"{{"disposed":true,"key_hash":"{}"}}"#, "ab".repeat(16))
        );
        let none = change(InstanceState::Unregistered, &[], None);
        assert_eq!(
            instance_change(&none, None, Style::Text),
            "(unregistered) key=-"
        );
        assert_eq!(
            instance_change(&none, None, Style::Json),
            r#"{"unregistered":true,"key":null}"#
        );
    }
}
