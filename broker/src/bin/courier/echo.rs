//! `courier echo <url> <topic>`: every sample of one topic, decoded, one a
//! line (like `ros2 topic echo`, `z_sub`).
//!
//! On IPC the format is `--format`, or the one central holds for the
//! message (looked up at its first delivery); on DDS `--format` (the CDR
//! layout the derive gives that format), else the discovered type when
//! Courier knows it. Anything else prints as hex.

use std::cell::Cell;
use std::time::{Duration, Instant};

use courier::format::Format;
use courier::{RawSample, Session};
use futures::StreamExt;

use crate::cli::{kind, EchoArgs, Kind};
use crate::connect::{connect, target, PROGRESS_EVERY};
use crate::dds_type::DdsType;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{err, out, progress};
use crate::values::{Decoded, Style};
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
    let until = o.duration.map(|d| started + Duration::from_secs(d));
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
