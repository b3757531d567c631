//! The writer liveliness protocol (WLP, RTPS 2.5 §8.4.13): the built-in
//! participant-message endpoints (`ENTITYID_P2P_BUILTIN_PARTICIPANT_MESSAGE_
//! WRITER` 00.02.00.c2 and `_READER` 00.02.00.c7, builtin-endpoint-set
//! bits 10 and 11), the `ParticipantMessageData` they carry, and what
//! asserts the liveliness of a remote writer.
//!
//! # ParticipantMessageData on the wire
//!
//! A keyed, reliable, transient-local topic (Cyclone DDS 11 creates both
//! endpoints with its built-in endpoint QoS, keep-last 1). Its sample, after
//! the 4-byte encapsulation header (`CDR_BE` 00 00 or `CDR_LE` 00 01):
//!
//! | octets | field |
//! |---|---|
//! | 12 | participant GUID prefix (the key, with the kind) |
//! | 4 | kind, as octets: 00 00 00 01 automatic, 00 00 00 02 manual (any endianness) |
//! | 4 | data length, in the encapsulation's endianness |
//! | n | data |
//!
//! Cyclone DDS writes a data length of 1 (one zero octet) and accepts 0;
//! Courier writes 0, so the sample is 24 octets and needs no padding.
//! Fast DDS 2.9 labels the same layout `PL_CDR_LE` (00 03; `PL_CDR_BE`
//! 00 02 on big-endian hosts) though it is no parameter list, and writes a
//! data length of 0 and four more zero octets (28 octets, no key hash in
//! inline QoS); it reads the prefix and kind at their offsets whatever the
//! encapsulation says (its `WLP.cpp` and `WLPListener.cpp`, 2.9.1).
//! Courier takes both labels of each byte order.
//! Cyclone ignores a message whose prefix is not the RTPS sender's, and so
//! does Courier.
//!
//! # What asserts liveliness (DDS 1.4 §2.2.3.11, as Cyclone DDS does it)
//!
//! - AUTOMATIC: anything from the writer's participant — its SPDP, its
//!   participant messages, any submessage of any of its endpoints
//!   ([`Participants::heard`](crate::rtps::matching::Participants::heard)).
//! - MANUAL_BY_PARTICIPANT: a participant message of the manual kind, or
//!   data (or a HEARTBEAT with the liveliness flag) of any writer of that
//!   participant; participant messages of the automatic kind do not.
//! - MANUAL_BY_TOPIC: that writer's data, or a HEARTBEAT of it with the
//!   liveliness flag.
//!
//! Courier sends an automatic message every third of the shortest finite
//! AUTOMATIC lease among its writers (none without one), and a manual one
//! on [`Participant::assert_liveliness`].

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use foldhash::{HashMap, HashMapExt};

use super::change::{envelope, ChangeKind};
use super::{KeyHash, Participant};
use crate::rtps::discovery::{Duration as RtpsDuration, LivelinessKind};
use crate::rtps::reliability::{Reader, Writer};
use crate::rtps::{EntityId, Guid, GuidPrefix, SequenceNumber};

/// `PARTICIPANT_MESSAGE_DATA_KIND_AUTOMATIC_LIVELINESS_UPDATE`.
pub const PMD_KIND_AUTOMATIC: [u8; 4] = [0, 0, 0, 1];
/// `PARTICIPANT_MESSAGE_DATA_KIND_MANUAL_LIVELINESS_UPDATE`.
pub const PMD_KIND_MANUAL: [u8; 4] = [0, 0, 0, 2];

/// The largest data length accepted in a received message (the data is
/// not kept; a longer one is counted as malformed).
const MAX_PMD_DATA: usize = 64 * 1024;

/// A decoded `ParticipantMessageData` (RTPS 2.5 §9.6.2.1), the sample of
/// the writer liveliness protocol's built-in topic, keyed by participant
/// and kind. After the 4-byte encapsulation header (`CDR_BE` 00 00 or
/// `CDR_LE` 00 01; Fast DDS 2.9 labels it `PL_CDR_BE` 00 02 or `PL_CDR_LE`
/// 00 03, with the same layout):
///
/// | octets | field |
/// |---|---|
/// | 12 | participant GUID prefix |
/// | 4 | kind, as octets: 00 00 00 01 automatic, 00 00 00 02 manual |
/// | 4 | data length, in the encapsulation's endianness |
/// | n | data |
///
/// Cyclone DDS 11 writes one zero octet of data; Courier writes none.
/// [`Participant::liveliness_asserted`] says what a received one asserts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParticipantMessage {
    /// The participant it speaks for.
    pub prefix: GuidPrefix,
    /// Its kind octets ([`PMD_KIND_AUTOMATIC`], [`PMD_KIND_MANUAL`], or
    /// another, e.g. vendor-specific, which asserts nothing).
    pub kind: [u8; 4],
    /// Its data (opaque).
    pub data: Vec<u8>,
}

/// Why a participant message did not decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PmdError {
    /// Shorter than header, prefix, kind and length.
    #[error("participant message shorter than its fixed part")]
    Short,
    /// Not CDR (or PL_CDR, as Fast DDS labels it), big or little endian.
    #[error("participant message with encapsulation {0:#06x}, not CDR")]
    Encapsulation(u16),
    /// The data length runs past the end, or past what is accepted.
    #[error("participant message data length {0} runs past its end")]
    Length(u32),
}

impl ParticipantMessage {
    /// The serialized sample, `CDR_LE`, with the encapsulation header.
    pub fn to_payload(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(24 + self.data.len());
        v.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        v.extend_from_slice(&self.prefix.0);
        v.extend_from_slice(&self.kind);
        let len = u32::try_from(self.data.len()).unwrap_or(u32::MAX);
        v.extend_from_slice(&len.to_le_bytes());
        v.extend_from_slice(&self.data);
        v
    }

    /// Decodes a serialized sample (with its encapsulation header): `CDR_BE`
    /// or `CDR_LE`, or the same layout labelled `PL_CDR_BE` / `PL_CDR_LE`
    /// (Fast DDS 2.9). Bounded: the data length is checked against what is
    /// there.
    pub fn from_payload(p: &[u8]) -> Result<Self, PmdError> {
        if p.len() < 24 {
            return Err(PmdError::Short);
        }
        let enc = u16::from_be_bytes([p[0], p[1]]);
        let little = match enc {
            // CDR_BE, and PL_CDR_BE as Fast DDS 2.9 labels it
            0x0000 | 0x0002 => false,
            // CDR_LE, and PL_CDR_LE
            0x0001 | 0x0003 => true,
            e => return Err(PmdError::Encapsulation(e)),
        };
        let mut prefix = [0u8; 12];
        prefix.copy_from_slice(&p[4..16]);
        let mut kind = [0u8; 4];
        kind.copy_from_slice(&p[16..20]);
        let lb = [p[20], p[21], p[22], p[23]];
        let len = if little {
            u32::from_le_bytes(lb)
        } else {
            u32::from_be_bytes(lb)
        };
        let rest = &p[24..];
        let n = len as usize;
        if n > rest.len() || n > MAX_PMD_DATA {
            return Err(PmdError::Length(len));
        }
        Ok(ParticipantMessage {
            prefix: GuidPrefix(prefix),
            kind,
            data: rest[..n].to_vec(),
        })
    }

    /// The instance key hash: the prefix and the kind (16 octets, as the
    /// key is serialized big-endian).
    pub fn key_hash(&self) -> [u8; 16] {
        let mut k = [0u8; 16];
        k[..12].copy_from_slice(&self.prefix.0);
        k[12..].copy_from_slice(&self.kind);
        k
    }
}

/// The participant's WLP state: its built-in pair and the assertions heard.
pub(super) struct Wlp {
    pub(super) writer: Writer,
    /// Remote participant-message readers matched with `writer`.
    pub(super) readers: BTreeSet<Guid>,
    pub(super) reader: Reader,
    /// The automatic message period (a third of the shortest finite
    /// automatic lease of a local writer), and when the next is due.
    period: Option<Duration>,
    next: Option<Instant>,
    /// The sequence numbers of the last message of each kind (keep-last 1
    /// per instance: the older one leaves the history).
    last_auto: Option<SequenceNumber>,
    last_manual: Option<SequenceNumber>,
    /// Per remote participant: the last manual-by-participant assertion.
    manual: HashMap<GuidPrefix, Instant>,
    /// Per remote writer: the last manual-by-topic assertion.
    topic: HashMap<Guid, Instant>,
    /// Some remote writer has a finite manual lease: data is recorded as
    /// an assertion (not before, to keep the data path free of it).
    recording: bool,
    /// Participant messages that did not decode or spoke for another
    /// participant than their sender.
    pub(super) ignored: u64,
}

impl Wlp {
    pub(super) fn new(prefix: GuidPrefix, heartbeat: Duration, max_out_of_order: usize) -> Self {
        let g = Guid {
            prefix,
            entity: EntityId::P2P_MESSAGE_WRITER,
        };
        Wlp {
            writer: Writer::new(g, true, None, 16, heartbeat).retain_acked(true),
            readers: BTreeSet::new(),
            reader: Reader::new(true, max_out_of_order),
            period: None,
            next: None,
            last_auto: None,
            last_manual: None,
            manual: HashMap::new(),
            topic: HashMap::new(),
            recording: false,
            ignored: 0,
        }
    }

    pub(super) fn poll_timeout(&self) -> [Option<Instant>; 3] {
        [
            self.next,
            self.writer.poll_timeout(),
            self.reader.poll_timeout(),
        ]
    }

    pub(super) fn forget_writer(&mut self, writer: Guid) {
        self.topic.remove(&writer);
    }

    pub(super) fn forget_participant(&mut self, prefix: GuidPrefix) {
        self.manual.remove(&prefix);
        self.topic.retain(|g, _| g.prefix != prefix);
    }
}

fn finite(d: RtpsDuration) -> Option<Duration> {
    d.to_std().filter(|d| !d.is_zero())
}

impl Participant {
    /// When the liveliness of remote writer `writer`, of liveliness `kind`,
    /// was last asserted as DDS counts it for that kind (AUTOMATIC: anything
    /// from its participant; MANUAL_BY_PARTICIPANT: a participant message
    /// of the manual kind, or data or a liveliness HEARTBEAT of any writer
    /// of its participant; MANUAL_BY_TOPIC: its own data or liveliness
    /// HEARTBEAT); `None` when nothing was heard since it was known.
    /// Without a record the caller takes the time it matched.
    pub fn liveliness_asserted(&self, writer: Guid, kind: LivelinessKind) -> Option<Instant> {
        match kind {
            LivelinessKind::Automatic => self.participants.heard(&writer.prefix),
            LivelinessKind::ManualByParticipant => self.wlp.manual.get(&writer.prefix).copied(),
            LivelinessKind::ManualByTopic => self.wlp.topic.get(&writer).copied(),
        }
    }

    /// Asserts the liveliness of every MANUAL_BY_PARTICIPANT writer of this
    /// participant: a participant message of the manual kind to every
    /// matched participant-message reader (DDS's
    /// `DomainParticipant::assert_liveliness`).
    pub fn assert_liveliness(&mut self, now: Instant) {
        self.touch();
        if self.closed {
            return;
        }
        self.write_pmd(PMD_KIND_MANUAL, now);
        self.flush(now);
    }

    /// Asserts the liveliness of local writer `writer` without data: a
    /// HEARTBEAT with the liveliness flag to its matched readers (what
    /// asserts a MANUAL_BY_TOPIC writer); for a MANUAL_BY_PARTICIPANT one,
    /// also a manual participant message. False for an unknown writer.
    pub fn assert_writer_liveliness(&mut self, writer: Guid, now: Instant) -> bool {
        self.touch();
        if self.closed || !self.is_local(writer) {
            return false;
        }
        let Some(lw) = self.writers.get_mut(&writer.entity) else {
            return false;
        };
        let by_participant = lw.data.qos.liveliness.0 == LivelinessKind::ManualByParticipant;
        lw.writer.assert_liveliness();
        if by_participant {
            self.write_pmd(PMD_KIND_MANUAL, now);
        }
        self.flush(now);
        true
    }

    /// Participant messages received that were ignored (malformed,
    /// speaking for another participant than their sender, or from a
    /// participant not known by its SPDP).
    pub fn pmd_ignored(&self) -> u64 {
        self.wlp.ignored
    }

    /// Writes one participant message of `kind`; the previous one of that
    /// kind leaves the history.
    fn write_pmd(&mut self, kind: [u8; 4], now: Instant) {
        let m = ParticipantMessage {
            prefix: self.cfg.guid_prefix,
            kind,
            data: Vec::new(),
        };
        let env = envelope(
            ChangeKind::Alive,
            Some(KeyHash(m.key_hash())),
            Some(self.wall(now)),
            &m.to_payload(),
        );
        let Some(sn) = self.wlp.writer.write(env, now) else {
            return;
        };
        let old = if kind == PMD_KIND_MANUAL {
            self.wlp.last_manual.replace(sn)
        } else {
            self.wlp.last_auto.replace(sn)
        };
        if let Some(old) = old {
            self.wlp.writer.remove(old);
        }
    }

    /// The local writers changed: the automatic message period follows
    /// the shortest finite AUTOMATIC lease among them.
    pub(super) fn wlp_reschedule(&mut self, now: Instant) {
        let period = self
            .writers
            .values()
            .filter(|w| w.data.qos.liveliness.0 == LivelinessKind::Automatic)
            .filter_map(|w| finite(w.data.qos.liveliness.1))
            .min()
            .map(|l| (l / 3).max(Duration::from_millis(1)));
        if period != self.wlp.period {
            self.wlp.period = period;
            // the first one at once: a reader's lease started at the match
            self.wlp.next = period.map(|_| now);
        }
    }

    /// The automatic message, when due.
    pub(super) fn wlp_timeout(&mut self, now: Instant) {
        if let (Some(next), Some(period)) = (self.wlp.next, self.wlp.period) {
            if next <= now {
                self.write_pmd(PMD_KIND_AUTOMATIC, now);
                self.wlp.next = Some(crate::time::later(now, period));
            }
        }
        self.wlp.writer.handle_timeout(now);
        self.wlp.reader.handle_timeout(now);
    }

    /// A remote writer became known: a finite manual lease turns recording
    /// of data as assertions on.
    pub(super) fn wlp_writer_known(&mut self, kind: LivelinessKind, lease: RtpsDuration) {
        if kind != LivelinessKind::Automatic && finite(lease).is_some() {
            self.wlp.recording = true;
        }
    }

    /// A known remote writer wrote data, or sent a HEARTBEAT with the
    /// liveliness flag: it asserts itself (manual by topic) and its
    /// participant (manual by participant). Writers not announced by SEDP
    /// are not recorded (what is kept stays bounded by what is known).
    pub(super) fn writer_asserted(&mut self, writer: Guid, now: Instant) {
        if self.wlp.recording && self.remote_writers.contains_key(&writer) {
            self.wlp.manual.insert(writer.prefix, now);
            self.wlp.topic.insert(writer, now);
        }
    }

    /// A participant message arrived from `from` (its sender's prefix).
    pub(super) fn on_pmd(&mut self, from: Guid, sn: SequenceNumber, payload: &[u8], now: Instant) {
        let m = match ParticipantMessage::from_payload(payload) {
            Ok(m) => m,
            Err(_) => {
                self.wlp.ignored += 1;
                return;
            }
        };
        // as Cyclone DDS: a message for another participant than its
        // sender, or from a participant not known, asserts nothing
        if m.prefix != from.prefix || self.participants.get(&m.prefix).is_none() {
            self.wlp.ignored += 1;
            return;
        }
        if m.kind == PMD_KIND_MANUAL {
            self.wlp.manual.insert(m.prefix, now);
        }
        // through the reliable reader for its acknowledgements; the
        // content was used above, the sample is dropped in `flush`
        self.wlp
            .reader
            .handle_data(from, sn, envelope(ChangeKind::Alive, None, None, &[]));
    }

    /// Samples the participant-message reader delivered (already used).
    pub(super) fn wlp_drain(&mut self) {
        while self.wlp.reader.poll_sample().is_some() {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_round_trips_and_malformed_ones_are_refused() {
        let m = ParticipantMessage {
            prefix: GuidPrefix([7; 12]),
            kind: PMD_KIND_MANUAL,
            data: vec![0],
        };
        assert_eq!(ParticipantMessage::from_payload(&m.to_payload()), Ok(m));
        assert_eq!(
            ParticipantMessage::from_payload(&[0, 1, 0, 0]),
            Err(PmdError::Short)
        );
        let mut p = ParticipantMessage {
            prefix: GuidPrefix([7; 12]),
            kind: PMD_KIND_AUTOMATIC,
            data: Vec::new(),
        }
        .to_payload();
        p[20] = 1; // data length 1 with no data
        assert_eq!(
            ParticipantMessage::from_payload(&p),
            Err(PmdError::Length(1))
        );
        p[1] = 4;
        assert_eq!(
            ParticipantMessage::from_payload(&p),
            Err(PmdError::Encapsulation(4))
        );
        // big-endian, as Cyclone's own test sends it
        let mut be = vec![0, 0, 0, 0];
        be.extend_from_slice(&[7; 12]);
        be.extend_from_slice(&[0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 0]);
        let m = ParticipantMessage::from_payload(&be).unwrap();
        assert_eq!((m.kind, m.data), (PMD_KIND_MANUAL, vec![0]));
    }

    /// Fast DDS 2.9.1's participant messages, as captured on lo (a manual
    /// one and an automatic one, of two participants): labelled PL_CDR_LE
    /// (00 03), data length 0, four more zero octets. They decode as what
    /// they say.
    #[test]
    fn fast_dds_participant_messages_labelled_pl_cdr_decode() {
        let manual = unhex("00030000010f78fd1256853400000000000000020000000000000000");
        let automatic = unhex("00030000010f78fd1356a1f300000000000000010000000000000000");
        for (p, kind) in [(&manual, PMD_KIND_MANUAL), (&automatic, PMD_KIND_AUTOMATIC)] {
            let mut prefix = [0u8; 12];
            prefix.copy_from_slice(&p[4..16]);
            assert_eq!(
                ParticipantMessage::from_payload(p),
                Ok(ParticipantMessage {
                    prefix: GuidPrefix(prefix),
                    kind,
                    data: Vec::new(),
                })
            );
        }
        // PL_CDR_BE (a big-endian host): the length is big-endian
        let mut be = manual.clone();
        be[1] = 0x02;
        be[23] = 1; // data length 1: one of the four octets that follow
        let m = ParticipantMessage::from_payload(&be).unwrap();
        assert_eq!((m.kind, m.data), (PMD_KIND_MANUAL, vec![0]));
    }

    fn unhex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }
}
