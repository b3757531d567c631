//! RTPS messages and submessages (DDSI-RTPS 2.5 §8.3, §9.4).

use super::types::{
    Cursor, EntityId, FragmentNumberSet, GuidPrefix, Locator, Out, ProtocolVersion, SequenceNumber,
    SequenceNumberSet, Time, VendorId,
};
use super::Error;

/// Size of the RTPS message header.
pub const HEADER_SIZE: usize = 20;

/// Submessage ids (§9.4.5.1.1).
pub mod id {
    /// PAD.
    pub const PAD: u8 = 0x01;
    /// ACKNACK.
    pub const ACKNACK: u8 = 0x06;
    /// HEARTBEAT.
    pub const HEARTBEAT: u8 = 0x07;
    /// GAP.
    pub const GAP: u8 = 0x08;
    /// INFO_TS.
    pub const INFO_TS: u8 = 0x09;
    /// INFO_SRC.
    pub const INFO_SRC: u8 = 0x0c;
    /// INFO_REPLY_IP4.
    pub const INFO_REPLY_IP4: u8 = 0x0d;
    /// INFO_DST.
    pub const INFO_DST: u8 = 0x0e;
    /// INFO_REPLY.
    pub const INFO_REPLY: u8 = 0x0f;
    /// NACK_FRAG.
    pub const NACK_FRAG: u8 = 0x12;
    /// HEARTBEAT_FRAG.
    pub const HEARTBEAT_FRAG: u8 = 0x13;
    /// DATA.
    pub const DATA: u8 = 0x15;
    /// DATA_FRAG.
    pub const DATA_FRAG: u8 = 0x16;
}

/// The 20-byte message header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Header {
    /// Protocol version (2.1–2.5 accepted).
    pub version: ProtocolVersion,
    /// Sender's vendor.
    pub vendor: VendorId,
    /// Sender's participant.
    pub guid_prefix: GuidPrefix,
}

impl Header {
    /// Parses the header; only major version 2 is accepted.
    pub fn parse(b: &[u8]) -> Result<Header, Error> {
        if b.len() < HEADER_SIZE {
            return Err(Error::Truncated {
                offset: 0,
                needed: HEADER_SIZE,
                remaining: b.len(),
            });
        }
        if &b[..4] != b"RTPS" {
            return Err(Error::BadMagic([b[0], b[1], b[2], b[3]]));
        }
        let version = ProtocolVersion {
            major: b[4],
            minor: b[5],
        };
        if version.major != 2 {
            return Err(Error::UnsupportedVersion(version));
        }
        let mut p = [0; 12];
        p.copy_from_slice(&b[8..20]);
        Ok(Header {
            version,
            vendor: VendorId([b[6], b[7]]),
            guid_prefix: GuidPrefix(p),
        })
    }

    /// Appends the header.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(b"RTPS");
        out.push(self.version.major);
        out.push(self.version.minor);
        out.extend_from_slice(&self.vendor.0);
        out.extend_from_slice(&self.guid_prefix.0);
    }
}

/// DATA (§8.3.7.2): one sample or a key/dispose/unregister.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Data<'a> {
    /// Reader addressed (`ENTITYID_UNKNOWN` = every matched reader).
    pub reader_id: EntityId,
    /// Writer.
    pub writer_id: EntityId,
    /// The sample's sequence number.
    pub writer_sn: SequenceNumber,
    /// Inline QoS parameter list bytes (Q flag), in the submessage's byte order.
    pub inline_qos: Option<&'a [u8]>,
    /// Serialized payload (D flag: data; K flag: key).
    pub payload: Option<&'a [u8]>,
    /// K flag: the payload is the serialized key.
    pub key: bool,
    /// N flag: non-standard payload.
    pub non_standard: bool,
}

/// DATA_FRAG (§8.3.7.3): some fragments of a sample.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataFrag<'a> {
    /// Reader addressed.
    pub reader_id: EntityId,
    /// Writer.
    pub writer_id: EntityId,
    /// The sample's sequence number.
    pub writer_sn: SequenceNumber,
    /// First fragment in this submessage (1-based).
    pub fragment_starting_num: u32,
    /// Number of fragments in this submessage.
    pub fragments_in_submessage: u16,
    /// Size of every fragment but the last.
    pub fragment_size: u16,
    /// Size of the whole serialized sample.
    pub sample_size: u32,
    /// Inline QoS parameter list bytes (Q flag).
    pub inline_qos: Option<&'a [u8]>,
    /// The fragments' bytes.
    pub payload: &'a [u8],
    /// K flag: the sample is a serialized key.
    pub key: bool,
    /// N flag: non-standard payload.
    pub non_standard: bool,
}

/// HEARTBEAT (§8.3.7.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Heartbeat {
    /// Reader addressed.
    pub reader_id: EntityId,
    /// Writer.
    pub writer_id: EntityId,
    /// First available sequence number.
    pub first_sn: SequenceNumber,
    /// Last sequence number written.
    pub last_sn: SequenceNumber,
    /// Counter, incremented per heartbeat.
    pub count: i32,
    /// F flag: no response required.
    pub final_flag: bool,
    /// L flag: liveliness only.
    pub liveliness: bool,
}

/// ACKNACK (§8.3.7.1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AckNack {
    /// Reader.
    pub reader_id: EntityId,
    /// Writer addressed.
    pub writer_id: EntityId,
    /// Everything below `base` is acknowledged; set bits are missing.
    pub reader_sn_state: SequenceNumberSet,
    /// Counter.
    pub count: i32,
    /// F flag: the reader does not expect a heartbeat in reply.
    pub final_flag: bool,
}

/// GAP (§8.3.7.4): sequence numbers that are irrelevant to the reader.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Gap {
    /// Reader addressed.
    pub reader_id: EntityId,
    /// Writer.
    pub writer_id: EntityId,
    /// First irrelevant sequence number.
    pub gap_start: SequenceNumber,
    /// `[gap_start, gap_list.base)` is irrelevant, and so are the members of the list.
    pub gap_list: SequenceNumberSet,
    /// Any bytes after the list (RTPS 2.4+ group info / filtered count).
    pub extra: Vec<u8>,
}

/// HEARTBEAT_FRAG (§8.3.7.6).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatFrag {
    /// Reader addressed.
    pub reader_id: EntityId,
    /// Writer.
    pub writer_id: EntityId,
    /// Sample.
    pub writer_sn: SequenceNumber,
    /// Highest fragment number available.
    pub last_fragment_num: u32,
    /// Counter.
    pub count: i32,
}

/// NACK_FRAG (§8.3.7.7).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NackFrag {
    /// Reader.
    pub reader_id: EntityId,
    /// Writer addressed.
    pub writer_id: EntityId,
    /// Sample.
    pub writer_sn: SequenceNumber,
    /// Missing fragments.
    pub fragment_number_state: FragmentNumberSet,
    /// Counter.
    pub count: i32,
}

/// INFO_SRC (§8.3.7.9).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InfoSrc {
    /// Protocol version of the source.
    pub version: ProtocolVersion,
    /// Vendor of the source.
    pub vendor: VendorId,
    /// Participant the following submessages come from.
    pub guid_prefix: GuidPrefix,
}

/// INFO_REPLY (§8.3.7.11): where to send replies.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InfoReply {
    /// Unicast reply locators.
    pub unicast: Vec<Locator>,
    /// Multicast reply locators (M flag).
    pub multicast: Option<Vec<Locator>>,
}

/// One submessage.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Submessage<'a> {
    /// DATA.
    Data(Data<'a>),
    /// DATA_FRAG.
    DataFrag(DataFrag<'a>),
    /// HEARTBEAT.
    Heartbeat(Heartbeat),
    /// HEARTBEAT_FRAG.
    HeartbeatFrag(HeartbeatFrag),
    /// ACKNACK.
    AckNack(AckNack),
    /// NACK_FRAG.
    NackFrag(NackFrag),
    /// GAP.
    Gap(Gap),
    /// INFO_TS; `None` when the I flag invalidates the timestamp.
    InfoTs(Option<Time>),
    /// INFO_DST.
    InfoDst(GuidPrefix),
    /// INFO_SRC.
    InfoSrc(InfoSrc),
    /// INFO_REPLY.
    InfoReply(InfoReply),
    /// PAD.
    Pad,
    /// A submessage this implementation does not interpret (vendor ids
    /// 0x80–0xff, unknown standard ids, INFO_REPLY_IP4): kept, skipped by length.
    Unknown {
        /// Submessage id.
        id: u8,
        /// Flags.
        flags: u8,
        /// Body.
        body: &'a [u8],
    },
}

/// A parsed RTPS message: header plus submessages, borrowing the datagram.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message<'a> {
    /// The header.
    pub header: Header,
    /// The submessages in order.
    pub submessages: Vec<Submessage<'a>>,
    /// The byte order each submessage was received in (its E flag), used
    /// again by [`Message::to_vec`] so that opaque parts (inline QoS) stay
    /// valid; a missing entry means little-endian, what every peer sends.
    pub little_endian: Vec<bool>,
}

const FLAG_E: u8 = 0x01;

fn opt_flag(flags: u8, bit: u8) -> bool {
    flags & bit != 0
}

impl<'a> Message<'a> {
    /// Parses a datagram. Every length is checked against the datagram;
    /// unknown submessages are skipped by length.
    pub fn parse(b: &'a [u8]) -> Result<Message<'a>, Error> {
        let mut submessages = Vec::new();
        let mut little_endian = Vec::new();
        let header = Self::parse_each(b, |little, sm| {
            submessages.push(sm);
            little_endian.push(little);
        })?;
        Ok(Message {
            header,
            submessages,
            little_endian,
        })
    }

    /// [`Message::parse`] without building a `Message`: each submessage is
    /// handed to `each` with its byte order (true: little-endian) as it is
    /// parsed, so the caller chooses where they go. An error can come after
    /// some submessages were handed over: a caller that must not act on a
    /// malformed datagram collects them and acts once this returns `Ok`.
    pub fn parse_each(
        b: &'a [u8],
        mut each: impl FnMut(bool, Submessage<'a>),
    ) -> Result<Header, Error> {
        let header = Header::parse(b)?;
        let mut pos = HEADER_SIZE;
        while pos < b.len() {
            if b.len() - pos < 4 {
                return Err(Error::Truncated {
                    offset: pos,
                    needed: 4,
                    remaining: b.len() - pos,
                });
            }
            let id = b[pos];
            let flags = b[pos + 1];
            let little = flags & FLAG_E != 0;
            let len_bytes = [b[pos + 2], b[pos + 3]];
            let len = if little {
                u16::from_le_bytes(len_bytes)
            } else {
                u16::from_be_bytes(len_bytes)
            } as usize;
            let body_start = pos + 4;
            // octetsToNextHeader 0: the submessage extends to the end of the
            // message (§9.4.5.1.3), except for PAD and INFO_TS where 0 is a real length.
            let body_end = if len == 0 && id != id::PAD && id != id::INFO_TS {
                b.len()
            } else {
                body_start + len
            };
            if body_end > b.len() {
                return Err(Error::Truncated {
                    offset: body_start,
                    needed: len,
                    remaining: b.len() - body_start,
                });
            }
            let body = &b[body_start..body_end];
            each(little, parse_submessage(id, flags, body, body_start)?);
            pos = body_end;
        }
        Ok(header)
    }

    /// A message to send: submessages written little-endian.
    pub fn new(header: Header, submessages: Vec<Submessage<'a>>) -> Self {
        Message {
            header,
            submessages,
            little_endian: Vec::new(),
        }
    }

    /// Encodes the message, each submessage in its byte order (see
    /// [`Message::little_endian`]).
    pub fn to_vec(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(256);
        self.header.write(&mut out);
        for (i, s) in self.submessages.iter().enumerate() {
            s.write(&mut out, self.little_endian.get(i).copied().unwrap_or(true));
        }
        out
    }
}

fn parse_submessage<'a>(
    id: u8,
    flags: u8,
    body: &'a [u8],
    offset: usize,
) -> Result<Submessage<'a>, Error> {
    let mut c = Cursor::new(body, flags & FLAG_E != 0, offset);
    let sm = match id {
        id::DATA => {
            c.u16()?; // extraFlags
            let to_inline_qos = c.u16()? as usize;
            let reader_id = c.entity()?;
            let writer_id = c.entity()?;
            let writer_sn = c.sn()?;
            // octetsToInlineQos counts from the byte after itself (16 bytes so far)
            skip_to(&mut c, 4 + to_inline_qos, "DATA octetsToInlineQos")?;
            let inline_qos = if opt_flag(flags, 0x02) {
                Some(parameter_list_bytes(&mut c)?)
            } else {
                None
            };
            let key = opt_flag(flags, 0x08);
            let payload = (opt_flag(flags, 0x04) || key).then(|| c.rest());
            Submessage::Data(Data {
                reader_id,
                writer_id,
                writer_sn,
                inline_qos,
                payload,
                key,
                non_standard: opt_flag(flags, 0x10),
            })
        }
        id::DATA_FRAG => {
            c.u16()?;
            let to_inline_qos = c.u16()? as usize;
            let reader_id = c.entity()?;
            let writer_id = c.entity()?;
            let writer_sn = c.sn()?;
            let fragment_starting_num = c.u32()?;
            let fragments_in_submessage = c.u16()?;
            let fragment_size = c.u16()?;
            let sample_size = c.u32()?;
            skip_to(&mut c, 4 + to_inline_qos, "DATA_FRAG octetsToInlineQos")?;
            let inline_qos = if opt_flag(flags, 0x02) {
                Some(parameter_list_bytes(&mut c)?)
            } else {
                None
            };
            if fragment_starting_num == 0 || (fragment_size == 0 && sample_size > 0) {
                return Err(Error::Invalid {
                    offset,
                    what: "DATA_FRAG",
                    detail: format!(
                        "fragmentStartingNum {fragment_starting_num}, fragmentSize {fragment_size}"
                    ),
                });
            }
            Submessage::DataFrag(DataFrag {
                reader_id,
                writer_id,
                writer_sn,
                fragment_starting_num,
                fragments_in_submessage,
                fragment_size,
                sample_size,
                inline_qos,
                payload: c.rest(),
                key: opt_flag(flags, 0x04),
                non_standard: opt_flag(flags, 0x08),
            })
        }
        id::HEARTBEAT => Submessage::Heartbeat(Heartbeat {
            reader_id: c.entity()?,
            writer_id: c.entity()?,
            first_sn: c.sn()?,
            last_sn: c.sn()?,
            count: c.i32()?,
            final_flag: opt_flag(flags, 0x02),
            liveliness: opt_flag(flags, 0x04),
        }),
        id::HEARTBEAT_FRAG => Submessage::HeartbeatFrag(HeartbeatFrag {
            reader_id: c.entity()?,
            writer_id: c.entity()?,
            writer_sn: c.sn()?,
            last_fragment_num: c.u32()?,
            count: c.i32()?,
        }),
        id::ACKNACK => Submessage::AckNack(AckNack {
            reader_id: c.entity()?,
            writer_id: c.entity()?,
            reader_sn_state: c.sn_set()?,
            count: c.i32()?,
            final_flag: opt_flag(flags, 0x02),
        }),
        id::NACK_FRAG => Submessage::NackFrag(NackFrag {
            reader_id: c.entity()?,
            writer_id: c.entity()?,
            writer_sn: c.sn()?,
            fragment_number_state: c.frag_set()?,
            count: c.i32()?,
        }),
        id::GAP => Submessage::Gap(Gap {
            reader_id: c.entity()?,
            writer_id: c.entity()?,
            gap_start: c.sn()?,
            gap_list: c.sn_set()?,
            extra: c.rest().to_vec(),
        }),
        id::INFO_TS => {
            if opt_flag(flags, 0x02) {
                Submessage::InfoTs(None)
            } else {
                Submessage::InfoTs(Some(c.time()?))
            }
        }
        id::INFO_DST => Submessage::InfoDst(c.prefix()?),
        id::INFO_SRC => {
            c.u32()?; // unused
            let v = c.take(2)?;
            let vendor = c.take(2)?;
            Submessage::InfoSrc(InfoSrc {
                version: ProtocolVersion {
                    major: v[0],
                    minor: v[1],
                },
                vendor: VendorId([vendor[0], vendor[1]]),
                guid_prefix: c.prefix()?,
            })
        }
        id::INFO_REPLY => {
            let unicast = locator_list(&mut c)?;
            let multicast = if opt_flag(flags, 0x02) {
                Some(locator_list(&mut c)?)
            } else {
                None
            };
            Submessage::InfoReply(InfoReply { unicast, multicast })
        }
        id::PAD => Submessage::Pad,
        _ => Submessage::Unknown { id, flags, body },
    };
    Ok(sm)
}

fn skip_to(c: &mut Cursor<'_>, target: usize, what: &'static str) -> Result<(), Error> {
    if target < c.pos {
        return Err(Error::Invalid {
            offset: c.base + c.pos,
            what,
            detail: format!("points back into the fixed fields ({target} < {})", c.pos),
        });
    }
    c.take(target - c.pos)?;
    Ok(())
}

/// Returns the bytes of a parameter list up to and including its sentinel.
fn parameter_list_bytes<'a>(c: &mut Cursor<'a>) -> Result<&'a [u8], Error> {
    let start = c.pos;
    loop {
        let pid = c.u16()?;
        let len = c.u16()? as usize;
        c.take(len)?;
        if pid == super::parameter::PID_SENTINEL {
            break;
        }
    }
    Ok(&c.buf[start..c.pos])
}

fn locator_list(c: &mut Cursor<'_>) -> Result<Vec<Locator>, Error> {
    let offset = c.base + c.pos;
    let n = c.u32()? as usize;
    if n.saturating_mul(24) > c.remaining() {
        return Err(Error::Invalid {
            offset,
            what: "LocatorList",
            detail: format!("{n} locators in {} bytes", c.remaining()),
        });
    }
    (0..n).map(|_| c.locator()).collect()
}

impl Submessage<'_> {
    /// The number of bytes [`Submessage::write`] appends (header included),
    /// without writing them: lets a sender decide whether a submessage still
    /// fits in the datagram it is filling.
    pub fn encoded_len(&self) -> usize {
        let words =
            |num_bits: u32, bitmap: &[u32]| 4 * bitmap.len().min(num_bits.div_ceil(32) as usize);
        let opt = |b: Option<&[u8]>| b.map_or(0, <[u8]>::len);
        4 + match self {
            Submessage::Data(d) => 20 + opt(d.inline_qos) + opt(d.payload),
            Submessage::DataFrag(d) => 32 + opt(d.inline_qos) + d.payload.len(),
            Submessage::Heartbeat(_) => 28,
            Submessage::HeartbeatFrag(_) => 24,
            Submessage::AckNack(a) => {
                8 + 12 + words(a.reader_sn_state.num_bits, &a.reader_sn_state.bitmap) + 4
            }
            Submessage::NackFrag(n) => {
                8 + 8
                    + 8
                    + words(
                        n.fragment_number_state.num_bits,
                        &n.fragment_number_state.bitmap,
                    )
                    + 4
            }
            Submessage::Gap(g) => {
                8 + 8 + 12 + words(g.gap_list.num_bits, &g.gap_list.bitmap) + g.extra.len()
            }
            Submessage::InfoTs(Some(_)) => 8,
            Submessage::InfoTs(None) | Submessage::Pad => 0,
            Submessage::InfoDst(_) => 12,
            Submessage::InfoSrc(_) => 20,
            Submessage::InfoReply(r) => {
                4 + 24 * r.unicast.len() + r.multicast.as_ref().map_or(0, |m| 4 + 24 * m.len())
            }
            Submessage::Unknown { body, .. } => body.len(),
        }
    }

    /// Appends the submessage (header and body) in the given byte order.
    /// Opaque parts (inline QoS bytes, [`Submessage::Unknown`] bodies) are
    /// copied as they are: they must already be in that byte order.
    pub fn write(&self, out: &mut Vec<u8>, little: bool) {
        let start = out.len();
        out.extend_from_slice(&[0, 0, 0, 0]);
        let mut o = Out {
            buf: &mut *out,
            little,
        };
        let e = if little { FLAG_E } else { 0 };
        let (id, flags) = match self {
            Submessage::Data(d) => {
                o.u16(0);
                o.u16(16);
                o.bytes(&d.reader_id.0);
                o.bytes(&d.writer_id.0);
                o.sn(d.writer_sn);
                if let Some(q) = d.inline_qos {
                    o.bytes(q);
                }
                if let Some(p) = d.payload {
                    o.bytes(p);
                }
                let mut f = e;
                if d.inline_qos.is_some() {
                    f |= 0x02;
                }
                if d.payload.is_some() && !d.key {
                    f |= 0x04;
                }
                if d.key {
                    f |= 0x08;
                }
                if d.non_standard {
                    f |= 0x10;
                }
                (id::DATA, f)
            }
            Submessage::DataFrag(d) => {
                o.u16(0);
                o.u16(28);
                o.bytes(&d.reader_id.0);
                o.bytes(&d.writer_id.0);
                o.sn(d.writer_sn);
                o.u32(d.fragment_starting_num);
                o.u16(d.fragments_in_submessage);
                o.u16(d.fragment_size);
                o.u32(d.sample_size);
                if let Some(q) = d.inline_qos {
                    o.bytes(q);
                }
                o.bytes(d.payload);
                let mut f = e;
                if d.inline_qos.is_some() {
                    f |= 0x02;
                }
                if d.key {
                    f |= 0x04;
                }
                if d.non_standard {
                    f |= 0x08;
                }
                (id::DATA_FRAG, f)
            }
            Submessage::Heartbeat(h) => {
                o.bytes(&h.reader_id.0);
                o.bytes(&h.writer_id.0);
                o.sn(h.first_sn);
                o.sn(h.last_sn);
                o.i32(h.count);
                let mut f = e;
                if h.final_flag {
                    f |= 0x02;
                }
                if h.liveliness {
                    f |= 0x04;
                }
                (id::HEARTBEAT, f)
            }
            Submessage::HeartbeatFrag(h) => {
                o.bytes(&h.reader_id.0);
                o.bytes(&h.writer_id.0);
                o.sn(h.writer_sn);
                o.u32(h.last_fragment_num);
                o.i32(h.count);
                (id::HEARTBEAT_FRAG, e)
            }
            Submessage::AckNack(a) => {
                o.bytes(&a.reader_id.0);
                o.bytes(&a.writer_id.0);
                o.sn_set(&a.reader_sn_state);
                o.i32(a.count);
                (id::ACKNACK, if a.final_flag { e | 0x02 } else { e })
            }
            Submessage::NackFrag(n) => {
                o.bytes(&n.reader_id.0);
                o.bytes(&n.writer_id.0);
                o.sn(n.writer_sn);
                o.frag_set(&n.fragment_number_state);
                o.i32(n.count);
                (id::NACK_FRAG, e)
            }
            Submessage::Gap(g) => {
                o.bytes(&g.reader_id.0);
                o.bytes(&g.writer_id.0);
                o.sn(g.gap_start);
                o.sn_set(&g.gap_list);
                o.bytes(&g.extra);
                (id::GAP, e)
            }
            Submessage::InfoTs(t) => match t {
                Some(t) => {
                    o.time(*t);
                    (id::INFO_TS, e)
                }
                None => (id::INFO_TS, e | 0x02),
            },
            Submessage::InfoDst(p) => {
                o.bytes(&p.0);
                (id::INFO_DST, e)
            }
            Submessage::InfoSrc(s) => {
                o.u32(0);
                o.bytes(&[s.version.major, s.version.minor]);
                o.bytes(&s.vendor.0);
                o.bytes(&s.guid_prefix.0);
                (id::INFO_SRC, e)
            }
            Submessage::InfoReply(r) => {
                o.u32(r.unicast.len() as u32);
                for l in &r.unicast {
                    o.locator(l);
                }
                if let Some(m) = &r.multicast {
                    o.u32(m.len() as u32);
                    for l in m {
                        o.locator(l);
                    }
                }
                (
                    id::INFO_REPLY,
                    if r.multicast.is_some() { e | 0x02 } else { e },
                )
            }
            Submessage::Pad => (id::PAD, e),
            Submessage::Unknown { id, flags, body } => {
                // the body is opaque: keep its flags (and so its byte order)
                o.bytes(body);
                (*id, *flags)
            }
        };
        // A body longer than 65535 bytes can only be the last submessage:
        // octetsToNextHeader 0 means "to the end of the message".
        let len = u16::try_from(out.len() - start - 4).unwrap_or(0);
        out[start] = id;
        out[start + 1] = flags;
        let l = if flags & FLAG_E != 0 {
            len.to_le_bytes()
        } else {
            len.to_be_bytes()
        };
        out[start + 2..start + 4].copy_from_slice(&l);
    }
}
