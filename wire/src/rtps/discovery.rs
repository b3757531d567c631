//! SPDP participant data and SEDP endpoint data (§8.5, §9.6.2), the QoS
//! they carry, and the two ways peers announce that an instance is gone
//! (`shared/protocols/rtps.md` §4–§5).
//!
//! Parsing is lenient the way the real peers require: absent PIDs take the
//! DDS defaults (Cyclone omits everything at its default), unknown PIDs are
//! skipped, vendor PIDs are read only together with the sender's vendor id.
//! Encoding writes what Courier announces, little-endian (`PL_CDR_LE`).

use super::parameter::{ParameterId, ParameterList, PID_VENDOR_SPECIFIC};
use super::types::{Cursor, Guid, GuidPrefix, Locator, ProtocolVersion, VendorId};
use super::Error;

/// Standard parameter ids (§9.6.2.2, Table 9.12, and DDS-XTypes).
#[allow(missing_docs)]
pub mod pid {
    pub const PARTICIPANT_LEASE_DURATION: u16 = 0x0002;
    pub const TIME_BASED_FILTER: u16 = 0x0004;
    pub const TOPIC_NAME: u16 = 0x0005;
    pub const OWNERSHIP_STRENGTH: u16 = 0x0006;
    pub const TYPE_NAME: u16 = 0x0007;
    pub const DOMAIN_ID: u16 = 0x000f;
    pub const PROTOCOL_VERSION: u16 = 0x0015;
    pub const VENDOR_ID: u16 = 0x0016;
    pub const RELIABILITY: u16 = 0x001a;
    pub const LIVELINESS: u16 = 0x001b;
    pub const DURABILITY: u16 = 0x001d;
    pub const DURABILITY_SERVICE: u16 = 0x001e;
    pub const OWNERSHIP: u16 = 0x001f;
    pub const PRESENTATION: u16 = 0x0021;
    pub const DEADLINE: u16 = 0x0023;
    pub const DESTINATION_ORDER: u16 = 0x0025;
    pub const LATENCY_BUDGET: u16 = 0x0027;
    pub const PARTITION: u16 = 0x0029;
    pub const LIFESPAN: u16 = 0x002b;
    pub const USER_DATA: u16 = 0x002c;
    pub const GROUP_DATA: u16 = 0x002d;
    pub const TOPIC_DATA: u16 = 0x002e;
    pub const UNICAST_LOCATOR: u16 = 0x002f;
    pub const MULTICAST_LOCATOR: u16 = 0x0030;
    pub const DEFAULT_UNICAST_LOCATOR: u16 = 0x0031;
    pub const METATRAFFIC_UNICAST_LOCATOR: u16 = 0x0032;
    pub const METATRAFFIC_MULTICAST_LOCATOR: u16 = 0x0033;
    pub const EXPECTS_INLINE_QOS: u16 = 0x0043;
    pub const HISTORY: u16 = 0x0040;
    pub const DEFAULT_MULTICAST_LOCATOR: u16 = 0x0048;
    pub const PARTICIPANT_GUID: u16 = 0x0050;
    pub const BUILTIN_ENDPOINT_SET: u16 = 0x0058;
    pub const PROPERTY_LIST: u16 = 0x0059;
    pub const ENDPOINT_GUID: u16 = 0x005a;
    pub const ENTITY_NAME: u16 = 0x0062;
    pub const KEY_HASH: u16 = 0x0070;
    pub const STATUS_INFO: u16 = 0x0071;
    pub const DATA_REPRESENTATION: u16 = 0x0073;
    pub const TYPE_CONSISTENCY_ENFORCEMENT: u16 = 0x0074;
    pub const TYPE_INFORMATION: u16 = 0x0075;
}

/// An RTPS `Duration_t`: seconds and 2^-32 fractions; [`Duration::INFINITE`] is DDS's infinity.
/// Debug prints it as a time (`Duration(100ms)`, `Duration(INFINITE)`),
/// its fields only when it is negative.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Duration {
    /// Seconds.
    pub seconds: i32,
    /// Fractions of a second (2^-32 s).
    pub fraction: u32,
}

impl Duration {
    /// Zero.
    pub const ZERO: Self = Duration {
        seconds: 0,
        fraction: 0,
    };
    /// `DURATION_INFINITE`.
    pub const INFINITE: Self = Duration {
        seconds: 0x7fff_ffff,
        fraction: 0xffff_ffff,
    };

    /// From a `std::time::Duration` (saturating at infinity). The fraction
    /// is rounded up, as Cyclone DDS rounds it (`ddsi_time.c`), so that a
    /// duration both sides were given goes out as the same bytes: 300 ms is
    /// 1288490189/2^32 s, not 1288490188.
    pub fn from_std(d: std::time::Duration) -> Self {
        match i32::try_from(d.as_secs()) {
            Ok(s) if s < i32::MAX => Duration {
                seconds: s,
                // < 2^32: a subsecond is under 10^9 ns
                fraction: (u64::from(d.subsec_nanos()) << 32).div_ceil(1_000_000_000) as u32,
            },
            _ => Self::INFINITE,
        }
    }

    /// Whether this duration is longer than `other` as times, to the
    /// nanosecond (infinity longest): what the QoS rules compare. Peers
    /// round a fraction each their own way (Cyclone DDS up, Courier before
    /// down), so two encodings of 300 ms differ by one 2^-32 s; compared
    /// by their bits, one was "longer" and a deadline or lease given alike
    /// on both sides did not match.
    pub fn longer_than(self, other: Duration) -> bool {
        // negative durations (never valid) order by their bits, below zero
        let key = |d: Duration| match d.to_std() {
            _ if d == Self::INFINITE => (2, 0, d),
            Some(t) => (1, t.as_nanos(), Duration::ZERO),
            None => (0, 0, d),
        };
        key(self) > key(other)
    }

    /// As a `std::time::Duration`; `None` for infinity or negative values.
    pub fn to_std(self) -> Option<std::time::Duration> {
        if self == Self::INFINITE || self.seconds < 0 {
            return None;
        }
        // to the nearest nanosecond: 100 ms goes out as 429496730/2^32 s
        // (Courier, Cyclone DDS) or 429496729/2^32 s (rounded down) and
        // must come back as 100 ms either way
        let nanos = (u64::from(self.fraction) * 1_000_000_000 + (1 << 31)) >> 32;
        Some(
            std::time::Duration::from_secs(self.seconds as u64)
                + std::time::Duration::from_nanos(nanos),
        )
    }
}

impl std::fmt::Debug for Duration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.to_std() {
            _ if *self == Self::INFINITE => f.write_str("Duration(INFINITE)"),
            Some(d) => write!(f, "Duration({d:?})"),
            None => f
                .debug_struct("Duration")
                .field("seconds", &self.seconds)
                .field("fraction", &self.fraction)
                .finish(),
        }
    }
}

/// Reliability QoS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Reliability {
    /// Best effort (wire value 1).
    BestEffort,
    /// Reliable (wire value 2), with max blocking time.
    Reliable(Duration),
}

/// Durability QoS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Durability {
    /// Volatile (0).
    Volatile,
    /// Transient local (1).
    TransientLocal,
    /// Transient (2).
    Transient,
    /// Persistent (3).
    Persistent,
}

/// History QoS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum History {
    /// Keep the last n samples per instance.
    KeepLast(i32),
    /// Keep everything (resource limits permitting).
    KeepAll,
}

/// Liveliness QoS kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LivelinessKind {
    /// Automatic (0).
    Automatic,
    /// Manual by participant (1).
    ManualByParticipant,
    /// Manual by topic (2).
    ManualByTopic,
}

/// The QoS an endpoint announces (the subset Courier uses; defaults per DDS 1.4 §2.2.3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EndpointQos {
    /// Reliability (default: best effort for readers, reliable for writers — see [`EndpointQos::reader_default`]).
    pub reliability: Reliability,
    /// Durability (default volatile).
    pub durability: Durability,
    /// History (default keep last 1).
    pub history: History,
    /// Deadline period (default infinite).
    pub deadline: Duration,
    /// Liveliness kind and lease (default automatic, infinite).
    pub liveliness: (LivelinessKind, Duration),
    /// Exclusive ownership (default shared).
    pub exclusive_ownership: bool,
    /// Ownership strength (writers; default 0).
    pub ownership_strength: i32,
    /// Partitions (default none = the default partition).
    pub partitions: Vec<String>,
    /// Minimum separation (readers; default 0).
    pub time_based_filter: Duration,
    /// Lifespan (writers; default infinite).
    pub lifespan: Duration,
    /// Data representations (default `[XCDR1]` = `[0]`; XCDR2 = 2).
    pub data_representation: Vec<i16>,
}

impl EndpointQos {
    /// DDS defaults for a data writer.
    pub fn writer_default() -> Self {
        EndpointQos {
            reliability: Reliability::Reliable(Duration {
                seconds: 0,
                fraction: 429_496_730, // 100 ms
            }),
            ..Self::reader_default()
        }
    }

    /// DDS defaults for a data reader.
    pub fn reader_default() -> Self {
        EndpointQos {
            reliability: Reliability::BestEffort,
            durability: Durability::Volatile,
            history: History::KeepLast(1),
            deadline: Duration::INFINITE,
            liveliness: (LivelinessKind::Automatic, Duration::INFINITE),
            exclusive_ownership: false,
            ownership_strength: 0,
            partitions: Vec::new(),
            time_based_filter: Duration::ZERO,
            lifespan: Duration::INFINITE,
            data_representation: vec![0],
        }
    }
}

/// SPDP data: what a participant announces about itself.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParticipantData {
    /// The participant.
    pub guid_prefix: GuidPrefix,
    /// Its RTPS version.
    pub protocol_version: ProtocolVersion,
    /// Its vendor.
    pub vendor: VendorId,
    /// Domain id (Fast DDS omits it).
    pub domain_id: Option<u32>,
    /// Where to send user data.
    pub default_unicast: Vec<Locator>,
    /// Multicast for user data.
    pub default_multicast: Vec<Locator>,
    /// Where to send discovery traffic.
    pub metatraffic_unicast: Vec<Locator>,
    /// Multicast for discovery traffic.
    pub metatraffic_multicast: Vec<Locator>,
    /// Lease: the participant is gone if silent this long.
    pub lease_duration: Duration,
    /// `BUILTIN_ENDPOINT_SET` bits.
    pub builtin_endpoints: u32,
    /// `PID_ENTITY_NAME`, if sent.
    pub entity_name: Option<String>,
}

/// SEDP data: a publication or subscription.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EndpointData {
    /// The endpoint.
    pub guid: Guid,
    /// Topic name.
    pub topic_name: String,
    /// Type name.
    pub type_name: String,
    /// QoS (defaults filled in for absent PIDs).
    pub qos: EndpointQos,
    /// Endpoint-specific unicast locators (else the participant's defaults apply).
    pub unicast: Vec<Locator>,
    /// Endpoint-specific multicast locators.
    pub multicast: Vec<Locator>,
    /// Readers: whether it expects inline QoS.
    pub expects_inline_qos: bool,
    /// XTypes TypeInformation bytes, if sent (kept opaque).
    pub type_information: Option<Vec<u8>>,
    /// A writer whose instances its readers dispose when it is deleted
    /// (WRITER_DATA_LIFECYCLE `autodispose_unregistered_instances`), where
    /// its vendor leaves that to the readers: Cyclone DDS sends no
    /// dispose for the instances of a writer it deletes, and says the
    /// policy in its `PID_ADLINK_WRITER_DATA_LIFECYCLE` (0x8003; absent:
    /// DDS's default, true). False for every other writer (they dispose
    /// what they mean to dispose, as Courier and Fast DDS do). See
    /// [`EndpointData::read_vendor_params`].
    pub disposes_when_deleted: bool,
}

/// `PID_STATUS_INFO` bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatusInfo {
    /// The instance was disposed.
    pub disposed: bool,
    /// The instance was unregistered.
    pub unregistered: bool,
}

impl StatusInfo {
    /// Parses the 4-byte big-endian flags (the value is always big-endian).
    pub fn parse(v: &[u8]) -> Option<Self> {
        let b = v.get(3)?;
        Some(StatusInfo {
            disposed: b & 1 != 0,
            unregistered: b & 2 != 0,
        })
    }

    /// The 4-byte value.
    pub fn to_bytes(self) -> [u8; 4] {
        [
            0,
            0,
            0,
            u8::from(self.disposed) | (u8::from(self.unregistered) << 1),
        ]
    }
}

fn cursor<'a>(v: &'a [u8], little: bool) -> Cursor<'a> {
    Cursor::new(v, little, 0)
}

fn duration(v: &[u8], little: bool) -> Result<Duration, Error> {
    let mut c = cursor(v, little);
    Ok(Duration {
        seconds: c.i32()?,
        fraction: c.u32()?,
    })
}

fn string(v: &[u8], little: bool) -> Result<String, Error> {
    let mut c = cursor(v, little);
    read_string(&mut c)
}

fn read_string(c: &mut Cursor<'_>) -> Result<String, Error> {
    let n = c.u32()? as usize;
    let b = c.take(n)?;
    let b = b.strip_suffix(&[0]).unwrap_or(b);
    String::from_utf8(b.to_vec()).map_err(|_| Error::Invalid {
        offset: c.base + c.pos,
        what: "string parameter",
        detail: "not UTF-8".into(),
    })
}

fn guid(v: &[u8]) -> Result<Guid, Error> {
    let b: [u8; 16] = v
        .get(..16)
        .and_then(|s| s.try_into().ok())
        .ok_or(Error::Truncated {
            offset: 0,
            needed: 16,
            remaining: v.len(),
        })?;
    Ok(Guid::from_bytes(b))
}

fn locator(v: &[u8], little: bool) -> Result<Locator, Error> {
    cursor(v, little).locator()
}

/// Splits an SPDP/SEDP payload (encapsulation header + parameter list).
pub fn payload_params(payload: &[u8]) -> Result<ParameterList<'_>, Error> {
    if payload.len() < 4 {
        return Err(Error::Truncated {
            offset: 0,
            needed: 4,
            remaining: payload.len(),
        });
    }
    let little = match [payload[0], payload[1]] {
        [0, 3] => true,
        [0, 2] => false,
        other => {
            return Err(Error::Invalid {
                offset: 0,
                what: "discovery payload",
                detail: format!("encapsulation {other:02x?} is not PL_CDR"),
            })
        }
    };
    Ok(ParameterList::parse(&payload[4..], little)?.0)
}

impl ParticipantData {
    /// Reads SPDP data from a parameter list sent by `vendor`.
    pub fn from_params(list: &ParameterList<'_>) -> Result<Self, Error> {
        let le = list.little;
        let mut d = ParticipantData {
            guid_prefix: GuidPrefix::UNKNOWN,
            protocol_version: ProtocolVersion::V2_1,
            vendor: VendorId::UNKNOWN,
            domain_id: None,
            default_unicast: Vec::new(),
            default_multicast: Vec::new(),
            metatraffic_unicast: Vec::new(),
            metatraffic_multicast: Vec::new(),
            lease_duration: Duration {
                seconds: 100,
                fraction: 0,
            },
            builtin_endpoints: 0,
            entity_name: None,
        };
        let mut have_guid = false;
        for p in &list.params {
            if p.pid & PID_VENDOR_SPECIFIC != 0 {
                continue;
            }
            let v = p.value;
            match p.pid & 0x3fff {
                pid::PARTICIPANT_GUID => {
                    d.guid_prefix = guid(v)?.prefix;
                    have_guid = true;
                }
                pid::PROTOCOL_VERSION if v.len() >= 2 => {
                    d.protocol_version = ProtocolVersion {
                        major: v[0],
                        minor: v[1],
                    }
                }
                pid::VENDOR_ID if v.len() >= 2 => d.vendor = VendorId([v[0], v[1]]),
                pid::DOMAIN_ID => d.domain_id = Some(cursor(v, le).u32()?),
                pid::DEFAULT_UNICAST_LOCATOR => d.default_unicast.push(locator(v, le)?),
                pid::DEFAULT_MULTICAST_LOCATOR => d.default_multicast.push(locator(v, le)?),
                pid::METATRAFFIC_UNICAST_LOCATOR => d.metatraffic_unicast.push(locator(v, le)?),
                pid::METATRAFFIC_MULTICAST_LOCATOR => d.metatraffic_multicast.push(locator(v, le)?),
                pid::PARTICIPANT_LEASE_DURATION => d.lease_duration = duration(v, le)?,
                pid::BUILTIN_ENDPOINT_SET => d.builtin_endpoints = cursor(v, le).u32()?,
                pid::ENTITY_NAME => d.entity_name = Some(string(v, le)?),
                _ => {}
            }
        }
        if !have_guid {
            return Err(Error::Invalid {
                offset: 0,
                what: "SPDP data",
                detail: "no PID_PARTICIPANT_GUID".into(),
            });
        }
        Ok(d)
    }

    /// The SPDP payload (PL_CDR_LE encapsulation + parameter list).
    pub fn to_payload(&self) -> Vec<u8> {
        let mut w = PlWriter::new();
        w.param(
            pid::PROTOCOL_VERSION,
            &[self.protocol_version.major, self.protocol_version.minor],
        );
        w.param(pid::VENDOR_ID, &self.vendor.0);
        let g = Guid {
            prefix: self.guid_prefix,
            entity: super::EntityId::PARTICIPANT,
        };
        w.param(pid::PARTICIPANT_GUID, &g.to_bytes());
        if let Some(d) = self.domain_id {
            w.param(pid::DOMAIN_ID, &d.to_le_bytes());
        }
        for (id, list) in [
            (pid::DEFAULT_UNICAST_LOCATOR, &self.default_unicast),
            (pid::DEFAULT_MULTICAST_LOCATOR, &self.default_multicast),
            (pid::METATRAFFIC_UNICAST_LOCATOR, &self.metatraffic_unicast),
            (
                pid::METATRAFFIC_MULTICAST_LOCATOR,
                &self.metatraffic_multicast,
            ),
        ] {
            for l in list {
                w.locator(id, l);
            }
        }
        w.duration(pid::PARTICIPANT_LEASE_DURATION, self.lease_duration);
        w.param(
            pid::BUILTIN_ENDPOINT_SET,
            &self.builtin_endpoints.to_le_bytes(),
        );
        if let Some(n) = &self.entity_name {
            w.string(pid::ENTITY_NAME, n);
        }
        w.finish()
    }
}

impl EndpointData {
    /// Reads SEDP data; `writer` selects the writer or reader QoS defaults.
    pub fn from_params(list: &ParameterList<'_>, writer: bool) -> Result<Self, Error> {
        let le = list.little;
        let mut qos = if writer {
            EndpointQos::writer_default()
        } else {
            EndpointQos::reader_default()
        };
        let mut guid_v = None;
        let mut topic = None;
        let mut type_name = None;
        let mut d_unicast = Vec::new();
        let mut d_multicast = Vec::new();
        let mut expects_inline_qos = false;
        let mut type_information = None;
        for p in &list.params {
            if p.pid & PID_VENDOR_SPECIFIC != 0 {
                continue;
            }
            let v = p.value;
            match p.pid & 0x3fff {
                pid::ENDPOINT_GUID => guid_v = Some(guid(v)?),
                pid::TOPIC_NAME => topic = Some(string(v, le)?),
                pid::TYPE_NAME => type_name = Some(string(v, le)?),
                pid::RELIABILITY => {
                    let mut c = cursor(v, le);
                    let kind = c.u32()?;
                    let block = if c.remaining() >= 8 {
                        Duration {
                            seconds: c.i32()?,
                            fraction: c.u32()?,
                        }
                    } else {
                        Duration::ZERO
                    };
                    qos.reliability = if kind == 2 {
                        Reliability::Reliable(block)
                    } else {
                        Reliability::BestEffort
                    };
                }
                pid::DURABILITY => {
                    qos.durability = match cursor(v, le).u32()? {
                        0 => Durability::Volatile,
                        1 => Durability::TransientLocal,
                        2 => Durability::Transient,
                        _ => Durability::Persistent,
                    }
                }
                pid::HISTORY => {
                    let mut c = cursor(v, le);
                    let kind = c.u32()?;
                    let depth = if c.remaining() >= 4 { c.i32()? } else { 1 };
                    qos.history = if kind == 1 {
                        History::KeepAll
                    } else {
                        History::KeepLast(depth)
                    };
                }
                pid::DEADLINE => qos.deadline = duration(v, le)?,
                pid::LIVELINESS => {
                    let mut c = cursor(v, le);
                    let kind = match c.u32()? {
                        1 => LivelinessKind::ManualByParticipant,
                        2 => LivelinessKind::ManualByTopic,
                        _ => LivelinessKind::Automatic,
                    };
                    let lease = Duration {
                        seconds: c.i32()?,
                        fraction: c.u32()?,
                    };
                    qos.liveliness = (kind, lease);
                }
                pid::OWNERSHIP => qos.exclusive_ownership = cursor(v, le).u32()? == 1,
                pid::OWNERSHIP_STRENGTH => qos.ownership_strength = cursor(v, le).i32()?,
                pid::PARTITION => {
                    let mut c = cursor(v, le);
                    let n = c.u32()? as usize;
                    if n.saturating_mul(5) > c.remaining() {
                        return Err(Error::Invalid {
                            offset: 0,
                            what: "PID_PARTITION",
                            detail: format!("{n} names in {} bytes", c.remaining()),
                        });
                    }
                    let mut names = Vec::with_capacity(n);
                    for _ in 0..n {
                        // each string is 4-aligned within the parameter
                        let pad = (4 - c.pos % 4) % 4;
                        c.take(pad)?;
                        names.push(read_string(&mut c)?);
                    }
                    qos.partitions = names;
                }
                pid::TIME_BASED_FILTER => qos.time_based_filter = duration(v, le)?,
                pid::LIFESPAN => qos.lifespan = duration(v, le)?,
                pid::DATA_REPRESENTATION => {
                    let mut c = cursor(v, le);
                    let n = c.u32()? as usize;
                    if n.saturating_mul(2) > c.remaining() {
                        return Err(Error::Invalid {
                            offset: 0,
                            what: "PID_DATA_REPRESENTATION",
                            detail: format!("{n} ids in {} bytes", c.remaining()),
                        });
                    }
                    qos.data_representation = (0..n)
                        .map(|_| c.u16().map(|x| x as i16))
                        .collect::<Result<_, _>>()?;
                }
                pid::UNICAST_LOCATOR => d_unicast.push(locator(v, le)?),
                pid::MULTICAST_LOCATOR => d_multicast.push(locator(v, le)?),
                pid::EXPECTS_INLINE_QOS => expects_inline_qos = v.first().is_some_and(|b| *b != 0),
                pid::TYPE_INFORMATION => type_information = Some(v.to_vec()),
                _ => {}
            }
        }
        let missing = |what: &str| Error::Invalid {
            offset: 0,
            what: "SEDP data",
            detail: format!("no {what}"),
        };
        Ok(EndpointData {
            guid: guid_v.ok_or_else(|| missing("PID_ENDPOINT_GUID"))?,
            topic_name: topic.ok_or_else(|| missing("PID_TOPIC_NAME"))?,
            type_name: type_name.ok_or_else(|| missing("PID_TYPE_NAME"))?,
            qos,
            unicast: d_unicast,
            multicast: d_multicast,
            expects_inline_qos,
            type_information,
            disposes_when_deleted: false,
        })
    }

    /// Reads what `vendor`'s own parameters in `list` say (see
    /// [`EndpointData::disposes_when_deleted`]).
    pub fn read_vendor_params(&mut self, list: &ParameterList<'_>, vendor: VendorId) {
        const ADLINK_WRITER_DATA_LIFECYCLE: u16 = PID_VENDOR_SPECIFIC | 0x0003;
        if vendor == VendorId::CYCLONE && self.guid.entity.is_writer() {
            self.disposes_when_deleted = list
                .get(
                    ParameterId::Vendor(vendor, ADLINK_WRITER_DATA_LIFECYCLE),
                    vendor,
                )
                .is_none_or(|p| p.value.first().is_some_and(|b| *b != 0));
        }
    }

    /// The SEDP payload (PL_CDR_LE). Every QoS is written, defaults included,
    /// as Fast DDS does: each peer then reads the same values whatever its defaults.
    pub fn to_payload(&self, vendor: VendorId, version: ProtocolVersion) -> Vec<u8> {
        let q = &self.qos;
        let mut w = PlWriter::new();
        w.string(pid::TOPIC_NAME, &self.topic_name);
        w.string(pid::TYPE_NAME, &self.type_name);
        w.param(pid::PROTOCOL_VERSION, &[version.major, version.minor]);
        w.param(pid::VENDOR_ID, &vendor.0);
        w.param(pid::ENDPOINT_GUID, &self.guid.to_bytes());
        let (kind, block) = match q.reliability {
            Reliability::BestEffort => (1u32, Duration::ZERO),
            Reliability::Reliable(d) => (2, d),
        };
        let mut rel = kind.to_le_bytes().to_vec();
        rel.extend_from_slice(&block.seconds.to_le_bytes());
        rel.extend_from_slice(&block.fraction.to_le_bytes());
        w.param(pid::RELIABILITY, &rel);
        let dur = q.durability as u32;
        w.param(pid::DURABILITY, &dur.to_le_bytes());
        let (hk, depth) = match q.history {
            History::KeepLast(n) => (0u32, n),
            History::KeepAll => (1, 1),
        };
        let mut hist = hk.to_le_bytes().to_vec();
        hist.extend_from_slice(&depth.to_le_bytes());
        w.param(pid::HISTORY, &hist);
        w.duration(pid::DEADLINE, q.deadline);
        let mut live = (q.liveliness.0 as u32).to_le_bytes().to_vec();
        live.extend_from_slice(&q.liveliness.1.seconds.to_le_bytes());
        live.extend_from_slice(&q.liveliness.1.fraction.to_le_bytes());
        w.param(pid::LIVELINESS, &live);
        w.param(
            pid::OWNERSHIP,
            &u32::from(q.exclusive_ownership).to_le_bytes(),
        );
        if q.exclusive_ownership || q.ownership_strength != 0 {
            w.param(pid::OWNERSHIP_STRENGTH, &q.ownership_strength.to_le_bytes());
        }
        if !q.partitions.is_empty() {
            let mut v = (q.partitions.len() as u32).to_le_bytes().to_vec();
            for p in &q.partitions {
                v.resize(v.len().div_ceil(4) * 4, 0);
                v.extend_from_slice(&(p.len() as u32 + 1).to_le_bytes());
                v.extend_from_slice(p.as_bytes());
                v.push(0);
            }
            w.param(pid::PARTITION, &v);
        }
        w.duration(pid::TIME_BASED_FILTER, q.time_based_filter);
        w.duration(pid::LIFESPAN, q.lifespan);
        let mut rep = (q.data_representation.len() as u32).to_le_bytes().to_vec();
        for r in &q.data_representation {
            rep.extend_from_slice(&r.to_le_bytes());
        }
        w.param(pid::DATA_REPRESENTATION, &rep);
        for l in &self.unicast {
            w.locator(pid::UNICAST_LOCATOR, l);
        }
        for l in &self.multicast {
            w.locator(pid::MULTICAST_LOCATOR, l);
        }
        if self.expects_inline_qos {
            w.param(pid::EXPECTS_INLINE_QOS, &[1]);
        }
        if let Some(t) = &self.type_information {
            w.param(pid::TYPE_INFORMATION, t);
        }
        w.finish()
    }
}

/// The instance a dispose/unregister DATA refers to, whichever way it was sent:
/// Cyclone sends a K-flag DATA whose payload is a PL_CDR key with the GUID;
/// Fast DDS sends inline `PID_KEY_HASH` + `PID_STATUS_INFO` and no payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Disposal {
    /// The key (for SPDP/SEDP: the participant or endpoint GUID bytes).
    pub key_hash: [u8; 16],
    /// Dispose/unregister flags.
    pub status: StatusInfo,
}

impl Disposal {
    /// Reads a disposal from a DATA's inline QoS (in its byte order) and
    /// payload; `None` if the DATA is an ordinary sample.
    pub fn from_data(
        inline_qos: Option<&[u8]>,
        little: bool,
        payload: Option<&[u8]>,
        key_flag: bool,
    ) -> Result<Option<Self>, Error> {
        let mut status = None;
        let mut key_hash = None;
        if let Some(q) = inline_qos {
            let (list, _) = ParameterList::parse(q, little)?;
            for p in &list.params {
                // vendor PIDs (0x8000 bit) never mean KEY_HASH or STATUS_INFO
                if p.pid & PID_VENDOR_SPECIFIC != 0 {
                    continue;
                }
                match p.pid & 0x3fff {
                    pid::STATUS_INFO => status = StatusInfo::parse(p.value),
                    pid::KEY_HASH => {
                        key_hash = p.value.get(..16).and_then(|s| <[u8; 16]>::try_from(s).ok())
                    }
                    _ => {}
                }
            }
        }
        let Some(status) = status.filter(|s| s.disposed || s.unregistered) else {
            return Ok(None);
        };
        if key_hash.is_none() && key_flag {
            if let Some(p) = payload {
                let list = payload_params(p)?;
                key_hash = list
                    .params
                    .iter()
                    .find(|x| {
                        x.pid & PID_VENDOR_SPECIFIC == 0
                            && matches!(x.pid & 0x3fff, pid::PARTICIPANT_GUID | pid::ENDPOINT_GUID)
                    })
                    .and_then(|x| x.value.get(..16))
                    .and_then(|s| s.try_into().ok());
            }
        }
        let key_hash = key_hash.ok_or(Error::Invalid {
            offset: 0,
            what: "dispose/unregister",
            detail: "neither PID_KEY_HASH nor a key payload".into(),
        })?;
        Ok(Some(Disposal { key_hash, status }))
    }
}

/// Builds a PL_CDR_LE payload.
struct PlWriter {
    out: Vec<u8>,
}

impl PlWriter {
    fn new() -> Self {
        PlWriter {
            out: vec![0x00, 0x03, 0x00, 0x00],
        }
    }

    fn param(&mut self, id: u16, value: &[u8]) {
        let padded = value.len().div_ceil(4) * 4;
        self.out.extend_from_slice(&id.to_le_bytes());
        self.out
            .extend_from_slice(&u16::try_from(padded).unwrap_or(u16::MAX).to_le_bytes());
        self.out.extend_from_slice(value);
        self.out.resize(self.out.len() + padded - value.len(), 0);
    }

    fn string(&mut self, id: u16, s: &str) {
        let mut v = (s.len() as u32 + 1).to_le_bytes().to_vec();
        v.extend_from_slice(s.as_bytes());
        v.push(0);
        self.param(id, &v);
    }

    fn duration(&mut self, id: u16, d: Duration) {
        let mut v = d.seconds.to_le_bytes().to_vec();
        v.extend_from_slice(&d.fraction.to_le_bytes());
        self.param(id, &v);
    }

    fn locator(&mut self, id: u16, l: &Locator) {
        let mut v = l.kind.to_le_bytes().to_vec();
        v.extend_from_slice(&l.port.to_le_bytes());
        v.extend_from_slice(&l.address);
        self.param(id, &v);
    }

    fn finish(mut self) -> Vec<u8> {
        self.out.extend_from_slice(&[0x01, 0x00, 0x00, 0x00]);
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::parameter::Parameter;
    use crate::rtps::{EntityId, Guid, GuidPrefix};

    /// Cyclone DDS's writer autodispose, from its vendor PID 0x8003 (a
    /// boolean; absent: DDS's default, true), read only from Cyclone and
    /// only for writers.
    #[test]
    fn cyclone_writer_autodispose_is_read_from_its_vendor_pid() {
        let endpoint = |entity: [u8; 4]| EndpointData {
            guid: Guid {
                prefix: GuidPrefix([1; 12]),
                entity: EntityId(entity),
            },
            topic_name: "t".into(),
            type_name: "T".into(),
            qos: EndpointQos::writer_default(),
            unicast: vec![],
            multicast: vec![],
            expects_inline_qos: false,
            type_information: None,
            disposes_when_deleted: false,
        };
        let list = |params: Vec<Parameter<'static>>| ParameterList {
            params,
            little: true,
        };
        let off = Parameter {
            pid: 0x8003,
            value: &[0, 0, 0, 0],
        };
        let on = Parameter {
            pid: 0x8003,
            value: &[1, 0, 0, 0],
        };
        let writer = [0, 0, 1, 0x02];
        for (vendor, params, entity, want) in [
            (VendorId::CYCLONE, vec![], writer, true),
            (VendorId::CYCLONE, vec![on], writer, true),
            (VendorId::CYCLONE, vec![off], writer, false),
            // another vendor's 0x8003 is something else
            (VendorId::EPROSIMA, vec![on], writer, false),
            (VendorId::EPROSIMA, vec![], writer, false),
            // a reader has no such policy
            (VendorId::CYCLONE, vec![], [0, 0, 1, 0x07], false),
        ] {
            let mut d = endpoint(entity);
            d.read_vendor_params(&list(params.clone()), vendor);
            assert_eq!(d.disposes_when_deleted, want, "{vendor:?} {params:?}");
        }
    }
}
