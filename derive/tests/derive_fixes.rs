//! Runtime checks of audit fixes: raw identifiers, length fields written
//! as `std::primitive::X`, the wire crate found without
//! `#[ipc(crate = "...")]`, and array type names of generic elements.
//!
//! None of these types says `#[ipc(crate = "...")]`: this test crate
//! depends on `courier-wire` (not `courier`), which the derive finds in
//! its `Cargo.toml`.
#![allow(non_camel_case_types)]

use courier_derive::IpcMessage;
use courier_wire::format::{self, FormatRegistry};
use courier_wire::{cdr, ipc, IpcMessage as _, NamedFormats};

#[derive(IpcMessage, Debug, PartialEq)]
struct Raw {
    #[ipc(key)]
    r#type: i32,
    r#n: i32,
    #[ipc(len = "n")]
    r#loop: Vec<u8>,
    m: u32,
    // the raw spelling names the same field
    #[ipc(len = "r#m")]
    r#match: Vec<u8>,
}

#[derive(IpcMessage, Debug, PartialEq)]
struct r#type {
    r#struct: f64,
}

#[derive(IpcMessage, Debug, PartialEq, Clone, Copy)]
enum Kw {
    r#As,
    r#type,
    Plain,
}

#[derive(IpcMessage, Debug, PartialEq)]
struct Uses {
    t: r#type,
    k: Kw,
}

fn round_trip<T: courier_wire::IpcMessage + PartialEq + std::fmt::Debug>(v: &T) {
    assert_eq!(&ipc::from_slice::<T>(&ipc::to_vec(v)).unwrap(), v);
    for enc in [cdr::Encoding::Xcdr1Le, cdr::Encoding::Xcdr2Be] {
        assert_eq!(&cdr::from_slice::<T>(&cdr::to_vec(v, enc)).unwrap(), v);
    }
}

/// The format as a session registers it: named formats defined, then resolved.
fn registers<T: courier_wire::IpcMessage>() {
    let mut reg = FormatRegistry::new();
    for (name, f) in NamedFormats::of::<T>().iter() {
        reg.define(name, f).unwrap();
    }
    format::parse_with(T::FORMAT, &reg).unwrap();
}

#[test]
fn raw_identifiers_lose_their_prefix() {
    assert_eq!(Raw::FORMAT, "{int, int, <ubyte:2>, uint, <ubyte:4>}");
    assert_eq!(Raw::KEYS, ["type"]);
    assert_eq!(r#type::FORMAT, "{double}");
    assert_eq!(r#type::FORMAT_NAME, Some("type"));
    assert!(
        r#type::TYPE_NAME.ends_with("::type"),
        "{}",
        r#type::TYPE_NAME
    );
    assert!(!r#type::TYPE_NAME.contains("r#"), "{}", r#type::TYPE_NAME);
    assert_eq!(Kw::FORMAT, "{enum As, type, Plain}");
    assert_eq!(Uses::FORMAT, "{type, {enum As, type, Plain}}");
    registers::<Uses>();
    registers::<Raw>();
    round_trip(&Raw {
        r#type: 3,
        r#n: 1,
        r#loop: vec![9],
        m: 2,
        r#match: vec![1, 2],
    });
    round_trip(&Uses {
        t: r#type { r#struct: 1.5 },
        k: Kw::r#type,
    });
}

#[derive(IpcMessage, Debug, PartialEq)]
struct PrimitivePaths {
    n: std::primitive::u32,
    #[ipc(len = "n")]
    v: Vec<u8>,
    m: ::core::primitive::i64,
    #[ipc(len = "m")]
    w: Vec<i16>,
}

#[test]
fn length_fields_through_std_primitive() {
    assert_eq!(PrimitivePaths::FORMAT, "{uint, <ubyte:1>, long, <short:3>}");
    round_trip(&PrimitivePaths {
        n: 2,
        v: vec![1, 2],
        m: 1,
        w: vec![-3],
    });
}

#[derive(IpcMessage, Debug, PartialEq)]
struct Stamped<T> {
    stamp: f64,
    t: T,
}

#[test]
fn array_type_names_keep_generic_arguments_whole() {
    let name = <[[Stamped<[i32; 2]>; 5]; 3]>::TYPE_NAME;
    assert!(name.ends_with("Stamped<int32[2]>[3][5]"), "{name}");
    let name = <[Stamped<[i32; 2]>; 5]>::TYPE_NAME;
    assert!(name.ends_with("Stamped<int32[2]>[5]"), "{name}");
}

#[derive(IpcMessage, Debug, PartialEq)]
enum Last {
    A = 2147483646,
    B,
}

#[test]
fn implicit_discriminant_up_to_int32_max() {
    assert_eq!(Last::FORMAT, "{enum : 2147483647}");
    round_trip(&Last::B);
    assert_eq!(ipc::to_vec(&Last::B), i32::MAX.to_ne_bytes());
}

/// A megabyte array behind a `Box` (or an optional pointer).
#[derive(IpcMessage, Debug, PartialEq)]
struct Scan {
    id: u32,
    ranges: Box<[u8; 1_000_000]>,
    extra: Option<Box<[u16; 300_000]>>,
}

/// A large fixed array behind a `Box` is decoded on the heap: a thread with
/// a 256 KiB stack decodes a megabyte of it, IPC and CDR (built on the
/// stack, it overflowed a 2 MiB tokio worker stack in debug builds).
#[test]
fn boxed_large_arrays_decode_on_the_heap() {
    let mut ranges = Box::new([0u8; 1_000_000]);
    ranges[999_999] = 7;
    let mut extra = Box::new([0u16; 300_000]);
    extra[1] = 9;
    let scan = Scan {
        id: 3,
        ranges,
        extra: Some(extra),
    };
    let ipc_bytes = ipc::to_vec(&scan);
    let cdr_bytes = cdr::to_vec(&scan, cdr::Encoding::Xcdr2Le);
    let (a, b) = std::thread::Builder::new()
        .stack_size(256 * 1024)
        .spawn(move || {
            let a = ipc::from_slice::<Scan>(&ipc_bytes).unwrap();
            let b = cdr::from_slice::<Scan>(&cdr_bytes).unwrap();
            (a, b)
        })
        .unwrap()
        .join()
        .unwrap();
    assert_eq!(a, scan);
    assert_eq!(b, scan);
}

/// Keys whose member ids are out of definition order.
#[derive(IpcMessage, Debug, PartialEq)]
#[ipc(extensibility = "mutable")]
struct Reordered {
    #[ipc(key, id = 5)]
    a: i32,
    #[ipc(key, id = 1)]
    b: i32,
    #[ipc(id = 9)]
    note: u32,
}

/// The key hash serializes key members in member-id order (DDS-XTypes 1.3
/// §7.6.8; Cyclone DDS's `dds_stream_key_size_keyhash` / idlc sort keys
/// by member id), while the serialized key keeps definition order: `b`
/// (id 1) comes first in the hash. It hashed `a` first.
#[test]
fn the_key_hash_takes_key_members_in_member_id_order() {
    let v = Reordered {
        a: 1,
        b: 2,
        note: 3,
    };
    let mut want = [0u8; 16];
    want[..8].copy_from_slice(&[0, 0, 0, 2, 0, 0, 0, 1]);
    assert_eq!(courier_wire::key_hash(&v), want);
    assert_eq!(cdr::key_hash_of_key::<Reordered>(&(1, 2)), Some(want));
    assert_eq!(cdr::key_from_key_hash::<Reordered>(&want), Some((1, 2)));
    // the serialized key (a dispose's payload) is unchanged: definition
    // order, with member headers, and reads back
    for enc in [cdr::Encoding::Xcdr2Le, cdr::Encoding::Xcdr1Le] {
        let key = cdr::key_to_vec(&v, enc);
        assert_eq!(
            cdr::key_from_slice::<Reordered>(&key),
            Ok((1, 2)),
            "{enc:?}"
        );
        assert_eq!(
            cdr::key_hash_of_payload::<Reordered>(&key, true),
            Some(want)
        );
    }
}
