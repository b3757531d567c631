//! CDR writer and reader: alignment, byte order, and the XCDR2 headers.

use super::{DecodeError, Encoding, Endianness, Extensibility, RepresentationId, Version};

/// `PID_SENTINEL` that ends an XCDR1 parameter list.
const PID_SENTINEL: u16 = 0x3f02;
/// `PID_EXTENDED`: the member id and length follow in 8 bytes.
const PID_EXTENDED: u16 = 0x3f01;
/// Flag bit of a short PID or EMHEADER meaning "must understand".
const PID_MUST_UNDERSTAND: u16 = 0x4000;
/// Deepest nesting the reader follows (pointers / recursive types).
pub(crate) const MAX_DEPTH: usize = 10_000;

/// Appends CDR-encoded data to a buffer.
#[derive(Debug, Clone)]
pub struct Writer {
    buf: Vec<u8>,
    origin: usize,
    encoding: Encoding,
}

macro_rules! put_num {
    ($($name:ident: $t:ty),* $(,)?) => {$(
        #[doc = concat!("Aligns, then appends a `", stringify!($t), "`.")]
        #[inline]
        pub fn $name(&mut self, v: $t) {
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
        }
    }

    /// A writer that starts with the encapsulation header for a type of
    /// extensibility `ext`; alignment is relative to the byte after it.
    pub fn with_header(encoding: Encoding, ext: Extensibility) -> Self {
        let id = RepresentationId::for_type(encoding, ext) as u16;
        let mut buf = Vec::with_capacity(64);
        buf.extend_from_slice(&id.to_be_bytes());
        buf.extend_from_slice(&[0, 0]);
        Writer {
            buf,
            origin: 4,
            encoding,
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

    /// Bytes written, including any header.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Returns the buffer.
    pub fn into_vec(self) -> Vec<u8> {
        self.buf
    }

    /// Reserves room for `n` more bytes.
    pub fn reserve(&mut self, n: usize) {
        self.buf.reserve(n);
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

    put_num! {
        write_i16: i16, write_u16: u16,
        write_i32: i32, write_u32: u32,
        write_i64: i64, write_u64: u64,
        write_f32: f32, write_f64: f64,
    }

    /// Appends one octet.
    #[inline]
    pub fn write_u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Appends one signed octet.
    #[inline]
    pub fn write_i8(&mut self, v: i8) {
        self.buf.push(v as u8);
    }

    /// Appends a boolean (one octet, 0 or 1).
    #[inline]
    pub fn write_bool(&mut self, v: bool) {
        self.buf.push(v as u8);
    }

    /// Appends raw bytes with no alignment.
    #[inline]
    pub fn write_bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }

    /// Appends a sequence length or similar `u32` count.
    #[inline]
    pub fn write_len(&mut self, n: usize) {
        self.write_u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// Appends a string: `u32` length including the NUL, the bytes, NUL.
    pub fn write_string(&mut self, s: &str) {
        self.write_len(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// XCDR2 only: reserves a `DHEADER`; pass the result to [`Writer::end_dheader`].
    /// Returns `None` (and writes nothing) in XCDR1.
    pub fn begin_dheader(&mut self) -> Option<usize> {
        match self.version() {
            Version::Xcdr1 => None,
            Version::Xcdr2 => {
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

    fn patch_u16(&mut self, at: usize, v: u16) {
        let b = match self.encoding.endianness() {
            Endianness::Little => v.to_le_bytes(),
            Endianness::Big => v.to_be_bytes(),
        };
        self.buf[at..at + 2].copy_from_slice(&b);
    }

    /// Starts a struct of the given extensibility.
    pub fn begin_struct(&mut self, ext: Extensibility) -> StructWriter {
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

/// An open member of a mutable struct (where its length gets patched).
#[derive(Debug)]
#[must_use = "end the member with StructWriter::end_member"]
pub struct MemberHeader {
    /// Member id.
    pub id: u32,
    /// The must-understand flag.
    pub must_understand: bool,
    /// Offset of the member's data.
    pub start: usize,
    /// Length of the member's data (reader side) .
    pub len: usize,
    /// Where the length field is (writer side), if any.
    len_at: Option<(usize, bool)>,
}

impl StructWriter {
    /// Starts member `id`. For final and appendable structs this writes nothing.
    pub fn begin_member(&self, w: &mut Writer, id: u32, must_understand: bool) -> MemberHeader {
        let mut h = MemberHeader {
            id,
            must_understand,
            start: 0,
            len: 0,
            len_at: None,
        };
        if self.ext != Extensibility::Mutable {
            h.start = w.buf.len();
            return h;
        }
        match w.version() {
            Version::Xcdr1 => {
                w.align(4);
                if id < 0x3f00 {
                    let pid = id as u16 | if must_understand { PID_MUST_UNDERSTAND } else { 0 };
                    w.write_u16(pid);
                    w.write_u16(0);
                    h.len_at = Some((w.buf.len() - 2, false));
                } else {
                    w.write_u16(PID_EXTENDED | PID_MUST_UNDERSTAND);
                    w.write_u16(8);
                    let flags = if must_understand { 0x4000_0000 } else { 0 };
                    w.write_u32(id | flags);
                    w.write_u32(0);
                    h.len_at = Some((w.buf.len() - 4, true));
                }
            }
            Version::Xcdr2 => {
                // EMHEADER1 with LC = 4: the length follows in NEXTINT.
                let m = if must_understand { 0x8000_0000 } else { 0 };
                w.write_u32(m | (4 << 28) | (id & 0x0fff_ffff));
                w.write_u32(0);
                h.len_at = Some((w.buf.len() - 4, true));
            }
        }
        h.start = w.buf.len();
        h
    }

    /// Ends a member started with [`StructWriter::begin_member`].
    pub fn end_member(&self, w: &mut Writer, h: MemberHeader) {
        if let Some((at, wide)) = h.len_at {
            let mut len = w.buf.len() - h.start;
            if w.version() == Version::Xcdr1 {
                // parameter values are padded to a multiple of 4
                let pad = (4 - len % 4) % 4;
                w.buf.resize(w.buf.len() + pad, 0);
                len += pad;
            }
            if wide {
                w.patch_u32(at, len as u32);
            } else {
                w.patch_u16(at, len.min(u16::MAX as usize) as u16);
            }
        }
    }

    /// Ends the struct (patches the `DHEADER`, writes the XCDR1 sentinel).
    pub fn end(self, w: &mut Writer) {
        if self.ext == Extensibility::Mutable && w.version() == Version::Xcdr1 {
            w.align(4);
            w.write_u16(PID_SENTINEL);
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
            buf,
            pos: 4,
            origin: 4,
            limit: buf.len(),
            encoding: rep.encoding(),
            depth: 0,
        })
    }

    /// The encoding being read.
    pub fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// The XCDR version being read.
    pub fn version(&self) -> Version {
        self.encoding.version()
    }

    /// Offset from the alignment origin (for error messages).
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
        Ok(n as usize)
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
        let (last, body) = b.split_last().expect("n > 0");
        if *last != 0 {
            return Err(DecodeError::UnterminatedString { offset });
        }
        core::str::from_utf8(body).map_err(|e| DecodeError::InvalidUtf8 {
            offset: offset + 4 + e.valid_up_to(),
        })
    }

    /// Enters a nested (pointer/recursive) level; fails past the depth limit.
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
                let offset = self.position();
                let len = self.read_u32()? as usize;
                if len > self.remaining() {
                    return Err(DecodeError::BadLength {
                        what: "DHEADER",
                        offset,
                        len: len as u64,
                        remaining: self.remaining(),
                    });
                }
                let old = self.limit;
                self.limit = self.pos + len;
                Ok(Some((self.limit, old)))
            }
        }
    }

    /// Skips what is left of a `DHEADER` region (members a newer type
    /// appended) and restores the outer limit.
    pub fn end_dheader(&mut self, saved: Option<(usize, usize)>) {
        if let Some((end, old)) = saved {
            self.pos = end;
            self.limit = old;
        }
    }

    /// Starts reading a struct of the given extensibility.
    pub fn begin_struct(&mut self, ext: Extensibility) -> Result<StructReader, DecodeError> {
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

/// An open struct in a [`Reader`].
#[derive(Debug)]
#[must_use = "end the struct with StructReader::end"]
pub struct StructReader {
    ext: Extensibility,
    dheader: Option<(usize, usize)>,
    /// (end of current member, outer limit)
    member_end: Option<(usize, usize)>,
    done: bool,
}

impl StructReader {
    /// Mutable structs: the next member's header, or `None` at the end.
    /// The reader is narrowed to the member's data until the next call.
    pub fn next_member(&mut self, r: &mut Reader<'_>) -> Result<Option<MemberHeader>, DecodeError> {
        if let Some((end, old)) = self.member_end.take() {
            r.pos = end;
            r.limit = old;
        }
        if self.done || self.ext != Extensibility::Mutable {
            return Ok(None);
        }
        let (id, must_understand, len, offset) = match r.version() {
            Version::Xcdr1 => {
                r.align(4)?;
                let offset = r.position();
                let pid = r.read_u16()?;
                let len = r.read_u16()? as usize;
                if pid == PID_SENTINEL {
                    self.done = true;
                    return Ok(None);
                }
                if pid & 0x3fff == PID_EXTENDED {
                    let a = r.read_u32()?;
                    let l = r.read_u32()? as usize;
                    (a & 0x0fff_ffff, a & 0x4000_0000 != 0, l, offset)
                } else {
                    ((pid & 0x3fff) as u32, pid & PID_MUST_UNDERSTAND != 0, len, offset)
                }
            }
            Version::Xcdr2 => {
                if r.remaining() == 0 {
                    self.done = true;
                    return Ok(None);
                }
                r.align(4)?;
                let offset = r.position();
                let h = r.read_u32()?;
                let lc = (h >> 28) & 0x7;
                let len = match lc {
                    0 => 1,
                    1 => 2,
                    2 => 4,
                    3 => 8,
                    4 => r.read_u32()? as usize,
                    // LC 5..7: NEXTINT is also the first word of the member (a length or count)
                    5..=7 => {
                        let at = r.pos;
                        let n = r.read_u32()? as usize;
                        r.pos = at;
                        let mult = match lc {
                            5 => 1,
                            6 => 4,
                            _ => 8,
                        };
                        n.saturating_mul(mult).saturating_add(4)
                    }
                    _ => unreachable!("3-bit field"),
                };
                (h & 0x0fff_ffff, h & 0x8000_0000 != 0, len, offset)
            }
        };
        if len > r.remaining() {
            return Err(DecodeError::BadLength {
                what: "member header",
                offset,
                len: len as u64,
                remaining: r.remaining(),
            });
        }
        let start = r.pos;
        self.member_end = Some((start + len, r.limit));
        r.limit = start + len;
        Ok(Some(MemberHeader {
            id,
            must_understand,
            start,
            len,
            len_at: None,
        }))
    }

    /// Ends the struct: skips unread appended members and restores limits.
    pub fn end(mut self, r: &mut Reader<'_>) -> Result<(), DecodeError> {
        if let Some((end, old)) = self.member_end.take() {
            r.pos = end;
            r.limit = old;
        }
        if self.ext == Extensibility::Mutable && r.version() == Version::Xcdr1 {
            // skip to the sentinel
            while self.next_member(r)?.is_some() {}
            if let Some((end, old)) = self.member_end.take() {
                r.pos = end;
                r.limit = old;
            }
        }
        r.end_dheader(self.dheader);
        Ok(())
    }
}
