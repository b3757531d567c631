//! CDR writer and reader: alignment, byte order, and the XCDR2 headers.
//!
//! Member framing follows what Cyclone DDS (`dds_cdrstream`) emits, byte for
//! byte:
//!
//! - XCDR1 mutable members and XCDR1 `@optional` members of final/appendable
//!   structs use the *extended* parameter header (`PID_EXTENDED | FLAG_MU`,
//!   length 8, member id, u32 length); the value's alignment origin is the
//!   start of the value. Mutable members are padded to a multiple of 4 (the
//!   padding counts in the length); optional members are not. An absent
//!   optional has length 0. The list ends with `PID_LIST_END | FLAG_MU`
//!   (`0x7f02`).
//! - XCDR2 `EMHEADER` length codes (LC) depend on the member's type: 1/2/4/8
//!   byte primitives, enums and booleans use LC 0–3; strings, sequences of
//!   1-byte primitives and sequences/arrays with a `DHEADER` use LC 5; sequences
//!   of 4- and 8-byte primitives LC 6 and 7; everything else (structs, arrays of
//!   primitives, sequences of 2-byte primitives) LC 4 with an explicit `NEXTINT`.
//!   The writer learns the type from the first item written in the member.
//! - XCDR2 optional members: a boolean flag then the value; in mutable structs
//!   an absent optional member is left out.

use super::{DecodeError, Encoding, Endianness, Extensibility, RepresentationId, Version};

/// `PID_LIST_END` (sentinel) that ends an XCDR1 parameter list.
const PID_SENTINEL: u16 = 0x3f02;
/// `PID_EXTENDED`: the member id and length follow in 8 bytes.
const PID_EXTENDED: u16 = 0x3f01;
/// `PID_IGNORE`: a parameter to skip.
const PID_IGNORE: u16 = 0x3f03;
/// Flag bit of a short PID meaning "must understand".
const PID_MUST_UNDERSTAND: u16 = 0x4000;
/// Mask of the parameter id in a short PID.
const PID_MASK: u16 = 0x3fff;
/// Must-understand flag of the member id in an extended parameter header.
const PL_LONG_MUST_UNDERSTAND: u32 = 0x4000_0000;
/// Member id mask (28 bits) of EMHEADERs and extended parameter headers.
const MEMBER_ID_MASK: u32 = 0x0fff_ffff;
/// EMHEADER must-understand flag.
const EM_MUST_UNDERSTAND: u32 = 0x8000_0000;
/// EMHEADER length code 4: an explicit `NEXTINT` holds the length.
const LC_NEXTINT: u32 = 4;
/// Deepest nesting the CDR reader follows (recursive types), counting each
/// struct and each optional member as one level: a linked-list node takes
/// two. Deeper data is refused instead of overflowing the stack; the writer
/// does not check it.
pub const MAX_DEPTH: usize = 500;

/// Kind of member framing being written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum MemberKind {
    /// Member of a final or appendable struct: no header.
    Plain,
    /// XCDR1 mutable member: extended parameter header.
    Param,
    /// XCDR2 mutable member: EMHEADER (+ NEXTINT placeholder until the LC is known).
    Em,
}

/// A member whose first item has not been written yet.
#[derive(Debug, Clone, Copy)]
struct Pending {
    id: u32,
    must_understand: bool,
    kind: MemberKind,
}

/// Spare capacity a [`Writer`] keeps after its data when it grows for a
/// large write, so that a transport can append its framing to the encoded
/// buffer (the RTPS writer history appends a sample's envelope) without
/// reallocating and copying a large sample.
pub const TAIL_ROOM: usize = 64;

/// Appends CDR-encoded data to a buffer.
#[derive(Debug, Clone)]
pub struct Writer {
    buf: Vec<u8>,
    origin: usize,
    encoding: Encoding,
    /// The open member whose first item is still to come.
    pending: Option<Pending>,
    /// Length code chosen for the innermost open XCDR2 member.
    member_lc: u32,
    /// An absent optional value asked for the open mutable member to be dropped.
    absent: bool,
    /// Key-hash form: every struct is written as a final one (no `DHEADER`,
    /// no member headers or parameter list), as DDSI-RTPS §9.6.4.8
    /// serializes a key for its hash.
    flat: bool,
}

macro_rules! put_num {
    ($($name:ident: $t:ty, $lc:expr;)*) => {$(
        #[doc = concat!("Aligns, then appends a `", stringify!($t), "`.")]
        #[inline]
        pub fn $name(&mut self, v: $t) {
            self.first($lc);
            self.align(core::mem::size_of::<$t>());
            match self.encoding.endianness() {
                Endianness::Little => self.buf.extend_from_slice(&v.to_le_bytes()),
                Endianness::Big => self.buf.extend_from_slice(&v.to_be_bytes()),
            }
        }
    )*};
}

impl Writer {
    /// A writer without encapsulation header: alignment origin at byte 0.
    pub fn new(encoding: Encoding) -> Self {
        Writer {
            buf: Vec::new(),
            origin: 0,
            encoding,
            pending: None,
            member_lc: LC_NEXTINT,
            absent: false,
            flat: false,
        }
    }

    /// A writer of the key-hash form in XCDR2 (DDSI-RTPS 2.5 §9.6.4.8,
    /// DDS-XTypes 1.3 §7.6.8): [`Writer::key_hash_form_in`]
    /// `(`[`Version::Xcdr2`]`)`, the form the specification names.
    pub fn key_hash_form() -> Self {
        Self::key_hash_form_in(Version::Xcdr2)
    }

    /// A writer of the key-hash form in XCDR version `version`: big-endian
    /// without encapsulation header, alignment from the first byte, every
    /// struct written as a final one (no `DHEADER`, no member headers or
    /// parameter list), whatever its extensibility. Feed it
    /// [`IpcMessage::cdr_encode_key`] (see
    /// [`crate::rtps::participant::KeyHash::of_in`]).
    ///
    /// DDS-XTypes 1.3 §7.6.8 specifies XCDR2; Cyclone DDS and Fast DDS
    /// serialize the key in the XCDR version of the data instead (XCDR1
    /// for most final types: 8-byte members aligned to 8), as Cyclone's
    /// `DDS_CDR_KEY_SERIALIZATION_KEYHASH` does with the data's version,
    /// with no member headers for a mutable struct in either version.
    ///
    /// ```
    /// use courier_wire::cdr::{Version, Writer};
    /// let mut w = Writer::key_hash_form_in(Version::Xcdr1);
    /// w.write_i32(1);
    /// w.write_i64(2);
    /// assert_eq!(w.as_bytes(), [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2]);
    /// let mut w = Writer::key_hash_form_in(Version::Xcdr2);
    /// w.write_i32(1);
    /// w.write_i64(2);
    /// assert_eq!(w.as_bytes(), [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 2]);
    /// ```
    ///
    /// [`IpcMessage::cdr_encode_key`]: crate::IpcMessage::cdr_encode_key
    pub fn key_hash_form_in(version: Version) -> Self {
        Writer {
            flat: true,
            ..Writer::new(Encoding::new(version, Endianness::Big))
        }
    }

    /// A writer that starts with the encapsulation header for a type of
    /// extensibility `ext`; alignment is relative to the byte after it.
    pub fn with_header(encoding: Encoding, ext: Extensibility) -> Self {
        // a small sample and TAIL_ROOM fit without growing
        Self::with_header_capacity(encoding, ext, 64)
    }

    /// [`Writer::with_header`] with room for `capacity` bytes (and
    /// [`TAIL_ROOM`]) before it grows: for a caller that knows about how
    /// large its samples are.
    pub fn with_header_capacity(encoding: Encoding, ext: Extensibility, capacity: usize) -> Self {
        let id = RepresentationId::for_type(encoding, ext) as u16;
        let mut buf = Vec::with_capacity(capacity.max(4) + TAIL_ROOM);
        buf.extend_from_slice(&id.to_be_bytes());
        buf.extend_from_slice(&[0, 0]);
        Writer {
            buf,
            origin: 4,
            ..Writer::new(encoding)
        }
    }

    /// The encoding being written.
    pub fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// The XCDR version being written.
    pub fn version(&self) -> Version {
        self.encoding.version()
    }

    /// True when writing little-endian.
    pub fn is_little_endian(&self) -> bool {
        matches!(self.encoding.endianness(), Endianness::Little)
    }

    /// Whether this writes the key-hash form ([`Writer::key_hash_form_in`], either version),
    /// where key members go in member-id order (Cyclone DDS sorts them so;
    /// the serialized key keeps definition order), and so do the members
    /// of a struct written whole (a key member whose type has no key
    /// fields: all its members are keys).
    pub fn is_key_hash_form(&self) -> bool {
        self.flat
    }

    /// Bytes written, including any header.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Returns the buffer.
    pub fn into_vec(self) -> Vec<u8> {
        self.buf
    }

    /// Reserves room for `n` more bytes (and [`TAIL_ROOM`] after them).
    pub fn reserve(&mut self, n: usize) {
        self.buf.reserve(n + TAIL_ROOM);
    }

    /// Effective alignment for an item of natural alignment `n` (XCDR2 caps it at 4).
    #[inline]
    pub fn effective_align(&self, n: usize) -> usize {
        match self.version() {
            Version::Xcdr1 => n,
            Version::Xcdr2 => n.min(4),
        }
    }

    /// Pads with zeros to the alignment for an item of natural size `n`.
    #[inline]
    pub fn align(&mut self, n: usize) {
        let a = self.effective_align(n);
        if a > 1 {
            let off = (self.buf.len() - self.origin) % a;
            if off != 0 {
                self.buf.resize(self.buf.len() + (a - off), 0);
            }
        }
    }

    /// Called before the first byte of every item: if it is the first item of
    /// an XCDR2 mutable member, `lc` (the length code Cyclone DDS uses for a
    /// member of this item's type) becomes the member's length code, and the
    /// `NEXTINT` placeholder goes when the code does not need it.
    #[inline]
    fn first(&mut self, lc: u32) {
        if let Some(p) = self.pending.take() {
            if p.kind == MemberKind::Em {
                self.member_lc = lc;
                if lc != LC_NEXTINT {
                    // begin_member left EMHEADER + NEXTINT as the last 8 bytes
                    self.buf.truncate(self.buf.len().saturating_sub(4));
                }
            }
        }
    }

    put_num! {
        write_i16: i16, 1;
        write_u16: u16, 1;
        write_i32: i32, 2;
        write_u32: u32, 2;
        write_i64: i64, 3;
        write_u64: u64, 3;
        write_f32: f32, 2;
        write_f64: f64, 3;
    }

    /// Appends one octet.
    #[inline]
    pub fn write_u8(&mut self, v: u8) {
        self.first(0);
        self.buf.push(v);
    }

    /// Appends one signed octet.
    #[inline]
    pub fn write_i8(&mut self, v: i8) {
        self.first(0);
        self.buf.push(v as u8);
    }

    /// Appends a boolean (one octet, 0 or 1).
    #[inline]
    pub fn write_bool(&mut self, v: bool) {
        self.first(0);
        self.buf.push(v as u8);
    }

    /// Appends raw bytes with no alignment.
    #[inline]
    pub fn write_bytes(&mut self, b: &[u8]) {
        self.first(LC_NEXTINT);
        if self.buf.capacity() - self.buf.len() < b.len() {
            // a large write grows the buffer to fit it exactly; keep room
            // for what a transport appends (see TAIL_ROOM)
            self.buf.reserve(b.len() + TAIL_ROOM);
        }
        self.buf.extend_from_slice(b);
    }

    /// Appends a sequence length or similar `u32` count. Prefer
    /// [`Writer::begin_sequence`] for sequences: it also writes the XCDR2
    /// `DHEADER` and picks the member length code Cyclone DDS uses.
    #[inline]
    pub fn write_len(&mut self, n: usize) {
        self.first(LC_NEXTINT);
        self.write_u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// Appends a string: `u32` length including the NUL, the bytes, NUL.
    pub fn write_string(&mut self, s: &str) {
        self.first(5);
        self.write_len(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// Starts a sequence of `len` elements: in XCDR2 a `DHEADER` when the
    /// elements are not primitive (`primitive_size` is `None`; strings, enums
    /// and structs are not primitive), then the count. End it with
    /// [`Writer::end_dheader`]. `primitive_size` is the element size of a
    /// sequence of primitives (1 for `bool`, `char`, octets).
    pub fn begin_sequence(&mut self, len: usize, primitive_size: Option<usize>) -> Option<usize> {
        self.first(match primitive_size {
            Some(1) | None => 5,
            Some(4) => 6,
            Some(8) => 7,
            Some(_) => LC_NEXTINT,
        });
        let d = if primitive_size.is_none() {
            self.begin_dheader()
        } else {
            None
        };
        self.write_len(len);
        d
    }

    /// Starts a fixed-size array: in XCDR2 a `DHEADER` when the elements are
    /// not primitive. End it with [`Writer::end_dheader`].
    pub fn begin_array(&mut self, primitive: bool) -> Option<usize> {
        if primitive {
            self.first(LC_NEXTINT);
            None
        } else {
            self.first(5);
            self.begin_dheader()
        }
    }

    /// XCDR2 only: reserves a `DHEADER`; pass the result to [`Writer::end_dheader`].
    /// Returns `None` (and writes nothing) in XCDR1.
    pub fn begin_dheader(&mut self) -> Option<usize> {
        match self.version() {
            Version::Xcdr1 => None,
            Version::Xcdr2 => {
                self.first(5);
                self.write_u32(0);
                Some(self.buf.len())
            }
        }
    }

    /// Patches a `DHEADER` with the number of bytes written since it.
    pub fn end_dheader(&mut self, start: Option<usize>) {
        if let Some(start) = start {
            let len = (self.buf.len() - start) as u32;
            self.patch_u32(start - 4, len);
        }
    }

    fn patch_u32(&mut self, at: usize, v: u32) {
        let b = match self.encoding.endianness() {
            Endianness::Little => v.to_le_bytes(),
            Endianness::Big => v.to_be_bytes(),
        };
        self.buf[at..at + 4].copy_from_slice(&b);
    }

    fn read_u32_at(&self, at: usize) -> Option<u32> {
        let b: [u8; 4] = self.buf.get(at..at + 4)?.try_into().ok()?;
        Some(match self.encoding.endianness() {
            Endianness::Little => u32::from_le_bytes(b),
            Endianness::Big => u32::from_be_bytes(b),
        })
    }

    /// Writes an XCDR1 extended parameter header (`PID_EXTENDED`, id, length
    /// placeholder) and returns where the value starts.
    fn write_param_header(&mut self, id: u32, must_understand: bool) -> usize {
        self.align(4);
        self.write_u16(PID_EXTENDED | PID_MUST_UNDERSTAND);
        self.write_u16(8);
        let mu = if must_understand {
            PL_LONG_MUST_UNDERSTAND
        } else {
            0
        };
        self.write_u32(mu | (id & MEMBER_ID_MASK));
        self.write_u32(0);
        self.buf.len()
    }

    /// Writes an optional value (`@optional` member): see [`super::write_optional`].
    pub(super) fn write_optional_with<T: ?Sized>(
        &mut self,
        v: Option<&T>,
        enc: impl FnOnce(&T, &mut Writer),
    ) {
        match self.pending.take() {
            Some(p) if p.kind != MemberKind::Plain => {
                // the whole member of a mutable struct: absent means left out
                match v {
                    None => self.absent = true,
                    Some(v) => {
                        self.pending = Some(p);
                        enc(v, self);
                    }
                }
            }
            p if self.version() == Version::Xcdr1 => {
                let (id, mu) = p.map_or((0, false), |p| (p.id, p.must_understand));
                let start = self.write_param_header(id, mu);
                if let Some(v) = v {
                    let origin = core::mem::replace(&mut self.origin, start);
                    enc(v, self);
                    self.origin = origin;
                    let len = (self.buf.len() - start) as u32;
                    self.patch_u32(start - 4, len);
                }
            }
            _ => {
                self.write_bool(v.is_some());
                if let Some(v) = v {
                    enc(v, self);
                }
            }
        }
    }

    /// Starts a struct of the given extensibility.
    pub fn begin_struct(&mut self, ext: Extensibility) -> StructWriter {
        self.first(LC_NEXTINT);
        let ext = if self.flat { Extensibility::Final } else { ext };
        let dheader = match (self.version(), ext) {
            (Version::Xcdr2, Extensibility::Appendable | Extensibility::Mutable) => {
                self.begin_dheader()
            }
            _ => None,
        };
        StructWriter { ext, dheader }
    }
}

/// An open struct in a [`Writer`]; members are framed as its extensibility requires.
#[derive(Debug)]
#[must_use = "end the struct with StructWriter::end"]
pub struct StructWriter {
    ext: Extensibility,
    dheader: Option<usize>,
}

/// A member of a struct: the header read by [`StructReader::next_member`],
/// or the open member returned by [`StructWriter::begin_member`].
#[derive(Debug)]
#[must_use = "end the member with StructWriter::end_member"]
pub struct MemberHeader {
    /// Member id.
    pub id: u32,
    /// The must-understand flag.
    pub must_understand: bool,
    /// Offset of the member's data.
    pub start: usize,
    /// Length of the member's data (reader side).
    pub len: usize,
    /// Writer side: framing and the writer state to restore.
    kind: MemberKind,
    hdr_start: usize,
    saved_pending: Option<Pending>,
    saved_lc: u32,
    saved_origin: usize,
}

impl StructWriter {
    /// Starts member `id`. For final and appendable structs this writes
    /// nothing (but an `@optional` member uses `id` in XCDR1). For mutable
    /// structs it writes the parameter header (XCDR1) or `EMHEADER` (XCDR2).
    /// `must_understand` sets the must-understand flag; Cyclone DDS sets it
    /// only for `@must_understand` members, not for keys.
    #[inline]
    pub fn begin_member(&self, w: &mut Writer, id: u32, must_understand: bool) -> MemberHeader {
        // A member started while the enclosing member has written nothing
        // yet (only possible without begin_struct): frame the enclosing one
        // with an explicit NEXTINT.
        w.first(LC_NEXTINT);
        let saved_pending = w.pending.take();
        let saved_lc = w.member_lc;
        let saved_origin = w.origin;
        let hdr_start = w.buf.len();
        let kind = match (self.ext, w.version()) {
            (Extensibility::Mutable, Version::Xcdr1) => {
                let start = w.write_param_header(id, must_understand);
                w.origin = start;
                MemberKind::Param
            }
            (Extensibility::Mutable, Version::Xcdr2) => {
                w.align(4);
                w.write_u32(0); // EMHEADER, patched by end_member
                w.write_u32(0); // NEXTINT, dropped unless LC 4
                MemberKind::Em
            }
            _ => MemberKind::Plain,
        };
        w.pending = Some(Pending {
            id,
            must_understand,
            kind,
        });
        w.member_lc = LC_NEXTINT;
        MemberHeader {
            id,
            must_understand,
            start: w.buf.len(),
            len: 0,
            kind,
            hdr_start,
            saved_pending,
            saved_lc,
            saved_origin,
        }
    }

    /// Ends a member started with [`StructWriter::begin_member`].
    #[inline]
    pub fn end_member(&self, w: &mut Writer, h: MemberHeader) {
        let nothing_written = w.pending.take().is_some();
        let absent = core::mem::take(&mut w.absent);
        match h.kind {
            MemberKind::Plain => {}
            MemberKind::Param => {
                if absent {
                    w.buf.truncate(h.hdr_start);
                } else {
                    // XTypes 1.1 style, as Cyclone DDS writes: padded to 4
                    w.align(4);
                    let len = (w.buf.len() - h.start) as u32;
                    w.patch_u32(h.start - 4, len);
                }
            }
            MemberKind::Em => {
                if absent {
                    w.buf.truncate(h.hdr_start);
                } else {
                    let mut lc = if nothing_written {
                        LC_NEXTINT
                    } else {
                        w.member_lc
                    };
                    let data = if lc == LC_NEXTINT {
                        h.start
                    } else {
                        h.start - 4
                    };
                    let len = w.buf.len() - data;
                    let first = if len >= 4 {
                        w.read_u32_at(data).map(|n| n as u64)
                    } else {
                        None
                    };
                    let rest = len.saturating_sub(4) as u64;
                    let ok = match lc {
                        0 => len == 1,
                        1 => len == 2,
                        2 => len == 4,
                        3 => len == 8,
                        5 => first == Some(rest),
                        6 => first.map(|n| n * 4) == Some(rest),
                        7 => first.map(|n| n * 8) == Some(rest),
                        _ => true,
                    };
                    if !ok {
                        // the value was not what its first item suggested:
                        // fall back to an explicit NEXTINT (alignment is at
                        // most 4 in XCDR2, so shifting by 4 keeps it)
                        w.buf.splice(data..data, [0u8; 4]);
                        lc = LC_NEXTINT;
                    }
                    let data = if lc == LC_NEXTINT {
                        h.start
                    } else {
                        h.start - 4
                    };
                    let mu = if h.must_understand {
                        EM_MUST_UNDERSTAND
                    } else {
                        0
                    };
                    let em = mu | (lc << 28) | (h.id & MEMBER_ID_MASK);
                    if lc == LC_NEXTINT {
                        let len = (w.buf.len() - data) as u32;
                        w.patch_u32(data - 4, len);
                        w.patch_u32(data - 8, em);
                    } else {
                        w.patch_u32(data - 4, em);
                    }
                }
            }
        }
        w.origin = h.saved_origin;
        w.pending = h.saved_pending;
        w.member_lc = h.saved_lc;
    }

    /// Ends the struct (patches the `DHEADER`, writes the XCDR1 sentinel).
    pub fn end(self, w: &mut Writer) {
        if self.ext == Extensibility::Mutable && w.version() == Version::Xcdr1 {
            w.align(4);
            w.write_u16(PID_SENTINEL | PID_MUST_UNDERSTAND);
            w.write_u16(0);
        }
        w.end_dheader(self.dheader);
    }
}

/// Reads CDR-encoded data.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    origin: usize,
    /// End of the region being read (a DHEADER or parameter may narrow it).
    limit: usize,
    encoding: Encoding,
    depth: usize,
    /// Start of the data of the mutable member just returned by
    /// [`StructReader::next_member`] (an optional member's value is there
    /// without presence flag).
    member_start: Option<usize>,
    /// Key-hash form: every struct is read as a final one (see
    /// [`Writer::key_hash_form`]).
    flat: bool,
}

macro_rules! get_num {
    ($($name:ident: $t:ty),* $(,)?) => {$(
        #[doc = concat!("Aligns, then reads a `", stringify!($t), "`.")]
        #[inline]
        pub fn $name(&mut self) -> Result<$t, DecodeError> {
            const N: usize = core::mem::size_of::<$t>();
            self.align(N)?;
            let s = self.take(N)?;
            let mut b = [0u8; N];
            b.copy_from_slice(s);
            Ok(match self.encoding.endianness() {
                Endianness::Little => <$t>::from_le_bytes(b),
                Endianness::Big => <$t>::from_be_bytes(b),
            })
        }
    )*};
}

impl<'a> Reader<'a> {
    /// A reader over headerless data in a known encoding.
    pub fn new(buf: &'a [u8], encoding: Encoding) -> Self {
        Reader {
            buf,
            pos: 0,
            origin: 0,
            limit: buf.len(),
            encoding,
            depth: 0,
            member_start: None,
            flat: false,
        }
    }

    /// A reader of the key-hash form that [`Writer::key_hash_form`] writes:
    /// big-endian XCDR2, every struct read as a final one.
    pub fn key_hash_form(buf: &'a [u8]) -> Self {
        Self::key_hash_form_in(buf, Version::Xcdr2)
    }

    /// A reader of the key-hash form that [`Writer::key_hash_form_in`]
    /// writes: big-endian XCDR version `version`, every struct read as a
    /// final one.
    pub fn key_hash_form_in(buf: &'a [u8], version: Version) -> Self {
        Reader {
            flat: true,
            ..Reader::new(buf, Encoding::new(version, Endianness::Big))
        }
    }

    /// A reader over a payload that starts with an encapsulation header.
    pub fn with_header(buf: &'a [u8]) -> Result<Self, DecodeError> {
        if buf.len() < 4 {
            return Err(DecodeError::MissingHeader(buf.len()));
        }
        let id = u16::from_be_bytes([buf[0], buf[1]]);
        let rep = RepresentationId::from_u16(id).ok_or(DecodeError::UnknownRepresentation(id))?;
        Ok(Reader {
            pos: 4,
            origin: 4,
            ..Reader::new(buf, rep.encoding())
        })
    }

    /// Whether this reads the key-hash form ([`Reader::key_hash_form_in`], either version):
    /// structs without `DHEADER` or member headers, whatever their
    /// extensibility.
    pub fn is_key_hash_form(&self) -> bool {
        self.flat
    }

    /// The encoding being read.
    pub fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// The XCDR version being read.
    pub fn version(&self) -> Version {
        self.encoding.version()
    }

    /// Offset from the current alignment origin (for error messages).
    pub fn position(&self) -> usize {
        self.pos - self.origin
    }

    /// Bytes left in the current region.
    pub fn remaining(&self) -> usize {
        self.limit - self.pos
    }

    /// Effective alignment for an item of natural alignment `n`.
    #[inline]
    pub fn effective_align(&self, n: usize) -> usize {
        match self.version() {
            Version::Xcdr1 => n,
            Version::Xcdr2 => n.min(4),
        }
    }

    /// Skips padding to the alignment of an item of natural size `n`.
    #[inline]
    pub fn align(&mut self, n: usize) -> Result<(), DecodeError> {
        let a = self.effective_align(n);
        if a > 1 {
            let off = (self.pos - self.origin) % a;
            if off != 0 {
                self.take(a - off)?;
            }
        }
        Ok(())
    }

    /// Takes `n` raw bytes (no alignment).
    #[inline]
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(DecodeError::UnexpectedEnd {
                offset: self.position(),
                needed: n,
                remaining: self.remaining(),
            });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    get_num! {
        read_i16: i16, read_u16: u16,
        read_i32: i32, read_u32: u32,
        read_i64: i64, read_u64: u64,
        read_f32: f32, read_f64: f64,
    }

    /// Reads one octet.
    #[inline]
    pub fn read_u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }

    /// Reads one signed octet.
    #[inline]
    pub fn read_i8(&mut self) -> Result<i8, DecodeError> {
        Ok(self.read_u8()? as i8)
    }

    /// Reads a boolean; values other than 0 and 1 are an error.
    pub fn read_bool(&mut self) -> Result<bool, DecodeError> {
        let offset = self.position();
        match self.read_u8()? {
            0 => Ok(false),
            1 => Ok(true),
            byte => Err(DecodeError::InvalidBool { offset, byte }),
        }
    }

    /// Reads a `u32` count of elements of at least `min_size` bytes each,
    /// checked against the remaining data before anything is allocated.
    pub fn read_len(&mut self, min_size: usize) -> Result<usize, DecodeError> {
        self.align(4)?;
        let offset = self.position();
        let n = self.read_u32()? as u64;
        if n.saturating_mul(min_size.max(1) as u64) > self.remaining() as u64 {
            return Err(DecodeError::CountTooLarge {
                offset,
                count: n,
                remaining: self.remaining(),
            });
        }
        usize::try_from(n).map_err(|_| DecodeError::CountTooLarge {
            offset,
            count: n,
            remaining: self.remaining(),
        })
    }

    /// Reads a string (length including NUL, bytes, NUL).
    pub fn read_str(&mut self) -> Result<&'a str, DecodeError> {
        self.align(4)?;
        let offset = self.position();
        let n = self.read_len(1)?;
        if n == 0 {
            // Some writers send an empty string as length 0; accept it.
            return Ok("");
        }
        let b = self.take(n)?;
        let Some((&last, body)) = b.split_last() else {
            return Err(DecodeError::UnterminatedString { offset });
        };
        if last != 0 {
            return Err(DecodeError::UnterminatedString { offset });
        }
        core::str::from_utf8(body).map_err(|e| DecodeError::InvalidUtf8 {
            offset: offset + 4 + e.valid_up_to(),
        })
    }

    /// Enters a nested level (struct, optional value); fails past [`MAX_DEPTH`].
    pub fn enter(&mut self) -> Result<(), DecodeError> {
        if self.depth >= MAX_DEPTH {
            return Err(DecodeError::TooDeep {
                offset: self.position(),
                max: MAX_DEPTH,
            });
        }
        self.depth += 1;
        Ok(())
    }

    /// Leaves a level entered with [`Reader::enter`].
    pub fn leave(&mut self) {
        self.depth = self.depth.saturating_sub(1);
    }

    /// XCDR2 only: reads a `DHEADER` and narrows the region to it. Returns
    /// the previous limit, to restore with [`Reader::end_dheader`]; `None` in XCDR1.
    pub fn begin_dheader(&mut self) -> Result<Option<(usize, usize)>, DecodeError> {
        match self.version() {
            Version::Xcdr1 => Ok(None),
            Version::Xcdr2 => {
                self.align(4)?;
                let offset = self.position();
                let len = self.read_u32()? as u64;
                if len > self.remaining() as u64 {
                    return Err(DecodeError::BadLength {
                        what: "DHEADER",
                        offset,
                        len,
                        remaining: self.remaining(),
                    });
                }
                let old = self.limit;
                self.limit = self.pos + len as usize;
                Ok(Some((self.limit, old)))
            }
        }
    }

    /// Skips what is left of a `DHEADER` region (members a newer type
    /// appended) and restores the outer limit.
    pub fn end_dheader(&mut self, saved: Option<(usize, usize)>) {
        if let Some((end, old)) = saved {
            self.pos = end.max(self.pos).min(old);
            self.limit = old;
        }
    }

    /// Starts a fixed-size array: reads the XCDR2 `DHEADER` when the elements
    /// are not primitive. End it with [`Reader::end_dheader`].
    pub fn begin_array(&mut self, primitive: bool) -> Result<Option<(usize, usize)>, DecodeError> {
        self.member_start = None;
        if primitive {
            Ok(None)
        } else {
            self.begin_dheader()
        }
    }

    /// Reads an optional value: see [`super::read_optional`].
    pub(super) fn read_optional_with<T>(
        &mut self,
        dec: impl FnOnce(&mut Reader<'a>) -> Result<T, DecodeError>,
    ) -> Result<Option<T>, DecodeError> {
        if self.member_start.take() == Some(self.pos) {
            // an optional member of a mutable struct: present, no flag
            self.enter()?;
            let v = dec(self);
            self.leave();
            return v.map(Some);
        }
        match self.version() {
            Version::Xcdr2 => {
                if !self.read_bool()? {
                    return Ok(None);
                }
                self.enter()?;
                let v = dec(self);
                self.leave();
                v.map(Some)
            }
            Version::Xcdr1 => {
                self.align(4)?;
                let offset = self.position();
                let pid = self.read_u16()?;
                let slen = self.read_u16()?;
                if pid & PID_MASK != PID_EXTENDED || slen != 8 {
                    return Err(DecodeError::Malformed {
                        offset,
                        what: "XCDR1 optional member without extended parameter header",
                    });
                }
                let _id = self.read_u32()?;
                let len = self.read_u32()? as u64;
                if len > self.remaining() as u64 {
                    return Err(DecodeError::BadLength {
                        what: "optional member",
                        offset,
                        len,
                        remaining: self.remaining(),
                    });
                }
                if len == 0 {
                    return Ok(None);
                }
                let end = self.pos + len as usize;
                let (limit, origin) = (self.limit, self.origin);
                self.limit = end;
                self.origin = self.pos;
                self.enter()?;
                let v = dec(self);
                self.leave();
                self.pos = end;
                self.limit = limit;
                self.origin = origin;
                v.map(Some)
            }
        }
    }

    /// Starts reading a struct of the given extensibility.
    pub fn begin_struct(&mut self, ext: Extensibility) -> Result<StructReader, DecodeError> {
        self.member_start = None;
        self.enter()?;
        let ext = if self.flat { Extensibility::Final } else { ext };
        let dheader = match (self.version(), ext) {
            (Version::Xcdr2, Extensibility::Appendable | Extensibility::Mutable) => {
                self.begin_dheader()?
            }
            _ => None,
        };
        Ok(StructReader {
            ext,
            dheader,
            member_end: None,
            done: false,
        })
    }

    /// Succeeds if at most alignment padding (< 4 bytes) is left.
    pub fn finish_padding(&self) -> Result<(), DecodeError> {
        if self.remaining() < 4 {
            Ok(())
        } else {
            Err(DecodeError::TrailingBytes {
                offset: self.position(),
                count: self.remaining(),
            })
        }
    }
}

/// Saved reader state while a mutable member is being read.
#[derive(Debug, Clone, Copy)]
struct MemberRegion {
    end: usize,
    limit: usize,
    origin: usize,
}

/// An open struct in a [`Reader`].
#[derive(Debug)]
#[must_use = "end the struct with StructReader::end"]
pub struct StructReader {
    ext: Extensibility,
    dheader: Option<(usize, usize)>,
    member_end: Option<MemberRegion>,
    done: bool,
}

impl StructReader {
    fn close_member(&mut self, r: &mut Reader<'_>) {
        if let Some(m) = self.member_end.take() {
            r.pos = m.end;
            r.limit = m.limit;
            r.origin = m.origin;
        }
        r.member_start = None;
    }

    /// Appendable structs in XCDR2: true when the data (its `DHEADER`)
    /// holds no more members. A writer with an older version of the type
    /// stops there; the members it does not have take their defaults
    /// (XTypes). Always false for final structs and in XCDR1, which do
    /// not say where a struct ends.
    pub fn ended(&self, r: &Reader<'_>) -> bool {
        self.ext == Extensibility::Appendable && self.dheader.is_some() && r.remaining() == 0
    }

    /// Mutable structs: the next member's header, or `None` at the end.
    /// The reader is narrowed to the member's data until the next call.
    /// Callers skip members they do not know unless
    /// [`MemberHeader::must_understand`] is set, which is an error
    /// ([`DecodeError::UnknownMustUnderstand`]).
    pub fn next_member(&mut self, r: &mut Reader<'_>) -> Result<Option<MemberHeader>, DecodeError> {
        self.close_member(r);
        if self.done || self.ext != Extensibility::Mutable {
            return Ok(None);
        }
        let (id, must_understand, len, offset) = match r.version() {
            Version::Xcdr1 => loop {
                r.align(4)?;
                let offset = r.position();
                let pid = r.read_u16()?;
                let len = r.read_u16()? as usize;
                match pid & PID_MASK {
                    PID_SENTINEL => {
                        self.done = true;
                        return Ok(None);
                    }
                    PID_IGNORE => {
                        r.take(len).map_err(|_| DecodeError::BadLength {
                            what: "parameter",
                            offset,
                            len: len as u64,
                            remaining: r.remaining(),
                        })?;
                    }
                    PID_EXTENDED => {
                        if len != 8 {
                            return Err(DecodeError::Malformed {
                                offset,
                                what: "PID_EXTENDED with a length other than 8",
                            });
                        }
                        let a = r.read_u32()?;
                        let l = r.read_u32()? as usize;
                        break (
                            a & MEMBER_ID_MASK,
                            a & PL_LONG_MUST_UNDERSTAND != 0,
                            l,
                            offset,
                        );
                    }
                    p => break (p as u32, pid & PID_MUST_UNDERSTAND != 0, len, offset),
                }
            },
            Version::Xcdr2 => {
                if r.remaining() == 0 {
                    self.done = true;
                    return Ok(None);
                }
                r.align(4)?;
                let offset = r.position();
                let h = r.read_u32()?;
                let lc = (h >> 28) & 0x7;
                let len: u64 = match lc {
                    0 => 1,
                    1 => 2,
                    2 => 4,
                    3 => 8,
                    4 => r.read_u32()? as u64,
                    // LC 5..7: NEXTINT is also the first word of the member (a length or count)
                    _ => {
                        let at = r.pos;
                        let n = r.read_u32()? as u64;
                        r.pos = at;
                        let mult = match lc {
                            5 => 1,
                            6 => 4,
                            _ => 8,
                        };
                        n * mult + 4
                    }
                };
                if len > r.remaining() as u64 {
                    return Err(DecodeError::BadLength {
                        what: "EMHEADER",
                        offset,
                        len,
                        remaining: r.remaining(),
                    });
                }
                (
                    h & MEMBER_ID_MASK,
                    h & EM_MUST_UNDERSTAND != 0,
                    len as usize,
                    offset,
                )
            }
        };
        if len > r.remaining() {
            return Err(DecodeError::BadLength {
                what: "parameter",
                offset,
                len: len as u64,
                remaining: r.remaining(),
            });
        }
        let start = r.pos;
        self.member_end = Some(MemberRegion {
            end: start + len,
            limit: r.limit,
            origin: r.origin,
        });
        r.limit = start + len;
        if r.version() == Version::Xcdr1 {
            // XCDR1: the value is aligned relative to its own start
            r.origin = start;
        }
        r.member_start = Some(start);
        Ok(Some(MemberHeader {
            id,
            must_understand,
            start,
            len,
            kind: MemberKind::Plain,
            hdr_start: start,
            saved_pending: None,
            saved_lc: LC_NEXTINT,
            saved_origin: 0,
        }))
    }

    /// Ends the struct: skips unread members (appended by a newer version of
    /// the type, or unknown) and restores limits.
    pub fn end(mut self, r: &mut Reader<'_>) -> Result<(), DecodeError> {
        self.close_member(r);
        if self.ext == Extensibility::Mutable && r.version() == Version::Xcdr1 {
            // skip to the sentinel
            while self.next_member(r)?.is_some() {}
            self.close_member(r);
        }
        r.end_dheader(self.dheader);
        r.leave();
        Ok(())
    }
}
