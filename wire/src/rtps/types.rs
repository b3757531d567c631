//! RTPS basic types (DDSI-RTPS 2.5 §9.3): GUIDs, sequence numbers, sets,
//! locators, time.

use super::Error;

/// Protocol version of the message header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ProtocolVersion {
    /// Major version (2 for RTPS 2.x).
    pub major: u8,
    /// Minor version.
    pub minor: u8,
}

impl ProtocolVersion {
    /// RTPS 2.1 (Cyclone DDS 0.10).
    pub const V2_1: Self = ProtocolVersion { major: 2, minor: 1 };
    /// RTPS 2.3 (Fast DDS 2.9).
    pub const V2_3: Self = ProtocolVersion { major: 2, minor: 3 };
    /// RTPS 2.4.
    pub const V2_4: Self = ProtocolVersion { major: 2, minor: 4 };
    /// RTPS 2.5 (Cyclone DDS 11).
    pub const V2_5: Self = ProtocolVersion { major: 2, minor: 5 };
}

/// Vendor id (the DDS-RTPS vendor registry).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VendorId(pub [u8; 2]);

impl VendorId {
    /// Unknown vendor.
    pub const UNKNOWN: Self = VendorId([0, 0]);
    /// RTI Connext DDS.
    pub const RTI: Self = VendorId([0x01, 0x01]);
    /// eProsima Fast DDS.
    pub const EPROSIMA: Self = VendorId([0x01, 0x0f]);
    /// Eclipse Cyclone DDS.
    pub const CYCLONE: Self = VendorId([0x01, 0x10]);
}

/// The 12-byte GUID prefix of a participant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct GuidPrefix(pub [u8; 12]);

// Hashed as two words, not as a length-prefixed byte slice: GUIDs key the
// maps looked up for every received sample.
impl std::hash::Hash for GuidPrefix {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        let [a0, a1, a2, a3, a4, a5, a6, a7, b0, b1, b2, b3] = self.0;
        state.write_u64(u64::from_ne_bytes([a0, a1, a2, a3, a4, a5, a6, a7]));
        state.write_u32(u32::from_ne_bytes([b0, b1, b2, b3]));
    }
}

impl GuidPrefix {
    /// The all-zero prefix ("unknown", or "any participant" in INFO_DST).
    pub const UNKNOWN: Self = GuidPrefix([0; 12]);

    /// Every GUID of this participant, in order: a range of a map keyed
    /// by [`Guid`] holds its entities.
    pub fn guids(self) -> std::ops::RangeInclusive<Guid> {
        Guid {
            prefix: self,
            entity: EntityId([0; 4]),
        }..=Guid {
            prefix: self,
            entity: EntityId([0xff; 4]),
        }
    }
}

/// An entity id: 3-byte key and 1-byte kind (§9.3.1.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct EntityId(pub [u8; 4]);

impl EntityId {
    /// `ENTITYID_UNKNOWN`.
    pub const UNKNOWN: Self = EntityId([0, 0, 0, 0]);
    /// `ENTITYID_PARTICIPANT`.
    pub const PARTICIPANT: Self = EntityId([0, 0, 1, 0xc1]);
    /// SEDP topic writer.
    pub const SEDP_TOPICS_WRITER: Self = EntityId([0, 0, 2, 0xc2]);
    /// SEDP topic reader.
    pub const SEDP_TOPICS_READER: Self = EntityId([0, 0, 2, 0xc7]);
    /// SEDP publications writer.
    pub const SEDP_PUBLICATIONS_WRITER: Self = EntityId([0, 0, 3, 0xc2]);
    /// SEDP publications reader.
    pub const SEDP_PUBLICATIONS_READER: Self = EntityId([0, 0, 3, 0xc7]);
    /// SEDP subscriptions writer.
    pub const SEDP_SUBSCRIPTIONS_WRITER: Self = EntityId([0, 0, 4, 0xc2]);
    /// SEDP subscriptions reader.
    pub const SEDP_SUBSCRIPTIONS_READER: Self = EntityId([0, 0, 4, 0xc7]);
    /// SPDP participant writer.
    pub const SPDP_WRITER: Self = EntityId([0, 1, 0, 0xc2]);
    /// SPDP participant reader.
    pub const SPDP_READER: Self = EntityId([0, 1, 0, 0xc7]);
    /// Participant message (liveliness) writer.
    pub const P2P_MESSAGE_WRITER: Self = EntityId([0, 2, 0, 0xc2]);
    /// Participant message (liveliness) reader.
    pub const P2P_MESSAGE_READER: Self = EntityId([0, 2, 0, 0xc7]);

    /// The kind octet.
    pub const fn kind(self) -> u8 {
        self.0[3]
    }

    /// True for built-in entities (kind bits 0xc0 = 0xc0).
    pub const fn is_builtin(self) -> bool {
        self.0[3] & 0xc0 == 0xc0
    }

    /// True for writer kinds (0x02 with key, 0x03 no key, and built-in variants).
    pub const fn is_writer(self) -> bool {
        matches!(self.0[3] & 0x0f, 0x02 | 0x03)
    }

    /// True for reader kinds (0x04 no key, 0x07 with key).
    pub const fn is_reader(self) -> bool {
        matches!(self.0[3] & 0x0f, 0x04 | 0x07)
    }

    /// True for the kinds of keyed endpoints (writer 0x02, reader 0x07, of
    /// any category: user-defined, built-in or vendor-specific): the
    /// topic's type has a key, and an endpoint of the other kind does not
    /// match (Cyclone DDS refuses the pair).
    pub const fn is_keyed(self) -> bool {
        matches!(self.0[3] & 0x3f, 0x02 | 0x07)
    }
}

/// A GUID: participant prefix plus entity id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct Guid {
    /// Participant.
    pub prefix: GuidPrefix,
    /// Entity within it.
    pub entity: EntityId,
}

// Two words (see GuidPrefix).
impl std::hash::Hash for Guid {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        let b = self.to_bytes();
        let (a, c) = b.split_at(8);
        let word = |s: &[u8]| u64::from_ne_bytes(s.try_into().unwrap_or_default());
        state.write_u64(word(a));
        state.write_u64(word(c));
    }
}

impl Guid {
    /// The 16 bytes of the GUID.
    pub fn to_bytes(self) -> [u8; 16] {
        let mut b = [0; 16];
        b[..12].copy_from_slice(&self.prefix.0);
        b[12..].copy_from_slice(&self.entity.0);
        b
    }

    /// A GUID from its 16 bytes.
    pub fn from_bytes(b: [u8; 16]) -> Self {
        let mut p = [0; 12];
        p.copy_from_slice(&b[..12]);
        let mut e = [0; 4];
        e.copy_from_slice(&b[12..]);
        Guid {
            prefix: GuidPrefix(p),
            entity: EntityId(e),
        }
    }
}

/// A 64-bit sequence number (on the wire: high `i32`, low `u32`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct SequenceNumber(pub i64);

impl SequenceNumber {
    /// `SEQUENCENUMBER_UNKNOWN` (high -1, low 0).
    pub const UNKNOWN: Self = SequenceNumber(-1i64 << 32);
}

/// A Time_t: seconds and 2^-32 fractions (§9.3.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Time {
    /// Seconds since the UNIX epoch.
    pub seconds: i32,
    /// Fraction of a second in units of 2^-32 s.
    pub fraction: u32,
}

impl Time {
    /// The time since the UNIX epoch (the fraction to the nearest
    /// nanosecond below); `None` before it.
    pub fn since_epoch(self) -> Option<std::time::Duration> {
        let secs = u64::try_from(self.seconds).ok()?;
        let nanos = (u64::from(self.fraction) * 1_000_000_000) >> 32;
        Some(std::time::Duration::new(secs, nanos as u32))
    }

    /// As a `SystemTime`; `None` before the UNIX epoch.
    pub fn to_system_time(self) -> Option<std::time::SystemTime> {
        std::time::SystemTime::UNIX_EPOCH.checked_add(self.since_epoch()?)
    }
}

/// A UDPv4/UDPv6 (or other) locator (§9.3.2): 24 bytes on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Locator {
    /// `LOCATOR_KIND_UDPv4` = 1, `UDPv6` = 2, vendor kinds otherwise.
    pub kind: i32,
    /// Port.
    pub port: u32,
    /// Address; IPv4 addresses sit in the last 4 bytes.
    pub address: [u8; 16],
}

impl Locator {
    /// `LOCATOR_KIND_UDPv4`.
    pub const KIND_UDPV4: i32 = 1;
    /// `LOCATOR_KIND_UDPv6`.
    pub const KIND_UDPV6: i32 = 2;

    /// A UDPv4 locator.
    pub fn udpv4(ip: [u8; 4], port: u16) -> Self {
        let mut address = [0; 16];
        address[12..].copy_from_slice(&ip);
        Locator {
            kind: Self::KIND_UDPV4,
            port: port as u32,
            address,
        }
    }

    /// The socket address of a UDPv4/UDPv6 locator.
    pub fn socket_addr(&self) -> Option<std::net::SocketAddr> {
        let port = u16::try_from(self.port).ok()?;
        match self.kind {
            Self::KIND_UDPV4 => {
                let a = &self.address[12..];
                Some(std::net::SocketAddr::from(([a[0], a[1], a[2], a[3]], port)))
            }
            Self::KIND_UDPV6 => Some(std::net::SocketAddr::from((self.address, port))),
            _ => None,
        }
    }
}

/// A set of sequence numbers: base plus up to 256 bits (§9.4.2.6).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct SequenceNumberSet {
    /// First sequence number the bitmap covers.
    pub base: SequenceNumber,
    /// Number of bits (0..=256).
    pub num_bits: u32,
    /// Bitmap words; bit 31 of word 0 is `base`.
    pub bitmap: Vec<u32>,
}

impl SequenceNumberSet {
    /// An empty set starting at `base`.
    pub fn empty(base: SequenceNumber) -> Self {
        SequenceNumberSet {
            base,
            num_bits: 0,
            bitmap: Vec::new(),
        }
    }

    /// A set over `[base, base + num_bits)` containing `members`
    /// (members outside the range are ignored).
    pub fn from_members(
        base: SequenceNumber,
        num_bits: u32,
        members: impl IntoIterator<Item = SequenceNumber>,
    ) -> Self {
        let num_bits = num_bits.min(256);
        let mut bitmap = vec![0u32; num_bits.div_ceil(32) as usize];
        for m in members {
            let d = m.0 - base.0;
            if d >= 0 && d < num_bits as i64 {
                bitmap[(d / 32) as usize] |= 1 << (31 - (d % 32));
            }
        }
        SequenceNumberSet {
            base,
            num_bits,
            bitmap,
        }
    }

    /// The members of the set, ascending.
    pub fn iter(&self) -> impl Iterator<Item = SequenceNumber> + '_ {
        (0..self.num_bits).filter_map(move |i| {
            let w = self.bitmap.get((i / 32) as usize)?;
            (w & (1 << (31 - i % 32)) != 0).then_some(SequenceNumber(self.base.0 + i as i64))
        })
    }
}

/// A set of fragment numbers (NACK_FRAG): base plus up to 256 bits.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct FragmentNumberSet {
    /// First fragment number (1-based) the bitmap covers.
    pub base: u32,
    /// Number of bits (0..=256).
    pub num_bits: u32,
    /// Bitmap words; bit 31 of word 0 is `base`.
    pub bitmap: Vec<u32>,
}

impl FragmentNumberSet {
    /// The members of the set, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.num_bits).filter_map(move |i| {
            let w = self.bitmap.get((i / 32) as usize)?;
            (w & (1 << (31 - i % 32)) != 0).then_some(self.base + i)
        })
    }
}

/// Reads RTPS fields in a submessage's byte order.
#[derive(Debug)]
pub(crate) struct Cursor<'a> {
    pub(crate) buf: &'a [u8],
    pub(crate) pos: usize,
    pub(crate) little: bool,
    /// Offset of `buf[0]` in the whole message, for error messages.
    pub(crate) base: usize,
}

impl<'a> Cursor<'a> {
    pub(crate) fn new(buf: &'a [u8], little: bool, base: usize) -> Self {
        Cursor {
            buf,
            pos: 0,
            little,
            base,
        }
    }

    pub(crate) fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    pub(crate) fn take(&mut self, n: usize) -> Result<&'a [u8], Error> {
        if n > self.remaining() {
            return Err(Error::Truncated {
                offset: self.base + self.pos,
                needed: n,
                remaining: self.remaining(),
            });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub(crate) fn rest(&mut self) -> &'a [u8] {
        let s = &self.buf[self.pos..];
        self.pos = self.buf.len();
        s
    }

    fn arr<const N: usize>(&mut self) -> Result<[u8; N], Error> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    pub(crate) fn u16(&mut self) -> Result<u16, Error> {
        let a = self.arr::<2>()?;
        Ok(if self.little {
            u16::from_le_bytes(a)
        } else {
            u16::from_be_bytes(a)
        })
    }

    pub(crate) fn u32(&mut self) -> Result<u32, Error> {
        let a = self.arr::<4>()?;
        Ok(if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    }

    pub(crate) fn i32(&mut self) -> Result<i32, Error> {
        Ok(self.u32()? as i32)
    }

    pub(crate) fn entity(&mut self) -> Result<EntityId, Error> {
        Ok(EntityId(self.arr::<4>()?))
    }

    pub(crate) fn prefix(&mut self) -> Result<GuidPrefix, Error> {
        Ok(GuidPrefix(self.arr::<12>()?))
    }

    pub(crate) fn sn(&mut self) -> Result<SequenceNumber, Error> {
        let high = self.i32()? as i64;
        let low = self.u32()? as i64;
        Ok(SequenceNumber((high << 32) | low))
    }

    pub(crate) fn time(&mut self) -> Result<Time, Error> {
        Ok(Time {
            seconds: self.i32()?,
            fraction: self.u32()?,
        })
    }

    pub(crate) fn locator(&mut self) -> Result<Locator, Error> {
        Ok(Locator {
            kind: self.i32()?,
            port: self.u32()?,
            address: self.arr::<16>()?,
        })
    }

    fn bitmap(&mut self, what: &'static str) -> Result<(u32, Vec<u32>), Error> {
        let offset = self.base + self.pos;
        let num_bits = self.u32()?;
        if num_bits > 256 {
            return Err(Error::Invalid {
                offset,
                what,
                detail: format!("numBits {num_bits} > 256"),
            });
        }
        let words = num_bits.div_ceil(32) as usize;
        let mut bitmap = Vec::with_capacity(words);
        for _ in 0..words {
            bitmap.push(self.u32()?);
        }
        Ok((num_bits, bitmap))
    }

    pub(crate) fn sn_set(&mut self) -> Result<SequenceNumberSet, Error> {
        let base = self.sn()?;
        let (num_bits, bitmap) = self.bitmap("SequenceNumberSet")?;
        Ok(SequenceNumberSet {
            base,
            num_bits,
            bitmap,
        })
    }

    pub(crate) fn frag_set(&mut self) -> Result<FragmentNumberSet, Error> {
        let base = self.u32()?;
        let (num_bits, bitmap) = self.bitmap("FragmentNumberSet")?;
        Ok(FragmentNumberSet {
            base,
            num_bits,
            bitmap,
        })
    }
}

/// Writes RTPS fields in a chosen byte order.
#[derive(Debug)]
pub(crate) struct Out<'a> {
    pub(crate) buf: &'a mut Vec<u8>,
    pub(crate) little: bool,
}

impl Out<'_> {
    pub(crate) fn u16(&mut self, v: u16) {
        self.buf.extend_from_slice(&if self.little {
            v.to_le_bytes()
        } else {
            v.to_be_bytes()
        });
    }
    pub(crate) fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&if self.little {
            v.to_le_bytes()
        } else {
            v.to_be_bytes()
        });
    }
    pub(crate) fn i32(&mut self, v: i32) {
        self.u32(v as u32);
    }
    pub(crate) fn bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }
    pub(crate) fn sn(&mut self, s: SequenceNumber) {
        self.i32((s.0 >> 32) as i32);
        self.u32(s.0 as u32);
    }
    pub(crate) fn time(&mut self, t: Time) {
        self.i32(t.seconds);
        self.u32(t.fraction);
    }
    pub(crate) fn locator(&mut self, l: &Locator) {
        self.i32(l.kind);
        self.u32(l.port);
        self.bytes(&l.address);
    }
    pub(crate) fn sn_set(&mut self, s: &SequenceNumberSet) {
        self.sn(s.base);
        self.u32(s.num_bits);
        for w in s.bitmap.iter().take(s.num_bits.div_ceil(32) as usize) {
            self.u32(*w);
        }
    }
    pub(crate) fn frag_set(&mut self, s: &FragmentNumberSet) {
        self.u32(s.base);
        self.u32(s.num_bits);
        for w in s.bitmap.iter().take(s.num_bits.div_ceil(32) as usize) {
            self.u32(*w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{EntityId, Time};

    #[test]
    fn times_read_as_durations_since_the_epoch() {
        let t = Time {
            seconds: 1,
            fraction: 1 << 31,
        };
        assert_eq!(
            t.since_epoch(),
            Some(std::time::Duration::from_millis(1500))
        );
        assert_eq!(
            t.to_system_time(),
            Some(std::time::UNIX_EPOCH + std::time::Duration::from_millis(1500))
        );
        let before = Time {
            seconds: -1,
            fraction: 0,
        };
        assert_eq!(before.since_epoch(), None);
        assert_eq!(before.to_system_time(), None);
    }

    #[test]
    fn keyed_kinds_of_every_category() {
        for (kind, keyed) in [
            (0x02, true),  // user writer with key
            (0x03, false), // user writer, no key
            (0x04, false), // user reader, no key
            (0x07, true),  // user reader with key
            (0xc2, true),  // built-in writer (SEDP: keyed by GUID)
            (0xc7, true),
            (0x42, true), // vendor-specific writer with key
            (0x44, false),
            (0xc1, false), // participant
        ] {
            assert_eq!(EntityId([0, 0, 1, kind]).is_keyed(), keyed, "{kind:#04x}");
        }
    }
}
