//! The CDR primitives XRCE payloads are made of (`protocols/xrce.md` §3):
//! alignment counted from the start of the XRCE message, byte order from
//! the submessage's endianness flag, strings as a u32 length that counts
//! the NUL, booleans as one byte, optionals as a boolean then the value.

use super::{DecodeError, EncodeError};

/// Reads one submessage payload; every offset it reports is from the start
/// of the buffer it was given (the XRCE message).
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    end: usize,
    le: bool,
    /// Contents of every alignment padding byte skipped, in order.
    pub(crate) padding: Vec<u8>,
}

impl<'a> Reader<'a> {
    /// Reads `buf[start..end]`, aligning relative to `buf[0]`.
    pub(crate) fn new(buf: &'a [u8], start: usize, end: usize, le: bool) -> Self {
        debug_assert!(start <= end && end <= buf.len());
        Reader {
            buf,
            pos: start,
            end,
            le,
            padding: Vec::new(),
        }
    }

    pub(crate) fn pos(&self) -> usize {
        self.pos
    }

    pub(crate) fn remaining(&self) -> usize {
        self.end - self.pos
    }

    pub(crate) fn truncated(&self, what: &'static str, needed: usize) -> DecodeError {
        DecodeError::Truncated {
            offset: self.pos,
            what,
            needed,
            remaining: self.remaining(),
        }
    }

    pub(crate) fn invalid(&self, offset: usize, what: &'static str, value: u64) -> DecodeError {
        DecodeError::Invalid {
            offset,
            what,
            value,
        }
    }

    /// Skips the padding before a primitive of `size` bytes.
    pub(crate) fn align(&mut self, size: usize, what: &'static str) -> Result<(), DecodeError> {
        let pad = (size - self.pos % size) % size;
        if pad > self.remaining() {
            return Err(self.truncated(what, pad));
        }
        self.padding
            .extend_from_slice(&self.buf[self.pos..self.pos + pad]);
        self.pos += pad;
        Ok(())
    }

    pub(crate) fn bytes(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(self.truncated(what, n));
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub(crate) fn array<const N: usize>(
        &mut self,
        what: &'static str,
    ) -> Result<[u8; N], DecodeError> {
        let mut a = [0; N];
        a.copy_from_slice(self.bytes(N, what)?);
        Ok(a)
    }

    /// The rest of the payload.
    pub(crate) fn rest(&mut self) -> &'a [u8] {
        let s = &self.buf[self.pos..self.end];
        self.pos = self.end;
        s
    }

    pub(crate) fn u8(&mut self, what: &'static str) -> Result<u8, DecodeError> {
        Ok(self.array::<1>(what)?[0])
    }

    pub(crate) fn bool(&mut self, what: &'static str) -> Result<bool, DecodeError> {
        let at = self.pos;
        match self.u8(what)? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(self.invalid(at, what, v.into())),
        }
    }

    fn prim<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], DecodeError> {
        self.align(N, what)?;
        let mut a = self.array::<N>(what)?;
        if !self.le {
            a.reverse();
        }
        Ok(a)
    }

    pub(crate) fn u16(&mut self, what: &'static str) -> Result<u16, DecodeError> {
        self.prim(what).map(u16::from_le_bytes)
    }

    pub(crate) fn i16(&mut self, what: &'static str) -> Result<i16, DecodeError> {
        self.prim(what).map(i16::from_le_bytes)
    }

    pub(crate) fn u32(&mut self, what: &'static str) -> Result<u32, DecodeError> {
        self.prim(what).map(u32::from_le_bytes)
    }

    pub(crate) fn i32(&mut self, what: &'static str) -> Result<i32, DecodeError> {
        self.prim(what).map(i32::from_le_bytes)
    }

    pub(crate) fn u64(&mut self, what: &'static str) -> Result<u64, DecodeError> {
        self.prim(what).map(u64::from_le_bytes)
    }

    /// `sequence<octet>`: u32 count, then the bytes. The count is checked
    /// against the payload before anything is allocated.
    pub(crate) fn octets(&mut self, what: &'static str) -> Result<Vec<u8>, DecodeError> {
        let n = self.u32(what)?;
        Ok(self.bytes(n as usize, what)?.to_vec())
    }

    /// `string`: u32 length including the NUL, the bytes, the NUL.
    pub(crate) fn string(&mut self, what: &'static str) -> Result<String, DecodeError> {
        self.align(4, what)?;
        let at = self.pos;
        let n = self.u32(what)? as usize;
        if n == 0 {
            return Err(self.invalid(at, what, 0));
        }
        let start = self.pos;
        let b = self.bytes(n, what)?;
        if b[n - 1] != 0 {
            return Err(self.invalid(start + n - 1, what, b[n - 1].into()));
        }
        String::from_utf8(b[..n - 1].to_vec()).map_err(|_| DecodeError::NotUtf8 {
            offset: start,
            what,
        })
    }

    /// An optional: a boolean, then the value when it is true.
    pub(crate) fn optional<T>(
        &mut self,
        what: &'static str,
        f: impl FnOnce(&mut Self) -> Result<T, DecodeError>,
    ) -> Result<Option<T>, DecodeError> {
        if self.bool(what)? {
            f(self).map(Some)
        } else {
            Ok(None)
        }
    }

    /// A u32 count, then that many elements; nothing is reserved up front.
    pub(crate) fn sequence<T>(
        &mut self,
        what: &'static str,
        mut f: impl FnMut(&mut Self) -> Result<T, DecodeError>,
    ) -> Result<Vec<T>, DecodeError> {
        let n = self.u32(what)?;
        let mut v = Vec::new();
        for _ in 0..n {
            if self.remaining() == 0 {
                return Err(self.truncated(what, 1));
            }
            v.push(f(self)?);
        }
        Ok(v)
    }
}

/// Appends CDR primitives to a message buffer; alignment is relative to
/// the byte where the message starts.
pub(crate) struct Writer<'a> {
    out: &'a mut Vec<u8>,
    origin: usize,
    le: bool,
    /// Contents for the padding bytes, in order; zeros once used up.
    padding: &'a [u8],
    /// Padding bytes written so far.
    pub(crate) padded: usize,
}

impl<'a> Writer<'a> {
    pub(crate) fn new(out: &'a mut Vec<u8>, origin: usize, le: bool, padding: &'a [u8]) -> Self {
        Writer {
            out,
            origin,
            le,
            padding,
            padded: 0,
        }
    }

    pub(crate) fn align(&mut self, size: usize) {
        let pos = self.out.len() - self.origin;
        let pad = (size - pos % size) % size;
        for _ in 0..pad {
            let b = self.padding.get(self.padded).copied().unwrap_or(0);
            self.out.push(b);
            self.padded += 1;
        }
    }

    pub(crate) fn bytes(&mut self, b: &[u8]) {
        self.out.extend_from_slice(b);
    }

    pub(crate) fn u8(&mut self, v: u8) {
        self.out.push(v);
    }

    pub(crate) fn bool(&mut self, v: bool) {
        self.out.push(v.into());
    }

    fn prim<const N: usize>(&mut self, mut le_bytes: [u8; N]) {
        self.align(N);
        if !self.le {
            le_bytes.reverse();
        }
        self.out.extend_from_slice(&le_bytes);
    }

    pub(crate) fn u16(&mut self, v: u16) {
        self.prim(v.to_le_bytes());
    }

    pub(crate) fn i16(&mut self, v: i16) {
        self.prim(v.to_le_bytes());
    }

    pub(crate) fn u32(&mut self, v: u32) {
        self.prim(v.to_le_bytes());
    }

    pub(crate) fn i32(&mut self, v: i32) {
        self.prim(v.to_le_bytes());
    }

    pub(crate) fn u64(&mut self, v: u64) {
        self.prim(v.to_le_bytes());
    }

    fn count(&mut self, what: &'static str, n: usize) -> Result<(), EncodeError> {
        let n = u32::try_from(n).map_err(|_| EncodeError::TooLong {
            what,
            len: n,
            max: u32::MAX as usize,
        })?;
        self.u32(n);
        Ok(())
    }

    pub(crate) fn octets(&mut self, what: &'static str, b: &[u8]) -> Result<(), EncodeError> {
        self.count(what, b.len())?;
        self.bytes(b);
        Ok(())
    }

    pub(crate) fn string(&mut self, what: &'static str, s: &str) -> Result<(), EncodeError> {
        self.count(what, s.len() + 1)?;
        self.bytes(s.as_bytes());
        self.u8(0);
        Ok(())
    }

    pub(crate) fn optional<T>(
        &mut self,
        v: Option<&T>,
        f: impl FnOnce(&mut Self, &T) -> Result<(), EncodeError>,
    ) -> Result<(), EncodeError> {
        self.bool(v.is_some());
        match v {
            Some(v) => f(self, v),
            None => Ok(()),
        }
    }

    pub(crate) fn sequence<T>(
        &mut self,
        what: &'static str,
        items: &[T],
        mut f: impl FnMut(&mut Self, &T) -> Result<(), EncodeError>,
    ) -> Result<(), EncodeError> {
        self.count(what, items.len())?;
        items.iter().try_for_each(|i| f(self, i))
    }
}
