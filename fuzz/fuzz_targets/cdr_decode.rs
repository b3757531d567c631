//! Fuzzes the CDR decoder: arbitrary bytes (the first two choose the
//! encapsulation: XCDR1/XCDR2, LE/BE, final/appendable/mutable ids) are
//! decoded as several types shaped like `#[derive(IpcMessage)]` output: a
//! final struct with optionals, appendable structs with nested appendable
//! sequences, a mutable struct with every length code, sequences, strings and
//! optionals, and recursive types. Decoding must never panic; whatever decodes
//! must re-encode to bytes that decode and re-encode to the same bytes.
//! Types copied from wire/tests/cdr_types/mod.rs.
#![no_main]
#![allow(dead_code, clippy::box_collection)]

use courier_wire::cdr::{self, DecodeError, Encoding, Extensibility};
use courier_wire::{__private, ipc, IpcMessage};
use libfuzzer_sys::fuzz_target;

/// Encodes one field the way the derive does.
macro_rules! enc {
    (val, $v:expr, $w:expr) => {
        IpcMessage::cdr_encode($v, $w)
    };
    (seq, $v:expr, $w:expr) => {
        __private::cdr_encode_seq($v, $w)
    };
}

/// Decodes one field the way the derive does.
macro_rules! dec {
    (val, $r:expr) => {
        IpcMessage::cdr_decode($r)?
    };
    (seq, $r:expr) => {
        __private::cdr_decode_seq($r)?
    };
}

/// `IpcMessage` for a struct: fields with member id, must-understand flag
/// and kind (`val` or `seq`), then the key fields.
macro_rules! cdr_struct {
    ($name:ident, $ext:expr, [$($f:ident: $kind:ident = $id:expr, $mu:expr);* $(;)?], keys [$($k:ident: $kk:ident = $kid:expr);* $(;)?]) => {
        impl IpcMessage for $name {
            const FORMAT: &'static str = "{int}";
            const TYPE_NAME: &'static str = stringify!($name);
            const EXTENSIBILITY: Extensibility = $ext;
            const IPC_MIN_SIZE: usize = 0;
            const CDR_MIN_SIZE: usize = 1;
            const KEYS: &'static [&'static str] = &[$(stringify!($k)),*];

            fn ipc_encode(&self, _: &mut ipc::Writer) {}
            fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
                Err(ipc::DecodeError::Format("CDR-only test type".into()))
            }
            fn cdr_encode(&self, w: &mut cdr::Writer) {
                let s = w.begin_struct($ext);
                $(
                    let m = s.begin_member(w, $id, $mu);
                    enc!($kind, &self.$f, w);
                    s.end_member(w, m);
                )*
                s.end(w);
            }
            type Key = Self;
            fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
                Self::cdr_decode(r)
            }
            fn cdr_encode_key(&self, w: &mut cdr::Writer) {
                let s = w.begin_struct($ext);
                $(
                    let m = s.begin_member(w, $kid, false);
                    enc!($kk, &self.$k, w);
                    s.end_member(w, m);
                )*
                s.end(w);
            }
            #[allow(unused_mut, unused_assignments)]
            fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
                if $ext == Extensibility::Mutable {
                    let mut s = r.begin_struct($ext)?;
                    $( let mut $f = None; )*
                    while let Some(m) = s.next_member(r)? {
                        let mut known = false;
                        $(
                            if !known && m.id == $id {
                                $f = Some(dec!($kind, r));
                                known = true;
                            }
                        )*
                        if !known && m.must_understand {
                            return Err(DecodeError::UnknownMustUnderstand {
                                type_name: stringify!($name),
                                id: m.id,
                                offset: m.start,
                            });
                        }
                    }
                    s.end(r)?;
                    // Cyclone fills members that are not present with defaults
                    Ok($name { $( $f: $f.unwrap_or_default() ),* })
                } else {
                    let s = r.begin_struct($ext)?;
                    $( let $f = dec!($kind, r); )*
                    s.end(r)?;
                    Ok($name { $($f),* })
                }
            }
        }
    };
}

/// IDL `enum Color { RED, GREEN, BLUE }`: an int32 on the wire; not a CDR
/// primitive (XCDR2 puts a DHEADER before sequences and arrays of enums).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Color {
    /// 0
    #[default]
    Red,
    /// 1
    Green,
    /// 2
    Blue,
}

impl IpcMessage for Color {
    type Key = Self;
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        Self::cdr_decode(r)
    }
    const FORMAT: &'static str = "{enum Red, Green, Blue}";
    const TYPE_NAME: &'static str = "Color";
    const IPC_MIN_SIZE: usize = 4;
    const CDR_MIN_SIZE: usize = 4;
    fn ipc_encode(&self, w: &mut ipc::Writer) {
        w.write_i32(*self as i32);
    }
    fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Err(ipc::DecodeError::Format("CDR-only test type".into()))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        w.write_i32(*self as i32);
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        let offset = r.position();
        match r.read_i32()? {
            0 => Ok(Color::Red),
            1 => Ok(Color::Green),
            2 => Ok(Color::Blue),
            v => Err(DecodeError::InvalidEnum {
                offset,
                value: v.into(),
                type_name: "Color",
            }),
        }
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        self.cdr_encode(w);
    }
}

/// `@final struct Point { int32 x; double y; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Point {
    pub x: i32,
    pub y: f64,
}
cdr_struct!(Point, Extensibility::Final, [x: val = 0, false; y: val = 1, false], keys []);

/// `@appendable struct AppInner { int16 v; string s; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AppInner {
    pub v: i16,
    pub s: String,
}
cdr_struct!(AppInner, Extensibility::Appendable, [v: val = 0, false; s: val = 1, false], keys []);

/// `@appendable struct App`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct App {
    pub id: i32,
    pub inner: AppInner,
    pub d: f64,
    pub items: Vec<AppInner>,
}
cdr_struct!(App, Extensibility::Appendable, [id: val = 0, false; inner: val = 1, false; d: val = 2, false; items: seq = 3, false], keys []);

/// `@mutable struct Mut`: one member of each length-code class, two optionals.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mut {
    pub a: i8,
    pub b: i16,
    pub c: i32,
    pub d: i64,
    pub s: String,
    pub color: Color,
    pub flag: bool,
    pub p: Point,
    pub si32: Vec<i32>,
    pub si16: Vec<i16>,
    pub su8: Vec<u8>,
    pub sf64: Vec<f64>,
    pub spts: Vec<Point>,
    pub arr: [i32; 2],
    pub sarr: [String; 2],
    pub opt: Option<Box<i32>>,
    pub optp: Option<Box<Point>>,
}
cdr_struct!(Mut, Extensibility::Mutable, [a: val = 0, false; b: val = 1, false; c: val = 2, false; d: val = 3, false;
    s: val = 4, false; color: val = 5, false; flag: val = 6, false; p: val = 7, false; si32: seq = 8, false;
    si16: seq = 9, false; su8: seq = 10, false; sf64: seq = 11, false; spts: seq = 12, false; arr: val = 13, false;
    sarr: val = 14, false; opt: val = 15, false; optp: val = 16, false], keys []);

/// `@final struct Opt { uint8 a; @optional int32 x; @optional double d; @optional string s; int16 z; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Opt {
    pub a: u8,
    pub x: Option<Box<i32>>,
    pub d: Option<Box<f64>>,
    pub s: Option<Box<String>>,
    pub z: i16,
}
cdr_struct!(Opt, Extensibility::Final, [a: val = 0, false; x: val = 1, false; d: val = 2, false; s: val = 3, false; z: val = 4, false], keys []);

/// A recursive type (linked list through an optional pointer), for depth limits.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Node {
    pub v: u8,
    pub next: Option<Box<Node>>,
}
cdr_struct!(Node, Extensibility::Final, [v: val = 0, false; next: val = 1, false], keys []);

/// A recursive type through a sequence.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tree {
    pub children: Vec<Tree>,
}
cdr_struct!(Tree, Extensibility::Appendable, [children: seq = 0, false], keys []);

fn round_trip<T: IpcMessage>(data: &[u8]) {
    let Ok(v) = cdr::from_slice::<T>(data) else {
        return;
    };
    let enc = cdr::Reader::with_header(data)
        .expect("decoded, so the header is valid")
        .encoding();
    let once = cdr::to_vec(&v, enc);
    let again: T =
        cdr::from_slice(&once).unwrap_or_else(|e| panic!("own encoding does not decode: {e}"));
    assert_eq!(cdr::to_vec(&again, enc), once, "encoding is not stable");
    // the other encodings too
    for e in [
        Encoding::Xcdr1Le,
        Encoding::Xcdr1Be,
        Encoding::Xcdr2Le,
        Encoding::Xcdr2Be,
    ] {
        let b = cdr::to_vec(&v, e);
        let w: T = cdr::from_slice(&b).unwrap_or_else(|err| panic!("{e:?}: {err}"));
        assert_eq!(cdr::to_vec(&w, e), b);
    }
}

fuzz_target!(|data: &[u8]| {
    round_trip::<Opt>(data);
    round_trip::<App>(data);
    round_trip::<Mut>(data);
    round_trip::<Node>(data);
    round_trip::<Tree>(data);
});
