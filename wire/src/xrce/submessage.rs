//! Submessages (`protocols/xrce.md` §3, §4, §9–§11): the 4-byte header
//! (id, flags, little-endian length) and one payload type per id.

use super::cursor::{Reader, Writer};
use super::object::{AgentRepresentation, ClientRepresentation, ObjectInfo, ObjectVariant};
use super::types::{wire_code, BaseObjectRequest, ResultStatus, StreamId, Time};
use super::{DecodeError, EncodeError};

/// Size of a submessage header.
pub const SUBMESSAGE_HEADER_SIZE: usize = 4;

/// Flag bits of the submessage header (§3). Bit 0 is the endianness of
/// the payload; the others depend on the submessage.
pub mod flags {
    /// Bit 0: payload primitives are little-endian.
    pub const LITTLE_ENDIAN: u8 = 0x01;
    /// CREATE: reuse an existing object whose representation matches.
    pub const REUSE: u8 = 0x02;
    /// CREATE: replace an existing object.
    pub const REPLACE: u8 = 0x04;
    /// FRAGMENT: this is the last fragment.
    pub const LAST_FRAGMENT: u8 = 0x02;
    /// WRITE_DATA / DATA: mask of the data format bits.
    pub const FORMAT_MASK: u8 = 0x0E;
    /// Data format `FORMAT_DATA`: raw serialized data (the only one the agent handles).
    pub const FORMAT_DATA: u8 = 0x00;
    /// Data format `FORMAT_SAMPLE`.
    pub const FORMAT_SAMPLE: u8 = 0x02;
    /// Data format `FORMAT_DATA_SEQ`.
    pub const FORMAT_DATA_SEQ: u8 = 0x08;
    /// Data format `FORMAT_SAMPLE_SEQ`.
    pub const FORMAT_SAMPLE_SEQ: u8 = 0x0A;
    /// Data format `FORMAT_PACKED_SAMPLES`.
    pub const FORMAT_PACKED_SAMPLES: u8 = 0x0E;
}

wire_code! {
    /// Submessage ids (`submessageId`, §4).
    pub enum SubmessageId {
        /// 0x00 CREATE_CLIENT.
        CreateClient = 0x00,
        /// 0x01 CREATE.
        Create = 0x01,
        /// 0x02 GET_INFO.
        GetInfo = 0x02,
        /// 0x03 DELETE.
        Delete = 0x03,
        /// 0x04 STATUS_AGENT.
        StatusAgent = 0x04,
        /// 0x05 STATUS.
        Status = 0x05,
        /// 0x06 INFO.
        Info = 0x06,
        /// 0x07 WRITE_DATA.
        WriteData = 0x07,
        /// 0x08 READ_DATA.
        ReadData = 0x08,
        /// 0x09 DATA.
        Data = 0x09,
        /// 0x0A ACKNACK.
        AckNack = 0x0A,
        /// 0x0B HEARTBEAT.
        Heartbeat = 0x0B,
        /// 0x0C RESET.
        Reset = 0x0C,
        /// 0x0D FRAGMENT.
        Fragment = 0x0D,
        /// 0x0E TIMESTAMP.
        Timestamp = 0x0E,
        /// 0x0F TIMESTAMP_REPLY.
        TimestampReply = 0x0F,
    }
}

impl SubmessageId {
    /// The specification's name, e.g. `"CREATE_CLIENT"`.
    pub fn name(self) -> &'static str {
        use SubmessageId::*;
        match self {
            CreateClient => "CREATE_CLIENT",
            Create => "CREATE",
            GetInfo => "GET_INFO",
            Delete => "DELETE",
            StatusAgent => "STATUS_AGENT",
            Status => "STATUS",
            Info => "INFO",
            WriteData => "WRITE_DATA",
            ReadData => "READ_DATA",
            Data => "DATA",
            AckNack => "ACKNACK",
            Heartbeat => "HEARTBEAT",
            Reset => "RESET",
            Fragment => "FRAGMENT",
            Timestamp => "TIMESTAMP",
            TimestampReply => "TIMESTAMP_REPLY",
        }
    }
}

/// CREATE: make an object (creation mode in the flags: [`flags::REUSE`], [`flags::REPLACE`]).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Create {
    /// Request id and the new object's id (the agent ignores its kind nibble).
    pub request: BaseObjectRequest,
    /// What to create.
    pub object: ObjectVariant,
}

/// GET_INFO: ask about an object (the agent: ping and discovery).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GetInfo {
    /// Request id and object.
    pub request: BaseObjectRequest,
    /// `info_mask`: [`GetInfo::CONFIGURATION`] | [`GetInfo::ACTIVITY`].
    pub info_mask: u32,
}

impl GetInfo {
    /// Info mask bit 0: ask for the configuration.
    pub const CONFIGURATION: u32 = 0x1;
    /// Info mask bit 1: ask for the activity.
    pub const ACTIVITY: u32 = 0x2;
}

/// STATUS_AGENT: the agent's answer to CREATE_CLIENT.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct StatusAgent {
    /// Result.
    pub result: ResultStatus,
    /// The agent.
    pub agent: AgentRepresentation,
}

/// STATUS: the result of a CREATE, DELETE or failed READ_DATA.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Status {
    /// The request it answers (id and object echoed).
    pub request: BaseObjectRequest,
    /// Result.
    pub result: ResultStatus,
}

/// INFO: the answer to GET_INFO.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Info {
    /// The request it answers.
    pub request: BaseObjectRequest,
    /// Result.
    pub result: ResultStatus,
    /// Configuration and activity.
    pub info: ObjectInfo,
}

/// WRITE_DATA or DATA: a request and the data, in the format the flags name
/// (only `FORMAT_DATA` is in use: the sample's CDR body without an
/// encapsulation header, up to the end of the submessage).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Data {
    /// WRITE_DATA: a fresh request id and the writer; DATA: the READ_DATA's
    /// request id and the reader.
    pub request: BaseObjectRequest,
    /// The serialized data.
    pub data: Vec<u8>,
}

/// `DataDeliveryControl` of a READ_DATA (all u16).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct DeliveryControl {
    /// `max_samples`; 0xFFFF = unlimited.
    pub max_samples: u16,
    /// `max_elapsed_time` in seconds; 0 = unlimited.
    pub max_elapsed_time: u16,
    /// `max_bytes_per_second`; 0 = unlimited.
    pub max_bytes_per_second: u16,
    /// `min_pace_period` in ms.
    pub min_pace_period: u16,
}

/// READ_DATA: start (or, with all delivery-control fields 0, cancel) delivery.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ReadData {
    /// Request id and the reader, requester or replier.
    pub request: BaseObjectRequest,
    /// `preferred_stream_id`: the stream the agent sends DATA on.
    pub preferred_stream_id: StreamId,
    /// `data_format` (0 = FORMAT_DATA).
    pub data_format: u8,
    /// `content_filter_expression` (the eProsima client never sends one).
    pub content_filter: Option<String>,
    /// `delivery_control`; absent means one sample.
    pub delivery_control: Option<DeliveryControl>,
}

/// ACKNACK (5 bytes): what a reliable stream's receiver is missing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct AckNack {
    /// `first_unacked_seq_num`: everything below is acknowledged.
    pub first_unacked: u16,
    /// `nack_bitmap`, high byte first: `bitmap[1]` bit i ↔ first + i,
    /// `bitmap[0]` bit i ↔ first + 8 + i.
    pub nack_bitmap: [u8; 2],
    /// The reliable stream.
    pub stream_id: StreamId,
}

impl AckNack {
    /// The bitmap as a number whose bit i means `first_unacked + i` is missing.
    pub fn nack_bits(&self) -> u16 {
        u16::from_be_bytes(self.nack_bitmap)
    }

    /// Sets the bitmap from a number whose bit i means `first_unacked + i` is missing.
    pub fn set_nack_bits(&mut self, bits: u16) {
        self.nack_bitmap = bits.to_be_bytes();
    }
}

/// HEARTBEAT (5 bytes): the range a reliable stream's sender still holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Heartbeat {
    /// `first_unacked_seq_nr`.
    pub first_unacked: u16,
    /// `last_unacked_seq_nr`.
    pub last_unacked: u16,
    /// The reliable stream.
    pub stream_id: StreamId,
}

/// TIMESTAMP_REPLY: the agent's times and the client's, echoed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct TimestampReply {
    /// When the agent sent the reply.
    pub transmit: Time,
    /// When the agent received the TIMESTAMP.
    pub receive: Time,
    /// The TIMESTAMP's transmit time.
    pub originate: Time,
}

/// A submessage payload, one variant per [`SubmessageId`].
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Payload {
    /// CREATE_CLIENT.
    CreateClient(ClientRepresentation),
    /// CREATE.
    Create(Create),
    /// GET_INFO.
    GetInfo(GetInfo),
    /// DELETE.
    Delete(BaseObjectRequest),
    /// STATUS_AGENT.
    StatusAgent(StatusAgent),
    /// STATUS.
    Status(Status),
    /// INFO.
    Info(Info),
    /// WRITE_DATA.
    WriteData(Data),
    /// READ_DATA.
    ReadData(ReadData),
    /// DATA.
    Data(Data),
    /// ACKNACK.
    AckNack(AckNack),
    /// HEARTBEAT.
    Heartbeat(Heartbeat),
    /// RESET (empty).
    Reset,
    /// FRAGMENT: a slice of a submessage (header, payload and padding)
    /// split over several messages; see [`Message::reassembled`](super::Message::reassembled).
    Fragment(Vec<u8>),
    /// TIMESTAMP: the client's transmit time.
    Timestamp(Time),
    /// TIMESTAMP_REPLY.
    TimestampReply(TimestampReply),
}

impl Payload {
    /// The submessage id this payload is sent with.
    pub fn id(&self) -> SubmessageId {
        use Payload as P;
        use SubmessageId as I;
        match self {
            P::CreateClient(_) => I::CreateClient,
            P::Create(_) => I::Create,
            P::GetInfo(_) => I::GetInfo,
            P::Delete(_) => I::Delete,
            P::StatusAgent(_) => I::StatusAgent,
            P::Status(_) => I::Status,
            P::Info(_) => I::Info,
            P::WriteData(_) => I::WriteData,
            P::ReadData(_) => I::ReadData,
            P::Data(_) => I::Data,
            P::AckNack(_) => I::AckNack,
            P::Heartbeat(_) => I::Heartbeat,
            P::Reset => I::Reset,
            P::Fragment(_) => I::Fragment,
            P::Timestamp(_) => I::Timestamp,
            P::TimestampReply(_) => I::TimestampReply,
        }
    }

    fn read(id: SubmessageId, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use Payload as P;
        use SubmessageId as I;
        Ok(match id {
            I::CreateClient => P::CreateClient(ClientRepresentation::read(r)?),
            I::Create => P::Create(Create {
                request: BaseObjectRequest::read(r)?,
                object: ObjectVariant::read(r)?,
            }),
            I::GetInfo => P::GetInfo(GetInfo {
                request: BaseObjectRequest::read(r)?,
                info_mask: r.u32("info mask")?,
            }),
            I::Delete => P::Delete(BaseObjectRequest::read(r)?),
            I::StatusAgent => P::StatusAgent(StatusAgent {
                result: ResultStatus::read(r)?,
                agent: AgentRepresentation::read(r)?,
            }),
            I::Status => P::Status(Status {
                request: BaseObjectRequest::read(r)?,
                result: ResultStatus::read(r)?,
            }),
            I::Info => P::Info(Info {
                request: BaseObjectRequest::read(r)?,
                result: ResultStatus::read(r)?,
                info: ObjectInfo::read(r)?,
            }),
            I::WriteData => P::WriteData(read_data(r)?),
            I::Data => P::Data(read_data(r)?),
            I::ReadData => P::ReadData(ReadData {
                request: BaseObjectRequest::read(r)?,
                preferred_stream_id: StreamId(r.u8("preferred stream id")?),
                data_format: r.u8("data format")?,
                content_filter: r.optional("content filter flag", |r| {
                    r.string("content filter expression")
                })?,
                delivery_control: r.optional("delivery control flag", |r| {
                    Ok(DeliveryControl {
                        max_samples: r.u16("max samples")?,
                        max_elapsed_time: r.u16("max elapsed time")?,
                        max_bytes_per_second: r.u16("max bytes per second")?,
                        min_pace_period: r.u16("min pace period")?,
                    })
                })?,
            }),
            I::AckNack => P::AckNack(AckNack {
                first_unacked: r.u16("first unacked sequence number")?,
                nack_bitmap: r.array("nack bitmap")?,
                stream_id: StreamId(r.u8("stream id")?),
            }),
            I::Heartbeat => P::Heartbeat(Heartbeat {
                first_unacked: r.u16("first unacked sequence number")?,
                last_unacked: r.u16("last unacked sequence number")?,
                stream_id: StreamId(r.u8("stream id")?),
            }),
            I::Reset => P::Reset,
            I::Fragment => P::Fragment(r.rest().to_vec()),
            I::Timestamp => P::Timestamp(Time::read(r)?),
            I::TimestampReply => P::TimestampReply(TimestampReply {
                transmit: Time::read(r)?,
                receive: Time::read(r)?,
                originate: Time::read(r)?,
            }),
        })
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        use Payload as P;
        match self {
            P::CreateClient(c) => c.write(w)?,
            P::Create(c) => {
                c.request.write(w);
                c.object.write(w)?;
            }
            P::GetInfo(g) => {
                g.request.write(w);
                w.u32(g.info_mask);
            }
            P::Delete(r) => r.write(w),
            P::StatusAgent(s) => {
                s.result.write(w);
                s.agent.write(w)?;
            }
            P::Status(s) => {
                s.request.write(w);
                s.result.write(w);
            }
            P::Info(i) => {
                i.request.write(w);
                i.result.write(w);
                i.info.write(w)?;
            }
            P::WriteData(d) | P::Data(d) => {
                d.request.write(w);
                w.bytes(&d.data);
            }
            P::ReadData(r) => {
                r.request.write(w);
                w.u8(r.preferred_stream_id.0);
                w.u8(r.data_format);
                w.optional(r.content_filter.as_ref(), |w, s| {
                    w.string("content filter expression", s)
                })?;
                w.optional(r.delivery_control.as_ref(), |w, d| {
                    w.u16(d.max_samples);
                    w.u16(d.max_elapsed_time);
                    w.u16(d.max_bytes_per_second);
                    w.u16(d.min_pace_period);
                    Ok(())
                })?;
            }
            P::AckNack(a) => {
                w.u16(a.first_unacked);
                w.bytes(&a.nack_bitmap);
                w.u8(a.stream_id.0);
            }
            P::Heartbeat(h) => {
                w.u16(h.first_unacked);
                w.u16(h.last_unacked);
                w.u8(h.stream_id.0);
            }
            P::Reset => {}
            P::Fragment(b) => w.bytes(b),
            P::Timestamp(t) => t.write(w),
            P::TimestampReply(t) => {
                t.transmit.write(w);
                t.receive.write(w);
                t.originate.write(w);
            }
        }
        Ok(())
    }
}

fn read_data(r: &mut Reader<'_>) -> Result<Data, DecodeError> {
    Ok(Data {
        request: BaseObjectRequest::read(r)?,
        data: r.rest().to_vec(),
    })
}

/// One submessage: header flags and payload, plus the contents of its
/// padding bytes.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Submessage {
    /// The flags byte as sent: [`flags::LITTLE_ENDIAN`] and the
    /// submessage's own bits. The payload is encoded in the byte order bit
    /// 0 names.
    pub flags: u8,
    /// The payload.
    pub payload: Payload,
    /// Contents of the padding bytes, in wire order: the alignment padding
    /// inside the payload, then the 0–3 bytes that align the next
    /// submessage header to 4. The eProsima client does not clear its
    /// buffers, so these bytes are arbitrary; they are kept for byte-exact
    /// re-encoding. Encoding writes zeros past the end of this list, and
    /// decoding leaves it empty when every padding byte was zero.
    pub padding: Vec<u8>,
}

impl Submessage {
    /// A little-endian submessage with no other flag bits.
    pub fn new(payload: Payload) -> Self {
        Self::with_flags(flags::LITTLE_ENDIAN, payload)
    }

    /// A submessage with these flags.
    pub fn with_flags(flags: u8, payload: Payload) -> Self {
        Submessage {
            flags,
            payload,
            padding: Vec::new(),
        }
    }

    /// The submessage id.
    pub fn id(&self) -> SubmessageId {
        self.payload.id()
    }

    /// Whether the payload is little-endian (flag bit 0).
    pub fn is_little_endian(&self) -> bool {
        self.flags & flags::LITTLE_ENDIAN != 0
    }

    /// WRITE_DATA/DATA: the data format bits (`flags & FORMAT_MASK`).
    pub fn data_format(&self) -> u8 {
        self.flags & flags::FORMAT_MASK
    }

    /// FRAGMENT: whether this is the last fragment.
    pub fn is_last_fragment(&self) -> bool {
        self.flags & flags::LAST_FRAGMENT != 0
    }

    /// Decodes the submessage whose header starts at `buf[offset]`, which
    /// must be 4-aligned relative to `buf[0]`, the start of the message.
    /// Returns it and the offset just past its payload.
    ///
    /// The payload is decoded by its type within the declared length, and
    /// the two must agree (the real peers walk by type, not by length).
    /// WRITE_DATA and DATA with length 0 run to the end of the message when
    /// more than 65535 bytes follow (§10).
    pub fn decode(buf: &[u8], offset: usize) -> Result<(Submessage, usize), DecodeError> {
        let (mut s, end) = Self::decode_untrimmed(buf, offset)?;
        s.trim_padding();
        Ok((s, end))
    }

    /// [`decode`](Self::decode) with every inner padding byte kept, zero or not.
    pub(crate) fn decode_untrimmed(
        buf: &[u8],
        offset: usize,
    ) -> Result<(Submessage, usize), DecodeError> {
        let remaining = buf.len().saturating_sub(offset);
        if remaining < SUBMESSAGE_HEADER_SIZE {
            return Err(DecodeError::Truncated {
                offset,
                what: "submessage header",
                needed: SUBMESSAGE_HEADER_SIZE,
                remaining,
            });
        }
        let raw_id = buf[offset];
        let id = SubmessageId::from_u8(raw_id)
            .ok_or(DecodeError::UnknownSubmessage { offset, id: raw_id })?;
        let flags = buf[offset + 1];
        let declared = usize::from(u16::from_le_bytes([buf[offset + 2], buf[offset + 3]]));
        let start = offset + SUBMESSAGE_HEADER_SIZE;
        let available = buf.len() - start;
        let len = match id {
            SubmessageId::WriteData | SubmessageId::Data
                if declared == 0 && available > usize::from(u16::MAX) =>
            {
                available
            }
            _ => declared,
        };
        if len > available {
            return Err(DecodeError::Truncated {
                offset: start,
                what: "submessage payload",
                needed: len,
                remaining: available,
            });
        }
        let mut r = Reader::new(buf, start, start + len, flags & flags::LITTLE_ENDIAN != 0);
        let payload = Payload::read(id, &mut r)?;
        if r.remaining() != 0 {
            return Err(DecodeError::LengthMismatch {
                offset,
                id,
                declared: len,
                decoded: r.pos() - start,
            });
        }
        let mut s = Submessage::with_flags(flags, payload);
        s.padding = r.padding;
        Ok((s, start + len))
    }

    /// Drops trailing zeros of [`padding`](Self::padding): they encode the same.
    pub(crate) fn trim_padding(&mut self) {
        let keep = self
            .padding
            .iter()
            .rposition(|&b| b != 0)
            .map_or(0, |i| i + 1);
        self.padding.truncate(keep);
    }

    /// Appends the header and payload (no padding) to `out`, whose byte
    /// `origin` is the start of the message; the header must start
    /// 4-aligned from there.
    pub fn encode(&self, out: &mut Vec<u8>, origin: usize) -> Result<(), EncodeError> {
        self.encode_counting(out, origin).map(|_| ())
    }

    /// [`encode`](Self::encode), returning how many padding bytes it wrote.
    pub(crate) fn encode_counting(
        &self,
        out: &mut Vec<u8>,
        origin: usize,
    ) -> Result<usize, EncodeError> {
        let at = out.len();
        out.extend_from_slice(&[self.id() as u8, self.flags, 0, 0]);
        let mut w = Writer::new(out, origin, self.is_little_endian(), &self.padding);
        self.payload.write(&mut w)?;
        let padded = w.padded;
        let len = out.len() - at - SUBMESSAGE_HEADER_SIZE;
        let declared = match u16::try_from(len) {
            Ok(l) => l,
            Err(_) if matches!(self.payload, Payload::WriteData(_) | Payload::Data(_)) => 0,
            Err(_) => {
                out.truncate(at);
                return Err(EncodeError::TooLong {
                    what: self.id().name(),
                    len,
                    max: usize::from(u16::MAX),
                });
            }
        };
        out[at + 2..at + 4].copy_from_slice(&declared.to_le_bytes());
        Ok(padded)
    }
}
