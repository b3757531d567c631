//! Low-level IPC data codec: the primitive encodings of ipc.md §9.3.
//!
//! IPC data is packed (no alignment, no tags) and written in the sender's
//! native byte order; the receiver learns the sender's order from the
//! data-endian nibble of the frame's `classId` and swaps 2-, 4- and 8-byte
//! items when it differs from its own.

use super::DecodeError;

/// Byte order of IPC message data (the data-endian nibble of `classId`, ipc.md §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// Most significant byte first (nibble value 1).
    Big,
    /// Least significant byte first (nibble value 2).
    Little,
}

impl ByteOrder {
    /// The byte order of this machine, which is what C senders use.
    pub const NATIVE: ByteOrder = if cfg!(target_endian = "big") {
        ByteOrder::Big
    } else {
        ByteOrder::Little
    };

    /// The `classId` nibble value for this order (1 = big, 2 = little).
    pub const fn nibble(self) -> u8 {
        match self {
            ByteOrder::Big => 1,
            ByteOrder::Little => 2,
        }
    }

    /// The byte order named by a `classId` nibble; `None` for PDP (3) or unknown values.
    pub const fn from_nibble(n: u8) -> Option<ByteOrder> {
        match n {
            1 => Some(ByteOrder::Big),
            2 => Some(ByteOrder::Little),
            _ => None,
        }
    }
}

/// The filler byte that follows a zero-length string, and the "present" flag of a pointer.
pub const PRESENT: u8 = b'Z';

/// Appends IPC-marshalled data to a buffer, in native byte order.
#[derive(Debug, Default, Clone)]
pub struct Writer {
    buf: Vec<u8>,
}

macro_rules! put_num {
    ($($name:ident: $t:ty),* $(,)?) => {$(
        #[doc = concat!("Appends a `", stringify!($t), "` in native byte order.")]
        #[inline]
        pub fn $name(&mut self, v: $t) {
            self.buf.extend_from_slice(&v.to_ne_bytes());
        }
    )*};
}

impl Writer {
    /// An empty writer.
    pub fn new() -> Self {
        Writer { buf: Vec::new() }
    }

    /// An empty writer with room for `n` bytes.
    pub fn with_capacity(n: usize) -> Self {
        Writer {
            buf: Vec::with_capacity(n),
        }
    }

    /// Appends to an existing buffer (its current contents are kept).
    pub fn from_vec(buf: Vec<u8>) -> Self {
        Writer { buf }
    }

    /// The bytes written so far.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Number of bytes written so far.
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    /// True if nothing was written.
    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }

    /// Reserves room for `n` more bytes.
    pub fn reserve(&mut self, n: usize) {
        self.buf.reserve(n);
    }

    /// Returns the buffer.
    pub fn into_vec(self) -> Vec<u8> {
        self.buf
    }

    put_num! {
        write_i16: i16, write_u16: u16,
        write_i32: i32, write_u32: u32,
        write_i64: i64, write_u64: u64,
        write_f32: f32, write_f64: f64,
    }

    /// Appends one byte.
    #[inline]
    pub fn write_u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Appends one signed byte.
    #[inline]
    pub fn write_i8(&mut self, v: i8) {
        self.buf.push(v as u8);
    }

    /// Appends raw bytes (no length prefix).
    #[inline]
    pub fn write_bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }

    /// Appends a `boolean`: a native `int`, 1 for true, 0 for false.
    #[inline]
    pub fn write_bool(&mut self, v: bool) {
        self.write_i32(v as i32);
    }

    /// Appends a count or length as `int32`.
    ///
    /// IPC counts are C `int`s; a length above `i32::MAX` cannot be represented
    /// by any IPC peer and is written saturated (the caller must not produce
    /// such data: the C library could not receive it either).
    #[inline]
    pub fn write_len(&mut self, n: usize) {
        self.write_i32(i32::try_from(n).unwrap_or(i32::MAX));
    }

    /// Appends a `string`: `int32` length, the bytes, no NUL. The empty string
    /// (and C's NULL) is `0` followed by the filler byte `'Z'`.
    #[inline]
    pub fn write_str(&mut self, s: &str) {
        if s.is_empty() {
            self.write_i32(0);
            self.buf.push(PRESENT);
        } else {
            self.write_len(s.len());
            self.buf.extend_from_slice(s.as_bytes());
        }
    }

    /// Appends a pointer flag: `'Z'` if present (its pointee follows), 0 if NULL.
    #[inline]
    pub fn write_ptr_flag(&mut self, present: bool) {
        self.buf.push(if present { PRESENT } else { 0 });
    }
}

/// Reads IPC-marshalled data from a byte slice in a given byte order.
///
/// Every read checks the remaining length first; nothing is allocated
/// for more elements than the remaining input could hold.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    order: ByteOrder,
    depth: usize,
}

macro_rules! get_num {
    ($($name:ident: $t:ty),* $(,)?) => {$(
        #[doc = concat!("Reads a `", stringify!($t), "` in the reader's byte order.")]
        #[inline]
        pub fn $name(&mut self) -> Result<$t, DecodeError> {
            const N: usize = core::mem::size_of::<$t>();
            let b: [u8; N] = self.take_array::<N>()?;
            Ok(match self.order {
                ByteOrder::Little => <$t>::from_le_bytes(b),
                ByteOrder::Big => <$t>::from_be_bytes(b),
            })
        }
    )*};
}

impl<'a> Reader<'a> {
    /// A reader over `buf` whose data was written in `order`.
    pub fn new(buf: &'a [u8], order: ByteOrder) -> Self {
        Reader {
            buf,
            pos: 0,
            order,
            depth: 0,
        }
    }

    /// A reader over data in this machine's byte order.
    pub fn native(buf: &'a [u8]) -> Self {
        Self::new(buf, ByteOrder::NATIVE)
    }

    /// The byte order the data is read in.
    pub fn order(&self) -> ByteOrder {
        self.order
    }

    /// Current offset from the start of the input.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// The unread bytes.
    pub fn rest(&self) -> &'a [u8] {
        &self.buf[self.pos..]
    }

    /// Fails with [`DecodeError::TrailingBytes`] unless all input was consumed.
    pub fn finish(&self) -> Result<(), DecodeError> {
        if self.remaining() == 0 {
            Ok(())
        } else {
            Err(DecodeError::TrailingBytes {
                offset: self.pos,
                count: self.remaining(),
            })
        }
    }

    /// Takes `n` raw bytes.
    #[inline]
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(DecodeError::UnexpectedEnd {
                offset: self.pos,
                needed: n,
                remaining: self.remaining(),
            });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    #[inline]
    fn take_array<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    get_num! {
        read_i16: i16, read_u16: u16,
        read_i32: i32, read_u32: u32,
        read_i64: i64, read_u64: u64,
        read_f32: f32, read_f64: f64,
    }

    /// Reads one byte.
    #[inline]
    pub fn read_u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take_array::<1>()?[0])
    }

    /// Reads one signed byte.
    #[inline]
    pub fn read_i8(&mut self) -> Result<i8, DecodeError> {
        Ok(self.read_u8()? as i8)
    }

    /// Reads a `boolean` (native `int`; any non-zero value is true, as in C).
    #[inline]
    pub fn read_bool(&mut self) -> Result<bool, DecodeError> {
        Ok(self.read_i32()? != 0)
    }

    /// Reads an `int32` count of elements that take at least `min_size` bytes
    /// each, and checks it against the remaining input before anyone allocates.
    pub fn read_count(&mut self, min_size: usize) -> Result<usize, DecodeError> {
        let offset = self.pos;
        let n = self.read_i32()?;
        self.check_count(offset, n as i64, min_size)
    }

    /// Checks that `n` elements of at least `min_size` bytes can follow.
    /// Elements of size 0 are limited to the remaining byte count, so that
    /// a hostile count can never make the decoder loop or allocate unboundedly.
    pub fn check_count(
        &self,
        offset: usize,
        n: i64,
        min_size: usize,
    ) -> Result<usize, DecodeError> {
        if n < 0 {
            return Err(DecodeError::NegativeCount { offset, count: n });
        }
        let n = n as u64;
        let need = n.saturating_mul(min_size.max(1) as u64);
        if need > self.remaining() as u64 {
            return Err(DecodeError::CountTooLarge {
                offset,
                count: n,
                remaining: self.remaining(),
            });
        }
        Ok(n as usize)
    }

    /// Reads a `string`: `int32` length, then the bytes; length 0 is
    /// followed by one filler byte and means "" (C's NULL).
    pub fn read_str(&mut self) -> Result<&'a str, DecodeError> {
        let offset = self.pos;
        let n = self.read_count(1)?;
        if n == 0 {
            // The C encoder always writes a filler byte after a zero length.
            self.take(1)?;
            return Ok("");
        }
        let b = self.take(n)?;
        core::str::from_utf8(b).map_err(|e| DecodeError::InvalidUtf8 {
            offset: offset + 4 + e.valid_up_to(),
        })
    }

    /// Enters a nested pointer level; fails past [`super::MAX_DEPTH`] so
    /// that hostile recursive data cannot overflow the stack.
    pub fn enter(&mut self) -> Result<(), DecodeError> {
        if self.depth >= super::MAX_DEPTH {
            return Err(DecodeError::TooDeep {
                offset: self.pos,
                max: super::MAX_DEPTH,
            });
        }
        self.depth += 1;
        Ok(())
    }

    /// Leaves a level entered with [`Reader::enter`].
    pub fn leave(&mut self) {
        self.depth = self.depth.saturating_sub(1);
    }

    /// Reads a pointer flag: `'Z'` (present) or 0 (NULL); anything else is an error.
    pub fn read_ptr_flag(&mut self) -> Result<bool, DecodeError> {
        let offset = self.pos;
        match self.read_u8()? {
            PRESENT => Ok(true),
            0 => Ok(false),
            b => Err(DecodeError::InvalidPointerFlag { offset, byte: b }),
        }
    }
}
