//! The key hash a reader computes when the writer sends none (Cyclone DDS
//! 11 sends no `PID_KEY_HASH`): from a sample, or from the serialized key
//! a dispose carries, it equals `key_hash` of the value, for every
//! encoding and for keys of every shape the derive takes.

use courier::cdr::{self, Encoding};
use courier::{key_hash, IpcMessage};

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
    let want = key_hash(v);
    for enc in ALL {
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
