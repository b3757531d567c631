//! The key hash a reader computes when the writer sends none (Cyclone DDS
//! 11 sends no `PID_KEY_HASH`): from a sample, or from the serialized key
//! a dispose carries, it equals `key_hash_in` of the value in the XCDR
//! version of the payload (what its writer sends), for every encoding and
//! for keys of every shape the derive takes; and the key hashes of both
//! versions byte for byte.

use courier::cdr::{self, Encoding, Version};
use courier::{key_hash, key_hash_in, IpcMessage};

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct OneKey {
    #[ipc(key)]
    id: i32,
    v: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct TwoKeys {
    a: u8,
    #[ipc(key)]
    robot: String,
    #[ipc(key)]
    part: u16,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Inner {
    #[ipc(key)]
    x: i64,
    note: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Plain {
    p: i16,
    q: u32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
enum Side {
    Left,
    Right,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Nested {
    #[ipc(key)]
    inner: Inner,
    #[ipc(key)]
    plain: Plain,
    #[ipc(key)]
    side: Side,
    #[ipc(key)]
    arr: [u16; 3],
    rest: Vec<u8>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct App {
    #[ipc(key)]
    id: u32,
    #[ipc(key)]
    name: String,
    v: i8,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct Mut {
    v: i8,
    #[ipc(key)]
    id: u64,
    #[ipc(key)]
    tag: String,
}

const ALL: [Encoding; 4] = [
    Encoding::Xcdr1Le,
    Encoding::Xcdr1Be,
    Encoding::Xcdr2Le,
    Encoding::Xcdr2Be,
];

fn check<T: IpcMessage>(v: &T) {
    for enc in ALL {
        // what a writer of this encoding sends: the hash in its version
        let want = key_hash_in(v, enc.version());
        // a type some encodings cannot carry (mutable in XCDR1 is PL_CDR:
        // still written) is checked where it round-trips
        let sample = cdr::to_vec(v, enc);
        assert_eq!(
            cdr::key_hash_of_payload::<T>(&sample, false),
            Some(want),
            "{} sample {enc:?}",
            T::TYPE_NAME
        );
        let key = cdr::key_to_vec(v, enc);
        assert_eq!(
            cdr::key_hash_of_payload::<T>(&key, true),
            Some(want),
            "{} key {enc:?}",
            T::TYPE_NAME
        );
    }
}

#[test]
fn a_key_hash_from_a_payload_is_the_key_hash_of_the_value() {
    check(&OneKey { id: -7, v: 1.5 });
    check(&TwoKeys {
        a: 1,
        robot: "r2".into(),
        part: 9,
    });
    // a key longer than 16 bytes is an MD5 digest
    check(&TwoKeys {
        a: 1,
        robot: "a robot with a long name".into(),
        part: 9,
    });
    check(&Nested {
        inner: Inner {
            x: 1 << 40,
            note: "not a key".into(),
        },
        plain: Plain { p: -2, q: 3 },
        side: Side::Right,
        arr: [1, 2, 3],
        rest: vec![1, 2],
    });
    check(&App {
        id: 3,
        name: "x".into(),
        v: 1,
    });
    check(&Mut {
        v: 1,
        id: 77,
        tag: "t".into(),
    });
    // a type without keys has no instance key hash
    assert_eq!(
        cdr::key_hash_of_payload::<Plain>(
            &cdr::to_vec(&Plain { p: 1, q: 2 }, Encoding::Xcdr2Le),
            false
        ),
        None
    );
    // bytes that do not decode have none either
    assert_eq!(
        cdr::key_hash_of_payload::<OneKey>(&[0, 1, 0, 0, 1], true),
        None
    );
}

// Key hashes of bounded keys, byte for byte (DDSI-RTPS 2.5 §9.6.4.8): the
// type's largest key in the key-hash form decides, a bounded string
// `string<N>` counting 4 + N + 1 bytes. The MD5 digests were computed
// independently (Python's hashlib) of the key bytes shown.

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Name8 {
    #[ipc(key, bound = 8)]
    name: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Name11 {
    #[ipc(key, bound = 11)]
    name: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Name12 {
    #[ipc(key, bound = 12)]
    name: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct LongLongLong {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Seq3 {
    #[ipc(key, bound = 3)]
    ids: Vec<u32>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Seq4 {
    #[ipc(key, bound = 4)]
    ids: Vec<u32>,
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn padded(key: &[u8]) -> [u8; 16] {
    let mut h = [0; 16];
    h[..key.len()].copy_from_slice(key);
    h
}

#[test]
fn bounded_string_keys_pad_up_to_string_11() {
    // string<8>: at most 4 + 8 + 1 = 13 bytes, so "ab" is padded
    let v = Name8 {
        name: "ab".into(),
        v: 1,
    };
    assert_eq!(Name8::CDR_KEY_MAX_SIZE.max_len(), Some(13));
    assert_eq!(
        key_hash(&v),
        [0, 0, 0, 3, 0x61, 0x62, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    );
    assert_eq!(
        cdr::key_hash_of_key::<Name8>(&"ab".into()),
        Some(key_hash(&v))
    );
    assert_eq!(
        cdr::key_from_key_hash::<Name8>(&key_hash(&v)).as_deref(),
        Some("ab")
    );
    check(&v);

    // string<11> at its bound: exactly 16 bytes, the key itself
    let v = Name11 {
        name: "abcdefghijk".into(),
        v: 1,
    };
    assert_eq!(Name11::CDR_KEY_MAX_SIZE.max_len(), Some(16));
    let mut want = vec![0, 0, 0, 12];
    want.extend_from_slice(b"abcdefghijk\0");
    assert_eq!(key_hash(&v), padded(&want));
    assert_eq!(
        cdr::key_from_key_hash::<Name11>(&key_hash(&v)).as_deref(),
        Some("abcdefghijk")
    );
    // and the empty string: 00 00 00 01 00, padded
    let e = Name11 {
        name: String::new(),
        v: 1,
    };
    assert_eq!(key_hash(&e), padded(&[0, 0, 0, 1, 0]));
    assert_eq!(
        cdr::key_from_key_hash::<Name11>(&key_hash(&e)).as_deref(),
        Some("")
    );
    check(&v);

    // string<12>: up to 17 bytes, so even "ab" is an MD5 digest
    assert_eq!(Name12::CDR_KEY_MAX_SIZE.max_len(), None);
    let v = Name12 {
        name: "ab".into(),
        v: 1,
    };
    // md5(00 00 00 03 61 62 00)
    assert_eq!(hex(&key_hash(&v)), "186594b7205d08ac2ff8e1ac47fb4b2a");
    assert_eq!(cdr::key_from_key_hash::<Name12>(&key_hash(&v)), None);
    let v = Name12 {
        name: "abcdefghijkl".into(),
        v: 1,
    };
    // md5(00 00 00 0d "abcdefghijkl" 00)
    assert_eq!(hex(&key_hash(&v)), "e07ff2750c92eef9415df8da25dabdd7");
    check(&v);
}

#[test]
fn a_long_long_after_a_long_is_aligned_to_4() {
    // XCDR2 aligns 8-byte members to 4: 4 + 8 = 12 bytes
    let v = LongLongLong {
        a: 1,
        b: 0x0102_0304_0506_0708,
        v: 9,
    };
    assert_eq!(LongLongLong::CDR_KEY_MAX_SIZE.max_len(), Some(12));
    assert_eq!(
        key_hash(&v),
        [0, 0, 0, 1, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0, 0, 0]
    );
    assert_eq!(
        cdr::key_from_key_hash::<LongLongLong>(&key_hash(&v)),
        Some((1, 0x0102_0304_0506_0708))
    );
    check(&v);
}

#[test]
fn bounded_sequence_keys() {
    // sequence<uint32, 3>: count and 3 × 4 = 16 bytes at most, padded
    let v = Seq3 { ids: vec![1, 2] };
    assert_eq!(Seq3::CDR_KEY_MAX_SIZE.max_len(), Some(16));
    assert_eq!(
        key_hash(&v),
        [0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 0]
    );
    assert_eq!(
        cdr::key_from_key_hash::<Seq3>(&key_hash(&v)),
        Some(vec![1, 2])
    );
    let full = Seq3 { ids: vec![1, 2, 3] };
    assert_eq!(
        key_hash(&full),
        [0, 0, 0, 3, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3]
    );
    check(&full);
    // sequence<uint32, 4>: up to 20 bytes, so an MD5 digest even for two
    assert_eq!(Seq4::CDR_KEY_MAX_SIZE.max_len(), None);
    let v = Seq4 { ids: vec![1, 2] };
    // md5(00 00 00 02 00 00 00 01 00 00 00 02)
    assert_eq!(hex(&key_hash(&v)), "bdf2d93c1c6ade7f71e2fa7348135b1a");
    assert_eq!(cdr::key_from_key_hash::<Seq4>(&key_hash(&v)), None);
    let v = Seq4 {
        ids: vec![1, 2, 3, 4],
    };
    assert_eq!(hex(&key_hash(&v)), "f83ea1eddd3b25f7e1a55d81bd076a42");
    check(&v);
}

// `CDR_KEY_MAX_SIZE` (and `CDR_MAX_SIZE`) against the bytes the key-hash
// form actually holds, for keys of every shape: never shorter than any
// value's, and exactly a value's at the bounds.

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct OctShort {
    a: u8,
    b: i16,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct OctLong {
    a: u8,
    b: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Short {
    x: i16,
}

#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
enum Tri {
    A,
    B,
    C,
}

/// Unaligned starts: `p` begins at 1, its `i16` at 2, the string at 4.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Unaligned {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    p: OctShort,
    #[ipc(key, bound = 2)]
    s: String,
}

/// A nested struct laid out from offset 1 takes 8 bytes (1, 2, pad, 4),
/// not 4 + its 8 from offset 0.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct NestedFrom1 {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    n: OctLong,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct SeqOfStructs {
    #[ipc(key, bound = 2)]
    pts: Vec<Short>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct SeqOfEnums {
    #[ipc(key, bound = 2)]
    v: Vec<Tri>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct SeqOfArrays {
    #[ipc(key, bound = 2)]
    v: Vec<[u8; 3]>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct SeqOfStrings {
    #[ipc(key, bound = 1)]
    v: Vec<String>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Arrays {
    #[ipc(key)]
    a: [[i16; 2]; 3],
    #[ipc(key)]
    b: [[Short; 2]; 1],
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Chars {
    #[ipc(key, char)]
    c: u8,
    #[ipc(key)]
    d: char,
    #[ipc(key, bound = 9)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct MutBounded {
    v: i8,
    #[ipc(key, bound = 7)]
    s: String,
    #[ipc(key)]
    c: u32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct InnerBounded {
    #[ipc(key, bound = 3)]
    n: String,
    x: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Outer {
    #[ipc(key)]
    inner: InnerBounded,
    #[ipc(key)]
    b: Box<i64>,
    #[ipc(key)]
    k: u8,
}

/// The key-hash form of `v`'s key, and of all of `v`, in `version`.
fn forms<T: IpcMessage>(v: &T, version: Version) -> (Vec<u8>, Vec<u8>) {
    let mut k = cdr::Writer::key_hash_form_in(version);
    v.cdr_encode_key(&mut k);
    let mut w = cdr::Writer::key_hash_form_in(version);
    v.cdr_encode(&mut w);
    (k.into_vec(), w.into_vec())
}

/// `max` against byte counts: none above it, `worst` exactly it (or past
/// 16 when it says "more than 16").
fn check_max(what: &str, max: Option<usize>, lens: &[usize], worst: usize) {
    match max {
        Some(m) => {
            assert_eq!(worst, m, "{what}: the longest value's form");
            assert!(lens.iter().all(|l| *l <= m), "{what}: {lens:?} over {m}");
        }
        None => assert!(
            worst > 16,
            "{what}: over 16 bytes, the longest value takes {worst}"
        ),
    }
}

/// `values` of `T`, the last one at every bound: its key and whole value
/// reach the maxima, and the key hash is padded exactly when the type's
/// key fits 16 bytes, in both XCDR versions (`want_key_max` is XCDR2's).
fn measure<T: IpcMessage + std::fmt::Debug>(values: &[T], want_key_max: Option<usize>) {
    let name = T::TYPE_NAME;
    assert_eq!(T::CDR_KEY_MAX_SIZE.max_len(), want_key_max, "{name}");
    for version in [Version::Xcdr1, Version::Xcdr2] {
        let (keys, wholes): (Vec<usize>, Vec<usize>) = values
            .iter()
            .map(|v| {
                let (k, w) = forms(v, version);
                (k.len(), w.len())
            })
            .unzip();
        let last = values.len() - 1;
        check_max(
            &format!("{name} key {version:?}"),
            T::CDR_KEY_MAX_SIZE.max_len_in(version),
            &keys,
            keys[last],
        );
        check_max(
            &format!("{name} value {version:?}"),
            T::CDR_MAX_SIZE.max_len_in(version),
            &wholes,
            wholes[last],
        );
        let fits = T::CDR_KEY_MAX_SIZE.fits_key_hash_in(version);
        for v in values {
            let (k, _) = forms(v, version);
            let padded = k.len() <= 16 && key_hash_in(v, version) == self::padded(&k);
            assert_eq!(padded, fits, "{name} {version:?}: {v:?}");
        }
    }
    for v in values {
        check(v);
    }
}

fn strings(bound: usize) -> impl Iterator<Item = String> {
    (0..=bound).map(|n| "xyzw".chars().cycle().take(n).collect())
}

#[test]
fn key_max_sizes_are_the_exact_worst_case() {
    let v: Vec<Unaligned> = strings(2)
        .map(|s| Unaligned {
            o: 1,
            p: OctShort { a: 2, b: 3 },
            s,
        })
        .collect();
    // 1 + 1 + 2 = 4, then 4 + 2 + 1
    measure(&v, Some(11));
    measure(
        &[NestedFrom1 {
            o: 1,
            n: OctLong { a: 2, b: 3 },
        }],
        Some(8),
    );
    let v: Vec<SeqOfStructs> = (0..=2)
        .map(|n| SeqOfStructs {
            pts: vec![Short { x: 7 }; n],
        })
        .collect();
    // DHEADER, count, 2 × 2
    measure(&v, Some(12));
    let v: Vec<SeqOfEnums> = (0..=2).map(|n| SeqOfEnums { v: vec![Tri::C; n] }).collect();
    // an enum is no primitive element (Cyclone DDS): DHEADER, count, 2 × 4
    measure(&v, Some(16));
    let v: Vec<SeqOfArrays> = (0..=2)
        .map(|n| SeqOfArrays {
            v: vec![[1, 2, 3]; n],
        })
        .collect();
    // DHEADER (an array is no primitive element), count, 2 × 3
    measure(&v, Some(14));
    let v: Vec<SeqOfStrings> = [vec![], vec!["a string of some length".to_string()]]
        .into_iter()
        .map(|v| SeqOfStrings { v })
        .collect();
    measure(&v, None);
    // 12 bytes of i16 (no DHEADER), then DHEADER and 2 × 2
    measure(
        &[Arrays {
            a: [[1, 2], [3, 4], [5, 6]],
            b: [[Short { x: 1 }, Short { x: 2 }]],
        }],
        None,
    );
    assert_eq!(<[[i16; 2]; 3]>::CDR_MAX_SIZE.max_len(), Some(12));
    assert_eq!(<[[Short; 2]; 1]>::CDR_MAX_SIZE.max_len(), Some(8));
    let v: Vec<Chars> = strings(9).map(|s| Chars { c: b'c', d: 'd', s }).collect();
    // 2, then 4 + 4 + 9 + 1 = 18
    measure(&v, None);
    let v: Vec<MutBounded> = strings(7).map(|s| MutBounded { v: 1, s, c: 2 }).collect();
    // no EMHEADER or DHEADER in the key-hash form: 12 + 4
    measure(&v, Some(16));
    let v: Vec<Outer> = strings(3)
        .map(|n| Outer {
            inner: InnerBounded { n, x: 1.5 },
            b: Box::new(-1),
            k: 9,
        })
        .collect();
    // the inner key (8), the i64 (8) aligned to 4: 16, then the octet: 17
    measure(&v, None);
}

/// A struct that holds itself through a bounded `Vec` nests without end:
/// unbounded, and its constant does not depend on itself.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Tree {
    x: i32,
    #[ipc(bound = 3)]
    kids: Vec<Tree>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct KeyedTree {
    #[ipc(key)]
    t: Tree,
}

/// Types that hold each other through bounded `Vec`s compile, and so does
/// a keyed type holding them outside its key.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Ping {
    #[ipc(bound = 2)]
    pongs: Vec<Pong>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Pong {
    #[ipc(bound = 2)]
    pings: Vec<Ping>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct KeyedPing {
    #[ipc(key)]
    id: u8,
    ping: Ping,
}

#[test]
fn recursive_types_with_bounded_vecs() {
    assert_eq!(Tree::CDR_MAX_SIZE.max_len(), None);
    assert_eq!(KeyedTree::CDR_KEY_MAX_SIZE.max_len(), None);
    let t = KeyedTree {
        t: Tree { x: 1, kids: vec![] },
    };
    // 12 bytes now (x, DHEADER, count), but a tree can be any size: MD5
    assert_eq!(forms(&t, Version::Xcdr2).0.len(), 12);
    assert_ne!(key_hash(&t), padded(&forms(&t, Version::Xcdr2).0));
    check(&t);
    let p = KeyedPing {
        id: 7,
        ping: Ping {
            pongs: vec![Pong { pings: vec![] }],
        },
    };
    assert_eq!(KeyedPing::CDR_KEY_MAX_SIZE.max_len(), Some(1));
    assert_eq!(key_hash(&p), padded(&[7]));
    check(&p);
}

// A key member whose struct type has no key fields of its own: all its
// members are keys (implicit keys), and the key-hash form holds them in
// member-id order, scoped to their struct, as Cyclone DDS orders them
// (idlc sorts the key descriptors by their member-id path; the key-hash
// writer, `DDS_CDR_KEY_SERIALIZATION_KEYHASH`, follows that list). The
// expected bytes are built by hand and the MD5 digests computed with
// Python's hashlib, e.g. for `HoldsNote`:
// `hashlib.md5(bytes([7,0,0,0]) + struct.pack(">I", 3) + b"hi\0" + b"\0" + struct.pack(">H", 9))`.

/// `@mutable struct IdPair { @id(2) long a; @id(1) short b; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct IdPair {
    #[ipc(id = 2)]
    a: i32,
    #[ipc(id = 1)]
    b: i16,
}

/// `struct HoldsPair { @key IdPair p; long v; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct HoldsPair {
    #[ipc(key)]
    p: IdPair,
    v: i32,
}

/// `@appendable struct IdNote { @id(3) string note; @id(1) octet n; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct IdNote {
    #[ipc(id = 3)]
    note: String,
    #[ipc(id = 1)]
    n: u8,
}

/// `struct HoldsNote { @key IdNote k; @key unsigned short id; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct HoldsNote {
    #[ipc(key)]
    k: IdNote,
    #[ipc(key)]
    id: u16,
}

/// `@mutable struct Deep { @id(5) IdPair pair; @id(4) string note; }`:
/// a struct without keys inside one.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct Deep {
    #[ipc(id = 5)]
    pair: IdPair,
    #[ipc(id = 4)]
    note: String,
}

/// `struct HoldsDeep { @key Deep d; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct HoldsDeep {
    #[ipc(key)]
    d: Deep,
}

#[test]
fn members_of_a_keyless_key_member_go_in_member_id_order() {
    // b (id 1), padded to 4, then a (id 2): 8 bytes, the hash is the key
    // (definition order gave 01 02 03 04 05 06)
    let v = HoldsPair {
        p: IdPair {
            a: 0x0102_0304,
            b: 0x0506,
        },
        v: 9,
    };
    assert_eq!(hex(&key_hash(&v)), "05060000010203040000000000000000");
    assert_eq!(HoldsPair::CDR_KEY_MAX_SIZE.max_len(), Some(8));
    assert_eq!(
        cdr::key_from_key_hash::<HoldsPair>(&key_hash(&v)),
        Some(v.p.clone())
    );
    assert_eq!(cdr::key_hash_of_key::<HoldsPair>(&v.p), Some(key_hash(&v)));
    check(&v);

    // k (id 0): n (id 1) 07, padded, then note (id 3) "hi"; then id (id
    // 1): 07000000 00000003 686900 00 0009, an unbounded string: MD5
    // (definition order, 00000003 686900 07 0009, gave d9d03ba5…)
    let v = HoldsNote {
        k: IdNote {
            note: "hi".into(),
            n: 7,
        },
        id: 9,
    };
    assert_eq!(HoldsNote::CDR_KEY_MAX_SIZE.max_len(), None);
    assert_eq!(hex(&key_hash(&v)), "d4a0774d351f411a3668568023d0406d");
    assert_eq!(
        cdr::key_hash_of_key::<HoldsNote>(&(v.k.clone(), v.id)),
        Some(key_hash(&v))
    );
    check(&v);

    // note (id 4) "x", then pair (id 5) in its own member-id order, b then
    // a: 00000002 7800 fffe 7fffffff
    let v = HoldsDeep {
        d: Deep {
            pair: IdPair { a: i32::MAX, b: -2 },
            note: "x".into(),
        },
    };
    assert_eq!(hex(&key_hash(&v)), "7dc5933f95e26817e093098fc67a3c47");
    check(&v);
}

/// `struct TriArr { @key Tri a[3]; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct TriArr {
    #[ipc(key)]
    a: [Tri; 3],
}

#[test]
fn an_array_of_enums_has_a_dheader_in_the_key_hash() {
    // DHEADER 12, then C, B, A: 16 bytes, the hash is the key (Cyclone's
    // idlc gives `@key Color a[3]` DDS_TOPIC_FIXED_KEY_XCDR2, `a[4]` not)
    let v = TriArr {
        a: [Tri::C, Tri::B, Tri::A],
    };
    assert_eq!(hex(&key_hash(&v)), "0000000c000000020000000100000000");
    assert_eq!(TriArr::CDR_KEY_MAX_SIZE.max_len(), Some(16));
    assert_eq!(cdr::key_from_key_hash::<TriArr>(&key_hash(&v)), Some(v.a));
    check(&v);
}

// The XCDR1 and XCDR2 key hashes of keys with 8-byte members, byte for
// byte (DDSI-RTPS 2.5 §9.6.4.8 in the data's XCDR version, as Cyclone DDS
// and Fast DDS compute it): XCDR1 aligns a long long or double to 8, XCDR2
// to 4, and has no DHEADER. The MD5 digests were computed independently
// (Python's hashlib) of the key bytes shown.

/// `struct L3 { @key long a; @key long long b; @key long c; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct L3 {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    #[ipc(key)]
    c: i32,
}

/// `struct OctDbl { @key octet o; @key double d; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct OctDbl {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    d: f64,
}

/// `struct PtLL { long x; long long y; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct PtLL {
    x: i32,
    y: i64,
}

/// `struct NestLL { @key PtLL p; @key long c; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct NestLL {
    #[ipc(key)]
    p: PtLL,
    #[ipc(key)]
    c: i32,
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn a_long_long_after_a_long_is_aligned_to_8_in_xcdr1() {
    // @key long a; @key long long b;  XCDR1: a, 4 bytes of padding, b
    // (16 bytes, the key itself); XCDR2: a, b, then the hash's padding
    let v = LongLongLong {
        a: 1,
        b: 0x0102_0304_0506_0708,
        v: 9,
    };
    let x1 = "00000001000000000102030405060708";
    let x2 = "00000001010203040506070800000000";
    assert_eq!(
        LongLongLong::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr1),
        Some(16)
    );
    assert_eq!(
        LongLongLong::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr2),
        Some(12)
    );
    assert_eq!(hex(&key_hash_in(&v, Version::Xcdr1)), x1);
    assert_eq!(hex(&key_hash_in(&v, Version::Xcdr2)), x2);
    assert_eq!(hex(&key_hash(&v)), x2, "key_hash is the XCDR2 form");
    let key = (1, 0x0102_0304_0506_0708);
    assert_eq!(
        cdr::key_hash_of_key_in::<LongLongLong>(&key, Version::Xcdr1),
        Some(key_hash_in(&v, Version::Xcdr1))
    );
    // the round trip, in each version; the other version's reading is wrong
    let h1: [u8; 16] = unhex(x1).try_into().unwrap();
    let h2: [u8; 16] = unhex(x2).try_into().unwrap();
    assert_eq!(
        cdr::key_from_key_hash_in::<LongLongLong>(&h1, Version::Xcdr1),
        Some(key)
    );
    assert_eq!(
        cdr::key_from_key_hash_in::<LongLongLong>(&h2, Version::Xcdr2),
        Some(key)
    );
    assert_eq!(cdr::key_from_key_hash::<LongLongLong>(&h2), Some(key));
    assert_ne!(
        cdr::key_from_key_hash_in::<LongLongLong>(&h1, Version::Xcdr2),
        Some(key)
    );
    // the payload's version decides what a reader computes
    assert_eq!(
        cdr::key_hash_of_payload::<LongLongLong>(&cdr::to_vec(&v, Encoding::Xcdr1Le), false),
        Some(h1)
    );
    assert_eq!(
        cdr::key_hash_of_payload::<LongLongLong>(&cdr::key_to_vec(&v, Encoding::Xcdr2Be), true),
        Some(h2)
    );
    check(&v);
}

#[test]
fn a_key_that_fits_16_bytes_in_xcdr2_but_not_in_xcdr1() {
    // @key long a; @key long long b; @key long c;
    // XCDR2: 00000001 0102030405060708 ffffffff, 16 bytes: the key itself
    // XCDR1: 00000001 00000000 0102030405060708 ffffffff, up to 20: MD5
    let v = L3 {
        a: 1,
        b: 0x0102_0304_0506_0708,
        c: -1,
    };
    assert_eq!(L3::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr2), Some(16));
    assert_eq!(L3::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr1), None);
    assert_eq!(
        hex(&key_hash_in(&v, Version::Xcdr2)),
        "000000010102030405060708ffffffff"
    );
    assert_eq!(
        hex(&key_hash_in(&v, Version::Xcdr1)),
        "67a7014dd1221bb8c6e39ea21a08406d"
    );
    let key = (1, 0x0102_0304_0506_0708, -1);
    assert_eq!(
        cdr::key_from_key_hash_in::<L3>(&key_hash_in(&v, Version::Xcdr2), Version::Xcdr2),
        Some(key)
    );
    // an MD5 digest gives no key back
    assert_eq!(
        cdr::key_from_key_hash_in::<L3>(&key_hash_in(&v, Version::Xcdr1), Version::Xcdr1),
        None
    );
    // even a key of zeros is an MD5 digest in XCDR1: the type decides
    let zero = L3 { a: 0, b: 0, c: 0 };
    assert_eq!(
        hex(&key_hash_in(&zero, Version::Xcdr1)),
        hex(&courier::rtps::participant::md5(&[0; 20]))
    );
    check(&v);
}

#[test]
fn an_octet_then_a_double() {
    // @key octet o; @key double d;  (1.5 is 3ff8000000000000)
    // XCDR1: ab, 7 bytes of padding, d: 16; XCDR2: ab, 3 of padding, d: 12
    let v = OctDbl { o: 0xab, d: 1.5 };
    let x1 = "ab000000000000003ff8000000000000";
    let x2 = "ab0000003ff800000000000000000000";
    assert_eq!(
        OctDbl::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr1),
        Some(16)
    );
    assert_eq!(
        OctDbl::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr2),
        Some(12)
    );
    assert_eq!(hex(&key_hash_in(&v, Version::Xcdr1)), x1);
    assert_eq!(hex(&key_hash_in(&v, Version::Xcdr2)), x2);
    let h1: [u8; 16] = unhex(x1).try_into().unwrap();
    assert_eq!(
        cdr::key_from_key_hash_in::<OctDbl>(&h1, Version::Xcdr1),
        Some((0xab, 1.5))
    );
    check(&v);
}

#[test]
fn a_nested_struct_with_a_long_long_after_a_long() {
    // @key PtLL p; @key long c; with PtLL { long x; long long y; } (no
    // keys: all of it is key)
    // XCDR2: 00000002 0000000000000003 00000004: 16 bytes, the key itself
    // XCDR1: 00000002 00000000 0000000000000003 00000004: 20, MD5
    let v = NestLL {
        p: PtLL { x: 2, y: 3 },
        c: 4,
    };
    assert_eq!(
        NestLL::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr2),
        Some(16)
    );
    assert_eq!(NestLL::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr1), None);
    assert_eq!(
        hex(&key_hash_in(&v, Version::Xcdr2)),
        "00000002000000000000000300000004"
    );
    assert_eq!(
        hex(&key_hash_in(&v, Version::Xcdr1)),
        "307f1f0839e289af8d833354322469d5"
    );
    assert_eq!(
        cdr::key_from_key_hash_in::<NestLL>(&key_hash_in(&v, Version::Xcdr2), Version::Xcdr2),
        Some((v.p.clone(), 4))
    );
    assert_eq!(
        cdr::key_from_key_hash_in::<NestLL>(&key_hash_in(&v, Version::Xcdr1), Version::Xcdr1),
        None
    );
    check(&v);
}

#[test]
fn an_array_of_enums_has_no_dheader_in_xcdr1() {
    // C, B, A: 12 bytes, padded (XCDR2 puts a DHEADER of 12 first)
    let v = TriArr {
        a: [Tri::C, Tri::B, Tri::A],
    };
    let x1 = "00000002000000010000000000000000";
    assert_eq!(
        TriArr::CDR_KEY_MAX_SIZE.max_len_in(Version::Xcdr1),
        Some(12)
    );
    assert_eq!(hex(&key_hash_in(&v, Version::Xcdr1)), x1);
    let h1: [u8; 16] = unhex(x1).try_into().unwrap();
    assert_eq!(
        cdr::key_from_key_hash_in::<TriArr>(&h1, Version::Xcdr1),
        Some(v.a)
    );
}

/// `@mutable struct MutLL { @key long a; @key long long b; long v; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct MutLL {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    v: i32,
}

/// `@appendable struct AppLL { @key long a; @key long long b; long v; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct AppLL {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    v: i32,
}

#[test]
fn mutable_and_appendable_keys_have_no_headers_in_either_form() {
    // no parameter list (XCDR1), EMHEADERs or DHEADER (XCDR2): the key
    // members one after the other, as Cyclone DDS writes them for the hash
    let x1 = "0000000a000000000000000000000014";
    let x2 = "0000000a000000000000001400000000";
    let m = MutLL { a: 10, b: 20, v: 1 };
    let a = AppLL { a: 10, b: 20, v: 1 };
    assert_eq!(hex(&key_hash_in(&m, Version::Xcdr1)), x1);
    assert_eq!(hex(&key_hash_in(&a, Version::Xcdr1)), x1);
    assert_eq!(hex(&key_hash_in(&m, Version::Xcdr2)), x2);
    assert_eq!(hex(&key_hash_in(&a, Version::Xcdr2)), x2);
    let h1: [u8; 16] = unhex(x1).try_into().unwrap();
    let h2: [u8; 16] = unhex(x2).try_into().unwrap();
    for (h, version) in [(h1, Version::Xcdr1), (h2, Version::Xcdr2)] {
        assert_eq!(
            cdr::key_from_key_hash_in::<MutLL>(&h, version),
            Some((10, 20))
        );
        assert_eq!(
            cdr::key_from_key_hash_in::<AppLL>(&h, version),
            Some((10, 20))
        );
    }
    // from a PL_CDR (XCDR1 mutable) sample or key: the XCDR1 hash
    assert_eq!(
        cdr::key_hash_of_payload::<MutLL>(&cdr::to_vec(&m, Encoding::Xcdr1Le), false),
        Some(h1)
    );
    assert_eq!(
        cdr::key_hash_of_payload::<MutLL>(&cdr::key_to_vec(&m, Encoding::Xcdr1Be), true),
        Some(h1)
    );
    check(&m);
    check(&a);
}
