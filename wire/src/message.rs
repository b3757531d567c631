//! The [`IpcMessage`] trait and its implementations for primitives, strings,
//! fixed arrays and pointers.

use crate::cdr::{self, Extensibility};
use crate::const_str::{array_format, array_type_name, ConstStr};
use crate::ipc;

/// A Rust type with an IPC format and IPC and CDR encodings.
///
/// Implemented for the primitives of the IPC format language and derived
/// for structs and enums with `#[derive(IpcMessage)]`; the derive is the
/// normal way to implement it. The methods are the building blocks the
/// derive calls; users marshal with [`ipc::to_vec`] / [`cdr::to_vec`].
///
/// | IPC | Rust |
/// |---|---|
/// | `char` | `char` (Latin-1) |
/// | `byte` / `ubyte` | `i8` / `u8` |
/// | `short` / `ushort` | `i16` / `u16` |
/// | `int` / `uint` | `i32` / `u32` |
/// | `long` / `ulong` | `i64` / `u64` (8 bytes, as the 64-bit C library sends) |
/// | `float` / `double` | `f32` / `f64` |
/// | `boolean` | `bool` (4 bytes) |
/// | `string` | `String`, `Option<String>` |
/// | `[T:n]` | `[T; n]` |
/// | `*T` | `Option<Box<T>>` |
#[diagnostic::on_unimplemented(
    message = "`{Self}` is not an IPC message type",
    label = "`IpcMessage` is not implemented for `{Self}`",
    note = "derive it with `#[derive(courier::IpcMessage)]`; an `NdVec` or `Matrix` field is `<T:k1,k2>` and needs its size fields named, `#[ipc(len = \"rows, cols\")]`"
)]
pub trait IpcMessage: Sized {
    /// The IPC format string (manual §3), e.g. `"{int, {enum : 3}, [double:2,3], double}"`.
    const FORMAT: &'static str;
    /// How this type is written as a field of another format: its
    /// [`FORMAT`](Self::FORMAT), or for a named struct its format name.
    const FIELD_FORMAT: &'static str = Self::FORMAT;
    /// The name under which [`FORMAT`](Self::FORMAT) is registered as a
    /// named format (`IPC_defineFormat`), if the type is referenced by name.
    const FORMAT_NAME: Option<&'static str> = None;
    /// The DDS type name (`#[ipc(type_name = "...")]`).
    const TYPE_NAME: &'static str;
    /// DDS-XTypes extensibility of the CDR encoding.
    const EXTENSIBILITY: Extensibility = Extensibility::Final;
    /// Fewest bytes one value takes in IPC encoding (bounds allocations when decoding counts).
    const IPC_MIN_SIZE: usize;
    /// Fewest bytes one value takes in CDR encoding, ignoring alignment.
    const CDR_MIN_SIZE: usize;
    /// A CDR primitive: XCDR2 writes no `DHEADER` before sequences and
    /// arrays of it, and a mutable struct's member that is a sequence of
    /// it gets the `EMHEADER` length code of its element size. True for
    /// the integers, floats, `bool` and `char` only, as Cyclone DDS
    /// decides (`is_primitive_type` in `dds_cdrstream.c`): not for enums,
    /// though one is an int32 on the wire, nor for strings, structs or
    /// arrays.
    const CDR_PRIMITIVE: bool = false;
    /// The most bytes a whole value takes in the key-hash form
    /// ([`cdr::Writer::key_hash_form_in`]: big-endian, every struct final,
    /// its members in member-id order) of each XCDR version, exact up to
    /// 16 bytes: what a key member of this type contributes to the key of
    /// a struct when the type has no key fields of its own.
    /// [`cdr::MaxSize::UNBOUNDED`] unless the type says (an unbounded
    /// `String` or `Vec`, a pointer); `#[derive(IpcMessage)]` adds up its
    /// fields, a bounded `String` or `Vec` (`#[ipc(bound = N)]`) counting
    /// at its bound.
    ///
    /// ```
    /// use courier_wire::IpcMessage;
    /// use courier_wire::cdr::Version;
    /// assert_eq!(i64::CDR_MAX_SIZE.max_len(), Some(8));
    /// assert_eq!(<[u16; 3]>::CDR_MAX_SIZE.max_len(), Some(6));
    /// assert_eq!(String::CDR_MAX_SIZE.max_len(), None);
    /// // where it starts matters: a long long after 4 bytes ends at 12
    /// // in XCDR2 (aligned to 4), at 16 in XCDR1 (aligned to 8)
    /// assert_eq!(i64::CDR_MAX_SIZE.end_in(Version::Xcdr2, 4), Some(12));
    /// assert_eq!(i64::CDR_MAX_SIZE.end_in(Version::Xcdr1, 4), Some(16));
    /// ```
    const CDR_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::UNBOUNDED;
    /// The most bytes the key ([`cdr_encode_key`](Self::cdr_encode_key))
    /// takes in the key-hash form of each XCDR version, key members in
    /// member-id order. It decides what the DDS key hash of an instance is
    /// (DDSI-RTPS 2.5 §9.6.4.8) in that version: the key zero-padded to 16
    /// bytes when this is at most 16
    /// ([`cdr::MaxSize::fits_key_hash_in`]), else the key's MD5 digest,
    /// whatever the length of the actual value. A bounded string
    /// (`#[ipc(key, bound = 11)] name: String`, IDL `@key string<11>`)
    /// counts as 4 + 11 + 1 bytes, as Cyclone DDS and Fast DDS count it.
    /// The XCDR1 maximum is Cyclone DDS's `DDS_TOPIC_FIXED_KEY` (and Fast
    /// DDS's `getKeyMaxCdrSerializedSize`), the XCDR2 one its
    /// `DDS_TOPIC_FIXED_KEY_XCDR2`.
    ///
    /// ```
    /// use courier_wire::IpcMessage;
    /// use courier_wire::cdr::Version;
    /// assert!(u64::CDR_KEY_MAX_SIZE.fits_key_hash());
    /// assert!(u64::CDR_KEY_MAX_SIZE.fits_key_hash_in(Version::Xcdr1));
    /// assert!(!<[u32; 5]>::CDR_KEY_MAX_SIZE.fits_key_hash());
    /// ```
    const CDR_KEY_MAX_SIZE: cdr::MaxSize = Self::CDR_MAX_SIZE;
    /// Names of the key fields (`#[ipc(key)]`), for keyed DDS topics.
    const KEYS: &'static [&'static str] = &[];
    /// [`check_lengths`](Self::check_lengths) has something to check: the
    /// type (or a type inside it) has a `Vec` whose length lives in a field,
    /// a bounded `String` or `Vec` (`#[ipc(bound = N)]`), or a `char`.
    const CHECKS_LENGTHS: bool = false;

    /// `Err` if a `Vec` is longer than its length field's type can say (300
    /// elements with `#[ipc(len = "n")]` on `n: u8`): both encoders would
    /// send only as many as the field holds; if a `String` or `Vec` is
    /// longer than its `#[ipc(bound = N)]`, which a DDS reader of the
    /// bounded IDL type would refuse; or if a `char` is above U+00FF,
    /// which its one byte cannot carry. A session checks before it
    /// encodes what it publishes, queries or replies; [`ipc::to_vec`] and
    /// [`cdr::to_vec`] do not check (they send that many, and `'?'`).
    fn check_lengths(&self) -> Result<(), LengthError> {
        Ok(())
    }

    /// Adds the named formats this type's format refers to (itself included
    /// when it is named), so a session can register them (`IPC_defineFormat`)
    /// before the format is used.
    fn named_formats(out: &mut NamedFormats) {
        let _ = out;
    }

    /// Appends the IPC encoding.
    fn ipc_encode(&self, w: &mut ipc::Writer);
    /// Reads one value from IPC data.
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError>;

    /// Appends the IPC encoding of every item (bulk copy for primitives).
    fn ipc_encode_slice(items: &[Self], w: &mut ipc::Writer) {
        for it in items {
            it.ipc_encode(w);
        }
    }

    /// Reads `n` values; `n` must already be checked against the input
    /// (see [`ipc::Reader::read_count`]).
    fn ipc_decode_vec(r: &mut ipc::Reader<'_>, n: usize) -> Result<Vec<Self>, ipc::DecodeError> {
        let n = r.check_count(r.position(), n as i64, Self::IPC_MIN_SIZE)?;
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(Self::ipc_decode(r)?);
        }
        Ok(v)
    }

    /// Appends the CDR encoding.
    fn cdr_encode(&self, w: &mut cdr::Writer);
    /// Reads one value from CDR data.
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError>;

    /// The value a member of this type takes when the data leaves it out
    /// (XTypes: a member a mutable struct's writer does not have, or one
    /// past the end of an appendable struct's data): zero, false, empty,
    /// the first enumerator; a struct of its members' defaults. `None`
    /// when the type has none, and a missing member is then
    /// [`cdr::DecodeError::MissingMember`].
    #[doc(hidden)]
    fn cdr_default() -> Option<Self> {
        None
    }

    /// [`ipc_decode`](Self::ipc_decode) into a box (what a `Box<Self>`
    /// field decodes with): a fixed array builds its elements on the heap,
    /// not on the stack, where a large one (`Box<[u8; 1_000_000]>`)
    /// overflowed a 2 MiB tokio worker stack in debug builds.
    #[doc(hidden)]
    fn ipc_decode_boxed(r: &mut ipc::Reader<'_>) -> Result<Box<Self>, ipc::DecodeError> {
        Self::ipc_decode(r).map(Box::new)
    }

    /// [`cdr_decode`](Self::cdr_decode) into a box (see
    /// [`ipc_decode_boxed`](Self::ipc_decode_boxed)).
    #[doc(hidden)]
    fn cdr_decode_boxed(r: &mut cdr::Reader<'_>) -> Result<Box<Self>, cdr::DecodeError> {
        Self::cdr_decode(r).map(Box::new)
    }

    /// Appends the CDR encoding of every item, without count or `DHEADER`.
    fn cdr_encode_slice(items: &[Self], w: &mut cdr::Writer) {
        for it in items {
            it.cdr_encode(w);
        }
    }

    /// Reads `n` values, without count or `DHEADER`.
    fn cdr_decode_vec(r: &mut cdr::Reader<'_>, n: usize) -> Result<Vec<Self>, cdr::DecodeError> {
        if n.saturating_mul(Self::CDR_MIN_SIZE.max(1)) > r.remaining() {
            return Err(cdr::DecodeError::CountTooLarge {
                offset: r.position(),
                count: n as u64,
                remaining: r.remaining(),
            });
        }
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(Self::cdr_decode(r)?);
        }
        Ok(v)
    }

    /// CDR: true for fixed arrays `[T; N]`. Nested arrays are one
    /// multi-dimensional array to DDS: written flat, with one `DHEADER`.
    #[doc(hidden)]
    const CDR_IS_ARRAY: bool = false;
    /// CDR: the innermost element of a (nested) array is a primitive
    /// ([`CDR_PRIMITIVE`](Self::CDR_PRIMITIVE)), so XCDR2 writes no
    /// `DHEADER` before the array.
    #[doc(hidden)]
    const CDR_FLAT_PRIMITIVE: bool = Self::CDR_PRIMITIVE;

    /// [`CDR_MAX_SIZE`](Self::CDR_MAX_SIZE) of what
    /// [`cdr_encode_flat`](Self::cdr_encode_flat) writes: for an array,
    /// its elements without `DHEADER`.
    #[doc(hidden)]
    const CDR_FLAT_MAX_SIZE: cdr::MaxSize = Self::CDR_MAX_SIZE;

    /// Appends the elements of a (multi-dimensional) array without any
    /// `DHEADER`; other types write themselves.
    #[doc(hidden)]
    fn cdr_encode_flat(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }

    /// Reads what [`IpcMessage::cdr_encode_flat`] wrote.
    #[doc(hidden)]
    fn cdr_decode_flat(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }

    /// Appends the key fields only, in declaration order (DDS key hash and
    /// dispose/unregister payloads). Types without keys write nothing.
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        let _ = w;
    }

    /// What names an instance of a keyed DDS topic of this type: for a
    /// type with key fields (`#[ipc(key)]`), the key field's own `Key`
    /// when there is one key field, else a tuple of them in declaration
    /// order; for a type without key fields, the whole value (`Self`),
    /// which is what such a type contributes as a key field of another.
    /// `#[derive(IpcMessage)]` picks it.
    type Key;

    /// Reads the key that [`cdr_encode_key`](Self::cdr_encode_key) writes
    /// (for a type without key fields: the whole value, as
    /// [`cdr_decode`](Self::cdr_decode) reads it). See [`cdr::key_from_slice`].
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self::Key, cdr::DecodeError>;

    /// Appends what [`cdr_encode_key`](Self::cdr_encode_key) writes for a
    /// value whose key is `key` (as [`cdr_decode_key`](Self::cdr_decode_key)
    /// read it): the key hash of a dispose that carries only the
    /// serialized key ([`cdr::key_hash_of_key`]). For a type that is its own
    /// key, all of it, as a key field of another type contributes it. False
    /// (and the writer's content undefined) if the type cannot say.
    #[doc(hidden)]
    fn cdr_encode_key_value(key: &Self::Key, w: &mut cdr::Writer) -> bool {
        let _ = (key, w);
        false
    }
}

/// `cdr_encode_key_value` of a type that is its own key: all of it.
macro_rules! own_key_value {
    () => {
        fn cdr_encode_key_value(key: &Self::Key, w: &mut cdr::Writer) -> bool {
            IpcMessage::cdr_encode(key, w);
            true
        }
    };
}

/// A value longer than its type lets it be ([`IpcMessage::check_lengths`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LengthError {
    /// A `Vec` longer than its length field's type can say.
    #[error(
        "field `{field}` has {len} elements, more than its length field `{count}` ({count_type}) can say ({max})"
    )]
    Count {
        /// The `Vec` field.
        field: &'static str,
        /// Its length field.
        count: &'static str,
        /// The length field's type.
        count_type: &'static str,
        /// The `Vec`'s length.
        len: usize,
        /// The most the length field holds (at most `i32::MAX`, IPC's count).
        max: u64,
    },
    /// A `String` or `Vec` longer than its `#[ipc(bound = N)]` (IDL
    /// `string<N>`, `sequence<T, N>`; XDR `string<N>`, `T x<N>`).
    #[error("field `{field}` has {len} {unit}, more than its bound of {bound}")]
    Bound {
        /// The field.
        field: &'static str,
        /// Its length: bytes of a `String` (CDR's count, without the NUL),
        /// elements of a `Vec`.
        len: usize,
        /// `"bytes"` or `"elements"`.
        unit: &'static str,
        /// The bound.
        bound: u64,
    },
    /// A `char` above U+00FF, which a one-byte `char` (IPC's, and the IDL
    /// `char` the derive declares) cannot carry.
    #[error(
        "{} holds {value:?} (U+{:04X}), which a one-byte char (IPC and DDS `char`, Latin-1) cannot carry: use a String, or #[ipc(char)] u8 for raw bytes",
        what(field),
        u32::from(*value)
    )]
    NotLatin1 {
        /// The field (empty for a message that is one `char`).
        field: &'static str,
        /// The char.
        value: char,
    },
}

/// "field `x`", or "the value" for a message that is one `char`.
fn what(field: &str) -> String {
    if field.is_empty() {
        "the value".to_owned()
    } else {
        format!("field `{field}`")
    }
}

impl LengthError {
    /// The field that is too long (or holds the char).
    pub fn field(&self) -> &'static str {
        match self {
            LengthError::Count { field, .. }
            | LengthError::Bound { field, .. }
            | LengthError::NotLatin1 { field, .. } => field,
        }
    }

    /// Its length (1 for a char).
    pub fn length(&self) -> usize {
        match self {
            LengthError::Count { len, .. } | LengthError::Bound { len, .. } => *len,
            LengthError::NotLatin1 { .. } => 1,
        }
    }

    /// Names `field` as where a char is that said no field (a `char`, an
    /// array or `Vec` of them, checked by the struct that holds it).
    #[doc(hidden)]
    pub fn in_field(mut self, name: &'static str) -> Self {
        if let LengthError::NotLatin1 { field, .. } = &mut self {
            if field.is_empty() {
                *field = name;
            }
        }
        self
    }
}

/// The named formats a type depends on, collected by
/// [`IpcMessage::named_formats`], each once, in discovery order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NamedFormats {
    entries: Vec<(&'static str, &'static str)>,
}

impl NamedFormats {
    /// An empty collection.
    pub fn new() -> Self {
        Self::default()
    }

    /// Collects the named formats of `T`.
    pub fn of<T: IpcMessage>() -> Self {
        let mut n = Self::new();
        T::named_formats(&mut n);
        n
    }

    /// Adds `name` ↦ `format`; returns false if the name is already
    /// present, which also stops recursion through mutually recursive
    /// types. A name already present with another format (two types of one
    /// name, in different modules) is kept as well, for
    /// [`conflict`](Self::conflict) to report: one format would be sent
    /// for both.
    pub fn insert(&mut self, name: &'static str, format: &'static str) -> bool {
        match self.get(name) {
            Some(f) if f == format => false,
            Some(_) => {
                if !self.entries.contains(&(name, format)) {
                    self.entries.push((name, format));
                }
                false
            }
            None => {
                self.entries.push((name, format));
                true
            }
        }
    }

    /// The first name collected with two formats: `(name, first, second)`.
    /// IPC knows formats by name only, so a message carrying both types
    /// would be read with one of the formats for both; give one of them
    /// its own name (`#[ipc(name = "...")]`).
    pub fn conflict(&self) -> Option<(&'static str, &'static str, &'static str)> {
        self.entries.iter().enumerate().find_map(|(i, (n, f))| {
            self.entries[..i]
                .iter()
                .find(|(m, g)| m == n && g != f)
                .map(|(_, g)| (*n, *g, *f))
        })
    }

    /// True if `name` was collected.
    pub fn contains(&self, name: &str) -> bool {
        self.entries.iter().any(|(n, _)| *n == name)
    }

    /// The format registered under `name`.
    pub fn get(&self, name: &str) -> Option<&'static str> {
        self.entries
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, f)| *f)
    }

    /// `(name, format)` pairs in the order they were found.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, &'static str)> + '_ {
        self.entries.iter().copied()
    }

    /// Number of named formats.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True if there are none.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Copies packed numbers from (possibly unaligned) bytes into a new `Vec`
/// in one pass. Safe alternatives either zero-fill first or copy element by
/// element; both measured at ~0.7× memcpy (`cargo bench -p courier --bench
/// marshal`), this one at memcpy speed.
#[allow(unsafe_code)]
fn copy_pod_vec<T: bytemuck::Pod>(bytes: &[u8]) -> Vec<T> {
    let n = bytes.len() / core::mem::size_of::<T>();
    let mut v = Vec::<T>::with_capacity(n);
    // SAFETY: `v` has capacity for `n` elements, i.e. `n * size_of::<T>()`
    // bytes, and is a fresh allocation, so the ranges cannot overlap; the
    // source holds at least that many bytes. `T: Pod` has no padding and
    // every bit pattern is a valid `T`, so after the copy the first `n`
    // elements are initialised and `set_len(n)` is sound.
    unsafe {
        core::ptr::copy_nonoverlapping(
            bytes.as_ptr(),
            v.as_mut_ptr().cast::<u8>(),
            n * core::mem::size_of::<T>(),
        );
        v.set_len(n);
    }
    v
}

/// Decodes a packed array of numbers: one copy, then a byte swap in place
/// when the data is in the other byte order.
macro_rules! bulk_decode {
    ($t:ty, $bytes:expr, $native:expr) => {{
        let mut v: Vec<$t> = copy_pod_vec($bytes);
        if !$native {
            for x in &mut v {
                *x = <$t>::from_ne_bytes(x.to_ne_bytes().map_rev());
            }
        }
        v
    }};
}

macro_rules! numeric {
    ($($t:ty => $fmt:literal, $idl:literal, $ipc_w:ident, $ipc_r:ident, $cdr_w:ident, $cdr_r:ident;)*) => {$(
        impl IpcMessage for $t {
            const FORMAT: &'static str = $fmt;
            const TYPE_NAME: &'static str = $idl;
            const IPC_MIN_SIZE: usize = core::mem::size_of::<$t>();
            const CDR_MIN_SIZE: usize = core::mem::size_of::<$t>();
            const CDR_PRIMITIVE: bool = true;
            const CDR_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::primitive(core::mem::size_of::<$t>());

            #[inline]
            fn ipc_encode(&self, w: &mut ipc::Writer) {
                w.$ipc_w(*self);
            }
            #[inline]
            fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
                r.$ipc_r()
            }
            fn ipc_encode_slice(items: &[Self], w: &mut ipc::Writer) {
                // IPC data is native order: one copy of the slice's memory.
                w.write_bytes(bytemuck::cast_slice(items));
            }
            fn ipc_decode_vec(r: &mut ipc::Reader<'_>, n: usize) -> Result<Vec<Self>, ipc::DecodeError> {
                let n = r.check_count(r.position(), n as i64, core::mem::size_of::<$t>())?;
                let bytes = r.take(n * core::mem::size_of::<$t>())?;
                Ok(bulk_decode!($t, bytes, r.order() == ipc::ByteOrder::NATIVE))
            }
            #[inline]
            fn cdr_encode(&self, w: &mut cdr::Writer) {
                w.$cdr_w(*self);
            }
            fn cdr_default() -> Option<Self> {
                Some(<$t>::default())
            }
            #[inline]
            fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
                r.$cdr_r()
            }
            fn cdr_encode_slice(items: &[Self], w: &mut cdr::Writer) {
                if items.is_empty() {
                    return;
                }
                w.align(core::mem::size_of::<$t>());
                if w.is_little_endian() == cfg!(target_endian = "little") {
                    w.write_bytes(bytemuck::cast_slice(items));
                } else {
                    w.reserve(items.len() * core::mem::size_of::<$t>());
                    for x in items {
                        w.write_bytes(&x.to_ne_bytes().map_rev());
                    }
                }
            }
            fn cdr_decode_vec(r: &mut cdr::Reader<'_>, n: usize) -> Result<Vec<Self>, cdr::DecodeError> {
                if n == 0 {
                    return Ok(Vec::new());
                }
                r.align(core::mem::size_of::<$t>())?;
                let size = n.checked_mul(core::mem::size_of::<$t>()).filter(|s| *s <= r.remaining()).ok_or(
                    cdr::DecodeError::CountTooLarge { offset: r.position(), count: n as u64, remaining: r.remaining() },
                )?;
                let bytes = r.take(size)?;
                let little = matches!(r.encoding().endianness(), cdr::Endianness::Little);
                Ok(bulk_decode!($t, bytes, little == cfg!(target_endian = "little")))
            }
            fn cdr_encode_key(&self, w: &mut cdr::Writer) {
                self.cdr_encode(w);
            }
            type Key = Self;
            own_key_value!();
            fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
                Self::cdr_decode(r)
            }
        }
    )*};
}

/// Byte reversal of a fixed-size byte array (for swapping decoded numbers).
trait MapRev {
    fn map_rev(self) -> Self;
}
impl<const N: usize> MapRev for [u8; N] {
    #[inline]
    fn map_rev(mut self) -> Self {
        self.reverse();
        self
    }
}

numeric! {
    i8 => "byte", "int8", write_i8, read_i8, write_i8, read_i8;
    u8 => "ubyte", "uint8", write_u8, read_u8, write_u8, read_u8;
    i16 => "short", "int16", write_i16, read_i16, write_i16, read_i16;
    u16 => "ushort", "uint16", write_u16, read_u16, write_u16, read_u16;
    i32 => "int", "int32", write_i32, read_i32, write_i32, read_i32;
    u32 => "uint", "uint32", write_u32, read_u32, write_u32, read_u32;
    i64 => "long", "int64", write_i64, read_i64, write_i64, read_i64;
    u64 => "ulong", "uint64", write_u64, read_u64, write_u64, read_u64;
    f32 => "float", "float", write_f32, read_f32, write_f32, read_f32;
    f64 => "double", "double", write_f64, read_f64, write_f64, read_f64;
}

impl IpcMessage for bool {
    const FORMAT: &'static str = "boolean";
    const TYPE_NAME: &'static str = "boolean";
    const IPC_MIN_SIZE: usize = 4;
    const CDR_MIN_SIZE: usize = 1;
    const CDR_PRIMITIVE: bool = true;
    const CDR_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::primitive(1);

    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_bool(*self);
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        r.read_bool()
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        w.write_bool(*self);
    }
    fn cdr_default() -> Option<Self> {
        Some(false)
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        r.read_bool()
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// IPC `char` is one byte. Rust `char`s map to Latin-1: U+0000–U+00FF
/// travel as that byte. Any other char is refused by a session's publish,
/// query and reply ([`IpcMessage::check_lengths`],
/// [`LengthError::NotLatin1`]); [`ipc::to_vec`] and [`cdr::to_vec`], which
/// do not check, send `'?'` for it. Use `u8` with `#[ipc(char)]` for exact
/// bytes.
impl IpcMessage for char {
    const FORMAT: &'static str = "char";
    const TYPE_NAME: &'static str = "char";
    const IPC_MIN_SIZE: usize = 1;
    const CDR_MIN_SIZE: usize = 1;
    const CDR_PRIMITIVE: bool = true;
    const CDR_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::primitive(1);
    const CHECKS_LENGTHS: bool = true;

    fn check_lengths(&self) -> Result<(), LengthError> {
        if u32::from(*self) > 0xff {
            return Err(LengthError::NotLatin1 {
                field: "",
                value: *self,
            });
        }
        Ok(())
    }

    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_u8(latin1(*self));
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Ok(char::from(r.read_u8()?))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        w.write_u8(latin1(*self));
    }
    fn cdr_default() -> Option<Self> {
        Some('\0')
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Ok(char::from(r.read_u8()?))
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

fn latin1(c: char) -> u8 {
    u8::try_from(u32::from(c)).unwrap_or(b'?')
}

impl IpcMessage for String {
    const FORMAT: &'static str = "string";
    const TYPE_NAME: &'static str = "string";
    const IPC_MIN_SIZE: usize = 5;
    const CDR_MIN_SIZE: usize = 4;

    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_str(self);
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        r.read_str().map(str::to_owned)
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        w.write_string(self);
    }
    fn cdr_default() -> Option<Self> {
        Some(String::new())
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        r.read_str().map(str::to_owned)
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// `string` where NULL matters to the reader: `None` is sent as C's NULL,
/// and both NULL and `""` decode to `None` (they are the same bytes).
impl IpcMessage for Option<String> {
    const FORMAT: &'static str = "string";
    const TYPE_NAME: &'static str = "string";
    const IPC_MIN_SIZE: usize = 5;
    const CDR_MIN_SIZE: usize = 4;

    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_str(self.as_deref().unwrap_or(""));
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        let s = r.read_str()?;
        Ok((!s.is_empty()).then(|| s.to_owned()))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        w.write_string(self.as_deref().unwrap_or(""));
    }
    fn cdr_default() -> Option<Self> {
        Some(None)
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        let s = r.read_str()?;
        Ok((!s.is_empty()).then(|| s.to_owned()))
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// The empty message (`IPC_defineMsg(name, 0, NULL)`): no data at all.
impl IpcMessage for () {
    const FORMAT: &'static str = "";
    const TYPE_NAME: &'static str = "Empty";
    const IPC_MIN_SIZE: usize = 0;
    const CDR_MIN_SIZE: usize = 0;
    const CDR_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::EMPTY;

    fn ipc_encode(&self, _: &mut ipc::Writer) {}
    fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Ok(())
    }
    fn cdr_encode(&self, _: &mut cdr::Writer) {}
    fn cdr_default() -> Option<Self> {
        Some(())
    }
    fn cdr_decode(_: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Ok(())
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// A type name for a compile-time error message, `…` if too long to fit.
const fn short_type_name(name: &str) -> &str {
    if name.len() > 512 {
        "…"
    } else {
        name
    }
}

/// Compile-time format strings of generic types.
struct GenericFormat<T, const N: usize>(core::marker::PhantomData<T>);

impl<T: IpcMessage, const N: usize> GenericFormat<T, N> {
    const ARRAY: ConstStr = {
        if N > i32::MAX as usize {
            panic!("an IPC array holds at most 2147483647 elements (C's int): use a Vec with a length field");
        }
        if T::FIELD_FORMAT.is_empty() {
            let msg = ConstStr::new()
                .push_str("an array `[T; N]` of `")
                .push_str(short_type_name(T::TYPE_NAME))
                .push_str("`, a type with an empty IPC format (an empty message such as `()` or a unit struct): IPC arrays cannot hold it");
            panic!("{}", msg.as_str());
        }
        array_format(T::FIELD_FORMAT, N)
    };
    const ARRAY_REF: &'static ConstStr = &Self::ARRAY;
    const ARRAY_STR: &'static str = Self::ARRAY_REF.as_str();
    const ARRAY_TYPE: ConstStr = array_type_name(T::TYPE_NAME, N);
    const ARRAY_TYPE_REF: &'static ConstStr = &Self::ARRAY_TYPE;
    const ARRAY_TYPE_STR: &'static str = Self::ARRAY_TYPE_REF.as_str();
    const POINTER: ConstStr = {
        if T::FIELD_FORMAT.is_empty() {
            let msg = ConstStr::new()
                .push_str("a pointer `Option<Box<T>>` to `")
                .push_str(short_type_name(T::TYPE_NAME))
                .push_str("`, a type with an empty IPC format (an empty message such as `()` or a unit struct): IPC pointers cannot point to it");
            panic!("{}", msg.as_str());
        }
        ConstStr::new().push_str("*").push_str(T::FIELD_FORMAT)
    };
    const POINTER_REF: &'static ConstStr = &Self::POINTER;
    const POINTER_STR: &'static str = Self::POINTER_REF.as_str();
}

/// Fixed arrays `[T:n]`; nested arrays merge into `[T:n,m]`.
/// The `N` elements of a fixed array of `T`, without `DHEADER`, read into
/// a `Vec` (on the heap).
fn array_elements<T: IpcMessage, const N: usize>(
    r: &mut cdr::Reader<'_>,
) -> Result<Vec<T>, cdr::DecodeError> {
    if !T::CDR_IS_ARRAY {
        return T::cdr_decode_vec(r, N);
    }
    if N.saturating_mul(T::CDR_MIN_SIZE.max(1)) > r.remaining() {
        return Err(cdr::DecodeError::CountTooLarge {
            offset: r.position(),
            count: N as u64,
            remaining: r.remaining(),
        });
    }
    let mut v = Vec::with_capacity(N);
    for _ in 0..N {
        v.push(T::cdr_decode_flat(r)?);
    }
    Ok(v)
}

impl<T: IpcMessage, const N: usize> IpcMessage for [T; N] {
    const FORMAT: &'static str = GenericFormat::<T, N>::ARRAY_STR;
    /// `int32[4]`: not its element's name, which a reader of one element
    /// would match.
    const TYPE_NAME: &'static str = GenericFormat::<T, N>::ARRAY_TYPE_STR;
    const IPC_MIN_SIZE: usize = T::IPC_MIN_SIZE * N;
    const CDR_MIN_SIZE: usize = T::CDR_MIN_SIZE * N;
    const CHECKS_LENGTHS: bool = T::CHECKS_LENGTHS;

    fn check_lengths(&self) -> Result<(), LengthError> {
        if T::CHECKS_LENGTHS {
            self.iter().try_for_each(T::check_lengths)?;
        }
        Ok(())
    }

    fn named_formats(out: &mut NamedFormats) {
        T::named_formats(out);
    }
    fn ipc_encode(&self, w: &mut ipc::Writer) {
        T::ipc_encode_slice(self, w);
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        let v = T::ipc_decode_vec(r, N)?;
        v.try_into()
            .map_err(|_| ipc::DecodeError::Format("array length".into()))
    }
    fn ipc_decode_boxed(r: &mut ipc::Reader<'_>) -> Result<Box<Self>, ipc::DecodeError> {
        let v = T::ipc_decode_vec(r, N)?;
        v.into_boxed_slice()
            .try_into()
            .map_err(|_| ipc::DecodeError::Format("array length".into()))
    }
    const CDR_IS_ARRAY: bool = true;
    const CDR_FLAT_PRIMITIVE: bool = T::CDR_FLAT_PRIMITIVE;
    /// A `DHEADER` unless the innermost elements are primitive, then the
    /// elements (of a nested array: the inner arrays' elements).
    const CDR_MAX_SIZE: cdr::MaxSize =
        cdr::MaxSize::array(T::CDR_FLAT_MAX_SIZE, N, !T::CDR_FLAT_PRIMITIVE);
    const CDR_FLAT_MAX_SIZE: cdr::MaxSize = cdr::MaxSize::array(T::CDR_FLAT_MAX_SIZE, N, false);

    fn cdr_encode(&self, w: &mut cdr::Writer) {
        let d = w.begin_array(Self::CDR_FLAT_PRIMITIVE);
        self.cdr_encode_flat(w);
        w.end_dheader(d);
    }
    fn cdr_default() -> Option<Self> {
        let all: Vec<T> = (0..N).map(|_| T::cdr_default()).collect::<Option<_>>()?;
        all.try_into().ok()
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        let d = r.begin_array(Self::CDR_FLAT_PRIMITIVE)?;
        let v = Self::cdr_decode_flat(r)?;
        r.end_dheader(d);
        Ok(v)
    }
    fn cdr_decode_boxed(r: &mut cdr::Reader<'_>) -> Result<Box<Self>, cdr::DecodeError> {
        let d = r.begin_array(Self::CDR_FLAT_PRIMITIVE)?;
        let offset = r.position();
        let v = array_elements::<T, N>(r)?;
        r.end_dheader(d);
        let found = v.len();
        v.into_boxed_slice()
            .try_into()
            .map_err(|_| cdr::DecodeError::ArrayLength {
                offset,
                expected: N,
                found,
            })
    }
    fn cdr_encode_flat(&self, w: &mut cdr::Writer) {
        if T::CDR_IS_ARRAY {
            for x in self {
                x.cdr_encode_flat(w);
            }
        } else {
            T::cdr_encode_slice(self, w);
        }
    }
    fn cdr_decode_flat(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        let offset = r.position();
        let v = array_elements::<T, N>(r)?;
        let found = v.len();
        v.try_into().map_err(|_| cdr::DecodeError::ArrayLength {
            offset,
            expected: N,
            found,
        })
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// Pointers `*T`: a flag byte (`'Z'` or 0), then the pointee if present.
impl<T: IpcMessage> IpcMessage for Option<Box<T>> {
    const FORMAT: &'static str = GenericFormat::<T, 0>::POINTER_STR;
    const TYPE_NAME: &'static str = T::TYPE_NAME;
    const IPC_MIN_SIZE: usize = 1;
    const CDR_MIN_SIZE: usize = 1;
    // not `T::CHECKS_LENGTHS`: types that point at each other would make
    // the constant depend on itself
    const CHECKS_LENGTHS: bool = true;

    fn check_lengths(&self) -> Result<(), LengthError> {
        match self {
            Some(v) => v.check_lengths(),
            None => Ok(()),
        }
    }

    fn named_formats(out: &mut NamedFormats) {
        T::named_formats(out);
    }
    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_ptr_flag(self.is_some());
        if let Some(v) = self {
            v.ipc_encode(w);
        }
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        if !r.read_ptr_flag()? {
            return Ok(None);
        }
        r.enter()?;
        let v = T::ipc_decode_boxed(r);
        r.leave();
        Ok(Some(v?))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        cdr::write_optional(w, self.as_deref(), T::cdr_encode);
    }
    fn cdr_default() -> Option<Self> {
        Some(None)
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        cdr::read_optional(r, T::cdr_decode_boxed)
    }

    type Key = Self;
    own_key_value!();
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        Self::cdr_decode(r)
    }
}

/// `Box<T>` is encoded exactly as `T`.
impl<T: IpcMessage> IpcMessage for Box<T> {
    const FORMAT: &'static str = T::FORMAT;
    const FIELD_FORMAT: &'static str = T::FIELD_FORMAT;
    const FORMAT_NAME: Option<&'static str> = T::FORMAT_NAME;
    const TYPE_NAME: &'static str = T::TYPE_NAME;
    const EXTENSIBILITY: Extensibility = T::EXTENSIBILITY;
    const IPC_MIN_SIZE: usize = T::IPC_MIN_SIZE;
    const CDR_MIN_SIZE: usize = T::CDR_MIN_SIZE;
    const CDR_PRIMITIVE: bool = T::CDR_PRIMITIVE;
    const CDR_FLAT_PRIMITIVE: bool = T::CDR_FLAT_PRIMITIVE;
    const KEYS: &'static [&'static str] = T::KEYS;
    const CDR_MAX_SIZE: cdr::MaxSize = T::CDR_MAX_SIZE;
    const CDR_KEY_MAX_SIZE: cdr::MaxSize = T::CDR_KEY_MAX_SIZE;
    const CHECKS_LENGTHS: bool = T::CHECKS_LENGTHS;

    fn check_lengths(&self) -> Result<(), LengthError> {
        (**self).check_lengths()
    }
    fn named_formats(out: &mut NamedFormats) {
        T::named_formats(out);
    }
    fn ipc_encode(&self, w: &mut ipc::Writer) {
        (**self).ipc_encode(w);
    }
    fn ipc_decode(r: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        T::ipc_decode_boxed(r)
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        (**self).cdr_encode(w);
    }
    fn cdr_default() -> Option<Self> {
        T::cdr_default().map(Box::new)
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        T::cdr_decode_boxed(r)
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        (**self).cdr_encode_key(w);
    }
    type Key = T::Key;
    fn cdr_encode_key_value(key: &Self::Key, w: &mut cdr::Writer) -> bool {
        T::cdr_encode_key_value(key, w)
    }
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<T::Key, cdr::DecodeError> {
        T::cdr_decode_key(r)
    }
}

/// Helpers called by `#[derive(IpcMessage)]`-generated code. Not a stable API.
#[doc(hidden)]
pub mod __private {
    use super::*;
    pub use crate::const_str::ConstStr;
    use crate::ndvec::{NdVec, ShapeError};

    /// IPC variable array `<T:k>`: `int32` count, then the elements.
    pub fn ipc_encode_vec<T: IpcMessage>(v: &[T], w: &mut ipc::Writer) {
        w.write_len(v.len());
        T::ipc_encode_slice(v, w);
    }

    /// Reads an IPC variable array.
    pub fn ipc_decode_vec<T: IpcMessage>(
        r: &mut ipc::Reader<'_>,
    ) -> Result<Vec<T>, ipc::DecodeError> {
        let n = r.read_count(T::IPC_MIN_SIZE)?;
        T::ipc_decode_vec(r, n)
    }

    // The derived `CDR_MAX_SIZE` and `CDR_KEY_MAX_SIZE` read their
    // fields' constants through these functions rather than directly: a
    // constant that names another is evaluated as soon as its crate is
    // checked, and types that hold each other through bounded `Vec`s (`A`
    // a `Vec<B>`, `B` a `Vec<A>`) would then fail to compile, their
    // constants depending on themselves. Through a generic function a
    // constant is evaluated only when used: a key hash of such a type.

    /// `T::CDR_MAX_SIZE`, for a field of type `T`.
    pub const fn max_size<T: IpcMessage>() -> cdr::MaxSize {
        T::CDR_MAX_SIZE
    }

    /// What a key field of type `T` contributes to the key: its key if
    /// `T` has key fields, else all of it.
    pub const fn key_member_max_size<T: IpcMessage>() -> cdr::MaxSize {
        if T::KEYS.is_empty() {
            T::CDR_MAX_SIZE
        } else {
            T::CDR_KEY_MAX_SIZE
        }
    }

    /// A bounded sequence field of `T` (`#[ipc(bound = N)] Vec<T>`): a
    /// `DHEADER` unless `T` is primitive, the count, `bound` elements.
    pub const fn bounded_seq_max_size<T: IpcMessage>(bound: usize) -> cdr::MaxSize {
        cdr::MaxSize::bounded_sequence(T::CDR_MAX_SIZE, bound, !T::CDR_PRIMITIVE)
    }

    /// CDR sequence: (XCDR2 `DHEADER` for non-primitive elements), `u32` count, elements.
    pub fn cdr_encode_seq<T: IpcMessage>(v: &[T], w: &mut cdr::Writer) {
        let d = w.begin_sequence(v.len(), T::CDR_PRIMITIVE.then_some(T::CDR_MIN_SIZE));
        T::cdr_encode_slice(v, w);
        w.end_dheader(d);
    }

    /// Reads a CDR sequence.
    pub fn cdr_decode_seq<T: IpcMessage>(
        r: &mut cdr::Reader<'_>,
    ) -> Result<Vec<T>, cdr::DecodeError> {
        let d = if T::CDR_PRIMITIVE {
            None
        } else {
            r.begin_dheader()?
        };
        let n = r.read_len(T::CDR_MIN_SIZE)?;
        let v = T::cdr_decode_vec(r, n)?;
        r.end_dheader(d);
        Ok(v)
    }

    /// What the derive needs of a multi-dimensional variable array field
    /// (`<T:k1,k2,…>`, a field with several `len` names): its element type,
    /// its number of dimensions, its shape and elements, and how to build it
    /// from size fields and elements received.
    #[diagnostic::on_unimplemented(
        message = "`{Self}` is not a multi-dimensional variable array",
        label = "a field with several `len` names is `<T:k1,k2,…>`",
        note = "use `courier::NdVec<T, N>` (`courier::Matrix<T>` for two dimensions), or `Vec<T>` with one `len` name"
    )]
    pub trait NdField: Sized {
        /// The element type.
        type Elem: IpcMessage;
        /// The number of dimensions.
        const DIMS: usize;
        /// The size of dimension `d` (from 0); never above `i32::MAX`.
        fn dim(&self, d: usize) -> usize;
        /// The elements, row-major.
        fn elems(&self) -> &[Self::Elem];
        /// The array from its received size fields and elements.
        fn from_received(dims: &[i128], data: Vec<Self::Elem>) -> Result<Self, ShapeError>;
    }

    impl<T: IpcMessage, const N: usize> NdField for NdVec<T, N> {
        type Elem = T;
        const DIMS: usize = N;
        fn dim(&self, d: usize) -> usize {
            self.shape()[d]
        }
        fn elems(&self) -> &[T] {
            self.as_slice()
        }
        fn from_received(dims: &[i128], data: Vec<T>) -> Result<Self, ShapeError> {
            // the derive passes exactly `DIMS` size fields (checked at compile time)
            let mut shape = [0i128; N];
            for (s, d) in shape.iter_mut().zip(dims) {
                *s = *d;
            }
            crate::ndvec::from_received(shape, data)
        }
    }

    /// Builds an IPC-decoded `<T:k1,k2,…>` field; `offset` is where its count was.
    pub fn ipc_nd<F: NdField>(
        dims: &[i128],
        data: Vec<F::Elem>,
        offset: usize,
    ) -> Result<F, ipc::DecodeError> {
        F::from_received(dims, data).map_err(|error| ipc::DecodeError::Shape {
            offset,
            error: Box::new(error),
        })
    }

    /// Builds a CDR-decoded `<T:k1,k2,…>` field; `offset` is where its sequence was.
    pub fn cdr_nd<F: NdField>(
        dims: &[i128],
        data: Vec<F::Elem>,
        offset: usize,
    ) -> Result<F, cdr::DecodeError> {
        F::from_received(dims, data).map_err(|error| cdr::DecodeError::Shape {
            offset,
            error: Box::new(error),
        })
    }

    /// An empty `NdVec` field (all dimensions 0): its default in CDR.
    pub fn nd_default<F: NdField>() -> Option<F> {
        F::from_received(&vec![0; F::DIMS], Vec::new()).ok()
    }

    /// Self pointer `*!`: flag byte, then the enclosing struct.
    pub fn ipc_encode_self_ptr<T: IpcMessage>(v: &Option<Box<T>>, w: &mut ipc::Writer) {
        w.write_ptr_flag(v.is_some());
        if let Some(v) = v {
            v.ipc_encode(w);
        }
    }

    /// Reads a self pointer.
    pub fn ipc_decode_self_ptr<T: IpcMessage>(
        r: &mut ipc::Reader<'_>,
    ) -> Result<Option<Box<T>>, ipc::DecodeError> {
        <Option<Box<T>> as IpcMessage>::ipc_decode(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_formats_are_built_at_compile_time() {
        assert_eq!(<[[f64; 3]; 2]>::FORMAT, "[double:2,3]");
        assert_eq!(<Option<Box<i32>>>::FORMAT, "*int");
        assert_eq!(<Option<Box<[u8; 4]>>>::FORMAT, "*[ubyte:4]");
        assert_eq!(<[Option<Box<i16>>; 2]>::FORMAT, "[*short:2]");
    }

    #[test]
    fn e7_primitives() {
        assert_eq!(ipc::to_vec(&String::new()), [0, 0, 0, 0, 0x5a]);
        assert_eq!(ipc::to_vec(&None::<String>), [0, 0, 0, 0, 0x5a]);
        assert_eq!(
            ipc::to_vec(&0x0102030405060708i64),
            [8, 7, 6, 5, 4, 3, 2, 1]
        );
        assert_eq!(ipc::to_vec(&true), [1, 0, 0, 0]);
        assert_eq!(ipc::to_vec(&Some(Box::new(9i32))), [0x5a, 9, 0, 0, 0]);
        assert_eq!(ipc::to_vec(&None::<Box<i32>>), [0]);
        assert_eq!(
            ipc::to_vec(&[String::from("ab"), String::new()]),
            [2, 0, 0, 0, b'a', b'b', 0, 0, 0, 0, 0x5a]
        );
    }

    #[test]
    fn bulk_arrays_swap_foreign_order() {
        let v = [1.5f64, -2.0, 3.25];
        let mut be = Vec::new();
        for x in v {
            be.extend_from_slice(&x.to_be_bytes());
        }
        let got: [f64; 3] = ipc::from_slice_with_order(&be, ipc::ByteOrder::Big).unwrap();
        assert_eq!(got, v);
        let le = ipc::to_vec(&v);
        assert_eq!(ipc::from_slice::<[f64; 3]>(&le).unwrap(), v);
    }
}

#[cfg(test)]
mod bulk_tests {
    use super::*;

    /// `copy_pod_vec` on unaligned input, odd lengths and empty input.
    #[test]
    fn copy_pod_vec_handles_unaligned_input() {
        let src: Vec<u8> = (0..41u8).collect();
        for off in 0..8 {
            let b = &src[off..off + 32];
            let v: Vec<f64> = copy_pod_vec(b);
            assert_eq!(v.len(), 4);
            for (i, x) in v.iter().enumerate() {
                assert_eq!(x.to_ne_bytes(), b[8 * i..8 * i + 8]);
            }
            let v: Vec<u16> = copy_pod_vec(&b[..31]);
            assert_eq!(v.len(), 15);
            assert_eq!(v[14].to_ne_bytes(), b[28..30]);
        }
        assert!(copy_pod_vec::<u32>(&[]).is_empty());
    }
}

#[cfg(test)]
mod type_name_tests {
    use super::*;

    /// An array is named as IDL declares it, never as its element: a
    /// writer of `[i32; 4]` matched readers of `i32` (same name "int32"),
    /// which then failed on 12 trailing bytes.
    #[test]
    fn arrays_are_not_named_as_their_element() {
        assert_eq!(<[i32; 4]>::TYPE_NAME, "int32[4]");
        assert_eq!(<[[f64; 3]; 2]>::TYPE_NAME, "double[2][3]");
        assert_ne!(<[i32; 4]>::TYPE_NAME, i32::TYPE_NAME);
    }
}
