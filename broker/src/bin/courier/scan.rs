//! Reading an MCAP recording leniently, record by record from the start,
//! so that a truncated or damaged file still gives what is intact: each
//! damage is reported with what is wrong and at which byte, the damaged
//! part skipped (a chunk whose compressed data or CRC is bad), and reading
//! goes on where it can (it cannot past a record whose length runs beyond
//! the end of the file: that is where the file was cut, or where a
//! recorder killed while writing a chunk left it unfinished).
//!
//! Channels come from the summary section too, when the file has one: a
//! damaged chunk that held a channel's record does not lose the channel.
//! Memory is bounded by the largest record (limited to
//! [`RECORD_LIMIT`]), never by the file.

use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use mcap::records::{op, Record};

use crate::recording::SchemaDesc;

/// The largest record (and uncompressed chunk) this reader takes.
pub const RECORD_LIMIT: u64 = 1 << 30;

/// A channel of the recording.
#[derive(Debug, Clone)]
pub struct Chan {
    /// Its id in the file.
    pub id: u16,
    /// The topic (IPC message) name.
    pub topic: String,
    /// The message encoding.
    pub encoding: String,
    /// Its schema, when it has one.
    pub schema: Option<SchemaDesc>,
    /// Its metadata.
    pub metadata: BTreeMap<String, String>,
}

/// A message of the recording.
#[derive(Debug)]
pub struct Msg {
    /// Its channel's id.
    pub channel: u16,
    /// When it was recorded (ns since the Unix epoch).
    pub log_time: u64,
    /// Its bytes, in its channel's encoding.
    pub data: Vec<u8>,
}

/// What a walk meets, in file order.
pub enum Event {
    /// A channel, the first time it is met.
    Channel(Chan),
    /// An intact message of a known channel.
    Message(Msg),
}

/// What walking the whole file found: its channels, how many intact
/// messages each has, the log times they span, and the damage.
#[derive(Debug, Default)]
pub struct Survey {
    /// Every channel, by id.
    pub channels: BTreeMap<u16, Chan>,
    /// Intact messages, by channel id.
    pub counts: BTreeMap<u16, u64>,
    /// The earliest and latest log times of the intact messages, by
    /// channel id.
    pub spans: BTreeMap<u16, (u64, u64)>,
    /// Each damage found: what is wrong, and at which byte.
    pub damage: Vec<String>,
}

impl Survey {
    /// The earliest and latest log times of the intact messages of the
    /// channels `ids` (what a replay of those channels spans).
    pub fn span<'a>(&self, ids: impl IntoIterator<Item = &'a u16>) -> Option<(u64, u64)> {
        ids.into_iter()
            .filter_map(|id| self.spans.get(id))
            .copied()
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }
}

/// Walks the file once, counting (first pass of a replay). `Err`: the file
/// cannot be read at all (missing, not MCAP).
pub fn survey(path: &Path) -> Result<Survey, String> {
    let mut s = Survey::default();
    let damage = walk(path, &mut |e| {
        match e {
            Event::Channel(c) => {
                s.channels.insert(c.id, c);
            }
            Event::Message(m) => {
                *s.counts.entry(m.channel).or_default() += 1;
                let t = m.log_time;
                let span = s.spans.entry(m.channel).or_insert((t, t));
                *span = (span.0.min(t), span.1.max(t));
            }
        }
        true
    })?;
    s.damage = damage;
    Ok(s)
}

/// The name of a record's opcode, for messages.
fn op_name(o: u8) -> String {
    match o {
        op::HEADER => "header".into(),
        op::FOOTER => "footer".into(),
        op::SCHEMA => "schema".into(),
        op::CHANNEL => "channel".into(),
        op::MESSAGE => "message".into(),
        op::CHUNK => "chunk".into(),
        op::MESSAGE_INDEX => "message index".into(),
        op::CHUNK_INDEX => "chunk index".into(),
        op::ATTACHMENT => "attachment".into(),
        op::ATTACHMENT_INDEX => "attachment index".into(),
        op::STATISTICS => "statistics".into(),
        op::METADATA => "metadata".into(),
        op::METADATA_INDEX => "metadata index".into(),
        op::SUMMARY_OFFSET => "summary offset".into(),
        op::DATA_END => "data end".into(),
        o => format!("opcode 0x{o:02x}"),
    }
}

/// Top-level records of one file region, each with its offset.
struct Records<R> {
    r: R,
    pos: u64,
    end: u64,
}

/// What reading the next record gave.
enum Next {
    Record(u64, u8, Vec<u8>),
    /// The region ends here.
    End,
    /// The file is cut (or a length is absurd): nothing after can be found.
    Cut(String),
}

impl<R: Read> Records<R> {
    fn next(&mut self) -> Next {
        let at = self.pos;
        let left = self.end - at;
        if left == 0 {
            return Next::End;
        }
        if left < 9 {
            return Next::Cut(format!(
                "truncated at byte {}: a record at byte {at} needs 9 bytes of opcode and \
                 length, {left} remain",
                self.end
            ));
        }
        let mut h = [0u8; 9];
        if let Err(e) = self.r.read_exact(&mut h) {
            return Next::Cut(format!("cannot read byte {at}: {e}"));
        }
        let (o, len) = (
            h[0],
            u64::from_le_bytes(h[1..].try_into().unwrap_or_default()),
        );
        let left = left - 9;
        if len == u64::MAX {
            // the length a writer puts down before it knows it (the mcap
            // crate's chunks), never written over: the writer stopped
            // in the middle of this record
            return Next::Cut(format!(
                "the {} at byte {at} was left unfinished: the recorder was stopped before it \
                 wrote it (its length is still the placeholder), so its messages are lost",
                op_name(o)
            ));
        }
        if len > left {
            return Next::Cut(format!(
                "truncated at byte {}: the {} record at byte {at} needs {len} bytes, {left} remain",
                self.end,
                op_name(o)
            ));
        }
        if len > RECORD_LIMIT {
            return Next::Cut(format!(
                "the {} record at byte {at} is {len} bytes, more than the {RECORD_LIMIT} this \
                 reader takes",
                op_name(o)
            ));
        }
        let mut body = vec![0u8; len as usize];
        if let Err(e) = self.r.read_exact(&mut body) {
            return Next::Cut(format!("cannot read the record at byte {at}: {e}"));
        }
        self.pos += 9 + len;
        Next::Record(at, o, body)
    }
}

/// Schemas and channels known so far, and the channel ids whose messages
/// were already reported as orphans.
#[derive(Default)]
struct Known {
    schemas: BTreeMap<u16, SchemaDesc>,
    channels: BTreeMap<u16, Chan>,
    orphans: HashSet<u16>,
}

/// What one parsed record means to the walk: `false` once the visitor
/// wants no more.
fn take(
    rec: Record<'_>,
    at: u64,
    known: &mut Known,
    damage: &mut Vec<String>,
    visit: &mut dyn FnMut(Event) -> bool,
) -> bool {
    match rec {
        Record::Schema { header, data } => {
            known.schemas.insert(
                header.id,
                SchemaDesc {
                    name: header.name,
                    encoding: header.encoding,
                    data: data.into_owned(),
                },
            );
        }
        Record::Channel(c) => {
            if known.channels.contains_key(&c.id) {
                return true;
            }
            let schema = match c.schema_id {
                0 => None,
                id => {
                    let s = known.schemas.get(&id).cloned();
                    if s.is_none() {
                        damage.push(format!(
                            "the channel record of {:?} at byte {at} names schema {id}, which \
                             the file does not define: its messages replay without a schema",
                            c.topic
                        ));
                    }
                    s
                }
            };
            let chan = Chan {
                id: c.id,
                topic: c.topic,
                encoding: c.message_encoding,
                schema,
                metadata: c.metadata,
            };
            known.channels.insert(chan.id, chan.clone());
            return visit(Event::Channel(chan));
        }
        Record::Message { header, data } => {
            if !known.channels.contains_key(&header.channel_id) {
                if known.orphans.insert(header.channel_id) {
                    damage.push(format!(
                        "the message at byte {at} is on channel {}, whose channel record is \
                         lost: its messages are skipped",
                        header.channel_id
                    ));
                }
                return true;
            }
            return visit(Event::Message(Msg {
                channel: header.channel_id,
                log_time: header.log_time,
                data: data.into_owned(),
            }));
        }
        _ => {}
    }
    true
}

/// The records of a chunk, all of them, or what is wrong with it.
fn unchunk(
    header: mcap::records::ChunkHeader,
    data: &[u8],
) -> Result<Vec<Record<'static>>, String> {
    if header.uncompressed_size > RECORD_LIMIT {
        return Err(format!(
            "it claims {} uncompressed bytes, more than the {RECORD_LIMIT} this reader takes",
            header.uncompressed_size
        ));
    }
    let compression = if header.compression.is_empty() {
        "uncompressed".to_string()
    } else {
        header.compression.clone()
    };
    let reader =
        mcap::read::ChunkReader::new(header, data).map_err(|e| format!("{compression}: {e}"))?;
    reader
        .map(|r| r.map(Record::into_owned))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{compression} data: {e}"))
}

/// The summary section's offset, from the footer at the end, when the file
/// has one (it was finished).
fn summary_start(f: &mut File, len: u64) -> Option<(u64, u64)> {
    // footer record (1 + 8 + 20 bytes) then the magic
    let footer_at = len.checked_sub(29 + 8)?;
    let mut tail = [0u8; 37];
    f.seek(SeekFrom::Start(footer_at)).ok()?;
    f.read_exact(&mut tail).ok()?;
    if &tail[29..] != mcap::MAGIC || tail[0] != op::FOOTER || tail[1..9] != 20u64.to_le_bytes() {
        return None;
    }
    let start = u64::from_le_bytes(tail[9..17].try_into().ok()?);
    (start >= 8 && start < footer_at).then_some((start, footer_at))
}

/// What is wrong with what follows the data end record at byte
/// `data_end` (the summary, the footer and the closing magic of a finished
/// recording), if anything. A file cut there has every message, but tools
/// that read it through its summary and footer cannot open it: the
/// damage is reported as any other.
fn tail_damage<R: Read>(recs: &mut Records<R>, data_end: u64) -> Option<String> {
    let lost = format!(
        "the summary after the data end record at byte {data_end} is lost (the messages \
         before it are intact)"
    );
    loop {
        match recs.next() {
            Next::Record(at, op::FOOTER, _) => {
                let left = recs.end - recs.pos;
                let mut magic = [0u8; 8];
                let whole = left == 8 && recs.r.read_exact(&mut magic).is_ok();
                if whole && magic == mcap::MAGIC {
                    return None;
                }
                return Some(format!(
                    "the footer at byte {at} is followed by {left} bytes, not the 8 of the MCAP \
                     magic that end a finished recording: the file was cut or written over"
                ));
            }
            Next::Record(..) => {}
            Next::End => {
                return Some(format!(
                    "truncated at byte {}: the file ends before its footer: {lost}",
                    recs.end
                ))
            }
            Next::Cut(why) => return Some(format!("{why}: {lost}")),
        }
    }
}

/// Walks the file: the summary's channels first (when it has one), then
/// the data section in order, calling `visit` for each channel (once) and
/// intact message until it returns `false`. Returns the damage found, or
/// `Err` when the file cannot be read at all.
pub fn walk(path: &Path, visit: &mut dyn FnMut(Event) -> bool) -> Result<Vec<String>, String> {
    let shown = path.display();
    let mut f = File::open(path).map_err(|e| format!("cannot open {shown}: {e}"))?;
    let meta = f
        .metadata()
        .map_err(|e| format!("cannot read {shown}: {e}"))?;
    if meta.is_dir() {
        return Err(format!("{shown} is a directory, not an MCAP file"));
    }
    let len = meta.len();
    let mut magic = [0u8; 8];
    if len < 8 || f.read_exact(&mut magic).is_err() || magic != mcap::MAGIC {
        return Err(format!(
            "{shown} is not an MCAP file: it does not begin with the MCAP magic"
        ));
    }
    let mut known = Known::default();
    let mut damage = Vec::new();
    if let Some((start, end)) = summary_start(&mut f, len) {
        f.seek(SeekFrom::Start(start))
            .map_err(|e| format!("cannot read {shown}: {e}"))?;
        let mut recs = Records {
            r: BufReader::new(&mut f),
            pos: start,
            end,
        };
        let mut ignore = |_: Event| true;
        loop {
            match recs.next() {
                Next::Record(at, o @ (op::SCHEMA | op::CHANNEL), body) => {
                    match mcap::read::parse_record(o, &body) {
                        Ok(r) => {
                            take(r, at, &mut known, &mut damage, &mut ignore);
                        }
                        Err(e) => damage.push(format!(
                            "the summary's {} record at byte {at} is damaged: {e}",
                            op_name(o)
                        )),
                    }
                }
                Next::Record(..) => {}
                Next::End => break,
                Next::Cut(why) => {
                    damage.push(format!("the summary section is damaged: {why}"));
                    break;
                }
            }
        }
        // the summary's channels are the visitor's first
        let summary_channels: Vec<Chan> = known.channels.values().cloned().collect();
        for c in summary_channels {
            if !visit(Event::Channel(c)) {
                return Ok(damage);
            }
        }
    }
    f.seek(SeekFrom::Start(8))
        .map_err(|e| format!("cannot read {shown}: {e}"))?;
    let mut recs = Records {
        r: BufReader::new(&mut f),
        pos: 8,
        end: len,
    };
    loop {
        let (at, o, body) = match recs.next() {
            Next::Record(at, o, body) => (at, o, body),
            Next::End => {
                damage.push(format!(
                    "truncated at byte {len}: the file ends before its data end record (the \
                     recording was not finished)"
                ));
                break;
            }
            Next::Cut(why) => {
                damage.push(why);
                break;
            }
        };
        match o {
            op::DATA_END => {
                damage.extend(tail_damage(&mut recs, at));
                break;
            }
            op::FOOTER => {
                damage.push(format!(
                    "the footer at byte {at} comes before any data end record"
                ));
                break;
            }
            op::SCHEMA | op::CHANNEL | op::MESSAGE | op::CHUNK => {}
            // indexes, attachments, metadata, private records
            _ => continue,
        }
        let rec = match mcap::read::parse_record(o, &body) {
            Ok(r) => r,
            Err(e) => {
                let skipped = if o == op::CHUNK {
                    "; its messages are skipped"
                } else {
                    ""
                };
                damage.push(format!(
                    "the {} record at byte {at} is damaged: {e}{skipped}",
                    op_name(o)
                ));
                continue;
            }
        };
        let recs_in = match rec {
            Record::Chunk { header, data } => match unchunk(header, &data) {
                Ok(v) => v,
                Err(e) => {
                    damage.push(format!(
                        "the chunk at byte {at} is damaged ({e}): its messages are skipped"
                    ));
                    continue;
                }
            },
            r => vec![r.into_owned()],
        };
        for r in recs_in {
            if !take(r, at, &mut known, &mut damage, visit) {
                return Ok(damage);
            }
        }
    }
    Ok(damage)
}

#[cfg(test)]
mod span_tests {
    use super::*;

    /// A replay of some channels spans their messages only: offsets count
    /// from the first message replayed, so `--topic b` does not idle
    /// through the time before b's first message.
    #[test]
    fn the_span_of_chosen_channels_leaves_the_others_out() {
        let mut s = Survey::default();
        s.spans.insert(1, (1_000, 2_000));
        s.spans.insert(2, (3_500_000_000, 3_600_000_000));
        assert_eq!(s.span(&[2]), Some((3_500_000_000, 3_600_000_000)));
        assert_eq!(s.span(&[1, 2]), Some((1_000, 3_600_000_000)));
        assert_eq!(s.span(&[9]), None);
    }
}
