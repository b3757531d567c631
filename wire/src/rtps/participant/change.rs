//! Changes and the envelope they travel in: what a writer writes
//! ([`Change`], [`ChangeKind`], [`SampleIdentity`]), the [`Envelope`] that
//! carries a change through the reliability layer in one allocation (the
//! data, then a small trailer), what a reader receives ([`ReceivedSample`]),
//! and the inline QoS that carries a change's key hash, status and related
//! sample identity on the wire, both ways.

use std::borrow::Cow;
use std::sync::Arc;

use super::KeyHash;
use crate::rtps::discovery::{pid, StatusInfo};
use crate::rtps::parameter::{ParameterList, PID_MUST_UNDERSTAND, PID_VENDOR_SPECIFIC};
use crate::rtps::{Guid, SequenceNumber, Time, VendorId};

/// What a change does to its instance (`PID_STATUS_INFO`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ChangeKind {
    /// A sample with data.
    Alive,
    /// The instance was disposed.
    Disposed,
    /// The writer unregistered the instance.
    Unregistered,
    /// Both (what Cyclone and Fast DDS send when an entity goes away).
    DisposedUnregistered,
}

impl ChangeKind {
    fn bits(self) -> u8 {
        match self {
            ChangeKind::Alive => 0,
            ChangeKind::Disposed => 1,
            ChangeKind::Unregistered => 2,
            ChangeKind::DisposedUnregistered => 3,
        }
    }

    fn from_bits(b: u8) -> Self {
        match b & 3 {
            0 => ChangeKind::Alive,
            1 => ChangeKind::Disposed,
            2 => ChangeKind::Unregistered,
            _ => ChangeKind::DisposedUnregistered,
        }
    }

    /// From `PID_STATUS_INFO`.
    pub fn from_status(s: StatusInfo) -> Self {
        Self::from_bits(u8::from(s.disposed) | (u8::from(s.unregistered) << 1))
    }

    /// As `PID_STATUS_INFO`.
    pub fn status_info(self) -> StatusInfo {
        let b = self.bits();
        StatusInfo {
            disposed: b & 1 != 0,
            unregistered: b & 2 != 0,
        }
    }
}

/// A change to write: a sample, or a dispose/unregister of an instance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Change<'a> {
    /// Sample or dispose/unregister.
    pub kind: ChangeKind,
    /// For [`ChangeKind::Alive`]: the serialized sample, starting with its
    /// encapsulation header. Otherwise: the serialized key with its
    /// encapsulation header (sent with the K flag), or empty (then only the
    /// key hash identifies the instance).
    /// Owned data becomes the writer history's copy without another copy
    /// when it has spare capacity for the history's bookkeeping, as a
    /// buffer from [`crate::cdr::Writer`] has ([`crate::cdr::TAIL_ROOM`]).
    pub data: Cow<'a, [u8]>,
    /// The instance's key hash (keyed topics): sent inline and used for the
    /// per-instance keep-last history.
    pub key_hash: Option<KeyHash>,
    /// Source timestamp for INFO_TS; `None` takes the participant's clock at `now`.
    pub source_timestamp: Option<Time>,
    /// The request this change answers (request/reply): sent inline as
    /// `PID_RELATED_SAMPLE_IDENTITY`.
    pub related_sample_identity: Option<SampleIdentity>,
}

/// A sample's identity: its writer and sequence number (DDS-RPC
/// `SampleIdentity`), 24 bytes on the wire: GUID, then the sequence number
/// as high `i32` and low `u32` in the submessage's byte order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SampleIdentity {
    /// The writer.
    pub writer: Guid,
    /// Its sequence number there.
    pub sequence_number: SequenceNumber,
}

impl SampleIdentity {
    /// The 24-byte form.
    pub fn to_bytes(self, little: bool) -> [u8; 24] {
        let mut b = [0; 24];
        b[..16].copy_from_slice(&self.writer.to_bytes());
        let sn = self.sequence_number.0;
        let (high, low) = ((sn >> 32) as i32, sn as u32);
        if little {
            b[16..20].copy_from_slice(&high.to_le_bytes());
            b[20..].copy_from_slice(&low.to_le_bytes());
        } else {
            b[16..20].copy_from_slice(&high.to_be_bytes());
            b[20..].copy_from_slice(&low.to_be_bytes());
        }
        b
    }

    /// From the 24-byte form; `None` if shorter.
    pub fn from_bytes(b: &[u8], little: bool) -> Option<Self> {
        let g: [u8; 16] = b.get(..16)?.try_into().ok()?;
        let h: [u8; 4] = b.get(16..20)?.try_into().ok()?;
        let l: [u8; 4] = b.get(20..24)?.try_into().ok()?;
        let (high, low) = if little {
            (i32::from_le_bytes(h), u32::from_le_bytes(l))
        } else {
            (i32::from_be_bytes(h), u32::from_be_bytes(l))
        };
        Some(SampleIdentity {
            writer: Guid::from_bytes(g),
            sequence_number: SequenceNumber((i64::from(high) << 32) | i64::from(low)),
        })
    }
}

/// `PID_RELATED_SAMPLE_IDENTITY` of DDS-RPC.
pub const PID_RELATED_SAMPLE_IDENTITY: u16 = 0x0083;
/// Fast DDS's own (vendor 01.0f) `PID_CUSTOM_RELATED_SAMPLE_IDENTITY`, what
/// rmw_fastrtps services read; Courier writes both.
pub const PID_FASTDDS_RELATED_SAMPLE_IDENTITY: u16 = 0x800f;
/// eProsima's vendor id.
pub(super) const VENDOR_EPROSIMA: VendorId = VendorId([0x01, 0x0f]);

impl<'a> Change<'a> {
    /// A sample.
    pub fn alive(data: &'a [u8]) -> Self {
        Change::alive_with(Cow::Borrowed(data))
    }

    /// A sample whose serialized data the participant takes.
    pub fn alive_owned(data: Vec<u8>) -> Change<'static> {
        Change::alive_with(Cow::Owned(data))
    }

    fn alive_with(data: Cow<'a, [u8]>) -> Self {
        Change {
            kind: ChangeKind::Alive,
            data,
            key_hash: None,
            source_timestamp: None,
            related_sample_identity: None,
        }
    }

    /// Disposes the instance with this serialized key (may be empty) and key hash.
    pub fn dispose(key: &'a [u8], key_hash: KeyHash) -> Self {
        Change {
            kind: ChangeKind::Disposed,
            data: Cow::Borrowed(key),
            key_hash: Some(key_hash),
            source_timestamp: None,
            related_sample_identity: None,
        }
    }

    /// Unregisters the instance with this serialized key (may be empty) and key hash.
    pub fn unregister(key: &'a [u8], key_hash: KeyHash) -> Self {
        Change {
            kind: ChangeKind::Unregistered,
            ..Self::dispose(key, key_hash)
        }
    }

    /// Sets the key hash.
    pub fn with_key_hash(mut self, key_hash: KeyHash) -> Self {
        self.key_hash = Some(key_hash);
        self
    }

    /// Sets the source timestamp.
    pub fn with_timestamp(mut self, t: Time) -> Self {
        self.source_timestamp = Some(t);
        self
    }

    /// Marks this change as the reply to the sample `request`.
    pub fn with_related_sample_identity(mut self, request: SampleIdentity) -> Self {
        self.related_sample_identity = Some(request);
        self
    }
}

/// A change as the writer history and the reader queues keep it: the data,
/// then a small trailer (key hash, timestamp, flags, kind), so that one
/// allocation carries everything through the reliability layer and the
/// data can leave it as a `Vec` without being copied (see
/// [`ReceivedSample::into_data`]).
pub type Envelope = crate::rtps::reliability::Payload;

/// Bytes after the data in an [`Envelope`]: key hash, timestamp, flags, kind.
const ENV: usize = 26;

/// Room a buffer needs past its data to become an [`Envelope`] in place.
pub(crate) const ENVELOPE_ROOM: usize = ENV + 24;

pub(super) fn envelope(
    kind: ChangeKind,
    key_hash: Option<KeyHash>,
    ts: Option<Time>,
    data: &[u8],
) -> Envelope {
    envelope_with(kind, key_hash, ts, None, Cow::Borrowed(data))
}

/// An envelope that may also carry a related sample identity (24 more
/// bytes before the trailer, flag bit 2). Owned data is used as it is: in
/// place when it has [`ENVELOPE_ROOM`] to spare (a reassembled sample, a
/// CDR writer's buffer), else grown once.
pub(super) fn envelope_with(
    kind: ChangeKind,
    key_hash: Option<KeyHash>,
    ts: Option<Time>,
    related: Option<SampleIdentity>,
    data: Cow<'_, [u8]>,
) -> Envelope {
    let v = match data {
        Cow::Owned(v) => v,
        Cow::Borrowed(d) => {
            let mut v = Vec::with_capacity(d.len() + ENVELOPE_ROOM);
            v.extend_from_slice(d);
            v
        }
    };
    envelope_from_vec(v, kind, key_hash, ts, related)
}

// the CDR writer's spare capacity takes an envelope's trailer
const _: () = assert!(ENVELOPE_ROOM <= crate::cdr::TAIL_ROOM);

/// An envelope around data the caller owns: the trailer is appended to it.
fn envelope_from_vec(
    mut v: Vec<u8>,
    kind: ChangeKind,
    key_hash: Option<KeyHash>,
    ts: Option<Time>,
    related: Option<SampleIdentity>,
) -> Envelope {
    v.reserve_exact(ENVELOPE_ROOM);
    if let Some(r) = related {
        v.extend_from_slice(&r.to_bytes(true));
    }
    v.extend_from_slice(&key_hash.unwrap_or_default().0);
    let t = ts.unwrap_or_default();
    v.extend_from_slice(&t.seconds.to_le_bytes());
    v.extend_from_slice(&t.fraction.to_le_bytes());
    v.push(
        u8::from(key_hash.is_some())
            | (u8::from(ts.is_some()) << 1)
            | (u8::from(related.is_some()) << 2),
    );
    v.push(kind.bits());
    Arc::new(v)
}

/// Where the data ends in an envelope (0 for a malformed one).
fn data_len(b: &[u8]) -> usize {
    let trailer = match b.len().checked_sub(2).map(|i| b[i]) {
        Some(flags) if flags & 4 != 0 => ENV + 24,
        _ => ENV,
    };
    b.len().saturating_sub(trailer)
}

/// An envelope opened: the change's metadata and its data.
#[derive(Clone, Copy)]
pub(super) struct Env<'a> {
    pub(super) kind: ChangeKind,
    pub(super) key_hash: Option<KeyHash>,
    pub(super) ts: Option<Time>,
    pub(super) related: Option<SampleIdentity>,
    pub(super) data: &'a [u8],
}

pub(super) fn open(b: &[u8]) -> Env<'_> {
    if b.len() < ENV {
        return Env {
            kind: ChangeKind::Alive,
            key_hash: None,
            ts: None,
            related: None,
            data: &[],
        };
    }
    let n = b.len();
    let (kind, flags) = (b[n - 1], b[n - 2]);
    let t = n - ENV; // start of the fixed trailer
    let mut k = [0; 16];
    k.copy_from_slice(&b[t..t + 16]);
    let w = |i: usize| [b[i], b[i + 1], b[i + 2], b[i + 3]];
    let len = data_len(b);
    Env {
        kind: ChangeKind::from_bits(kind),
        key_hash: (flags & 1 != 0).then_some(KeyHash(k)),
        ts: (flags & 2 != 0).then(|| Time {
            seconds: i32::from_le_bytes(w(t + 16)),
            fraction: u32::from_le_bytes(w(t + 20)),
        }),
        related: (flags & 4 != 0)
            .then(|| SampleIdentity::from_bytes(b.get(len..t)?, true))
            .flatten(),
        data: &b[..len],
    }
}

/// A change received by a local reader.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReceivedSample {
    /// The local reader.
    pub reader: Guid,
    /// The writer it came from.
    pub writer: Guid,
    /// Its sequence number in that writer.
    pub sequence_number: SequenceNumber,
    /// The source timestamp (INFO_TS), if the writer sent one.
    pub source_timestamp: Option<Time>,
    /// The key hash, if the writer sent `PID_KEY_HASH` (Courier and Fast DDS
    /// do for keyed topics; Cyclone does not: compute it from the data).
    pub key_hash: Option<KeyHash>,
    /// Sample, or dispose/unregister.
    pub kind: ChangeKind,
    /// The request this sample answers, if the writer sent
    /// `PID_RELATED_SAMPLE_IDENTITY` (request/reply).
    pub related_sample_identity: Option<SampleIdentity>,
    envelope: Envelope,
}

impl ReceivedSample {
    pub(super) fn new(reader: Guid, writer: Guid, sn: SequenceNumber, envelope: Envelope) -> Self {
        let e = open(&envelope);
        ReceivedSample {
            reader,
            writer,
            sequence_number: sn,
            source_timestamp: e.ts,
            key_hash: e.key_hash,
            kind: e.kind,
            related_sample_identity: e.related,
            envelope,
        }
    }

    /// This sample's own identity (what a reply names as related).
    pub fn identity(&self) -> SampleIdentity {
        SampleIdentity {
            writer: self.writer,
            sequence_number: self.sequence_number,
        }
    }

    /// The serialized sample (with its encapsulation header) for
    /// [`ChangeKind::Alive`]; otherwise the serialized key if the writer sent
    /// one (K flag), else empty.
    pub fn data(&self) -> &[u8] {
        &self.envelope[..data_len(&self.envelope)]
    }

    /// This change without its data: the same reader, writer, sequence
    /// number and inline QoS, and no data; made without copying the data
    /// (a clone emptied with [`ReceivedSample::remove_data`] copies it and
    /// keeps its allocation).
    pub fn without_data(&self) -> ReceivedSample {
        let env = envelope_with(
            self.kind,
            self.key_hash,
            self.source_timestamp,
            self.related_sample_identity,
            Cow::Borrowed(&[]),
        );
        ReceivedSample::new(self.reader, self.writer, self.sequence_number, env)
    }

    /// Removes `len` bytes of the data starting at `at` (rmw_cyclonedds's
    /// request header, after the encapsulation); false, and nothing
    /// removed, if the data is shorter. Copies only a shared sample.
    pub fn remove_data(&mut self, at: usize, len: usize) -> bool {
        let end = at.saturating_add(len);
        if end > data_len(&self.envelope) {
            return false;
        }
        Arc::make_mut(&mut self.envelope).drain(at..end);
        true
    }

    /// [`ReceivedSample::data`] as an owned buffer: without a copy when no
    /// other reader shares this sample (the usual case).
    pub fn into_data(self) -> Vec<u8> {
        let len = data_len(&self.envelope);
        match Arc::try_unwrap(self.envelope) {
            Ok(mut v) => {
                v.truncate(len);
                v
            }
            Err(shared) => shared[..len].to_vec(),
        }
    }
}

/// The inline QoS a change is sent with: `PID_KEY_HASH`, `PID_STATUS_INFO`
/// unless alive, and the related sample identity in both forms; `None`
/// when there is nothing to say.
pub(super) fn inline_qos(e: &Env<'_>) -> Option<Vec<u8>> {
    if e.key_hash.is_none() && e.kind == ChangeKind::Alive && e.related.is_none() {
        return None;
    }
    let kh = e.key_hash.map(|k| k.0);
    let si = e.kind.status_info().to_bytes();
    let rsi = e.related.map(|r| r.to_bytes(true));
    let mut params: Vec<(u16, &[u8])> = Vec::new();
    if let Some(k) = &kh {
        params.push((pid::KEY_HASH, k));
    }
    if e.kind != ChangeKind::Alive {
        params.push((pid::STATUS_INFO, &si));
    }
    if let Some(r) = &rsi {
        params.push((PID_RELATED_SAMPLE_IDENTITY, r));
        params.push((PID_FASTDDS_RELATED_SAMPLE_IDENTITY, r));
    }
    let mut out = Vec::new();
    ParameterList::write(&params, true, &mut out);
    Some(out)
}

/// What a user sample's inline QoS says: key hash, status, related sample.
pub(super) type InlineInfo = (Option<KeyHash>, Option<StatusInfo>, Option<SampleIdentity>);

/// `PID_KEY_HASH`, `PID_STATUS_INFO` and `PID_RELATED_SAMPLE_IDENTITY` from
/// inline QoS (vendor PIDs skipped, except Fast DDS's related sample
/// identity when the sender is eProsima's).
pub(super) fn inline_info(qos: Option<&[u8]>, little: bool, vendor: VendorId) -> InlineInfo {
    let Some(list) = qos
        .and_then(|q| ParameterList::parse(q, little).ok())
        .map(|l| l.0)
    else {
        return (None, None, None);
    };
    let (mut key, mut status, mut related) = (None, None, None);
    for p in &list.params {
        if p.pid & !PID_MUST_UNDERSTAND == PID_FASTDDS_RELATED_SAMPLE_IDENTITY
            && vendor == VENDOR_EPROSIMA
        {
            related = related.or_else(|| SampleIdentity::from_bytes(p.value, little));
            continue;
        }
        if p.pid & PID_VENDOR_SPECIFIC != 0 {
            continue;
        }
        if p.pid & !PID_MUST_UNDERSTAND == PID_RELATED_SAMPLE_IDENTITY {
            related = SampleIdentity::from_bytes(p.value, little).or(related);
            continue;
        }
        match p.pid & !PID_MUST_UNDERSTAND {
            pid::KEY_HASH => {
                key = p
                    .value
                    .get(..16)
                    .and_then(|s| <[u8; 16]>::try_from(s).ok())
                    .map(KeyHash)
            }
            pid::STATUS_INFO => status = StatusInfo::parse(p.value),
            _ => {}
        }
    }
    (key, status, related)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn envelopes_round_trip() {
        let k = KeyHash([3; 16]);
        let t = Time {
            seconds: 5,
            fraction: 6,
        };
        let e = envelope(ChangeKind::Unregistered, Some(k), Some(t), b"abc");
        let o = open(&e);
        assert_eq!(
            (o.kind, o.key_hash, o.ts, o.data),
            (ChangeKind::Unregistered, Some(k), Some(t), &b"abc"[..])
        );
        let e = envelope(ChangeKind::Alive, None, None, b"");
        let o = open(&e);
        assert_eq!(
            (o.kind, o.key_hash, o.ts, o.data),
            (ChangeKind::Alive, None, None, &b""[..])
        );
        assert!(open(b"short").data.is_empty());
        // with a related sample identity (a reply): the longer trailer
        let r = SampleIdentity {
            writer: Guid::from_bytes([9; 16]),
            sequence_number: SequenceNumber(1 << 33 | 5),
        };
        let e = envelope_with(
            ChangeKind::Alive,
            Some(k),
            Some(t),
            Some(r),
            Cow::Borrowed(b"reply"),
        );
        let o = open(&e);
        assert_eq!(
            (o.related, o.key_hash, o.data),
            (Some(r), Some(k), &b"reply"[..])
        );
        for b in 0..4 {
            let k = ChangeKind::from_bits(b);
            assert_eq!(ChangeKind::from_status(k.status_info()), k);
        }
    }

    /// Owned data with room for the trailer becomes the envelope as it is
    /// (what a publisher's CDR buffer gives); without room it still opens
    /// to the same data.
    #[test]
    fn owned_data_with_room_becomes_the_envelope() {
        use crate::cdr::{Encoding, Extensibility, Writer};
        let mut w = Writer::with_header(Encoding::Xcdr1Le, Extensibility::Final);
        w.write_u32(70_000);
        w.write_bytes(&[7; 70_000]);
        let sample = w.into_vec();
        assert!(sample.capacity() - sample.len() >= ENVELOPE_ROOM);
        let (at, len) = (sample.as_ptr(), sample.len());
        let e = envelope_with(ChangeKind::Alive, None, None, None, Cow::Owned(sample));
        assert_eq!(e.as_ptr(), at, "not copied");
        assert_eq!(data_len(&e), len);
        let mut exact = vec![1u8, 2, 3];
        exact.shrink_to_fit();
        let e = envelope_with(ChangeKind::Alive, None, None, None, Cow::Owned(exact));
        assert_eq!(open(&e).data, &[1, 2, 3][..]);
    }

    /// A received sample leaves as the buffer it arrived in when nothing
    /// else holds it (the large-sample path copies nothing here), and as a
    /// copy when another reader shares it.
    #[test]
    fn into_data_hands_the_buffer_on() {
        let mut data = Vec::with_capacity(5000 + ENVELOPE_ROOM);
        data.extend((0..5000u32).map(|i| i as u8));
        let at = data.as_ptr();
        let env = envelope_from_vec(data, ChangeKind::Alive, None, None, None);
        let g = Guid::from_bytes([1; 16]);
        let s = ReceivedSample::new(g, g, SequenceNumber(1), env);
        assert_eq!(s.data().len(), 5000);
        let shared = s.clone();
        let copy = shared.into_data();
        assert_ne!(copy.as_ptr(), at);
        let own = s.into_data();
        assert_eq!(own.as_ptr(), at, "the buffer was copied");
        assert_eq!(own, copy);
        assert_eq!(own[4999], (4999u32 as u8));
    }
}
