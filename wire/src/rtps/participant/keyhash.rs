//! Key hashes (DDSI-RTPS 2.5 §9.6.4.8) and the MD5 they need (RFC 1321):
//! see [`KeyHash`] for the key-hash form, which XCDR version it is in,
//! and what Cyclone DDS and Fast DDS do.

use crate::cdr::Version;

/// A 16-byte instance key hash (`PID_KEY_HASH`, DDSI-RTPS 2.5 §9.6.4.8).
///
/// The key hash of an instance is computed from its key fields serialized
/// big-endian in the *key-hash form* ([`Writer::key_hash_form_in`]: no
/// encapsulation header, every struct final, key members in member-id
/// order, and so the members of a key member whose struct type has no key
/// fields): when the *type's* largest possible key in that form fits in 16
/// bytes, the hash is those bytes zero-padded to 16; otherwise it is their
/// MD5 digest, even for a value whose key is short. The type decides
/// ([`IpcMessage::CDR_KEY_MAX_SIZE`], a [`MaxSize`]), never the value: an
/// unbounded string or sequence always takes the MD5 path, while a bounded
/// string `string<N>` (`#[ipc(key, bound = N)] name: String`) counts as
/// 4 + N + 1 bytes aligned to 4, so `string<11>` is padded and `string<12>`
/// hashed.
///
/// # Which XCDR version
///
/// The form exists in both XCDR versions, and they differ: XCDR1 aligns an
/// 8-byte member to 8, XCDR2 to 4, and XCDR2 puts a `DHEADER` before an
/// array or sequence of non-primitive elements (enums, strings, structs).
/// `@key long a; @key long long b;` is `a`, 4 zero bytes, `b` in XCDR1 and
/// `a`, `b`, 4 zero bytes (padding of the hash) in XCDR2; with `@key long
/// c;` after them the XCDR1 key can reach 20 bytes, so its hash is an MD5
/// digest, while the XCDR2 key (16 bytes) is padded.
///
/// DDS-XTypes 1.3 §7.6.8 specifies XCDR2. The implementations Courier
/// talks to compute the hash in the XCDR version of the data instead:
/// Cyclone DDS (`serdata_default_get_keyhash` serializes the key with the
/// data's version and decides padding with `DDS_TOPIC_FIXED_KEY` for
/// XCDR1, `DDS_TOPIC_FIXED_KEY_XCDR2` for XCDR2), and Fast DDS 2.9, which
/// only writes XCDR1 (its generated `getKey`). Fast DDS readers tell
/// instances apart by the `PID_KEY_HASH` they receive, so:
///
/// - what Courier **sends** is the hash in the version of the data it goes
///   with: [`KeyHash::of_in`] with the publication's data representation
///   (XCDR1 for a final type unless asked otherwise, XCDR2 for appendable
///   and mutable ones);
/// - what a reader **computes** for a writer that sends none
///   ([`cdr::key_hash_of_payload`]) is in the version of the payload's
///   encapsulation header, what that writer would have sent;
/// - the functions that take no version ([`KeyHash::of`],
///   [`crate::key_hash`], [`cdr::key_hash_of_key`],
///   [`cdr::key_from_key_hash`]) use XCDR2, the specification's form.
///
/// A mutable struct has no member headers or parameter list in either
/// version's form (Cyclone DDS writes its key members one after the other
/// for the hash, `DDS_CDR_KEY_SERIALIZATION_KEYHASH`), and an appendable
/// one no `DHEADER`; both count as final in the maximum as well, as
/// Cyclone DDS 0.10's idlc counts them (Cyclone DDS 11 counts an XCDR1
/// mutable key's parameter headers, so its XCDR1 hash of a mutable type
/// is always an MD5 digest; Courier writes mutable types in XCDR2 unless
/// asked otherwise).
///
/// Key members go in member-id order in both versions' form, as Cyclone
/// DDS writes them, but Cyclone DDS measures the XCDR1 maximum in
/// definition order (idlc's `DDS_TOPIC_FIXED_KEY`), and so does
/// [`MaxSize`]: for a type whose `#[ipc(id = ..)]` reorders its keys, an
/// XCDR1 key the maximum says fits can be longer than 16 bytes in the
/// form, and is then hashed, as any key longer than 16 bytes is.
///
/// ```
/// use courier_wire::cdr::{Version, Writer};
/// use courier_wire::rtps::participant::KeyHash;
/// // `long id` as key: 4 bytes, zero-padded
/// let k = KeyHash::from_key(&7i32.to_be_bytes(), false);
/// assert_eq!(k.0[..4], [0, 0, 0, 7]);
/// assert_eq!(k.0[4..], [0; 12]);
/// // `string name` as key: unbounded, so MD5 of "\0\0\0\x03ab\0"
/// let k = KeyHash::from_key(b"\0\0\0\x03ab\0", true);
/// assert_ne!(k.0[4..], [0; 12]);
/// // `@key long a; @key long long b;`: the two forms differ
/// let form = |version| {
///     let mut w = Writer::key_hash_form_in(version);
///     w.write_i32(1);
///     w.write_i64(2);
///     w.into_vec()
/// };
/// assert_eq!(form(Version::Xcdr1), [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2]);
/// assert_eq!(form(Version::Xcdr2), [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 2]);
/// // both fit 16 bytes: the hashes are the forms, padded
/// assert_eq!(KeyHash::from_key(&form(Version::Xcdr2), false).0[12..], [0; 4]);
/// ```
///
/// Two peers decide padding differently: Cyclone DDS 0.10's runtime pads
/// by the actual length of the key, and the Python `cyclonedds` 11 binding
/// counts a bounded string as 4 + N bytes (no NUL); Courier follows the
/// specification, Cyclone DDS 11's C library and Fast DDS (the type's
/// largest key).
///
/// [`IpcMessage::CDR_KEY_MAX_SIZE`]: crate::IpcMessage::CDR_KEY_MAX_SIZE
/// [`MaxSize`]: crate::cdr::MaxSize
/// [`Writer::key_hash_form_in`]: crate::cdr::Writer::key_hash_form_in
/// [`cdr::key_hash_of_payload`]: crate::cdr::key_hash_of_payload
/// [`cdr::key_hash_of_key`]: crate::cdr::key_hash_of_key
/// [`cdr::key_from_key_hash`]: crate::cdr::key_from_key_hash
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct KeyHash(pub [u8; 16]);

impl KeyHash {
    /// The key hash of `value`'s instance in XCDR2 form: [`KeyHash::of_in`]
    /// `(value, `[`Version::Xcdr2`]`)`, the form DDS-XTypes 1.3 §7.6.8
    /// specifies and what a writer of XCDR2 data sends. A writer of XCDR1
    /// data (Fast DDS, Courier and Cyclone DDS for final types by default)
    /// sends [`KeyHash::of_in`] `(value, Version::Xcdr1)`.
    ///
    /// ```
    /// use courier_wire::rtps::participant::KeyHash;
    /// // an `int32` key: its 4 big-endian bytes, zero-padded
    /// assert_eq!(KeyHash::of(&7i32).0, [0, 0, 0, 7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    /// // an unbounded string: MD5, however short
    /// assert_ne!(KeyHash::of(&String::from("ab")).0[7..], [0; 9]);
    /// ```
    pub fn of<T: crate::IpcMessage>(value: &T) -> Self {
        Self::of_in(value, Version::Xcdr2)
    }

    /// The key hash of `value`'s instance (DDSI-RTPS 2.5 §9.6.4.8) in XCDR
    /// version `version`: its key fields ([`IpcMessage::cdr_encode_key`])
    /// big-endian in that version with every struct written as final
    /// ([`Writer::key_hash_form_in`]), zero-padded to 16 bytes when the
    /// type's key can never serialize to more in that version
    /// ([`IpcMessage::CDR_KEY_MAX_SIZE`]`.`[`fits_key_hash_in`]`(version)`),
    /// else their MD5 digest. This is the `PID_KEY_HASH` Courier sends with
    /// data of that version, and what Cyclone DDS and Fast DDS compute for
    /// `@final` types.
    ///
    /// ```
    /// use courier_wire::cdr::Version;
    /// use courier_wire::rtps::participant::KeyHash;
    /// // a `uint64` key: 8 bytes in either version
    /// let want = [1, 2, 3, 4, 5, 6, 7, 8, 0, 0, 0, 0, 0, 0, 0, 0];
    /// assert_eq!(KeyHash::of_in(&0x0102_0304_0506_0708u64, Version::Xcdr1).0, want);
    /// assert_eq!(KeyHash::of_in(&0x0102_0304_0506_0708u64, Version::Xcdr2).0, want);
    /// ```
    ///
    /// [`IpcMessage::cdr_encode_key`]: crate::IpcMessage::cdr_encode_key
    /// [`IpcMessage::CDR_KEY_MAX_SIZE`]: crate::IpcMessage::CDR_KEY_MAX_SIZE
    /// [`fits_key_hash_in`]: crate::cdr::MaxSize::fits_key_hash_in
    /// [`Writer::key_hash_form_in`]: crate::cdr::Writer::key_hash_form_in
    pub fn of_in<T: crate::IpcMessage>(value: &T, version: Version) -> Self {
        let mut w = crate::cdr::Writer::key_hash_form_in(version);
        value.cdr_encode_key(&mut w);
        KeyHash::from_key(w.as_bytes(), !T::CDR_KEY_MAX_SIZE.fits_key_hash_in(version))
    }

    /// The key hash of a key serialized in the key-hash form of either
    /// XCDR version (big-endian, without encapsulation header).
    /// `may_exceed_16` says whether the type's key *can* serialize to more
    /// than 16 bytes in that version (`!`[`MaxSize::fits_key_hash_in`] of
    /// [`IpcMessage::CDR_KEY_MAX_SIZE`]: an unbounded string or sequence
    /// in the key, bounded ones too long, or 8-byte members that XCDR1
    /// pads to 8); a key that actually is longer than 16 bytes is always
    /// hashed.
    ///
    /// [`MaxSize::fits_key_hash_in`]: crate::cdr::MaxSize::fits_key_hash_in
    /// [`IpcMessage::CDR_KEY_MAX_SIZE`]: crate::IpcMessage::CDR_KEY_MAX_SIZE
    pub fn from_key(key_be: &[u8], may_exceed_16: bool) -> Self {
        if may_exceed_16 || key_be.len() > 16 {
            KeyHash(md5(key_be))
        } else {
            let mut h = [0; 16];
            h[..key_be.len()].copy_from_slice(key_be);
            KeyHash(h)
        }
    }
}

const S: [u32; 64] = [
    7, 12, 17, 22, 7, 12, 17, 22, 7, 12, 17, 22, 7, 12, 17, 22, 5, 9, 14, 20, 5, 9, 14, 20, 5, 9,
    14, 20, 5, 9, 14, 20, 4, 11, 16, 23, 4, 11, 16, 23, 4, 11, 16, 23, 4, 11, 16, 23, 6, 10, 15,
    21, 6, 10, 15, 21, 6, 10, 15, 21, 6, 10, 15, 21,
];

/// `floor(abs(sin(i + 1)) * 2^32)`.
const K: [u32; 64] = [
    0xd76aa478, 0xe8c7b756, 0x242070db, 0xc1bdceee, 0xf57c0faf, 0x4787c62a, 0xa8304613, 0xfd469501,
    0x698098d8, 0x8b44f7af, 0xffff5bb1, 0x895cd7be, 0x6b901122, 0xfd987193, 0xa679438e, 0x49b40821,
    0xf61e2562, 0xc040b340, 0x265e5a51, 0xe9b6c7aa, 0xd62f105d, 0x02441453, 0xd8a1e681, 0xe7d3fbc8,
    0x21e1cde6, 0xc33707d6, 0xf4d50d87, 0x455a14ed, 0xa9e3e905, 0xfcefa3f8, 0x676f02d9, 0x8d2a4c8a,
    0xfffa3942, 0x8771f681, 0x6d9d6122, 0xfde5380c, 0xa4beea44, 0x4bdecfa9, 0xf6bb4b60, 0xbebfbc70,
    0x289b7ec6, 0xeaa127fa, 0xd4ef3085, 0x04881d05, 0xd9d4d039, 0xe6db99e5, 0x1fa27cf8, 0xc4ac5665,
    0xf4292244, 0x432aff97, 0xab9423a7, 0xfc93a039, 0x655b59c3, 0x8f0ccc92, 0xffeff47d, 0x85845dd1,
    0x6fa87e4f, 0xfe2ce6e0, 0xa3014314, 0x4e0811a1, 0xf7537e82, 0xbd3af235, 0x2ad7d2bb, 0xeb86d391,
];

/// The MD5 digest of `data` (RFC 1321). Only for key hashes: MD5 is no
/// longer a secure hash.
pub fn md5(data: &[u8]) -> [u8; 16] {
    let mut st: [u32; 4] = [0x67452301, 0xefcdab89, 0x98badcfe, 0x10325476];
    let bit_len = (data.len() as u64).wrapping_mul(8);
    let mut tail = Vec::with_capacity(128);
    let full = data.len() / 64 * 64;
    tail.extend_from_slice(&data[full..]);
    tail.push(0x80);
    while tail.len() % 64 != 56 {
        tail.push(0);
    }
    tail.extend_from_slice(&bit_len.to_le_bytes());
    for block in data[..full].chunks_exact(64).chain(tail.chunks_exact(64)) {
        let mut m = [0u32; 16];
        for (i, w) in block.chunks_exact(4).enumerate() {
            m[i] = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        }
        let [mut a, mut b, mut c, mut d] = st;
        for i in 0..64 {
            let (f, g) = match i / 16 {
                0 => ((b & c) | (!b & d), i),
                1 => ((d & b) | (!d & c), (5 * i + 1) % 16),
                2 => (b ^ c ^ d, (3 * i + 5) % 16),
                _ => (c ^ (b | !d), (7 * i) % 16),
            };
            let f = f.wrapping_add(a).wrapping_add(K[i]).wrapping_add(m[g]);
            a = d;
            d = c;
            c = b;
            b = b.wrapping_add(f.rotate_left(S[i]));
        }
        st[0] = st[0].wrapping_add(a);
        st[1] = st[1].wrapping_add(b);
        st[2] = st[2].wrapping_add(c);
        st[3] = st[3].wrapping_add(d);
    }
    let mut out = [0; 16];
    for (i, w) in st.iter().enumerate() {
        out[i * 4..i * 4 + 4].copy_from_slice(&w.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    #[test]
    fn rfc1321_test_suite() {
        for (input, digest) in [
            ("", "d41d8cd98f00b204e9800998ecf8427e"),
            ("a", "0cc175b9c0f1b6a831c399e269772661"),
            ("abc", "900150983cd24fb0d6963f7d28e17f72"),
            ("message digest", "f96b697d7cb7938d525a2f31aaf161d0"),
            (
                "abcdefghijklmnopqrstuvwxyz",
                "c3fcd3d76192e4007dfb496cca67e13b",
            ),
            (
                "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789",
                "d174ab98d277d9f5a5611c2c9f419d9f",
            ),
            (
                "12345678901234567890123456789012345678901234567890123456789012345678901234567890",
                "57edf4a22be3c955ac49da2e2107b67a",
            ),
        ] {
            assert_eq!(hex(&md5(input.as_bytes())), digest, "{input:?}");
        }
        // block-boundary lengths
        for n in [55, 56, 63, 64, 65, 119, 120, 128] {
            let d = md5(&vec![b'x'; n]);
            assert_ne!(d, [0; 16], "{n}");
        }
    }

    /// The type decides, not the value: a fixed 16-byte key is the key, a
    /// 17-byte one an MD5, and an unbounded string an MD5 however short.
    #[test]
    fn the_type_decides_between_padding_and_md5() {
        let k = [7u8; 16];
        assert_eq!(KeyHash::of(&k).0, k);
        assert_eq!(KeyHash::of(&[7u8; 17]).0, md5(&[7; 17]));
        // md5(00 00 00 03 61 62 00), computed with Python's hashlib
        assert_eq!(
            hex(&KeyHash::of(&String::from("ab")).0),
            "186594b7205d08ac2ff8e1ac47fb4b2a"
        );
        // a nested array of int16: 8 bytes, no DHEADER, padded
        assert_eq!(
            KeyHash::of(&[[1i16, 2], [3, 4]]).0,
            [0, 1, 0, 2, 0, 3, 0, 4, 0, 0, 0, 0, 0, 0, 0, 0]
        );
    }

    /// XCDR1 has no `DHEADER`: an array of 16 octets as an element of an
    /// array of strings would differ, but primitives are the same bytes in
    /// both versions, and so is the decision for them.
    #[test]
    fn both_versions_agree_on_primitive_keys() {
        for v in [Version::Xcdr1, Version::Xcdr2] {
            assert_eq!(KeyHash::of_in(&[7u8; 16], v).0, [7; 16]);
            assert_eq!(KeyHash::of_in(&[7u8; 17], v).0, md5(&[7; 17]));
            assert_eq!(
                hex(&KeyHash::of_in(&String::from("ab"), v).0),
                "186594b7205d08ac2ff8e1ac47fb4b2a"
            );
            assert_eq!(
                KeyHash::of_in(&[1u64, 2], v).0,
                [0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 2]
            );
        }
        assert_eq!(
            KeyHash::of(&[1u64, 2]),
            KeyHash::of_in(&[1u64, 2], Version::Xcdr2)
        );
    }

    #[test]
    fn short_keys_pad_long_keys_hash() {
        let k = KeyHash::from_key(&[1, 2, 3], false);
        assert_eq!(k.0, [1, 2, 3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        let long = [9u8; 17];
        assert_eq!(KeyHash::from_key(&long, false).0, md5(&long));
        assert_eq!(KeyHash::from_key(&[1, 2, 3], true).0, md5(&[1, 2, 3]));
    }
}
