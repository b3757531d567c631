//! [`MaxSize`]: the most bytes a type takes in the key-hash form, in XCDR1
//! and in XCDR2, which decides whether a DDS key hash is the key itself or
//! its MD5.

use super::Version;

/// The most bytes a value of a type can take in the key-hash form
/// ([`Writer::key_hash_form_in`]: big-endian, every struct final, no
/// encapsulation header), in each XCDR version, as far as the key hash
/// needs to know: exact up to 16 bytes, and "more than 16" beyond.
///
/// DDSI-RTPS 2.5 §9.6.4.8 and DDS-XTypes 1.3 §7.6.8: a key hash is the key
/// in this form zero-padded to 16 bytes when the *type's* largest key can
/// never exceed 16 bytes, else the MD5 digest of the key, whatever the
/// length of the actual value. [`IpcMessage::CDR_KEY_MAX_SIZE`] holds it
/// for a type's key, [`IpcMessage::CDR_MAX_SIZE`] for a whole value (what a
/// key member whose type has no keys of its own contributes).
///
/// The two versions lay a key out differently, so a `MaxSize` measures
/// both: XCDR2 aligns a member to its size but at most 4 and puts a
/// `DHEADER` before arrays and sequences of non-primitive elements; XCDR1
/// aligns to the size up to 8 and has no `DHEADER`. `@key long a; @key
/// long long b;` takes 12 bytes in XCDR2 and 16 in XCDR1 (4 bytes of
/// padding before `b`); `@key long a; @key long long b; @key long c;`
/// takes 16 in XCDR2 (padded key hash) but 20 in XCDR1 (MD5). Which one
/// counts is the version the key hash is computed in
/// ([`max_len_in`](Self::max_len_in), [`fits_key_hash_in`](Self::fits_key_hash_in));
/// the methods without a version ([`max_len`](Self::max_len),
/// [`fits_key_hash`](Self::fits_key_hash), [`end`](Self::end)) answer
/// for XCDR2, the form DDS-XTypes 1.3 specifies.
///
/// Where a value starts matters (a `short` then a `string<3>` take 2 + 2
/// (padding) + 8 = 12 bytes), so a `MaxSize` is a table per version: for
/// each offset a value can start at (0 to 16), the largest offset at which
/// it ends; [`then`](Self::then) composes two of them as one member
/// follows another. It is built in `const` context, as
/// `#[derive(IpcMessage)]` does:
///
/// | type | `MaxSize` |
/// |---|---|
/// | `octet`, `short`, `long`, `long long`, … | [`primitive(size)`](Self::primitive) |
/// | enum | `primitive(4)` (but no primitive element: see below) |
/// | `string<N>` (`#[ipc(bound = N)] String`) | [`bounded_string(N)`](Self::bounded_string): 4 + N + 1 bytes, aligned to 4 |
/// | `sequence<T, N>` (`#[ipc(bound = N)] Vec<T>`) | [`bounded_sequence(T, N, dheader)`](Self::bounded_sequence): `DHEADER` (XCDR2, if `T` is not primitive), count, N elements |
/// | `T[N]` (`[T; N]`) | [`array(T, N, dheader)`](Self::array): `DHEADER` (XCDR2, if `T` is not primitive), N elements |
/// | struct | its members, one [`then`](Self::then) the next: in member-id order for XCDR2, in definition order for XCDR1 ([`per_version`](Self::per_version)) |
/// | `string`, `sequence<T>` | [`UNBOUNDED`](Self::UNBOUNDED) |
///
/// "Primitive" is what Cyclone DDS counts as one: integers, floats,
/// booleans and chars ([`IpcMessage::CDR_PRIMITIVE`]). An enum is not,
/// so in XCDR2 `@key Color a[3]` takes a `DHEADER` and 12 bytes, 16 in
/// all, and `Color a[4]` 20 (in XCDR1 12 and 16). A struct's members go
/// in member-id order in XCDR2 because a key member whose struct type has
/// no key fields of its own makes all its members keys, and Cyclone DDS
/// puts those in member-id order in the key-hash form, as it does the key
/// members of the outer struct. In XCDR1 Cyclone DDS measures them in
/// definition order (though it writes the XCDR1 form in member-id order
/// too): the two orders differ only for members whose ids are out of
/// definition order, and then a key the XCDR1 maximum says fits can be
/// longer in the form (its hash is then an MD5 digest, as a key longer
/// than 16 bytes always is). Structs count as final whatever their
/// extensibility (no `DHEADER`, member headers or parameter list), as the
/// key-hash form writes them.
///
/// This is how Cyclone DDS decides `DDS_TOPIC_FIXED_KEY` (XCDR1) and
/// `DDS_TOPIC_FIXED_KEY_XCDR2` in idlc 0.10 (checked against it for every
/// shape), and how Fast DDS's generated code measures a key (XCDR1).
///
/// ```
/// use courier_wire::cdr::{MaxSize, Version};
///
/// // @key long a; @key long long b;  (XCDR2 aligns the long long to 4, XCDR1 to 8)
/// const L2: MaxSize = MaxSize::primitive(4).then(MaxSize::primitive(8));
/// assert_eq!(L2.max_len(), Some(12));
/// assert_eq!(L2.max_len_in(Version::Xcdr2), Some(12));
/// assert_eq!(L2.max_len_in(Version::Xcdr1), Some(16));
/// // @key long c; after them: 16 bytes in XCDR2, 20 (MD5) in XCDR1
/// let l3 = L2.then(MaxSize::primitive(4));
/// assert!(l3.fits_key_hash_in(Version::Xcdr2));
/// assert!(!l3.fits_key_hash_in(Version::Xcdr1));
/// // @key string<11> name;  (4 + 11 + 1: the key hash is the key, padded)
/// assert_eq!(MaxSize::bounded_string(11).max_len(), Some(16));
/// assert!(MaxSize::bounded_string(11).fits_key_hash());
/// // @key string<12> name;  (17 bytes: the key hash is an MD5 digest)
/// assert_eq!(MaxSize::bounded_string(12).max_len(), None);
/// // @key short h; @key string<3> s;  (the string starts at 4, not 2)
/// let k = MaxSize::primitive(2).then(MaxSize::bounded_string(3));
/// assert_eq!(k.max_len(), Some(12));
/// // after an octet: the short at 2, the string at 4
/// assert_eq!(MaxSize::primitive(1).then(k).max_len(), Some(12));
/// // after a long: the short at 4, the string at 8, 16 in all
/// assert_eq!(MaxSize::primitive(4).then(k).max_len(), Some(16));
/// assert_eq!(k.end(4), Some(16));
/// ```
///
/// [`Writer::key_hash_form_in`]: super::Writer::key_hash_form_in
/// [`IpcMessage::CDR_KEY_MAX_SIZE`]: crate::IpcMessage::CDR_KEY_MAX_SIZE
/// [`IpcMessage::CDR_MAX_SIZE`]: crate::IpcMessage::CDR_MAX_SIZE
/// [`IpcMessage::CDR_PRIMITIVE`]: crate::IpcMessage::CDR_PRIMITIVE
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MaxSize {
    /// `end[v][i]`: in XCDR version `v` ([`XCDR1`] or [`XCDR2`]), the
    /// largest offset just past a value that starts at offset `i`;
    /// [`OVER`] when that is past 16 (and `end[v][OVER]` is `OVER`: a
    /// value after one that went past 16 ends past 16 too).
    end: [[u8; TABLE]; 2],
}

/// Past the 16 bytes of a key hash: the key hash is an MD5 digest.
const OVER: u8 = MaxSize::LIMIT as u8 + 1;
/// Offsets 0 to 16, and [`OVER`].
const TABLE: usize = OVER as usize + 1;
/// The index of XCDR1's table.
const XCDR1: usize = 0;
/// The index of XCDR2's table.
const XCDR2: usize = 1;
/// The largest alignment of each version (XCDR1: 8, XCDR2: 4).
const MAX_ALIGN: [usize; 2] = [8, 4];

/// The table of `version`.
const fn table(version: Version) -> usize {
    match version {
        Version::Xcdr1 => XCDR1,
        Version::Xcdr2 => XCDR2,
    }
}

/// `offset` rounded up to a multiple of `align`, plus `size`, capped at
/// [`OVER`].
const fn aligned_end(offset: usize, align: usize, size: usize) -> u8 {
    let start = offset.next_multiple_of(align);
    let end = start.saturating_add(size);
    if end > MaxSize::LIMIT {
        OVER
    } else {
        end as u8
    }
}

impl MaxSize {
    /// The largest key that a key hash holds as is (zero-padded): 16 bytes.
    pub const LIMIT: usize = 16;

    /// Nothing at all (a struct without members, `()`): ends where it starts.
    pub const EMPTY: MaxSize = {
        let mut end = [OVER; TABLE];
        let mut i = 0;
        while i < TABLE {
            end[i] = i as u8;
            i += 1;
        }
        MaxSize { end: [end, end] }
    };

    /// No upper bound (an unbounded `string` or `sequence`, a pointer, a
    /// type that does not say): always more than 16 bytes.
    pub const UNBOUNDED: MaxSize = MaxSize {
        end: [[OVER; TABLE]; 2],
    };

    /// `size` bytes aligned to `size`, at most 4 in XCDR2 and 8 in XCDR1:
    /// a number, an enum (4), a `boolean`, `octet` or `char` (1).
    pub const fn primitive(size: usize) -> MaxSize {
        let mut end = [[OVER; TABLE]; 2];
        let mut v = 0;
        while v < 2 {
            let align = if size == 0 {
                1
            } else if size > MAX_ALIGN[v] {
                MAX_ALIGN[v]
            } else {
                size
            };
            end[v] = Self::aligned(align, size);
            v += 1;
        }
        MaxSize { end }
    }

    /// One table: `size` bytes after padding to a multiple of `align`.
    const fn aligned(align: usize, size: usize) -> [u8; TABLE] {
        let mut end = [OVER; TABLE];
        let mut i = 0;
        while i < TABLE - 1 {
            end[i] = aligned_end(i, align, size);
            i += 1;
        }
        end
    }

    /// A bounded string, IDL `string<bound>` (`#[ipc(bound = N)] String`):
    /// its length (4 bytes, aligned to 4), at most `bound` bytes and the
    /// NUL, 4 + `bound` + 1 bytes in all, in both versions. (Bound 0 is
    /// not an unbounded string here: IDL's `string<0>` is
    /// [`UNBOUNDED`](Self::UNBOUNDED).)
    ///
    /// ```
    /// use courier_wire::cdr::MaxSize;
    /// assert_eq!(MaxSize::bounded_string(8).max_len(), Some(13));
    /// ```
    pub const fn bounded_string(bound: usize) -> MaxSize {
        let chars = Self::aligned(1, bound.saturating_add(1));
        Self::primitive(4).then(MaxSize {
            end: [chars, chars],
        })
    }

    /// A bounded sequence, IDL `sequence<T, bound>` (`#[ipc(bound = N)]
    /// Vec<T>`) of elements of `elem`'s size: in XCDR2 a `DHEADER` when
    /// `dheader` (XCDR2 writes one unless the elements are primitive; XCDR1
    /// never does), the count (4 bytes), then `bound` elements.
    ///
    /// ```
    /// use courier_wire::cdr::{MaxSize, Version};
    /// // sequence<octet, 12>: count and 12 octets
    /// let s = MaxSize::bounded_sequence(MaxSize::primitive(1), 12, false);
    /// assert_eq!(s.max_len(), Some(16));
    /// // sequence<string<2>, 1>: DHEADER, count, 4 + 2 + 1; XCDR1 without DHEADER
    /// let s = MaxSize::bounded_sequence(MaxSize::bounded_string(2), 1, true);
    /// assert_eq!(s.max_len(), Some(15));
    /// assert_eq!(s.max_len_in(Version::Xcdr1), Some(11));
    /// ```
    pub const fn bounded_sequence(elem: MaxSize, bound: usize, dheader: bool) -> MaxSize {
        Self::dheader(dheader)
            .then(Self::primitive(4))
            .then(elem.repeat(bound))
    }

    /// A fixed array of `len` elements of `elem`'s size (for a nested
    /// array, the inner array's elements without their own `DHEADER`): in
    /// XCDR2 a `DHEADER` when `dheader` (XCDR2 writes one unless the
    /// innermost elements are primitive; XCDR1 never does), then the
    /// elements.
    ///
    /// ```
    /// use courier_wire::cdr::{MaxSize, Version};
    /// // long a[4]
    /// assert_eq!(MaxSize::array(MaxSize::primitive(4), 4, false).max_len(), Some(16));
    /// // an array of 3 structs of one long, or of 3 enums (not
    /// // primitive): DHEADER and 12 in XCDR2, 12 in XCDR1
    /// let a = MaxSize::array(MaxSize::primitive(4), 3, true);
    /// assert_eq!(a.max_len(), Some(16));
    /// assert_eq!(a.max_len_in(Version::Xcdr1), Some(12));
    /// ```
    pub const fn array(elem: MaxSize, len: usize, dheader: bool) -> MaxSize {
        Self::dheader(dheader).then(elem.repeat(len))
    }

    /// A `DHEADER` (XCDR2 only: 4 bytes, aligned to 4) when `present`,
    /// else nothing.
    const fn dheader(present: bool) -> MaxSize {
        if present {
            MaxSize {
                end: [Self::EMPTY.end[XCDR1], Self::primitive(4).end[XCDR2]],
            }
        } else {
            Self::EMPTY
        }
    }

    /// The XCDR1 table of `xcdr1` and the XCDR2 table of `xcdr2`: for a
    /// struct whose members are measured in a different order in each
    /// version. Cyclone DDS measures the XCDR1 key in definition order
    /// (idlc's `DDS_TOPIC_FIXED_KEY`) and the XCDR2 one in member-id order
    /// (`DDS_TOPIC_FIXED_KEY_XCDR2`); `#[derive(IpcMessage)]` does the same
    /// when `#[ipc(id = ..)]` puts the fields out of order.
    ///
    /// ```
    /// use courier_wire::cdr::{MaxSize, Version};
    /// // @key @id(1) string<9> s; @key @id(0) short h;
    /// let (s, h) = (MaxSize::bounded_string(9), MaxSize::primitive(2));
    /// let k = MaxSize::per_version(s.then(h), h.then(s));
    /// assert_eq!(k.max_len_in(Version::Xcdr1), Some(16)); // s, h
    /// assert_eq!(k.max_len_in(Version::Xcdr2), None); // h, 2 bytes of padding, s: 18
    /// ```
    pub const fn per_version(xcdr1: MaxSize, xcdr2: MaxSize) -> MaxSize {
        MaxSize {
            end: [xcdr1.end[XCDR1], xcdr2.end[XCDR2]],
        }
    }

    /// This, then `next` right after it: two members of a struct.
    pub const fn then(self, next: MaxSize) -> MaxSize {
        let mut end = [[OVER; TABLE]; 2];
        let mut v = 0;
        while v < 2 {
            let mut i = 0;
            while i < TABLE {
                end[v][i] = next.end[v][self.end[v][i] as usize];
                i += 1;
            }
            v += 1;
        }
        MaxSize { end }
    }

    /// `n` of these, one after the other (the elements of an array or of a
    /// sequence at its bound).
    pub const fn repeat(self, n: usize) -> MaxSize {
        let mut acc = Self::EMPTY;
        let mut k = 0;
        while k < n {
            let next = acc.then(self);
            // once a repetition changes nothing (every entry is past 16,
            // or the element is empty), none will
            if next.same(&acc) {
                break;
            }
            acc = next;
            k += 1;
        }
        acc
    }

    /// `==` in `const` context.
    const fn same(&self, other: &MaxSize) -> bool {
        let mut v = 0;
        while v < 2 {
            let mut i = 0;
            while i < TABLE {
                if self.end[v][i] != other.end[v][i] {
                    return false;
                }
                i += 1;
            }
            v += 1;
        }
        true
    }

    /// In XCDR version `version`: the largest offset just past a value
    /// that starts at offset `start`, `None` when that is past 16 bytes
    /// (or `start` is).
    pub const fn end_in(self, version: Version, start: usize) -> Option<usize> {
        if start > Self::LIMIT {
            return None;
        }
        match self.end[table(version)][start] {
            OVER => None,
            e => Some(e as usize),
        }
    }

    /// [`end_in`](Self::end_in) XCDR2.
    pub const fn end(self, start: usize) -> Option<usize> {
        self.end_in(Version::Xcdr2, start)
    }

    /// The most bytes a value takes in XCDR version `version`, starting at
    /// offset 0 (as a key does in its key hash): `Some(n)` for at most 16,
    /// `None` for more (or no bound at all).
    pub const fn max_len_in(self, version: Version) -> Option<usize> {
        self.end_in(version, 0)
    }

    /// [`max_len_in`](Self::max_len_in) XCDR2.
    pub const fn max_len(self) -> Option<usize> {
        self.max_len_in(Version::Xcdr2)
    }

    /// Whether a key of this size never takes more than 16 bytes in XCDR
    /// version `version`, so that its key hash in that version is the key
    /// zero-padded; otherwise the key hash is the key's MD5 digest, even
    /// for a value whose key is shorter.
    pub const fn fits_key_hash_in(self, version: Version) -> bool {
        self.max_len_in(version).is_some()
    }

    /// [`fits_key_hash_in`](Self::fits_key_hash_in) XCDR2.
    pub const fn fits_key_hash(self) -> bool {
        self.fits_key_hash_in(Version::Xcdr2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The end offset of `sizes` (size, alignment) laid out from `start`,
    /// computed the plain way.
    fn layout(start: usize, items: &[(usize, usize)]) -> usize {
        items
            .iter()
            .fold(start, |o, (size, align)| o.next_multiple_of(*align) + size)
    }

    #[test]
    fn primitives_align_to_at_most_4() {
        for size in [1, 2, 4, 8] {
            let m = MaxSize::primitive(size);
            for start in 0..=16 {
                let want = layout(start, &[(size, size.min(4))]);
                assert_eq!(
                    m.end(start),
                    (want <= 16).then_some(want),
                    "{size} at {start}"
                );
            }
        }
        assert_eq!(MaxSize::primitive(8).end(1), Some(12));
        assert_eq!(MaxSize::primitive(2).end(15), None);
    }

    #[test]
    fn xcdr1_aligns_to_at_most_8() {
        for size in [1, 2, 4, 8] {
            let m = MaxSize::primitive(size);
            for start in 0..=16 {
                let want = layout(start, &[(size, size)]);
                assert_eq!(
                    m.end_in(Version::Xcdr1, start),
                    (want <= 16).then_some(want),
                    "{size} at {start}"
                );
            }
        }
        // long, long long: 4 + 4 (padding) + 8 = 16 in XCDR1, 12 in XCDR2
        let l2 = MaxSize::primitive(4).then(MaxSize::primitive(8));
        assert_eq!(l2.max_len_in(Version::Xcdr1), Some(16));
        assert_eq!(l2.max_len_in(Version::Xcdr2), Some(12));
        // then a long: 20 (over) in XCDR1, 16 in XCDR2
        let l3 = l2.then(MaxSize::primitive(4));
        assert!(!l3.fits_key_hash_in(Version::Xcdr1));
        assert_eq!(l3.max_len(), Some(16));
        // octet, double: 1 + 7 + 8 = 16 in XCDR1, 1 + 3 + 8 = 12 in XCDR2
        let od = MaxSize::primitive(1).then(MaxSize::primitive(8));
        assert_eq!(od.max_len_in(Version::Xcdr1), Some(16));
        assert_eq!(od.max_len_in(Version::Xcdr2), Some(12));
        // no DHEADER in XCDR1
        let a = MaxSize::array(MaxSize::primitive(4), 4, true);
        assert_eq!(a.max_len_in(Version::Xcdr1), Some(16));
        assert_eq!(a.max_len_in(Version::Xcdr2), None);
        let s = MaxSize::bounded_sequence(MaxSize::primitive(4), 3, true);
        assert_eq!(s.max_len_in(Version::Xcdr1), Some(16));
        assert_eq!(s.max_len_in(Version::Xcdr2), None);
        // the versions without a version are XCDR2
        assert_eq!(l2.end(4), l2.end_in(Version::Xcdr2, 4));
        assert_eq!(l2.end_in(Version::Xcdr1, 4), Some(16));
        assert_eq!(l2.end_in(Version::Xcdr1, 17), None);
    }

    #[test]
    fn composition_follows_the_layout() {
        // octet, long long, long, octet: 1 → 4 + 8 = 12, + 4 = 16, + 1 = 17
        let items = [(1, 1), (8, 4), (4, 4), (1, 1)];
        let mut m = MaxSize::EMPTY;
        for (i, (size, _)) in items.iter().enumerate() {
            m = m.then(MaxSize::primitive(*size));
            let want = layout(0, &items[..=i]);
            assert_eq!(m.max_len(), (want <= 16).then_some(want), "{i}");
        }
        assert_eq!(m.max_len(), None);
        // `then` is associative: a nested struct folds into the same offset
        let (a, b, c) = (
            MaxSize::primitive(1),
            MaxSize::primitive(2),
            MaxSize::bounded_string(3),
        );
        assert_eq!(a.then(b).then(c), a.then(b.then(c)));
        assert_eq!(a.then(MaxSize::EMPTY), a);
        assert_eq!(MaxSize::EMPTY.then(a), a);
    }

    #[test]
    fn strings_sequences_and_arrays() {
        for n in 1..=13 {
            let want = 4 + n + 1;
            assert_eq!(
                MaxSize::bounded_string(n).max_len(),
                (want <= 16).then_some(want),
                "string<{n}>"
            );
        }
        // a huge bound saturates rather than overflows
        assert_eq!(MaxSize::bounded_string(usize::MAX).max_len(), None);
        assert_eq!(
            MaxSize::bounded_sequence(MaxSize::primitive(1), 0x7fff_ffff, false).max_len(),
            None
        );
        // sequence<long long, 1>: count, then 8 aligned to 4
        assert_eq!(
            MaxSize::bounded_sequence(MaxSize::primitive(8), 1, false).max_len(),
            Some(12)
        );
        // sequence<short, 6>: 4 + 12
        assert_eq!(
            MaxSize::bounded_sequence(MaxSize::primitive(2), 6, false).max_len(),
            Some(16)
        );
        // an empty element repeats without end: still nothing
        assert_eq!(MaxSize::EMPTY.repeat(usize::MAX), MaxSize::EMPTY);
        assert_eq!(
            MaxSize::array(MaxSize::primitive(1), 16, false).max_len(),
            Some(16)
        );
        assert_eq!(
            MaxSize::array(MaxSize::primitive(1), 17, false).max_len(),
            None
        );
        assert_eq!(MaxSize::UNBOUNDED.max_len(), None);
        assert!(!MaxSize::UNBOUNDED.then(MaxSize::EMPTY).fits_key_hash());
        assert_eq!(MaxSize::EMPTY.max_len(), Some(0));
    }
}
