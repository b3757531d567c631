//! `#[derive(IpcMessage)]`: CDR (XCDR1/XCDR2, both byte orders) for final,
//! appendable and mutable structs, keyed types, and property-based round
//! trips in IPC and CDR.

use courier::cdr::{self, DecodeError, Encoding, Extensibility};
use courier::{ipc, IpcMessage};
use proptest::prelude::*;

const ENCODINGS: [Encoding; 4] = [
    Encoding::Xcdr1Le,
    Encoding::Xcdr1Be,
    Encoding::Xcdr2Le,
    Encoding::Xcdr2Be,
];

#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
enum Mode {
    Idle,
    Run,
    Stop,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Inner {
    a: u8,
    b: f64,
}

/// The same members under each extensibility.
macro_rules! sample {
    ($name:ident, $ext:literal) => {
        #[derive(IpcMessage, Debug, Clone, PartialEq)]
        #[ipc(extensibility = $ext)]
        struct $name {
            #[ipc(key)]
            id: i32,
            name: String,
            count: u16,
            #[ipc(len = "count")]
            items: Vec<Inner>,
            n: i32,
            #[ipc(len = "n")]
            samples: Vec<f32>,
            mode: Mode,
            #[ipc(char)]
            tag: u8,
            flags: [bool; 3],
            big: i64,
            next: Option<Box<Inner>>,
            note: Option<String>,
            grid: [[i16; 2]; 2],
            modes: [Mode; 2],
        }

        impl $name {
            fn sample() -> Self {
                $name {
                    id: -7,
                    name: "courier".into(),
                    count: 2,
                    items: vec![Inner { a: 1, b: 0.5 }, Inner { a: 2, b: -1.25 }],
                    n: 3,
                    samples: vec![1.0, 2.5, -3.0],
                    mode: Mode::Stop,
                    tag: b'q',
                    flags: [true, false, true],
                    big: i64::MIN + 1,
                    next: Some(Box::new(Inner { a: 9, b: 9.5 })),
                    note: None,
                    grid: [[1, -2], [3, -4]],
                    modes: [Mode::Run, Mode::Idle],
                }
            }
        }
    };
}

sample!(FinalS, "final");
sample!(AppendableS, "appendable");
sample!(MutableS, "mutable");

fn round_trip<T: IpcMessage + PartialEq + std::fmt::Debug>(v: &T) {
    for enc in ENCODINGS {
        let bytes = cdr::to_vec(v, enc);
        assert_eq!(
            &cdr::from_slice::<T>(&bytes).unwrap_or_else(|e| panic!("{enc:?}: {e}")),
            v,
            "{enc:?}"
        );
        let bare = cdr::to_vec_headerless(v, enc);
        assert_eq!(
            &cdr::from_slice_headerless::<T>(&bare, enc).unwrap(),
            v,
            "{enc:?}"
        );
    }
    assert_eq!(&ipc::from_slice::<T>(&ipc::to_vec(v)).unwrap(), v);
}

#[test]
fn all_extensibilities_round_trip_in_all_encodings() {
    assert_eq!(FinalS::EXTENSIBILITY, Extensibility::Final);
    assert_eq!(AppendableS::EXTENSIBILITY, Extensibility::Appendable);
    assert_eq!(MutableS::EXTENSIBILITY, Extensibility::Mutable);
    assert_eq!(FinalS::KEYS, ["id"]);
    round_trip(&FinalS::sample());
    round_trip(&AppendableS::sample());
    round_trip(&MutableS::sample());
    round_trip(&Mode::Run);
}

#[test]
fn final_xcdr1_golden() {
    // int32 count then items: count field is its own member, the sequence has its own count.
    let v = Inner { a: 3, b: 1.0 };
    assert_eq!(
        cdr::to_vec(&v, Encoding::Xcdr1Le),
        [0, 1, 0, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xf0, 0x3f]
    );
    let b = cdr::to_vec(&v, Encoding::Xcdr2Be);
    let id = cdr::RepresentationId::for_type(Encoding::Xcdr2Be, Extensibility::Final) as u16;
    assert_eq!(b[..2], id.to_be_bytes());
    assert_eq!(b[2..], [0, 0, 3, 0, 0, 0, 0x3f, 0xf0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        cdr::to_vec(&Mode::Stop, Encoding::Xcdr1Be),
        [0, 0, 0, 0, 0, 0, 0, 2]
    );
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct Km {
    #[ipc(key)]
    id: i32,
    v: u8,
}

/// Members in another order and with other ids: mutable decoding goes by id.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct KmReordered {
    #[ipc(id = 1)]
    v: u8,
    #[ipc(id = 0, key)]
    id: i32,
    #[ipc(id = 5)]
    extra: String,
}

/// Only member 0.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct KmShort {
    #[ipc(key)]
    id: i32,
}

/// Only member 1, not the key.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct KmNoKey {
    #[ipc(id = 1)]
    v: u8,
}

/// Member 0 plus an unknown must-understand key member 9.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct KmMustUnderstand {
    #[ipc(key)]
    id: i32,
    #[ipc(id = 9, key)]
    other: i32,
    #[ipc(id = 1)]
    v: u8,
}

#[test]
fn mutable_members_by_id() {
    for enc in ENCODINGS {
        let long = cdr::to_vec(
            &KmReordered {
                v: 4,
                id: 5,
                extra: "x".into(),
            },
            enc,
        );
        // unknown member 5 (not must-understand) is skipped
        assert_eq!(
            cdr::from_slice::<Km>(&long).unwrap(),
            Km { id: 5, v: 4 },
            "{enc:?}"
        );

        // a writer without member 1 (an older version of the type): its
        // default (XTypes)
        let short = cdr::to_vec(&KmShort { id: 1 }, enc);
        assert_eq!(cdr::from_slice::<Km>(&short).unwrap(), Km { id: 1, v: 0 });
        // a key has no default: it must come
        let keyless = cdr::to_vec(&KmNoKey { v: 7 }, enc);
        match cdr::from_slice::<Km>(&keyless) {
            Err(DecodeError::MissingMember {
                member: "id",
                id: 0,
                type_name,
            }) => assert!(type_name.ends_with("::Km")),
            other => panic!("{enc:?}: {other:?}"),
        }

        let mu = cdr::to_vec(
            &KmMustUnderstand {
                id: 1,
                other: 2,
                v: 3,
            },
            enc,
        );
        match cdr::from_slice::<Km>(&mu) {
            Err(DecodeError::UnknownMustUnderstand { id: 9, .. }) => {}
            other => panic!("{enc:?}: {other:?}"),
        }
    }
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct V1 {
    a: i32,
    s: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct V2 {
    a: i32,
    s: String,
    added: f64,
}

#[test]
fn appendable_skips_appended_members_in_xcdr2() {
    for enc in [Encoding::Xcdr2Le, Encoding::Xcdr2Be] {
        let b = cdr::to_vec(
            &V2 {
                a: 1,
                s: "s".into(),
                added: 2.0,
            },
            enc,
        );
        assert_eq!(
            cdr::from_slice::<V1>(&b).unwrap(),
            V1 {
                a: 1,
                s: "s".into()
            }
        );
    }
}

/// An older writer's appendable data ends before the members it lacks:
/// they take their defaults (XTypes), also inside another struct, where
/// the DHEADER says where the older version ends. XCDR1 does not say:
/// there it is an error, never a silently wrong value.
#[test]
fn appendable_fills_members_an_older_writer_lacks() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "OuterV")]
    struct Outer1 {
        inner: V1,
        after: u32,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "OuterV")]
    struct Outer2 {
        inner: V2,
        after: u32,
    }
    let v1 = V1 {
        a: 1,
        s: "s".into(),
    };
    let v2 = V2 {
        a: 1,
        s: "s".into(),
        added: 0.0,
    };
    for enc in [Encoding::Xcdr2Le, Encoding::Xcdr2Be] {
        assert_eq!(cdr::from_slice::<V2>(&cdr::to_vec(&v1, enc)).unwrap(), v2);
        let outer = Outer1 {
            inner: v1.clone(),
            after: 9,
        };
        assert_eq!(
            cdr::from_slice::<Outer2>(&cdr::to_vec(&outer, enc)).unwrap(),
            Outer2 {
                inner: v2.clone(),
                after: 9
            },
            "{enc:?}"
        );
    }
    for enc in [Encoding::Xcdr1Le, Encoding::Xcdr1Be] {
        assert!(cdr::from_slice::<V2>(&cdr::to_vec(&v1, enc)).is_err());
    }
}

/// What each kind of member defaults to when a mutable writer's version of
/// the type lacks it: zero, false, empty, the first enumerator, `None`,
/// and a struct of its members' defaults.
#[test]
fn mutable_members_an_older_writer_lacks_take_their_defaults() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "Evolving", extensibility = "mutable")]
    struct Old {
        #[ipc(key)]
        id: i32,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(name = "Evolving", extensibility = "mutable")]
    struct New {
        #[ipc(key)]
        id: i32,
        f: f64,
        flag: bool,
        mode: Mode,
        name: String,
        arr: [u16; 3],
        seq: Vec<Inner>,
        n: u32,
        #[ipc(len = "n")]
        counted: Vec<i8>,
        inner: Inner,
        opt: Option<Box<Inner>>,
        app: V2,
        #[ipc(char)]
        c: u8,
        rows: i32,
        cols: i32,
        #[ipc(len = "rows, cols")]
        grid: courier::Matrix<f32>,
    }
    for enc in ENCODINGS {
        let b = cdr::to_vec(&Old { id: 3 }, enc);
        assert_eq!(
            cdr::from_slice::<New>(&b).unwrap(),
            New {
                id: 3,
                f: 0.0,
                flag: false,
                mode: Mode::Idle,
                name: String::new(),
                arr: [0; 3],
                seq: vec![],
                n: 0,
                counted: vec![],
                inner: Inner { a: 0, b: 0.0 },
                opt: None,
                app: V2 {
                    a: 0,
                    s: String::new(),
                    added: 0.0
                },
                c: 0,
                rows: 0,
                cols: 0,
                grid: courier::Matrix::new([0, 0], vec![]).unwrap(),
            },
            "{enc:?}"
        );
    }
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "HelloWorldData::Msg")]
struct Keyed {
    #[ipc(key)]
    user_id: i32,
    message: String,
    #[ipc(key)]
    inner: Inner,
    #[ipc(key)]
    label: Option<String>,
}

#[test]
fn keys() {
    assert_eq!(Keyed::TYPE_NAME, "HelloWorldData::Msg");
    assert_eq!(Keyed::KEYS, ["user_id", "inner", "label"]);
    let k = Keyed {
        user_id: 0x0102_0304,
        message: "not in the key".into(),
        inner: Inner { a: 5, b: 1.0 },
        label: Some("k".into()),
    };
    let mut w = cdr::Writer::new(Encoding::Xcdr2Be);
    k.cdr_encode_key(&mut w);
    assert_eq!(
        w.into_vec(),
        [1, 2, 3, 4, 5, 0, 0, 0, 0x3f, 0xf0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, b'k', 0]
    );
    // A type without keys writes nothing.
    let mut w = cdr::Writer::new(Encoding::Xcdr2Be);
    V1 {
        a: 1,
        s: "s".into(),
    }
    .cdr_encode_key(&mut w);
    assert!(w.into_vec().is_empty());
    round_trip(&k);
}

// ---- property tests ----

fn inner() -> impl Strategy<Value = Inner> {
    (any::<u8>(), -1e9f64..1e9).prop_map(|(a, b)| Inner { a, b })
}

fn mode() -> impl Strategy<Value = Mode> {
    prop_oneof![Just(Mode::Idle), Just(Mode::Run), Just(Mode::Stop)]
}

fn sample<T: std::fmt::Debug>(make: fn(FinalS) -> T) -> impl Strategy<Value = T> {
    (
        (
            any::<i32>(),
            "[a-zA-Z0-9 ]{0,12}",
            prop::collection::vec(inner(), 0..4),
        ),
        (
            prop::collection::vec(-1e6f32..1e6, 0..6),
            mode(),
            any::<u8>(),
            any::<[bool; 3]>(),
        ),
        (
            any::<i64>(),
            prop::option::of(inner()),
            prop::option::of("[a-z]{1,5}"),
            any::<[[i16; 2]; 2]>(),
            (mode(), mode()),
        ),
    )
        .prop_map(
            move |(
                (id, name, items),
                (samples, m, tag, flags),
                (big, next, note, grid, (m1, m2)),
            )| {
                make(FinalS {
                    id,
                    name,
                    count: items.len() as u16,
                    items,
                    n: samples.len() as i32,
                    samples,
                    mode: m,
                    tag,
                    flags,
                    big,
                    next: next.map(Box::new),
                    note,
                    grid,
                    modes: [m1, m2],
                })
            },
        )
}

macro_rules! convert {
    ($to:ident) => {
        |f: FinalS| $to {
            id: f.id,
            name: f.name,
            count: f.count,
            items: f.items,
            n: f.n,
            samples: f.samples,
            mode: f.mode,
            tag: f.tag,
            flags: f.flags,
            big: f.big,
            next: f.next,
            note: f.note,
            grid: f.grid,
            modes: f.modes,
        }
    };
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn prop_final(v in sample(|f| f)) {
        for enc in ENCODINGS {
            prop_assert_eq!(cdr::from_slice::<FinalS>(&cdr::to_vec(&v, enc)).unwrap(), v.clone());
        }
        prop_assert_eq!(ipc::from_slice::<FinalS>(&ipc::to_vec(&v)).unwrap(), v);
    }

    #[test]
    fn prop_mutable(v in sample(convert!(MutableS))) {
        for enc in ENCODINGS {
            prop_assert_eq!(cdr::from_slice::<MutableS>(&cdr::to_vec(&v, enc)).unwrap(), v.clone());
        }
        prop_assert_eq!(ipc::from_slice::<MutableS>(&ipc::to_vec(&v)).unwrap(), v);
    }

    #[test]
    fn prop_appendable(v in sample(convert!(AppendableS))) {
        for enc in ENCODINGS {
            prop_assert_eq!(cdr::from_slice::<AppendableS>(&cdr::to_vec(&v, enc)).unwrap(), v.clone());
        }
    }

    /// Arbitrary bytes never panic the generated decoders.
    #[test]
    fn prop_garbage(b in prop::collection::vec(any::<u8>(), 0..200)) {
        let _ = ipc::from_slice::<FinalS>(&b);
        let _ = cdr::from_slice::<FinalS>(&b);
        let _ = cdr::from_slice::<MutableS>(&b);
        let _ = cdr::from_slice::<AppendableS>(&b);
        let _ = ipc::from_slice::<CdrCube>(&b);
        let _ = cdr::from_slice::<CdrCube>(&b);
        let _ = cdr::from_slice::<CdrGridM>(&b);
    }

    /// `<T:k1,k2,k3>` of any shape (empty dimensions too) survives IPC and
    /// every CDR encoding; a value's bytes with one byte changed decode to
    /// a value whose shape fits its elements, or to an error.
    #[test]
    fn prop_nd_shapes(
        shape in (0usize..4, 0usize..4, 0usize..4),
        seed in any::<u8>(),
        flip in (any::<prop::sample::Index>(), 1u8..=255),
    ) {
        let (a, b, c) = shape;
        let v = CdrCube {
            v: courier::NdVec::from_fn([a, b, c], |[i, j, k]| Inner {
                a: seed.wrapping_add((i * 16 + j * 4 + k) as u8),
                b: (i + j + k) as f64,
            })
            .unwrap(),
            a: a as u32,
            b: b as u64,
            c: c as i64,
        };
        round_trip(&v);
        for bytes in [ipc::to_vec(&v), cdr::to_vec(&v, Encoding::Xcdr2Le)] {
            let mut bytes = bytes;
            let at = flip.0.index(bytes.len());
            bytes[at] ^= flip.1;
            let shape_fits = |d: &CdrCube| {
                let [x, y, z] = d.v.shape();
                x * y * z == d.v.len() && (x, y, z) == (d.a as usize, d.b as usize, d.c as usize)
            };
            if let Ok(d) = ipc::from_slice::<CdrCube>(&bytes) {
                prop_assert!(shape_fits(&d));
            }
            if let Ok(d) = cdr::from_slice::<CdrCube>(&bytes) {
                prop_assert!(shape_fits(&d));
            }
        }
    }
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct KeyedAppendable {
    x: f64,
    #[ipc(key)]
    n: u16,
    #[ipc(key, len = "n")]
    ids: Vec<u8>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "mutable")]
struct KeyedMutable {
    #[ipc(key)]
    inner: KeyedAppendable,
    other: i32,
}

#[test]
fn key_framing() {
    let k = KeyedAppendable {
        x: 1.0,
        n: 0, // written as ids.len()
        ids: vec![7, 8],
    };
    // XCDR2 appendable: DHEADER around the key members only.
    let mut w = cdr::Writer::new(Encoding::Xcdr2Le);
    k.cdr_encode_key(&mut w);
    assert_eq!(w.into_vec(), [10, 0, 0, 0, 2, 0, 0, 0, 2, 0, 0, 0, 7, 8]);
    // XCDR1: no DHEADER.
    let mut w = cdr::Writer::new(Encoding::Xcdr1Be);
    k.cdr_encode_key(&mut w);
    assert_eq!(w.into_vec(), [0, 2, 0, 0, 0, 0, 0, 2, 7, 8]);
    round_trip(&KeyedAppendable { n: 2, ..k.clone() });
    let m = KeyedMutable {
        inner: KeyedAppendable { n: 2, ..k },
        other: 5,
    };
    round_trip(&m);
    // The nested key member contributes its own key; the mutable struct
    // frames it as a member.
    for enc in ENCODINGS {
        let key = cdr::key_to_vec(&m, enc);
        assert!(!key.is_empty());
    }
}

/// `IpcMessage::Key`: what `cdr_encode_key` writes comes back as the key
/// fields (one alone, several as a tuple), in every encoding and
/// extensibility; a key field of a keyed type is that type's key.
#[test]
fn keys_decode_to_the_key_type() {
    let k = Keyed {
        user_id: 9,
        message: "m".into(),
        inner: Inner { a: 5, b: 1.5 },
        label: None,
    };
    let m = KeyedMutable {
        inner: KeyedAppendable {
            x: 2.0,
            n: 2,
            ids: vec![7, 8],
        },
        other: 5,
    };
    for enc in ENCODINGS {
        let key: (i32, Inner, Option<String>) =
            cdr::key_from_slice::<Keyed>(&cdr::key_to_vec(&k, enc)).unwrap();
        assert_eq!(key, (9, Inner { a: 5, b: 1.5 }, None), "{enc:?}");
        // KeyedMutable's key is its member's key: (n, ids)
        let key: (u16, Vec<u8>) =
            cdr::key_from_slice::<KeyedMutable>(&cdr::key_to_vec(&m, enc)).unwrap();
        assert_eq!(key, (2, vec![7, 8]), "{enc:?}");
        let s = AppendableS {
            id: -4,
            ..AppendableS::sample()
        };
        let key: i32 = cdr::key_from_slice::<AppendableS>(&cdr::key_to_vec(&s, enc)).unwrap();
        assert_eq!(key, -4, "{enc:?}");
        let key: i32 = cdr::key_from_slice::<MutableS>(&cdr::key_to_vec(
            &MutableS {
                id: 3,
                ..MutableS::sample()
            },
            enc,
        ))
        .unwrap();
        assert_eq!(key, 3, "{enc:?}");
    }
    // a key that is not one: the error says where
    assert!(cdr::key_from_slice::<Keyed>(&[0, 1, 0, 0, 9]).is_err());
}

/// The key hash serializes every struct as final (no DHEADER, no
/// EMHEADER: DDSI-RTPS 2.5 §9.6.4.8), and a bounded key comes back from
/// its hash.
#[test]
fn key_hash_form_and_keys_from_hashes() {
    let s = AppendableS {
        id: 0x0a0b_0c0d,
        ..AppendableS::sample()
    };
    let h = courier::key_hash(&s);
    assert_eq!(
        h,
        [0x0a, 0x0b, 0x0c, 0x0d, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    );
    let m = MutableS {
        id: 0x0a0b_0c0d,
        ..MutableS::sample()
    };
    assert_eq!(courier::key_hash(&m), h, "no EMHEADER in the hash");
    assert_eq!(cdr::key_from_key_hash::<AppendableS>(&h), Some(0x0a0b_0c0d));
    assert_eq!(cdr::key_from_key_hash::<MutableS>(&h), Some(0x0a0b_0c0d));
    // an unbounded key (a string) hashes to MD5: no key in it
    let k = Keyed {
        user_id: 1,
        message: String::new(),
        inner: Inner { a: 1, b: 0.0 },
        label: Some("l".into()),
    };
    assert_eq!(
        cdr::key_from_key_hash::<Keyed>(&courier::key_hash(&k)),
        None
    );
    // bytes after the key that are not zero: not a key hash of this type
    let mut odd = h;
    odd[15] = 1;
    assert_eq!(cdr::key_from_key_hash::<AppendableS>(&odd), None);
}

/// Const generics: one format per `N`, inline.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Fixed<const N: usize> {
    data: [u8; N],
}

/// Type and const parameters of every kind, for the type name.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Mixed<T, const S: i128, const B: bool, const C: char> {
    v: T,
}

/// A generic element type inside a variable array.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Batch<T> {
    n: i32,
    #[ipc(len = "n")]
    items: Vec<T>,
}

#[test]
fn generics() {
    assert_eq!(<Fixed<4>>::FORMAT, "{[ubyte:4]}");
    assert_eq!(<Fixed<2>>::FORMAT, "{[ubyte:2]}");
    assert_eq!(<Batch<Inner>>::FORMAT, "{int, <Inner:1>}");
    assert_eq!(<Batch<Inner>>::FORMAT_NAME, None);
    // Fixed<4> and Fixed<2> lay out differently: their DDS type names differ
    // (they were both `Fixed`, so their DDS endpoints matched)
    assert!(
        <Fixed<4>>::TYPE_NAME.ends_with("::Fixed<4>"),
        "{}",
        <Fixed<4>>::TYPE_NAME
    );
    assert!(<Mixed<i32, -3, true, 'x'>>::TYPE_NAME.ends_with("::Mixed<int32, -3, true, 'x'>"));
    assert_eq!(
        <Mixed<Inner, { i128::MAX }, false, 'é'>>::TYPE_NAME,
        format!(
            "{}::Mixed<{}, {}, false, 'é'>",
            module_path!(),
            Inner::TYPE_NAME,
            i128::MAX
        )
    );
    round_trip(&Fixed { data: [1, 2, 3] });
    round_trip(&Batch {
        n: 1,
        items: vec![Inner { a: 1, b: 2.0 }],
    });
    round_trip(&Batch {
        n: 3,
        items: vec![Mode::Idle, Mode::Stop, Mode::Run],
    });
}

/// A `Vec` without `len` is a DDS `sequence<T>` (IDL `struct Msg { unsigned
/// long seq; string text; sequence<octet> payload; }`), as ROS 2 and the
/// RTPS interop peers use it. It has no C IPC form: its format names count
/// field 0, which the IPC format parser refuses with a clear error.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Msg")]
struct SeqMsg {
    seq: u32,
    text: String,
    payload: Vec<u8>,
}

#[test]
fn vec_without_len_is_a_cdr_sequence() {
    let m = SeqMsg {
        seq: 7,
        text: "hi".into(),
        payload: vec![1, 2, 3],
    };
    let b = cdr::to_vec(&m, cdr::Encoding::Xcdr1Le);
    #[rustfmt::skip]
    let want = [
        0, 1, 0, 0, // CDR_LE
        7, 0, 0, 0, // seq
        3, 0, 0, 0, b'h', b'i', 0, // text with NUL
        0, // pad to 4
        3, 0, 0, 0, 1, 2, 3, // sequence<octet>
    ];
    assert_eq!(b, want);
    assert_eq!(cdr::from_slice::<SeqMsg>(&b).unwrap(), m);
    assert_eq!(SeqMsg::FORMAT, "{uint, string, <ubyte:0>}");
    let e = courier::format::parse(SeqMsg::FORMAT).unwrap_err();
    assert!(e.to_string().contains("dimension 0"), "{e}");
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "A", extensibility = "appendable")]
struct GoldenA {
    #[ipc(key)]
    id: i32,
    text: String,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "M", extensibility = "mutable")]
struct GoldenM {
    #[ipc(key)]
    id: i32,
    text: String,
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// XCDR2 encapsulation headers and the key-only payloads of a dispose, as
/// Cyclone DDS 11 writes them (PyPI cyclonedds 11.0.1, `@appendable` /
/// `@mutable class A/M(IdlStruct) { id: int32 (key); text: str }`, value
/// `(7, "x")`: `serialize()` and `serialize_key()`), and the ids Courier's
/// publications use per representation.
#[test]
fn xcdr2_headers_and_key_payloads_golden() {
    let a = GoldenA {
        id: 7,
        text: "x".into(),
    };
    // D_CDR2_LE (0x0009), DHEADER 10, id, string "x"
    let sample = cdr::to_vec(&a, Encoding::Xcdr2Le);
    assert_eq!(sample, unhex("000900000a00000007000000020000007800"));
    assert_eq!(cdr::from_slice::<GoldenA>(&sample).unwrap(), a);
    // the serialized key of a dispose: the DHEADER around the key member
    assert_eq!(
        cdr::key_to_vec(&a, Encoding::Xcdr2Le),
        unhex("000900000400000007000000")
    );
    // Cyclone 11's mutable sample (PL_CDR2_LE, 0x000b) decodes; its key
    // member has no must-understand flag where Courier sets one (as idlc
    // does for @key members): both read back as id 7
    let cyclone_m = unhex("000b000012000000000000200700000001000050020000007800");
    let m = cdr::from_slice::<GoldenM>(&cyclone_m).unwrap();
    assert_eq!((m.id, m.text.as_str()), (7, "x"));
    assert_eq!(
        cdr::key_from_slice::<GoldenM>(&unhex("000b0000080000000000002007000000")),
        Ok(7)
    );
    assert_eq!(cdr::key_to_vec(&m, Encoding::Xcdr2Le)[..2], [0x00, 0x0b]);
    assert_eq!(
        cdr::key_from_slice::<GoldenM>(&cdr::key_to_vec(&m, Encoding::Xcdr2Le)),
        Ok(7)
    );
    // the encapsulation id per representation and extensibility
    for (enc, ext, id) in [
        (Encoding::Xcdr1Le, "final", 0x0001),
        (Encoding::Xcdr1Le, "mutable", 0x0003),
        (Encoding::Xcdr2Le, "final", 0x0007),
        (Encoding::Xcdr2Le, "appendable", 0x0009),
        (Encoding::Xcdr2Le, "mutable", 0x000b),
    ] {
        let b = match ext {
            "final" => cdr::to_vec(&FinalS::sample(), enc),
            "appendable" => cdr::to_vec(&AppendableS::sample(), enc),
            _ => cdr::to_vec(&MutableS::sample(), enc),
        };
        assert_eq!(u16::from_be_bytes([b[0], b[1]]), id, "{enc:?} {ext}");
        assert_eq!(b[2..4], [0, 0], "{enc:?} {ext}: options");
    }
}

/// `<T:k1,k2>` in CDR: the size fields are members of their own, the
/// elements one `sequence<T>`, flat, row-major (IDL `struct Grid { long
/// rows; long cols; sequence<double> cells; }`).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "Grid")]
struct CdrGrid {
    rows: i32,
    cols: i32,
    #[ipc(len = "rows, cols")]
    cells: courier::Matrix<f64>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "GridM", extensibility = "mutable")]
struct CdrGridM {
    rows: i32,
    cols: i32,
    #[ipc(len = "rows, cols")]
    cells: courier::Matrix<f64>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(extensibility = "appendable")]
struct CdrCube {
    #[ipc(len = "a, b, c")]
    v: courier::NdVec<Inner, 3>,
    a: u32,
    b: u64,
    c: i64,
}

/// Cyclone DDS 11's bytes for the same values (PyPI cyclonedds 11.0.1:
/// `Grid(IdlStruct)` / `@mutable GridM(IdlStruct)` with `rows: int32, cols:
/// int32, cells: sequence[float64]`, `serialize()` and
/// `serialize(use_version_2=True)`).
#[test]
fn nd_var_array_cdr_golden_as_cyclone() {
    let g = CdrGrid {
        rows: 2,
        cols: 3,
        cells: courier::Matrix::new([2, 3], vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]).unwrap(),
    };
    let xcdr1 = unhex(
        "00010000020000000300000006000000000000000000000000000000000000000000f03f\
         0000000000000040000000000000084000000000000010400000000000001440",
    );
    let xcdr2 = unhex(
        "000700000200000003000000060000000000000000000000000000000000f03f00000000\
         00000040000000000000084000000000000010400000000000001440",
    );
    assert_eq!(cdr::to_vec(&g, Encoding::Xcdr1Le), xcdr1);
    assert_eq!(cdr::to_vec(&g, Encoding::Xcdr2Le), xcdr2);
    assert_eq!(cdr::from_slice::<CdrGrid>(&xcdr1).unwrap(), g);
    assert_eq!(cdr::from_slice::<CdrGrid>(&xcdr2).unwrap(), g);

    let m = CdrGridM {
        rows: 2,
        cols: 1,
        cells: courier::Matrix::new([2, 1], vec![1.5, 2.5]).unwrap(),
    };
    let cyclone = unhex(
        "000b000028000000000000200200000001000020010000000200007002000000\
         000000000000f83f0000000000000440",
    );
    assert_eq!(cdr::from_slice::<CdrGridM>(&cyclone).unwrap(), m);
    assert_eq!(cdr::to_vec(&m, Encoding::Xcdr2Le), cyclone);
    round_trip(&m);
    round_trip(&g);
    round_trip(&CdrCube {
        v: courier::NdVec::from_fn([2, 1, 2], |[i, _, k]| Inner {
            a: i as u8,
            b: k as f64,
        })
        .unwrap(),
        a: 2,
        b: 1,
        c: 2,
    });
}

#[test]
fn nd_var_array_cdr_shape_errors() {
    // rows 2 × cols 3, but a sequence of 5
    let mut b = unhex("000100000200000003000000050000000000000000");
    b.extend([0u8; 40]);
    let e = cdr::from_slice::<CdrGrid>(&b).unwrap_err();
    assert_eq!(
        e.to_string(),
        "variable array at byte 8: shape [2, 3] holds 6 elements, but 5 were given"
    );
    // a negative size field
    let b = unhex("0001000002000000feffffff00000000");
    assert_eq!(
        cdr::from_slice::<CdrGrid>(&b).unwrap_err().to_string(),
        "variable array at byte 8: dimension 2 of the shape is -2: a size cannot be negative"
    );
    // mutable members in another order: sizes after the elements
    let m = CdrGridM {
        rows: 1,
        cols: 2,
        cells: courier::Matrix::new([1, 2], vec![1.0, 2.0]).unwrap(),
    };
    let b = cdr::to_vec(&m, Encoding::Xcdr2Le);
    let mut wrong = m.clone();
    wrong.cells = courier::Matrix::new([2, 2], vec![0.0; 4]).unwrap();
    wrong.rows = 1; // ignored on encode: 2 is written
    assert_ne!(cdr::to_vec(&wrong, Encoding::Xcdr2Le), b);
    assert_eq!(cdr::from_slice::<CdrGridM>(&b).unwrap(), m);
}

/// IDL `enum Color { RED, GREEN, BLUE }`, derived: an int32 on the wire,
/// but not a CDR primitive.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(type_name = "Color")]
enum Color {
    Red,
    Green,
    Blue,
}

/// `struct S { sequence<Color> a; Color b[2]; int32 c; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "S")]
struct EnumCollections {
    a: Vec<Color>,
    b: [Color; 2],
    c: i32,
}

/// The same members, `@mutable`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "SM", extensibility = "mutable")]
struct EnumCollectionsM {
    a: Vec<Color>,
    b: [Color; 2],
    c: i32,
}

/// XCDR2 writes a `DHEADER` before a sequence or an array of enums:
/// Cyclone DDS counts only integers, booleans and (w)chars as primitive
/// (`is_primitive_type` in `dds_cdrstream.c`; `is_dheader_needed` is
/// `!is_primitive_type(type) && xcdrv == 2`). XCDR1 has no `DHEADER`.
/// The bytes are Cyclone DDS 11's (PyPI cyclonedds 11.0.1, `Color(IdlEnum)`,
/// `S(IdlStruct)` with `a: sequence[Color]`, `b: array[Color, 2]`, `c:
/// int32`, value `S([GREEN, BLUE], [BLUE, RED], 7)`: `serialize()` with
/// `use_version_2` True and False, both endiannesses; `@mutable SM` the
/// same members). Courier wrote no `DHEADER` there (a derived enum was a
/// CDR primitive), so Cyclone and Courier misread each other's samples.
#[test]
fn enum_sequences_and_arrays_golden_as_cyclone() {
    let v = EnumCollections {
        a: vec![Color::Green, Color::Blue],
        b: [Color::Blue, Color::Red],
        c: 7,
    };
    #[rustfmt::skip]
    let golden = [
        // XCDR2: DHEADER 12, count 2, GREEN, BLUE; DHEADER 8, BLUE, RED; c
        (Encoding::Xcdr2Le, "00070000 0c000000 02000000 01000000 02000000 08000000 02000000 00000000 07000000"),
        (Encoding::Xcdr2Be, "00060000 0000000c 00000002 00000001 00000002 00000008 00000002 00000000 00000007"),
        // XCDR1: no DHEADER
        (Encoding::Xcdr1Le, "00010000 02000000 01000000 02000000 02000000 00000000 07000000"),
        (Encoding::Xcdr1Be, "00000000 00000002 00000001 00000002 00000002 00000000 00000007"),
    ];
    for (enc, hex) in golden {
        let want = unhex(&hex.replace(' ', ""));
        assert_eq!(cdr::to_vec(&v, enc), want, "{enc:?}");
        assert_eq!(
            cdr::from_slice::<EnumCollections>(&want).unwrap(),
            v,
            "{enc:?}"
        );
    }
    // an empty sequence still has its DHEADER (4: the count)
    let e = EnumCollections {
        a: vec![],
        b: [Color::Red; 2],
        c: -1,
    };
    let want = unhex("000700000400000000000000080000000000000000000000ffffffff");
    assert_eq!(cdr::to_vec(&e, Encoding::Xcdr2Le), want);
    assert_eq!(cdr::from_slice::<EnumCollections>(&want).unwrap(), e);
    // mutable: the sequence and the array are EMHEADER LC 5 (the DHEADER
    // is the member's length), the int32 LC 2
    let m = EnumCollectionsM {
        a: v.a.clone(),
        b: v.b,
        c: v.c,
    };
    let want = unhex(
        "000b00002c000000000000500c00000002000000010000000200000001000050\
         0800000002000000000000000200002007000000",
    );
    assert_eq!(cdr::to_vec(&m, Encoding::Xcdr2Le), want);
    assert_eq!(cdr::from_slice::<EnumCollectionsM>(&want).unwrap(), m);
    for enc in ENCODINGS {
        assert_eq!(
            cdr::from_slice::<EnumCollections>(&cdr::to_vec(&v, enc)).unwrap(),
            v
        );
        assert_eq!(
            cdr::from_slice::<EnumCollectionsM>(&cdr::to_vec(&m, enc)).unwrap(),
            m
        );
    }
}
