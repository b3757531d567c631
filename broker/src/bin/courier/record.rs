//! `courier record <url> [topics…] -o FILE.mcap`: every sample of the
//! topics into an MCAP file (like `ros2 bag record`), one channel per topic
//! and type with its schema (see `recording`), log time = when received,
//! publish time = the writer's source timestamp when it sent one.
//!
//! Chunks are zstd-compressed and closed at least once a second, so a
//! recorder killed outright loses at most the last second (`courier
//! replay` reads such a file; other MCAP tools want `mcap recover` first,
//! since it ends without a summary); stopped by Ctrl-C, SIGTERM, SIGHUP
//! (a dropped ssh session), `--count` or `--duration` it writes the summary (statistics,
//! chunk and message indexes) and says how many messages it recorded.

use std::cell::RefCell;
use std::collections::HashMap;
use std::fs::File;
use std::io::BufWriter;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use courier::format::Format;
use courier::ipc::{ByteOrder, Value};
use courier::{InstanceState, RawSample, RawSubscriber, Session};
use futures::StreamExt;

use crate::cli::{kind, Kind, RecordArgs};
use crate::connect::connect;
use crate::recording::{dds_channel, ipc_channel, known_field_names, ChannelDesc};
use crate::stop::{count, deadline, run_session, Ended, Stop};
use crate::text::{err, out, progress, word};
use crate::values::known_type;
use crate::Result;

/// How often the chunk being written is closed (written to the file).
const FLUSH_EVERY: Duration = Duration::from_secs(1);

pub async fn run(o: RecordArgs, mut stop: Stop) -> Result<Ended> {
    // the file first: a bad path fails before anything connects
    if o.output.is_dir() {
        return Err(format!(
            "cannot create {}: it is a directory (-o names the MCAP file to write)",
            o.output.display()
        )
        .into());
    }
    let file = File::options()
        .write(true)
        .create(true)
        .truncate(true)
        .create_new(!o.overwrite)
        .open(&o.output)
        .map_err(|e| {
            let hint = if e.kind() == std::io::ErrorKind::AlreadyExists {
                " (--overwrite replaces it)"
            } else {
                ""
            };
            format!("cannot create {}: {e}{hint}", o.output.display())
        })?;
    let compression = (!o.no_compression).then_some(mcap::Compression::Zstd);
    let writer = mcap::WriteOptions::new()
        .compression(compression)
        .compression_threads(0)
        .chunk_size(Some(o.chunk_size))
        .library(concat!("courier ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::new(file))
        .map_err(|e| format!("cannot write {}: {e}", o.output.display()))?;
    let rec = RefCell::new(Recorder::new(writer, &o));
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => {
            rec.into_inner().finish(&o)?;
            return Ok(ended);
        }
    };
    let what = || format!("after {} recorded", count(rec.borrow().total, "message"));
    let ended = run_session(&s, &mut stop, record(&s, &o, &rec), what).await;
    // whatever stopped it, the file gets its summary
    let finished = rec.into_inner().finish(&o);
    let ended = ended?;
    finished?;
    if let Ended::Done = ended {
        out("done");
    }
    Ok(ended)
}

/// The file being written and what is in it.
struct Recorder {
    w: mcap::Writer<BufWriter<File>>,
    scheme: String,
    /// Recording on IPC (else DDS).
    ipc: bool,
    /// Channel id by (topic, DDS type name).
    channels: HashMap<(String, Option<String>), Channel>,
    total: u64,
    /// Samples not recorded, and why (said at the end).
    skipped: HashMap<&'static str, u64>,
    unflushed: bool,
    path: std::path::PathBuf,
}

struct Channel {
    id: u16,
    seq: u32,
    /// IPC: the format, to bring samples of the other byte order to ours.
    format: Option<Format>,
}

fn nanos(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl Recorder {
    fn new(w: mcap::Writer<BufWriter<File>>, o: &RecordArgs) -> Self {
        let scheme = o
            .url
            .split_once("://")
            .map_or("", |(s, _)| s)
            .to_ascii_lowercase();
        Recorder {
            w,
            scheme,
            ipc: kind(&o.url) == Kind::Ipc,
            channels: HashMap::new(),
            total: 0,
            skipped: HashMap::new(),
            unflushed: false,
            path: o.output.clone(),
        }
    }

    /// A write to the file that failed (a full disk, say): what it means
    /// for the file.
    fn write_failed(&self, e: mcap::McapError) -> String {
        format!(
            "cannot write {}: {}, after {} recorded; the file ends without its summary: \
             courier replay reads what it holds (other MCAP tools after `mcap recover`)",
            self.path.display(),
            crate::text::with_sources(&e),
            count(self.total, "message")
        )
    }

    fn add_channel(&mut self, d: &ChannelDesc, format: Option<Format>) -> Result<Channel> {
        let schema = match &d.schema {
            Some(s) => self
                .w
                .add_schema(&s.name, &s.encoding, &s.data)
                .map_err(|e| self.write_failed(e))?,
            None => 0,
        };
        let id = self
            .w
            .add_channel(schema, &d.topic, d.encoding, &d.metadata)
            .map_err(|e| self.write_failed(e))?;
        let schema_text = d.schema.as_ref().map_or("-".to_string(), |s| {
            let enc = if s.encoding.is_empty() {
                "name-only"
            } else {
                &s.encoding
            };
            format!("{enc}:{}", word(&s.name))
        });
        out(format_args!(
            "channel {} {} {schema_text}",
            word(&d.topic),
            d.encoding
        ));
        Ok(Channel { id, seq: 0, format })
    }

    fn skip(&mut self, why: &'static str) {
        *self.skipped.entry(why).or_default() += 1;
    }

    /// Writes one sample; `format` is the IPC format of its message (IPC).
    fn write(&mut self, smp: &RawSample, format: Option<&Format>) -> Result<()> {
        if smp.state != InstanceState::Alive {
            self.skip("disposes and unregistrations (no data to replay)");
            return Ok(());
        }
        let key = (
            smp.msg.clone(),
            smp.type_name.as_deref().map(str::to_string),
        );
        if !self.channels.contains_key(&key) {
            let (d, f) = if self.ipc {
                (
                    ipc_channel(&smp.msg, format, ByteOrder::NATIVE),
                    format.cloned(),
                )
            } else {
                // DDS: by the sample's type
                let ty = smp.type_name.as_deref().unwrap_or("");
                let f = known_type(ty).map(|k| k.parsed());
                let names = known_field_names(ty);
                let d = dds_channel(&self.scheme, &smp.msg, ty, f.as_ref().map(|f| (f, names)));
                (d, f)
            };
            let c = self.add_channel(&d, f)?;
            self.channels.insert(key.clone(), c);
        }
        let Some(c) = self.channels.get_mut(&key) else {
            return Ok(());
        };
        // IPC samples of the other byte order are brought to ours, the
        // one the channel names
        let converted;
        let data = if self.ipc && smp.order != ByteOrder::NATIVE {
            let Some(f) = &c.format else {
                self.skip("IPC messages of the other byte order with no format to convert them by");
                return Ok(());
            };
            match Value::from_ipc_bytes(f, &smp.data, smp.order)
                .map_err(|e| e.to_string())
                .and_then(|v| v.to_ipc_bytes(f).map_err(|e| e.to_string()))
            {
                Ok(b) => {
                    converted = b;
                    &converted
                }
                Err(e) => {
                    err(format_args!(
                        "courier: a message {:?} does not decode as {f}: {e}",
                        smp.msg
                    ));
                    self.skip("messages that did not decode");
                    return Ok(());
                }
            }
        } else {
            &smp.data
        };
        c.seq = c.seq.wrapping_add(1);
        let log_time = nanos(smp.received);
        let header = mcap::records::MessageHeader {
            channel_id: c.id,
            sequence: c.seq,
            log_time,
            publish_time: smp.source_time.map_or(log_time, nanos),
        };
        if let Err(e) = self.w.write_to_known_channel(&header, data) {
            return Err(self.write_failed(e).into());
        }
        self.total += 1;
        self.unflushed = true;
        Ok(())
    }

    /// Closes the chunk being written, if it has anything new.
    fn flush(&mut self) -> Result<()> {
        if self.unflushed {
            if let Err(e) = self.w.flush() {
                return Err(self.write_failed(e).into());
            }
            self.unflushed = false;
        }
        Ok(())
    }

    /// Writes the summary and footer; says what was recorded.
    fn finish(mut self, o: &RecordArgs) -> Result<()> {
        self.w
            .finish()
            .map_err(|e| format!("cannot finish {}: {e}", o.output.display()))?;
        let size = std::fs::metadata(&o.output).map_or(0, |m| m.len());
        out(format_args!(
            "recorded {} on {} in {} ({size} B)",
            count(self.total, "message"),
            count(self.channels.len() as u64, "channel"),
            o.output.display()
        ));
        let mut skipped: Vec<_> = self.skipped.into_iter().collect();
        skipped.sort();
        for (why, n) in skipped {
            err(format_args!("courier: not recorded: {n} {why}"));
        }
        Ok(())
    }
}

/// A subscription's samples as a stream.
fn samples(sub: RawSubscriber) -> impl futures::Stream<Item = RawSample> {
    futures::stream::unfold(sub, |mut sub| async move {
        sub.recv().await.map(|smp| (smp, sub))
    })
}

async fn record(s: &Session, o: &RecordArgs, rec: &RefCell<Recorder>) -> Result<()> {
    let mut subs = Vec::new();
    match kind(&o.url) {
        Kind::Ipc => {
            for t in &o.topics {
                subs.push(Box::pin(samples(s.subscribe_raw(t).await?)));
            }
        }
        Kind::Dds => {
            if o.topics.is_empty() {
                let p = s.subscribe_pattern("*", "*").await.map_err(|e| {
                    format!("recording every topic needs pattern subscriptions: {e}")
                })?;
                subs.push(Box::pin(samples(p)));
            }
            for t in &o.topics {
                let sub = if t.contains(['*', '?', '[']) {
                    s.subscribe_pattern(t, "*").await?
                } else {
                    s.subscribe_raw(t).await?
                };
                subs.push(Box::pin(samples(sub)));
            }
        }
    }
    let mut all = futures::stream::select_all(subs);
    // IPC: each message's format, asked of central at its first sample
    let mut formats: HashMap<String, Option<Format>> = HashMap::new();
    out("ready");
    let started = Instant::now();
    let until = o
        .duration
        .map(|d| courier_wire::time::later(started, Duration::from_secs(d)));
    let mut flush = tokio::time::interval(FLUSH_EVERY);
    loop {
        tokio::select! {
            _ = deadline(until) => break,
            _ = flush.tick() => {
                let mut r = rec.borrow_mut();
                r.flush()?;
                progress(format_args!(
                    "recording for {} s: {} on {}",
                    started.elapsed().as_secs(),
                    count(r.total, "message"),
                    count(r.channels.len() as u64, "channel")
                ));
            }
            smp = all.next() => {
                let Some(smp) = smp else {
                    return Err("the session ended".into());
                };
                let format = if kind(&o.url) == Kind::Ipc {
                    if !formats.contains_key(&smp.msg) {
                        let f = s
                            .ipc()?
                            .message_info(&smp.msg)
                            .await?
                            .and_then(|i| i.res_format);
                        formats.insert(smp.msg.clone(), f);
                    }
                    formats.get(&smp.msg).and_then(Option::as_ref)
                } else {
                    None
                };
                let mut r = rec.borrow_mut();
                r.write(&smp, format)?;
                if o.count.is_some_and(|c| c > 0 && r.total >= c) {
                    break;
                }
            }
        }
    }
    Ok(())
}
