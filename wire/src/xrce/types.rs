//! The small XRCE types submessages are built from: object and request
//! ids, stream ids, client keys, result status, time, locators and
//! properties (`protocols/xrce.md` §4, §5, §11).

use super::cursor::{Reader, Writer};
use super::{DecodeError, EncodeError};

/// `xrce_cookie`: the four bytes `XRCE` that open CLIENT and AGENT representations.
pub const COOKIE: [u8; 4] = *b"XRCE";
/// `xrce_version` 1.0, the only major version the agent accepts.
pub const VERSION: [u8; 2] = [1, 0];
/// `xrce_vendor_id` of eProsima (`01 0F`).
pub const VENDOR_EPROSIMA: [u8; 2] = [0x01, 0x0F];

/// Declares a fieldless `u8` enum of wire codes with `from_u8`.
macro_rules! wire_code {
    ($(#[$m:meta])* pub enum $name:ident { $($(#[$vm:meta])* $v:ident = $n:literal,)* }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name { $($(#[$vm])* $v = $n,)* }

        impl $name {
            /// The value with this code, if there is one.
            pub fn from_u8(v: u8) -> Option<Self> {
                match v {
                    $($n => Some(Self::$v),)*
                    _ => None,
                }
            }
        }
    };
}
pub(crate) use wire_code;

wire_code! {
    /// The kind of an XRCE object: the low 4 bits of an [`ObjectId`] and the
    /// discriminant of [`ObjectVariant`](super::ObjectVariant) (`DDS_XRCE_OBJK_*`).
    pub enum ObjectKind {
        /// `OBJK_PARTICIPANT` (0x1).
        Participant = 0x1,
        /// `OBJK_TOPIC` (0x2).
        Topic = 0x2,
        /// `OBJK_PUBLISHER` (0x3).
        Publisher = 0x3,
        /// `OBJK_SUBSCRIBER` (0x4).
        Subscriber = 0x4,
        /// `OBJK_DATAWRITER` (0x5).
        DataWriter = 0x5,
        /// `OBJK_DATAREADER` (0x6).
        DataReader = 0x6,
        /// `OBJK_REQUESTER` (0x7).
        Requester = 0x7,
        /// `OBJK_REPLIER` (0x8).
        Replier = 0x8,
        /// `OBJK_TYPE` (0xA).
        Type = 0xA,
        /// `OBJK_QOSPROFILE` (0xB).
        QosProfile = 0xB,
        /// `OBJK_APPLICATION` (0xC).
        Application = 0xC,
        /// `OBJK_AGENT` (0xD).
        Agent = 0xD,
        /// `OBJK_CLIENT` (0xE).
        Client = 0xE,
        /// `OBJK_OTHER` (0xF).
        Other = 0xF,
    }
}

/// `ObjectId`: a 12-bit id and a 4-bit kind, two bytes big-endian on the
/// wire (`raw[0] = id >> 4`, `raw[1] = (id & 0xF) << 4 | kind`, §5).
/// The value here is the 16-bit number those two bytes spell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ObjectId(pub u16);

impl ObjectId {
    /// `00 00`: no object.
    pub const INVALID: ObjectId = ObjectId(0x0000);
    /// `FF FD`: the agent.
    pub const AGENT: ObjectId = ObjectId(0xFFFD);
    /// `FF FE`: the client (DELETE of it ends the session).
    pub const CLIENT: ObjectId = ObjectId(0xFFFE);
    /// `FF FF`: the session.
    pub const SESSION: ObjectId = ObjectId(0xFFFF);

    /// The id of object number `id` (12 bits; higher bits are dropped) of `kind`.
    pub fn new(id: u16, kind: ObjectKind) -> Self {
        ObjectId((id << 4) | kind as u16)
    }

    /// The 12-bit object number.
    pub fn id(self) -> u16 {
        self.0 >> 4
    }

    /// The 4-bit kind, as sent.
    pub fn kind_bits(self) -> u8 {
        (self.0 & 0xF) as u8
    }

    /// The kind, if the low 4 bits name one.
    pub fn kind(self) -> Option<ObjectKind> {
        ObjectKind::from_u8(self.kind_bits())
    }

    /// The two bytes on the wire.
    pub fn to_bytes(self) -> [u8; 2] {
        self.0.to_be_bytes()
    }

    pub(crate) fn read(r: &mut Reader<'_>, what: &'static str) -> Result<Self, DecodeError> {
        r.array::<2>(what).map(|b| ObjectId(u16::from_be_bytes(b)))
    }
}

/// `RequestId`: a u16 sent high byte first whatever the endianness flag
/// says. The eProsima client counts from 10 and never reuses 0..=9 (§5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct RequestId(pub u16);

impl RequestId {
    /// 0x0002: DELETE of the client object (logout).
    pub const LOGOUT: RequestId = RequestId(0x0002);
    /// 0x0009: the discovery GET_INFO.
    pub const DISCOVERY: RequestId = RequestId(0x0009);
    /// 0x000A: the ping GET_INFO.
    pub const PING: RequestId = RequestId(0x000A);
}

/// `BaseObjectRequest`: a request id and the object it is about (4 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct BaseObjectRequest {
    /// The request id.
    pub request_id: RequestId,
    /// The object.
    pub object_id: ObjectId,
}

impl BaseObjectRequest {
    /// A request about `object_id`.
    pub fn new(request_id: u16, object_id: ObjectId) -> Self {
        BaseObjectRequest {
            request_id: RequestId(request_id),
            object_id,
        }
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let request_id = RequestId(u16::from_be_bytes(r.array::<2>("request id")?));
        let object_id = ObjectId::read(r, "object id")?;
        Ok(BaseObjectRequest {
            request_id,
            object_id,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) {
        w.bytes(&self.request_id.0.to_be_bytes());
        w.bytes(&self.object_id.to_bytes());
    }
}

/// A stream id (§8): 0 is NONE, 0x01–0x7F best-effort, 0x80–0xFF reliable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct StreamId(pub u8);

impl StreamId {
    /// 0x00: no stream (ACKNACK, HEARTBEAT, TIMESTAMP, GET_INFO, session DELETE).
    pub const NONE: StreamId = StreamId(0x00);
    /// 0x01: the built-in best-effort stream.
    pub const BEST_EFFORT: StreamId = StreamId(0x01);
    /// 0x80: the built-in reliable stream.
    pub const RELIABLE: StreamId = StreamId(0x80);

    /// Best-effort stream number `index` (0..=126).
    pub fn best_effort(index: u8) -> Option<Self> {
        (index < 0x7F).then(|| StreamId(index + 1))
    }

    /// Reliable stream number `index` (0..=127).
    pub fn reliable(index: u8) -> Option<Self> {
        (index < 0x80).then(|| StreamId(index + 0x80))
    }

    /// Whether this is a reliable stream.
    pub fn is_reliable(self) -> bool {
        self.0 >= 0x80
    }

    /// Whether this is a best-effort stream.
    pub fn is_best_effort(self) -> bool {
        (0x01..0x80).contains(&self.0)
    }
}

/// `ClientKey`: four raw bytes, the most significant first (`0xCCCCDDDD`
/// travels as `CC CC DD DD`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ClientKey(pub [u8; 4]);

impl From<u32> for ClientKey {
    fn from(v: u32) -> Self {
        ClientKey(v.to_be_bytes())
    }
}

impl From<ClientKey> for u32 {
    fn from(k: ClientKey) -> u32 {
        u32::from_be_bytes(k.0)
    }
}

/// A result `status` code (§4). Unknown values are kept as they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct StatusCode(pub u8);

impl StatusCode {
    /// 0x00 `STATUS_OK`.
    pub const OK: StatusCode = StatusCode(0x00);
    /// 0x01 `STATUS_OK_MATCHED`: an existing object matched (REUSE).
    pub const OK_MATCHED: StatusCode = StatusCode(0x01);
    /// 0x80 `STATUS_ERR_DDS_ERROR`.
    pub const ERR_DDS_ERROR: StatusCode = StatusCode(0x80);
    /// 0x81 `STATUS_ERR_MISMATCH`.
    pub const ERR_MISMATCH: StatusCode = StatusCode(0x81);
    /// 0x82 `STATUS_ERR_ALREADY_EXISTS`.
    pub const ERR_ALREADY_EXISTS: StatusCode = StatusCode(0x82);
    /// 0x83 `STATUS_ERR_DENIED`.
    pub const ERR_DENIED: StatusCode = StatusCode(0x83);
    /// 0x84 `STATUS_ERR_UNKNOWN_REFERENCE`.
    pub const ERR_UNKNOWN_REFERENCE: StatusCode = StatusCode(0x84);
    /// 0x85 `STATUS_ERR_INVALID_DATA`.
    pub const ERR_INVALID_DATA: StatusCode = StatusCode(0x85);
    /// 0x86 `STATUS_ERR_INCOMPATIBLE`.
    pub const ERR_INCOMPATIBLE: StatusCode = StatusCode(0x86);
    /// 0x87 `STATUS_ERR_RESOURCES`.
    pub const ERR_RESOURCES: StatusCode = StatusCode(0x87);

    /// Whether the code means success (`OK` or `OK_MATCHED`).
    pub fn is_ok(self) -> bool {
        self.0 < 0x80
    }

    /// The spec's name (`STATUS_ERR_ALREADY_EXISTS`…), or `STATUS_UNKNOWN`.
    pub fn name(self) -> &'static str {
        match self.0 {
            0x00 => "STATUS_OK",
            0x01 => "STATUS_OK_MATCHED",
            0x80 => "STATUS_ERR_DDS_ERROR",
            0x81 => "STATUS_ERR_MISMATCH",
            0x82 => "STATUS_ERR_ALREADY_EXISTS",
            0x83 => "STATUS_ERR_DENIED",
            0x84 => "STATUS_ERR_UNKNOWN_REFERENCE",
            0x85 => "STATUS_ERR_INVALID_DATA",
            0x86 => "STATUS_ERR_INCOMPATIBLE",
            0x87 => "STATUS_ERR_RESOURCES",
            _ => "STATUS_UNKNOWN",
        }
    }
}

impl std::fmt::Display for StatusCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({:#04x})", self.name(), self.0)
    }
}

/// `ResultStatus`: a status code and an implementation-specific byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ResultStatus {
    /// The status code.
    pub status: StatusCode,
    /// `implementation_status`; the agent puts 1 in a ping reply when the
    /// sender has a session, 0 otherwise.
    pub implementation_status: u8,
}

impl ResultStatus {
    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(ResultStatus {
            status: StatusCode(r.u8("result status")?),
            implementation_status: r.u8("implementation status")?,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) {
        w.u8(self.status.0);
        w.u8(self.implementation_status);
    }
}

/// `Time_t`: seconds and nanoseconds, as TIMESTAMP and TIMESTAMP_REPLY carry it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Time {
    /// Seconds.
    pub seconds: i32,
    /// Nanoseconds.
    pub nanoseconds: u32,
}

impl Time {
    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(Time {
            seconds: r.i32("time seconds")?,
            nanoseconds: r.u32("time nanoseconds")?,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) {
        w.i32(self.seconds);
        w.u32(self.nanoseconds);
    }
}

/// `Property`: a name/value pair of a CLIENT or AGENT representation
/// (`uxr_sm`, `uxr_hl`).
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct Property {
    /// Name.
    pub name: String,
    /// Value.
    pub value: String,
}

/// `PropertySeq` as an optional: a boolean, then a u32 count and the pairs.
pub(crate) fn read_properties(r: &mut Reader<'_>) -> Result<Option<Vec<Property>>, DecodeError> {
    r.optional("properties flag", |r| {
        r.sequence("property count", |r| {
            Ok(Property {
                name: r.string("property name")?,
                value: r.string("property value")?,
            })
        })
    })
}

pub(crate) fn write_properties(
    w: &mut Writer<'_>,
    p: Option<&Vec<Property>>,
) -> Result<(), EncodeError> {
    w.optional(p, |w, p| {
        w.sequence("property count", p, |w, p| {
            w.string("property name", &p.name)?;
            w.string("property value", &p.value)
        })
    })
}

/// `TransportLocator`: an agent address in an INFO reply (§11).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum TransportLocator {
    /// Format 0 `SMALL`: 2-byte address, 1-byte port.
    Small {
        /// Address.
        address: [u8; 2],
        /// Port.
        port: u8,
    },
    /// Format 1 `MEDIUM`: IPv4 address and u16 port.
    Medium {
        /// Address.
        address: [u8; 4],
        /// Port.
        port: u16,
    },
    /// Format 2 `LARGE`: IPv6 address and u32 port.
    Large {
        /// Address.
        address: [u8; 16],
        /// Port.
        port: u32,
    },
    /// Format 3 `STRING`.
    String(String),
}

impl TransportLocator {
    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let at = r.pos();
        Ok(match r.u8("locator format")? {
            0 => TransportLocator::Small {
                address: r.array("locator address")?,
                port: r.u8("locator port")?,
            },
            1 => TransportLocator::Medium {
                address: r.array("locator address")?,
                port: r.u16("locator port")?,
            },
            2 => TransportLocator::Large {
                address: r.array("locator address")?,
                port: r.u32("locator port")?,
            },
            3 => TransportLocator::String(r.string("locator string")?),
            f => return Err(r.invalid(at, "locator format", f.into())),
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        match self {
            TransportLocator::Small { address, port } => {
                w.u8(0);
                w.bytes(address);
                w.u8(*port);
            }
            TransportLocator::Medium { address, port } => {
                w.u8(1);
                w.bytes(address);
                w.u16(*port);
            }
            TransportLocator::Large { address, port } => {
                w.u8(2);
                w.bytes(address);
                w.u32(*port);
            }
            TransportLocator::String(s) => {
                w.u8(3);
                w.string("locator string", s)?;
            }
        }
        Ok(())
    }
}
