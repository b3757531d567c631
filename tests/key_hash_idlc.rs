//! Key hashes against Cyclone DDS's IDL compiler: whether a keyed type's key
//! hash is its key zero-padded or the key's MD5 (DDSI-RTPS 2.5 §9.6.4.8)
//! is decided by the type's largest possible key-hash form, in the XCDR
//! version the hash is computed in, as idlc decides `DDS_TOPIC_FIXED_KEY`
//! (XCDR1: every member aligned to its size up to 8, no `DHEADER`, key
//! members in definition order) and `DDS_TOPIC_FIXED_KEY_XCDR2` (XCDR2:
//! bounded strings as 4 + N + 1 bytes, every member aligned to at most 4,
//! key members in member-id order, and so the members of a key member
//! whose struct type has no key fields; a `DHEADER` before an array of
//! enums).
//!
//! The test writes the IDL of [`IDL`] into a fresh temporary directory,
//! runs `idlc -x final` (Debian package `cyclonedds-tools`; a missing
//! `idlc` fails the test, naming the package), reads each type's
//! `.m_flagset` from the generated C, and checks the Rust twin of every
//! type in both versions: its key hash, for a value at the bounds and for
//! a short one, is padded exactly when idlc gives the type
//! `DDS_TOPIC_FIXED_KEY` (XCDR1) / `DDS_TOPIC_FIXED_KEY_XCDR2` (XCDR2),
//! and [`IpcMessage::CDR_KEY_MAX_SIZE`] says the same.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use courier::cdr::Version;
use courier::{cdr, key_hash, key_hash_in, IpcMessage};
use courier_tests::peers;

/// The IDL types, each with a Rust twin below and the size of its largest
/// key-hash form (XCDR2: alignment at most 4; `string<N>` 4 + N + 1).
const IDL: &str = r#"
module KeyOracle {
  // string<0> is an unbounded string
  struct Str0 { @key string<0> name; long v; };
  struct StrU { @key string name; long v; };
  struct Str1 { @key string<1> name; long v; };
  struct Str2 { @key string<2> name; long v; };
  struct Str3 { @key string<3> name; long v; };
  struct Str4 { @key string<4> name; long v; };
  struct Str5 { @key string<5> name; long v; };
  struct Str6 { @key string<6> name; long v; };
  struct Str7 { @key string<7> name; long v; };
  struct Str8 { @key string<8> name; long v; };
  struct Str9 { @key string<9> name; long v; };
  struct Str10 { @key string<10> name; long v; };
  struct Str11 { @key string<11> name; long v; };   // 16
  struct Str12 { @key string<12> name; long v; };   // 17
  struct Str13 { @key string<13> name; long v; };
  struct L2 { @key long a; @key long long b; long v; };                 // 4 + 8 = 12
  struct OctLL { @key octet o; @key long long l; @key long m; long v; };  // 4 + 8 + 4 = 16
  struct OctLL2 { @key octet o; @key long long l; @key long m; @key octet p; }; // 17
  enum Color { RED, GREEN, BLUE };
  struct EnumStr7 { @key Color c; @key string<7> s; };   // 4 + 12 = 16
  struct EnumStr8 { @key Color c; @key string<8> s; };   // 17
  struct ArrStr3 { @key short a[3]; @key string<3> s; }; // 6, aligned 8, + 8 = 16
  struct ArrStr4 { @key short a[3]; @key string<4> s; }; // 17
  struct Long4 { @key long a[4]; };                      // 16
  struct Long5 { @key long a[5]; };                      // 20
  struct Bools16 { @key boolean b[16]; };                // 16
  struct Pt { long x; short y; };
  struct NestStr3 { @key Pt p; @key string<3> s; };      // 6, aligned 8, + 8 = 16
  struct NestStr4 { @key Pt p; @key string<4> s; };      // 17
  struct Inner { @key long x; string note; };
  struct NestKey7 { @key Inner inner; @key string<7> s; long v; }; // 4 + 12 = 16
  struct NestKey8 { @key Inner inner; @key string<8> s; long v; }; // 17
  struct TwoStr { @key string<3> a; @key string<3> b; };  // 8 + 8 = 16
  struct TwoStr2 { @key string<3> a; @key string<4> b; }; // 17
  struct CharStr7 { @key char c; @key string<7> s; };     // 1, aligned 4, + 12 = 16
  struct CharStr9 { @key char c; @key string<9> s; };     // 18
  // member-id order: h (2), aligned 4, + s (14) = 18; definition order 16
  struct Ord { @key @id(1) string<9> s; @key @id(0) short h; @id(2) long v; };
  // member-id order: s (14) + h (2) = 16; definition order 18
  struct OrdFits { @key @id(1) short h; @key @id(0) string<9> s; @id(2) long v; };
  // an array of enums has a DHEADER (enums are not primitive): 4 + 12 = 16
  struct EnumArr3 { @key Color a[3]; };
  struct EnumArr4 { @key Color a[4]; };                  // 4 + 16 = 20
  // a key member whose struct type has no keys: all its members are keys,
  // in member-id order: s (14) + h (2) = 16; definition order 18
  @final struct OrdInF { @id(1) short h; @id(0) string<9> s; };
  struct NestOrdF { @key OrdInF i; long v; };
  // the same, mutable and appendable: no EMHEADER or DHEADER in the key hash
  @mutable struct OrdInM { @id(1) short h; @id(0) string<9> s; };
  struct NestOrdM { @key OrdInM i; long v; };
  @appendable struct OrdInA { @id(1) short h; @id(0) string<9> s; };
  struct NestOrdA { @key OrdInA i; long v; };
  // ids in definition order: h (2), aligned 4, + s (14) = 18
  @mutable struct InOrdM { @id(0) short h; @id(1) string<9> s; };
  struct NestInOrdM { @key InOrdM i; long v; };
  // 8-byte members: XCDR1 aligns them to 8, XCDR2 to 4
  struct LL { @key long a; @key long long b; };          // XCDR1 16, XCDR2 12
  struct LL3 { @key long a; @key long long b; @key long c; }; // XCDR1 20, XCDR2 16
  struct OctDbl { @key octet o; @key double d; };         // XCDR1 16, XCDR2 12
  struct OctDbl2 { @key octet o; @key double d; @key octet p; }; // XCDR1 17, XCDR2 13
  struct PtLL { long x; long long y; };
  struct NestLL { @key PtLL p; @key long c; };            // XCDR1 20, XCDR2 16
  struct NestLL2 { @key long a; @key PtLL p; };           // XCDR1 16, XCDR2 16
  struct InnerLL { @key long x; @key long long y; string note; };
  struct NestKeyLL { @key InnerLL i; @key long c; long v; }; // XCDR1 20, XCDR2 16
  // the XCDR1 key of mutable and appendable types has no parameter list
  // or DHEADER either
  @mutable struct MutLL3 { @key long a; @key long long b; @key long c; };  // XCDR1 20, XCDR2 16
  @appendable struct AppLL { @key long a; @key long long b; };            // XCDR1 16, XCDR2 12
  // a keyed struct inside a key member whose type has no keys: idlc 0.10
  // takes all of In2 as well (its key list is w.i.x, w.i.y, w.z, s):
  // 4 + 4 + 2, aligned 4, + 4 + 1 + 1 = 18; In2's key alone would be 14
  struct In2 { @key long x; long y; };
  @final struct Wrap { In2 i; short z; };
  struct NestWrap { @key Wrap w; @key string<1> s; };
};
"#;

macro_rules! bounded_string_key {
    ($($name:ident = $type_name:tt, $bound:tt;)*) => {$(
        #[derive(IpcMessage, Debug, Clone, PartialEq)]
        #[ipc(type_name = $type_name)]
        struct $name {
            #[ipc(key, bound = $bound)]
            name: String,
            v: i32,
        }
    )*};
}

bounded_string_key! {
    Str1 = "KeyOracle::Str1", 1;
    Str2 = "KeyOracle::Str2", 2;
    Str3 = "KeyOracle::Str3", 3;
    Str4 = "KeyOracle::Str4", 4;
    Str5 = "KeyOracle::Str5", 5;
    Str6 = "KeyOracle::Str6", 6;
    Str7 = "KeyOracle::Str7", 7;
    Str8 = "KeyOracle::Str8", 8;
    Str9 = "KeyOracle::Str9", 9;
    Str10 = "KeyOracle::Str10", 10;
    Str11 = "KeyOracle::Str11", 11;
    Str12 = "KeyOracle::Str12", 12;
    Str13 = "KeyOracle::Str13", 13;
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Str0")]
struct Str0 {
    #[ipc(key)]
    name: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::StrU")]
struct StrU {
    #[ipc(key)]
    name: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::L2")]
struct L2 {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::OctLL")]
struct OctLL {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    l: i64,
    #[ipc(key)]
    m: i32,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::OctLL2")]
struct OctLL2 {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    l: i64,
    #[ipc(key)]
    m: i32,
    #[ipc(key)]
    p: u8,
}

#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(type_name = "KeyOracle::Color")]
enum Color {
    Red,
    Green,
    Blue,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::EnumStr7")]
struct EnumStr7 {
    #[ipc(key)]
    c: Color,
    #[ipc(key, bound = 7)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::EnumStr8")]
struct EnumStr8 {
    #[ipc(key)]
    c: Color,
    #[ipc(key, bound = 8)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::ArrStr3")]
struct ArrStr3 {
    #[ipc(key)]
    a: [i16; 3],
    #[ipc(key, bound = 3)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::ArrStr4")]
struct ArrStr4 {
    #[ipc(key)]
    a: [i16; 3],
    #[ipc(key, bound = 4)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Long4")]
struct Long4 {
    #[ipc(key)]
    a: [i32; 4],
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Long5")]
struct Long5 {
    #[ipc(key)]
    a: [i32; 5],
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Bools16")]
struct Bools16 {
    #[ipc(key)]
    b: [bool; 16],
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Pt")]
struct Pt {
    x: i32,
    y: i16,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::In2")]
struct In2 {
    #[ipc(key)]
    x: i32,
    y: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Wrap", extensibility = "final")]
struct Wrap {
    i: In2,
    z: i16,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestWrap")]
struct NestWrap {
    #[ipc(key)]
    w: Wrap,
    #[ipc(key, bound = 1)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestStr3")]
struct NestStr3 {
    #[ipc(key)]
    p: Pt,
    #[ipc(key, bound = 3)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestStr4")]
struct NestStr4 {
    #[ipc(key)]
    p: Pt,
    #[ipc(key, bound = 4)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Inner")]
struct Inner {
    #[ipc(key)]
    x: i32,
    note: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestKey7")]
struct NestKey7 {
    #[ipc(key)]
    inner: Inner,
    #[ipc(key, bound = 7)]
    s: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestKey8")]
struct NestKey8 {
    #[ipc(key)]
    inner: Inner,
    #[ipc(key, bound = 8)]
    s: String,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::TwoStr")]
struct TwoStr {
    #[ipc(key, bound = 3)]
    a: String,
    #[ipc(key, bound = 3)]
    b: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::TwoStr2")]
struct TwoStr2 {
    #[ipc(key, bound = 3)]
    a: String,
    #[ipc(key, bound = 4)]
    b: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::CharStr7")]
struct CharStr7 {
    #[ipc(key)]
    c: char,
    #[ipc(key, bound = 7)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::CharStr9")]
struct CharStr9 {
    #[ipc(key)]
    c: char,
    #[ipc(key, bound = 9)]
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::Ord")]
struct Ord {
    #[ipc(key, id = 1, bound = 9)]
    s: String,
    #[ipc(key, id = 0)]
    h: i16,
    #[ipc(id = 2)]
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::OrdFits")]
struct OrdFits {
    #[ipc(key, id = 1)]
    h: i16,
    #[ipc(key, id = 0, bound = 9)]
    s: String,
    #[ipc(id = 2)]
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::EnumArr3")]
struct EnumArr3 {
    #[ipc(key)]
    a: [Color; 3],
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::EnumArr4")]
struct EnumArr4 {
    #[ipc(key)]
    a: [Color; 4],
}

/// A struct without key fields whose member ids are out of definition
/// order, and a keyed struct with it as its key member.
macro_rules! nested_ord {
    ($($inner:ident = $inner_name:literal, $ext:literal, $hid:literal, $sid:literal;
        $outer:ident = $outer_name:literal;)*) => {$(
        #[derive(IpcMessage, Debug, Clone, PartialEq)]
        #[ipc(type_name = $inner_name, extensibility = $ext)]
        struct $inner {
            #[ipc(id = $hid)]
            h: i16,
            #[ipc(id = $sid, bound = 9)]
            s: String,
        }

        #[derive(IpcMessage, Debug, Clone, PartialEq)]
        #[ipc(type_name = $outer_name)]
        struct $outer {
            #[ipc(key)]
            i: $inner,
            v: i32,
        }
    )*};
}

nested_ord! {
    OrdInF = "KeyOracle::OrdInF", "final", 1, 0; NestOrdF = "KeyOracle::NestOrdF";
    OrdInM = "KeyOracle::OrdInM", "mutable", 1, 0; NestOrdM = "KeyOracle::NestOrdM";
    OrdInA = "KeyOracle::OrdInA", "appendable", 1, 0; NestOrdA = "KeyOracle::NestOrdA";
    InOrdM = "KeyOracle::InOrdM", "mutable", 0, 1; NestInOrdM = "KeyOracle::NestInOrdM";
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::LL")]
struct LL {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::LL3")]
struct LL3 {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    #[ipc(key)]
    c: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::OctDbl")]
struct OctDbl {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    d: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::OctDbl2")]
struct OctDbl2 {
    #[ipc(key)]
    o: u8,
    #[ipc(key)]
    d: f64,
    #[ipc(key)]
    p: u8,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::PtLL")]
struct PtLL {
    x: i32,
    y: i64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestLL")]
struct NestLL {
    #[ipc(key)]
    p: PtLL,
    #[ipc(key)]
    c: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestLL2")]
struct NestLL2 {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    p: PtLL,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::InnerLL")]
struct InnerLL {
    #[ipc(key)]
    x: i32,
    #[ipc(key)]
    y: i64,
    note: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::NestKeyLL")]
struct NestKeyLL {
    #[ipc(key)]
    i: InnerLL,
    #[ipc(key)]
    c: i32,
    v: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::MutLL3", extensibility = "mutable")]
struct MutLL3 {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
    #[ipc(key)]
    c: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyOracle::AppLL", extensibility = "appendable")]
struct AppLL {
    #[ipc(key)]
    a: i32,
    #[ipc(key)]
    b: i64,
}

/// `n` bytes of text: a string at its bound.
fn text(n: usize) -> String {
    "abcdefghijklmnopqrstuvwxyz"
        .chars()
        .cycle()
        .take(n)
        .collect()
}

/// The key-hash form of `v`'s key in XCDR version `version`: big-endian,
/// structs final.
fn key_form<T: IpcMessage>(v: &T, version: Version) -> Vec<u8> {
    let mut w = cdr::Writer::key_hash_form_in(version);
    v.cdr_encode_key(&mut w);
    w.into_vec()
}

/// Whether `v`'s key hash in `version` is its key-hash form zero-padded
/// (rather than the MD5 of it).
fn padded<T: IpcMessage>(v: &T, version: Version) -> bool {
    let (hash, key) = (key_hash_in(v, version), key_form(v, version));
    key.len() <= 16 && hash[..key.len()] == key[..] && hash[key.len()..].iter().all(|b| *b == 0)
}

/// What Courier decides for type `T` in one XCDR version.
struct Decision {
    /// Courier pads the key hash of the longest value (`None`: see
    /// [`case_reordered`]).
    pads: Option<bool>,
    /// `CDR_KEY_MAX_SIZE` is at most 16 bytes in this version.
    fits: bool,
}

/// What Courier does with type `T`: given a value at the bounds (the
/// longest key) and a short one, the decisions (padded or not, XCDR1 and
/// XCDR2) and their inconsistencies.
struct Case {
    type_name: &'static str,
    xcdr1: Decision,
    xcdr2: Decision,
    /// Problems found without idlc: the decision depends on the value, or
    /// the maximum and the longest value's key disagree.
    problems: Vec<String>,
}

fn decide<T: IpcMessage>(
    longest: &T,
    short: &T,
    version: Version,
    problems: &mut Vec<String>,
) -> Decision {
    let pads = padded(longest, version);
    if padded(short, version) != pads {
        problems.push(format!(
            "{version:?}: the key hash of a short value is {}, of the longest {}: decided by the value, not the type",
            if padded(short, version) { "padded" } else { "an MD5" },
            if pads { "padded" } else { "an MD5" },
        ));
    }
    let max = T::CDR_KEY_MAX_SIZE;
    let fits = max.fits_key_hash_in(version);
    let (long_len, short_len) = (
        key_form(longest, version).len(),
        key_form(short, version).len(),
    );
    if fits != pads {
        problems.push(format!(
            "{version:?}: CDR_KEY_MAX_SIZE says {}, the key hash is {}",
            if fits {
                "fits 16 bytes"
            } else {
                "over 16 bytes"
            },
            if pads { "padded" } else { "an MD5" },
        ));
    }
    // the maximum is the exact worst case: the longest value reaches it
    let expect = (long_len <= 16).then_some(long_len);
    if max.max_len_in(version) != expect || short_len > long_len {
        problems.push(format!(
            "{version:?}: CDR_KEY_MAX_SIZE.max_len_in() is {:?}, the longest value's key is {long_len} bytes (a short one's {short_len})",
            max.max_len_in(version)
        ));
    }
    Decision {
        pads: Some(pads),
        fits,
    }
}

fn case<T: IpcMessage>(longest: T, short: T) -> Case {
    let mut problems = Vec::new();
    let xcdr1 = decide(&longest, &short, Version::Xcdr1, &mut problems);
    let xcdr2 = decide(&longest, &short, Version::Xcdr2, &mut problems);
    // the functions without a version are XCDR2
    if key_hash(&longest) != key_hash_in(&longest, Version::Xcdr2) {
        problems.push("key_hash is not key_hash_in(.., Xcdr2)".into());
    }
    Case {
        type_name: T::TYPE_NAME,
        xcdr1,
        xcdr2,
        problems,
    }
}

/// [`case`] for a type whose key members (or the members of a keyless
/// key member) have ids out of definition order. Cyclone DDS measures the
/// XCDR1 key in definition order (idlc's `DDS_TOPIC_FIXED_KEY`, which
/// Courier's XCDR1 maximum follows) but writes the key-hash form in
/// member-id order in both versions, so in XCDR1 the longest value's form
/// can be longer than the maximum: `Ord`'s is 18 bytes (`h`, 2 bytes of
/// padding, `string<9>`) where definition order gives 16. Courier then
/// hashes that value's key with MD5, as it does any key longer than 16
/// bytes (Cyclone DDS 0.10 pads by the actual length, so it does the
/// same). In XCDR1 only the maximum is compared with idlc, a short value
/// is padded exactly when it fits, and the longest when it fits and its
/// form has at most 16 bytes.
fn case_reordered<T: IpcMessage>(longest: T, short: T) -> Case {
    let mut problems = Vec::new();
    let xcdr2 = decide(&longest, &short, Version::Xcdr2, &mut problems);
    let fits = T::CDR_KEY_MAX_SIZE.fits_key_hash_in(Version::Xcdr1);
    if padded(&short, Version::Xcdr1) != fits {
        problems.push(format!(
            "Xcdr1: CDR_KEY_MAX_SIZE says {}, a short value's key hash is {}",
            if fits { "fits" } else { "over 16 bytes" },
            if fits { "an MD5" } else { "padded" },
        ));
    }
    let long_len = key_form(&longest, Version::Xcdr1).len();
    if padded(&longest, Version::Xcdr1) != (fits && long_len <= 16) {
        problems.push(format!(
            "Xcdr1: the longest value's key ({long_len} bytes) is {}",
            if fits { "not padded" } else { "padded" }
        ));
    }
    Case {
        type_name: T::TYPE_NAME,
        xcdr1: Decision { pads: None, fits },
        xcdr2,
        problems,
    }
}

fn cases() -> Vec<Case> {
    macro_rules! strs {
        ($($t:ident = $n:expr),*) => {
            vec![$(case($t { name: text($n), v: 1 }, $t { name: String::new(), v: 1 })),*]
        };
    }
    let mut v = strs![
        Str0 = 40,
        StrU = 40,
        Str1 = 1,
        Str2 = 2,
        Str3 = 3,
        Str4 = 4,
        Str5 = 5,
        Str6 = 6,
        Str7 = 7,
        Str8 = 8,
        Str9 = 9,
        Str10 = 10,
        Str11 = 11,
        Str12 = 12,
        Str13 = 13
    ];
    let pt = || Pt { x: -1, y: 2 };
    let inner = || Inner {
        x: 5,
        note: "not a key".into(),
    };
    v.extend([
        case(L2 { a: 1, b: -2, v: 3 }, L2 { a: 0, b: 0, v: 0 }),
        case(
            OctLL {
                o: 1,
                l: 2,
                m: 3,
                v: 4,
            },
            OctLL {
                o: 0,
                l: 0,
                m: 0,
                v: 0,
            },
        ),
        case(
            OctLL2 {
                o: 1,
                l: 2,
                m: 3,
                p: 4,
            },
            OctLL2 {
                o: 0,
                l: 0,
                m: 0,
                p: 0,
            },
        ),
        case(
            EnumStr7 {
                c: Color::Blue,
                s: text(7),
            },
            EnumStr7 {
                c: Color::Red,
                s: String::new(),
            },
        ),
        case(
            EnumStr8 {
                c: Color::Green,
                s: text(8),
            },
            EnumStr8 {
                c: Color::Red,
                s: String::new(),
            },
        ),
        case(
            ArrStr3 {
                a: [1, 2, 3],
                s: text(3),
            },
            ArrStr3 {
                a: [0; 3],
                s: String::new(),
            },
        ),
        case(
            ArrStr4 {
                a: [1, 2, 3],
                s: text(4),
            },
            ArrStr4 {
                a: [0; 3],
                s: String::new(),
            },
        ),
        case(Long4 { a: [1, 2, 3, 4] }, Long4 { a: [0; 4] }),
        case(Long5 { a: [1, 2, 3, 4, 5] }, Long5 { a: [0; 5] }),
        case(Bools16 { b: [true; 16] }, Bools16 { b: [false; 16] }),
        case(
            NestStr3 {
                p: pt(),
                s: text(3),
            },
            NestStr3 {
                p: pt(),
                s: String::new(),
            },
        ),
        case(
            NestStr4 {
                p: pt(),
                s: text(4),
            },
            NestStr4 {
                p: pt(),
                s: String::new(),
            },
        ),
        case(
            NestKey7 {
                inner: inner(),
                s: text(7),
                v: 1,
            },
            NestKey7 {
                inner: inner(),
                s: String::new(),
                v: 1,
            },
        ),
        case(
            NestKey8 {
                inner: inner(),
                s: text(8),
                v: 1,
            },
            NestKey8 {
                inner: inner(),
                s: String::new(),
                v: 1,
            },
        ),
        case(
            TwoStr {
                a: text(3),
                b: text(3),
            },
            TwoStr {
                a: String::new(),
                b: String::new(),
            },
        ),
        case(
            TwoStr2 {
                a: text(3),
                b: text(4),
            },
            TwoStr2 {
                a: String::new(),
                b: String::new(),
            },
        ),
        case(
            CharStr7 { c: 'c', s: text(7) },
            CharStr7 {
                c: 'c',
                s: String::new(),
            },
        ),
        case(
            CharStr9 { c: 'c', s: text(9) },
            CharStr9 {
                c: 'c',
                s: String::new(),
            },
        ),
        case_reordered(
            Ord {
                s: text(9),
                h: 1,
                v: 2,
            },
            Ord {
                s: String::new(),
                h: 1,
                v: 2,
            },
        ),
        case_reordered(
            OrdFits {
                h: 1,
                s: text(9),
                v: 2,
            },
            OrdFits {
                h: 1,
                s: String::new(),
                v: 2,
            },
        ),
        case(
            EnumArr3 {
                a: [Color::Blue, Color::Green, Color::Red],
            },
            EnumArr3 { a: [Color::Red; 3] },
        ),
        case(
            EnumArr4 {
                a: [Color::Blue; 4],
            },
            EnumArr4 { a: [Color::Red; 4] },
        ),
    ]);
    macro_rules! nested {
        ($($case:ident: $outer:ident($inner:ident)),*) => {
            v.extend([$($case(
                $outer {
                    i: $inner { h: -2, s: text(9) },
                    v: 1,
                },
                $outer {
                    i: $inner { h: 3, s: String::new() },
                    v: 1,
                },
            )),*])
        };
    }
    nested!(
        case_reordered: NestOrdF(OrdInF),
        case_reordered: NestOrdM(OrdInM),
        case_reordered: NestOrdA(OrdInA),
        case: NestInOrdM(InOrdM)
    );
    v.extend([case(
        NestWrap {
            w: Wrap {
                i: In2 { x: 1, y: 2 },
                z: 3,
            },
            s: text(1),
        },
        NestWrap {
            w: Wrap {
                i: In2 { x: 1, y: 2 },
                z: 3,
            },
            s: String::new(),
        },
    )]);
    let pt = || PtLL { x: -3, y: 1 << 40 };
    v.extend([
        case(LL { a: 1, b: -2 }, LL { a: 0, b: 0 }),
        case(LL3 { a: 1, b: -2, c: 3 }, LL3 { a: 0, b: 0, c: 0 }),
        case(OctDbl { o: 1, d: 2.5 }, OctDbl { o: 0, d: 0.0 }),
        case(
            OctDbl2 { o: 1, d: 2.5, p: 3 },
            OctDbl2 { o: 0, d: 0.0, p: 0 },
        ),
        case(NestLL { p: pt(), c: 4 }, NestLL { p: pt(), c: 0 }),
        case(NestLL2 { a: 4, p: pt() }, NestLL2 { a: 0, p: pt() }),
        case(
            NestKeyLL {
                i: InnerLL {
                    x: 1,
                    y: 2,
                    note: "not a key".into(),
                },
                c: 3,
                v: 4,
            },
            NestKeyLL {
                i: InnerLL {
                    x: 0,
                    y: 0,
                    note: String::new(),
                },
                c: 0,
                v: 0,
            },
        ),
        case(MutLL3 { a: 1, b: 2, c: 3 }, MutLL3 { a: 0, b: 0, c: 0 }),
        case(AppLL { a: 1, b: 2 }, AppLL { a: 0, b: 0 }),
    ]);
    v
}

/// A directory of its own under the system's temporary directory, removed
/// when dropped: concurrent runs never share one.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        static N: AtomicU32 = AtomicU32::new(0);
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!(
            "courier-key-hash-idlc-{}-{nanos}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        // create_dir, not create_dir_all: fails rather than share a directory
        std::fs::create_dir(&dir)
            .unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
        TempDir(dir)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The `.m_flagset` of the descriptor of IDL type `a::b::T`
/// (`const dds_topic_descriptor_t a_b_T_desc = { ... .m_flagset = ..., }`).
fn flagset<'a>(c: &'a str, type_name: &str) -> Option<&'a str> {
    let decl = format!(
        "const dds_topic_descriptor_t {}_desc =",
        type_name.replace("::", "_")
    );
    let rest = &c[c.find(&decl)? + decl.len()..];
    let body = &rest[..rest.find("};")?];
    let line = body
        .lines()
        .find(|l| l.trim_start().starts_with(".m_flagset"))?;
    Some(line.split_once('=')?.1.trim().trim_end_matches(','))
}

#[test]
fn fixed_keys_agree_with_idlc() {
    let dir = TempDir::new();
    let idl = dir.path().join("key_oracle.idl");
    std::fs::write(&idl, IDL).unwrap_or_else(|e| panic!("cannot write {}: {e}", idl.display()));
    peers::run_idlc(&["-x", "final"], &idl, dir.path())
        .unwrap_or_else(|e| panic!("the key-hash oracle needs idlc: {e}"));
    let c_file = dir.path().join("key_oracle.c");
    let c = std::fs::read_to_string(&c_file)
        .unwrap_or_else(|e| panic!("idlc wrote no {}: {e}", c_file.display()));

    let mut failures = Vec::new();
    let mut checked = 0;
    for case in cases() {
        let flags = flagset(&c, case.type_name).unwrap_or_else(|| {
            panic!(
                "no descriptor for {} in {}",
                case.type_name,
                c_file.display()
            )
        });
        let has = |flag: &str| flags.split('|').any(|f| f.trim() == flag);
        for (version, flag, d) in [
            (Version::Xcdr1, "DDS_TOPIC_FIXED_KEY", &case.xcdr1),
            (Version::Xcdr2, "DDS_TOPIC_FIXED_KEY_XCDR2", &case.xcdr2),
        ] {
            let fixed = has(flag);
            if fixed != d.fits {
                failures.push(format!(
                    "{} {version:?}: idlc flags {flags}; Courier's CDR_KEY_MAX_SIZE is {}",
                    case.type_name,
                    if d.fits {
                        "at most 16 bytes"
                    } else {
                        "over 16 bytes"
                    }
                ));
            }
            if d.pads.is_some_and(|pads| pads != fixed) {
                failures.push(format!(
                    "{} {version:?}: idlc flags {flags}; Courier {}",
                    case.type_name,
                    // they disagree: Courier does the other thing
                    if fixed {
                        "hashes the key with MD5"
                    } else {
                        "pads the key"
                    }
                ));
            }
        }
        for p in &case.problems {
            failures.push(format!("{}: {p}", case.type_name));
        }
        checked += 1;
    }
    assert!(checked >= 50, "only {checked} types checked");
    assert!(
        failures.is_empty(),
        "{} disagreements with idlc -x final:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
