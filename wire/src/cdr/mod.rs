//! OMG CDR as DDS uses it: XCDR1 (plain CDR) and XCDR2, both byte orders.
//!
//! A serialized payload starts with the 4-byte encapsulation header
//! (representation identifier, big-endian, then two option bytes);
//! alignment is relative to the first byte *after* that header.
//!
//! | version | max alignment | appendable struct | mutable struct | `@optional` member |
//! |---|---|---|---|---|
//! | XCDR1 | 8 | as final | parameter list (`PL_CDR`), `PID_LIST_END` | extended parameter header, length 0 if absent |
//! | XCDR2 | 4 | `DHEADER` (u32 size) | `DHEADER` + `EMHEADER` per member | boolean flag (left out in mutable structs) |
//!
//! The bytes are those Cyclone DDS 11 writes, down to the `EMHEADER` length
//! codes and the XCDR1 parameter headers (see the `cdr_golden` tests and
//! `tools/cdr-golden`). XCDR2 puts a `DHEADER` before sequences and arrays
//! whose elements are not primitive (strings, enums, structs, sequences).
//! Payloads are not padded to a multiple of 4: DDS writers add that padding
//! on the wire, and [`from_slice`] accepts up to 3 padding bytes.
//!
//! Keys have a form of their own for DDS key hashes (`PID_KEY_HASH`): the
//! *key-hash form* ([`Writer::key_hash_form_in`]), big-endian without
//! encapsulation header, every struct final, key members in member-id
//! order, in either XCDR version. A writer's key hash is in the version of
//! its data ([`key_hash_of_payload`] reads it from the encapsulation
//! header; [`key_hash_of_key_in`] and [`key_from_key_hash_in`] take it);
//! the functions without a version ([`key_hash_of_key`],
//! [`key_from_key_hash`], [`crate::key_hash`]) use XCDR2, the form
//! DDS-XTypes 1.3 §7.6.8 specifies. A reader whose writers write both
//! versions names each instance in one of them
//! ([`crate::dds::InstanceKeys`]): [`key_hash_of_payload_in`] and
//! [`translate_key_hash`] give a hash in the other. [`MaxSize`] measures
//! the largest key in each version. See
//! [`crate::rtps::participant::KeyHash`] for why the versions differ and
//! what Cyclone DDS and Fast DDS do.
//!
//! ```
//! use courier_wire::cdr::{self, Encoding};
//! let b = cdr::to_vec(&String::from("hi"), Encoding::Xcdr1Le);
//! assert_eq!(b, [0x00, 0x01, 0, 0, 3, 0, 0, 0, b'h', b'i', 0]);
//! ```

mod codec;
mod max_size;

pub use codec::{MemberHeader, Reader, StructReader, StructWriter, Writer, MAX_DEPTH, TAIL_ROOM};
pub use max_size::MaxSize;

use crate::IpcMessage;

/// Byte order of CDR data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Endianness {
    /// Big-endian.
    Big,
    /// Little-endian.
    Little,
}

/// XCDR version.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Version {
    /// XCDR version 1 (classic CDR; `PL_CDR` for mutable types).
    Xcdr1,
    /// XCDR version 2 (DDS-XTypes 1.3 §7.4.3).
    Xcdr2,
}

/// What a writer produces: XCDR version and byte order. The exact
/// encapsulation id also depends on the type's [`Extensibility`]
/// (see [`RepresentationId::for_type`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// XCDR1, little-endian.
    Xcdr1Le,
    /// XCDR1, big-endian.
    Xcdr1Be,
    /// XCDR2, little-endian.
    Xcdr2Le,
    /// XCDR2, big-endian.
    Xcdr2Be,
}

impl Encoding {
    /// The XCDR version.
    pub const fn version(self) -> Version {
        match self {
            Encoding::Xcdr1Le | Encoding::Xcdr1Be => Version::Xcdr1,
            Encoding::Xcdr2Le | Encoding::Xcdr2Be => Version::Xcdr2,
        }
    }

    /// The byte order.
    pub const fn endianness(self) -> Endianness {
        match self {
            Encoding::Xcdr1Le | Encoding::Xcdr2Le => Endianness::Little,
            Encoding::Xcdr1Be | Encoding::Xcdr2Be => Endianness::Big,
        }
    }

    /// Builds an encoding from its parts.
    pub const fn new(version: Version, endianness: Endianness) -> Self {
        match (version, endianness) {
            (Version::Xcdr1, Endianness::Little) => Encoding::Xcdr1Le,
            (Version::Xcdr1, Endianness::Big) => Encoding::Xcdr1Be,
            (Version::Xcdr2, Endianness::Little) => Encoding::Xcdr2Le,
            (Version::Xcdr2, Endianness::Big) => Encoding::Xcdr2Be,
        }
    }
}

/// DDS-XTypes type extensibility (`@final`, `@appendable`, `@mutable`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Extensibility {
    /// Members in order, no headers (the default, as in Cyclone's idlc).
    #[default]
    Final,
    /// XCDR2: a `DHEADER` with the byte size precedes the members.
    Appendable,
    /// Members identified by id: parameter list (XCDR1) or `EMHEADER`s (XCDR2).
    Mutable,
}

/// The representation identifier of the encapsulation header (DDS-XTypes 1.3
/// §7.6.3.1.2, Table 60); the values are those Cyclone DDS 11 and Fast DDS send.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum RepresentationId {
    /// `CDR_BE` (XCDR1, final/appendable, big-endian).
    CdrBe = 0x0000,
    /// `CDR_LE`.
    CdrLe = 0x0001,
    /// `PL_CDR_BE` (XCDR1 mutable).
    PlCdrBe = 0x0002,
    /// `PL_CDR_LE`.
    PlCdrLe = 0x0003,
    /// `CDR2_BE` (XCDR2 final).
    Cdr2Be = 0x0006,
    /// `CDR2_LE`.
    Cdr2Le = 0x0007,
    /// `D_CDR2_BE` (XCDR2 appendable).
    DCdr2Be = 0x0008,
    /// `D_CDR2_LE`.
    DCdr2Le = 0x0009,
    /// `PL_CDR2_BE` (XCDR2 mutable).
    PlCdr2Be = 0x000a,
    /// `PL_CDR2_LE`.
    PlCdr2Le = 0x000b,
}

impl RepresentationId {
    /// The id to announce for a type of the given extensibility in the given encoding.
    pub const fn for_type(encoding: Encoding, ext: Extensibility) -> Self {
        use RepresentationId::*;
        let le = matches!(encoding.endianness(), Endianness::Little);
        match (encoding.version(), ext, le) {
            (Version::Xcdr1, Extensibility::Mutable, true) => PlCdrLe,
            (Version::Xcdr1, Extensibility::Mutable, false) => PlCdrBe,
            (Version::Xcdr1, _, true) => CdrLe,
            (Version::Xcdr1, _, false) => CdrBe,
            (Version::Xcdr2, Extensibility::Final, true) => Cdr2Le,
            (Version::Xcdr2, Extensibility::Final, false) => Cdr2Be,
            (Version::Xcdr2, Extensibility::Appendable, true) => DCdr2Le,
            (Version::Xcdr2, Extensibility::Appendable, false) => DCdr2Be,
            (Version::Xcdr2, Extensibility::Mutable, true) => PlCdr2Le,
            (Version::Xcdr2, Extensibility::Mutable, false) => PlCdr2Be,
        }
    }

    /// Parses the 16-bit id of an encapsulation header.
    pub const fn from_u16(v: u16) -> Option<Self> {
        use RepresentationId::*;
        Some(match v {
            0x0000 => CdrBe,
            0x0001 => CdrLe,
            0x0002 => PlCdrBe,
            0x0003 => PlCdrLe,
            0x0006 => Cdr2Be,
            0x0007 => Cdr2Le,
            0x0008 => DCdr2Be,
            0x0009 => DCdr2Le,
            0x000a => PlCdr2Be,
            0x000b => PlCdr2Le,
            _ => return None,
        })
    }

    /// The encoding (version and byte order) this id stands for.
    pub const fn encoding(self) -> Encoding {
        use RepresentationId::*;
        match self {
            CdrBe | PlCdrBe => Encoding::Xcdr1Be,
            CdrLe | PlCdrLe => Encoding::Xcdr1Le,
            Cdr2Be | PlCdr2Be | DCdr2Be => Encoding::Xcdr2Be,
            Cdr2Le | PlCdr2Le | DCdr2Le => Encoding::Xcdr2Le,
        }
    }
}

/// Why CDR data could not be decoded. Offsets count from the start of the
/// payload after the encapsulation header.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The payload is shorter than the 4-byte encapsulation header.
    #[error("CDR payload of {0} byte(s) is shorter than the 4-byte encapsulation header")]
    MissingHeader(usize),
    /// The encapsulation id is unknown.
    #[error("unknown CDR representation identifier 0x{0:04x}")]
    UnknownRepresentation(u16),
    /// The data ended before an item was complete.
    #[error("CDR data ends at byte {offset}: {needed} more byte(s) needed, {remaining} left")]
    UnexpectedEnd {
        /// Offset of the incomplete item.
        offset: usize,
        /// Bytes needed.
        needed: usize,
        /// Bytes left.
        remaining: usize,
    },
    /// A length or element count promised more data than the input holds.
    #[error("count {count} at byte {offset} exceeds the {remaining} remaining byte(s)")]
    CountTooLarge {
        /// Offset of the count.
        offset: usize,
        /// The count read.
        count: u64,
        /// Bytes remaining.
        remaining: usize,
    },
    /// A string lacked its terminating NUL or had length 0.
    #[error("string at byte {offset} is not NUL-terminated")]
    UnterminatedString {
        /// Offset of the string's length.
        offset: usize,
    },
    /// A string was not valid UTF-8.
    #[error("string is not valid UTF-8 at byte {offset}")]
    InvalidUtf8 {
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// A boolean was neither 0 nor 1.
    #[error("invalid boolean 0x{byte:02x} at byte {offset}")]
    InvalidBool {
        /// Offset.
        offset: usize,
        /// Byte read.
        byte: u8,
    },
    /// An enum value is outside the enum.
    #[error("value {value} at byte {offset} is not a valid {type_name}")]
    InvalidEnum {
        /// Offset.
        offset: usize,
        /// Value read.
        value: i64,
        /// The type.
        type_name: &'static str,
    },
    /// A `char` held a value the Rust type cannot hold.
    #[error("invalid char 0x{byte:02x} at byte {offset}")]
    InvalidChar {
        /// Offset.
        offset: usize,
        /// Byte read.
        byte: u8,
    },
    /// A DHEADER, EMHEADER or parameter length points past the enclosing data.
    #[error("{what} at byte {offset} claims {len} byte(s), only {remaining} remain")]
    BadLength {
        /// Which header.
        what: &'static str,
        /// Offset of the header.
        offset: usize,
        /// The length claimed.
        len: u64,
        /// Bytes available.
        remaining: usize,
    },
    /// A mutable struct lacked a member that the type requires.
    #[error("member {member} (id {id}) of {type_name} is missing")]
    MissingMember {
        /// The type.
        type_name: &'static str,
        /// Member name.
        member: &'static str,
        /// Member id.
        id: u32,
    },
    /// A member flagged must-understand is unknown to this type.
    #[error("unknown must-understand member id {id} in {type_name} at byte {offset}")]
    UnknownMustUnderstand {
        /// The type.
        type_name: &'static str,
        /// Member id.
        id: u32,
        /// Offset of the member header.
        offset: usize,
    },
    /// A fixed-size array held the wrong number of elements.
    #[error("array at byte {offset} has {found} elements, expected {expected}")]
    ArrayLength {
        /// Offset.
        offset: usize,
        /// Expected element count.
        expected: usize,
        /// Found element count.
        found: usize,
    },
    /// A multi-dimensional variable array's size fields do not fit its
    /// elements (or are negative, or too large).
    #[error("variable array at byte {offset}: {error}")]
    Shape {
        /// Offset of the array's count.
        offset: usize,
        /// What is wrong with the shape (boxed: decoders recurse, and
        /// every frame carries room for the error).
        error: Box<crate::ShapeError>,
    },
    /// Nesting too deep.
    #[error("data nested deeper than {max} levels at byte {offset}")]
    TooDeep {
        /// Offset.
        offset: usize,
        /// The limit.
        max: usize,
    },
    /// Bytes were left over after the value.
    #[error("{count} unexpected trailing byte(s) at byte {offset}")]
    TrailingBytes {
        /// Offset of the first unread byte.
        offset: usize,
        /// Number of unread bytes.
        count: usize,
    },
    /// Something else was malformed.
    #[error("malformed CDR at byte {offset}: {what}")]
    Malformed {
        /// Offset.
        offset: usize,
        /// What was wrong.
        what: &'static str,
    },
}

/// Serializes `value` with its encapsulation header.
pub fn to_vec<T: IpcMessage>(value: &T, encoding: Encoding) -> Vec<u8> {
    let mut w = Writer::with_header(encoding, T::EXTENSIBILITY);
    value.cdr_encode(&mut w);
    w.into_vec()
}

/// [`to_vec`] into a buffer with room for `capacity` bytes from the start
/// (e.g. the size of the last sample of the same topic): a large sample
/// then needs no reallocation while it is written.
pub fn to_vec_with_capacity<T: IpcMessage>(
    value: &T,
    encoding: Encoding,
    capacity: usize,
) -> Vec<u8> {
    let mut w = Writer::with_header_capacity(encoding, T::EXTENSIBILITY, capacity);
    value.cdr_encode(&mut w);
    w.into_vec()
}

/// Serializes `value` without an encapsulation header (alignment origin at byte 0).
pub fn to_vec_headerless<T: IpcMessage>(value: &T, encoding: Encoding) -> Vec<u8> {
    let mut w = Writer::new(encoding);
    value.cdr_encode(&mut w);
    w.into_vec()
}

/// Deserializes a `T` from a payload that starts with an encapsulation
/// header; the header decides version and byte order. Trailing bytes
/// after the value are allowed only as padding (up to 3 bytes, as DDS
/// writers pad payloads to a multiple of 4).
pub fn from_slice<T: IpcMessage>(bytes: &[u8]) -> Result<T, DecodeError> {
    let mut r = Reader::with_header(bytes)?;
    let v = T::cdr_decode(&mut r)?;
    r.finish_padding()?;
    Ok(v)
}

/// Deserializes a `T` from a payload without an encapsulation header.
pub fn from_slice_headerless<T: IpcMessage>(
    bytes: &[u8],
    encoding: Encoding,
) -> Result<T, DecodeError> {
    let mut r = Reader::new(bytes, encoding);
    let v = T::cdr_decode(&mut r)?;
    r.finish_padding()?;
    Ok(v)
}

/// Serializes the key of `value` ([`IpcMessage::cdr_encode_key`]) with an
/// encapsulation header, as Cyclone DDS's `serialize_key` does: the struct's
/// framing (DHEADER, parameter list) with only its key members.
pub fn key_to_vec<T: IpcMessage>(value: &T, encoding: Encoding) -> Vec<u8> {
    let mut w = Writer::with_header(encoding, T::EXTENSIBILITY);
    value.cdr_encode_key(&mut w);
    w.into_vec()
}

/// Deserializes a key that [`key_to_vec`] (or a DDS writer's dispose or
/// unregister: the serialized key of a key-only DATA) wrote, with its
/// encapsulation header, as the type's [`IpcMessage::Key`]: for
/// `struct Keyed { #[ipc(key)] id: i32, .. }` an `i32`.
///
/// ```
/// use courier_wire::cdr;
/// // a type without key fields is its own key (a key field of such a type
/// // is written whole); derived keyed structs give their key fields
/// let key = cdr::key_to_vec(&7u32, cdr::Encoding::Xcdr2Le);
/// assert_eq!(cdr::key_from_slice::<u32>(&key), Ok(7));
/// ```
pub fn key_from_slice<T: IpcMessage>(bytes: &[u8]) -> Result<T::Key, DecodeError> {
    let mut r = Reader::with_header(bytes)?;
    let k = T::cdr_decode_key(&mut r)?;
    r.finish_padding()?;
    Ok(k)
}

/// The DDS key hash in XCDR2 form of the instance whose key is `key` (what
/// [`key_from_slice`] returns): [`key_hash_of_key_in`] `(key,`
/// [`Version::Xcdr2`]`)`, the same as [`crate::key_hash`] of a value with
/// that key.
pub fn key_hash_of_key<T: IpcMessage>(key: &T::Key) -> Option<[u8; 16]> {
    key_hash_of_key_in::<T>(key, Version::Xcdr2)
}

/// The DDS key hash in XCDR version `version` of the instance whose key is
/// `key` (what [`key_from_slice`] returns): the same as
/// [`crate::key_hash_in`] of a value with that key. `None` for a type that
/// cannot say (a key member that is a `Vec` with a length field, that
/// length field, or an n-d array).
pub fn key_hash_of_key_in<T: IpcMessage>(key: &T::Key, version: Version) -> Option<[u8; 16]> {
    let mut w = Writer::key_hash_form_in(version);
    T::cdr_encode_key_value(key, &mut w).then(|| {
        let may_exceed_16 = !T::CDR_KEY_MAX_SIZE.fits_key_hash_in(version);
        crate::rtps::participant::KeyHash::from_key(w.as_bytes(), may_exceed_16).0
    })
}

/// The DDS key hash of a received payload of a keyed `T`: a sample
/// (`key_only` false) or the serialized key a dispose or unregister
/// carries, with its encapsulation header. What a reader computes when
/// the writer sent no `PID_KEY_HASH` (Cyclone DDS 11 sends none).
///
/// The hash is in the XCDR version of the payload (its encapsulation
/// header): what the writer of that payload sends when it sends a key
/// hash (Cyclone DDS and Fast DDS compute it in the data's version, as
/// Courier does), so that its samples with and without one name the same
/// instance. `None` for a type without key fields, or bytes that do not
/// decode.
pub fn key_hash_of_payload<T: IpcMessage>(data: &[u8], key_only: bool) -> Option<[u8; 16]> {
    if T::KEYS.is_empty() {
        return None;
    }
    let version = Reader::with_header(data).ok()?.version();
    key_hash_of_payload_in::<T>(data, key_only, version)
}

/// The DDS key hash in XCDR version `version` of a received payload of a
/// keyed `T` (a sample, or with `key_only` the serialized key of a dispose
/// or unregister, with its encapsulation header), whatever version the
/// payload itself is in: how a reader names the instance of a writer of
/// the other version as its other writers do (see
/// [`crate::dds::InstanceKeys`]). `None` for a type without key fields, or
/// bytes that do not decode.
///
/// ```
/// use courier_wire::cdr::{self, Encoding, Version};
/// let key = cdr::key_to_vec(&7i32, Encoding::Xcdr1Le);
/// // an `i32` has no key fields
/// assert_eq!(cdr::key_hash_of_payload_in::<i32>(&key, true, Version::Xcdr2), None);
/// ```
pub fn key_hash_of_payload_in<T: IpcMessage>(
    data: &[u8],
    key_only: bool,
    version: Version,
) -> Option<[u8; 16]> {
    if T::KEYS.is_empty() {
        return None;
    }
    if key_only {
        key_hash_of_key_in::<T>(&key_from_slice::<T>(data).ok()?, version)
    } else {
        Some(crate::key_hash_in(&from_slice::<T>(data).ok()?, version))
    }
}

/// The key hash in XCDR version `to` of the instance whose key hash in
/// version `from` is `hash`, when that hash holds the key itself
/// ([`key_from_key_hash_in`]): the key is read back from it and hashed
/// again. `hash` itself when the versions are the same. `None` when
/// `hash` is an MD5 digest (the type's key can be longer than 16 bytes in
/// `from`), is no key, or the type cannot say ([`key_hash_of_key_in`]).
pub fn translate_key_hash<T: IpcMessage>(
    hash: &[u8; 16],
    from: Version,
    to: Version,
) -> Option<[u8; 16]> {
    if from == to {
        return Some(*hash);
    }
    key_hash_of_key_in::<T>(&key_from_key_hash_in::<T>(hash, from)?, to)
}

/// The key behind a DDS key hash in XCDR2 form: [`key_from_key_hash_in`]
/// `(hash,` [`Version::Xcdr2`]`)`. A hash sent by a writer of XCDR1 data
/// (Fast DDS, Cyclone DDS and Courier for final types by default) needs
/// [`key_from_key_hash_in`] with [`Version::Xcdr1`].
pub fn key_from_key_hash<T: IpcMessage>(hash: &[u8; 16]) -> Option<T::Key> {
    key_from_key_hash_in::<T>(hash, Version::Xcdr2)
}

/// The key behind a DDS key hash in XCDR version `version`, when the hash
/// holds the key itself: a type whose key can never take more than 16
/// bytes in that version's key-hash form ([`IpcMessage::CDR_KEY_MAX_SIZE`],
/// [`MaxSize::fits_key_hash_in`]) has the key, in that form
/// ([`Writer::key_hash_form_in`]), zero-padded as its hash; a bounded
/// string (`string<11>` at most) comes back too, its bytes up to its NUL,
/// then zeros. `None` for a type whose key can be longer (its hash is an
/// MD5 digest, even of a short key), a type without key fields, or bytes
/// that do not decode.
///
/// The two versions lay out some keys differently (XCDR1 aligns an 8-byte
/// member to 8, XCDR2 to 4): the version must be the one the hash was
/// computed in, the writer's data representation.
pub fn key_from_key_hash_in<T: IpcMessage>(hash: &[u8; 16], version: Version) -> Option<T::Key> {
    if T::KEYS.is_empty() || !T::CDR_KEY_MAX_SIZE.fits_key_hash_in(version) {
        return None;
    }
    let mut r = Reader::key_hash_form_in(hash, version);
    let k = T::cdr_decode_key(&mut r).ok()?;
    let rest = hash.get(r.position()..)?;
    rest.iter().all(|b| *b == 0).then_some(k)
}

/// Writes an optional value (an `@optional` member, `Option<Box<T>>`), as
/// Cyclone DDS does:
///
/// - XCDR2, final or appendable struct: a boolean "present" flag, then the value;
/// - XCDR1, final or appendable struct: an extended parameter header with the
///   member id (from [`StructWriter::begin_member`]) and the value's length,
///   0 when absent; the value is aligned relative to its own start;
/// - member of a mutable struct (both versions): an absent value leaves the
///   member out entirely; a present one is written as the plain value.
pub fn write_optional<T: ?Sized>(w: &mut Writer, v: Option<&T>, enc: impl FnOnce(&T, &mut Writer)) {
    w.write_optional_with(v, enc);
}

/// Reads an optional value written by [`write_optional`].
pub fn read_optional<'a, T>(
    r: &mut Reader<'a>,
    dec: impl FnOnce(&mut Reader<'a>) -> Result<T, DecodeError>,
) -> Result<Option<T>, DecodeError> {
    r.read_optional_with(dec)
}
