//! Hand-written `IpcMessage` impls that call the CDR API exactly as
//! `#[derive(IpcMessage)]` does (begin_struct / begin_member / end_member /
//! end; next_member for mutable structs). Shared by the `cdr_*` tests.
//! The IPC parts are placeholders: these types are CDR-only.
#![allow(dead_code)]
// `@optional string` maps to `Option<Box<String>>`, the IPC pointer type
#![allow(clippy::box_collection)]

use courier_wire::cdr::{self, DecodeError, Extensibility};
use courier_wire::{__private, ipc, IpcMessage};

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
                    // an appendable struct's data may end early (an older
                    // writer): the rest take their defaults
                    $( let $f = if s.ended(r) { Default::default() } else { dec!($kind, r) }; )*
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

/// `typedef sequence<long> SeqI32;` (a sequence as a sequence element).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SeqI32(pub Vec<i32>);

impl IpcMessage for SeqI32 {
    type Key = Self;
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        Self::cdr_decode(r)
    }
    const FORMAT: &'static str = "<int:1>";
    const TYPE_NAME: &'static str = "SeqI32";
    const IPC_MIN_SIZE: usize = 4;
    const CDR_MIN_SIZE: usize = 4;
    fn ipc_encode(&self, _: &mut ipc::Writer) {}
    fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Err(ipc::DecodeError::Format("CDR-only test type".into()))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        __private::cdr_encode_seq(&self.0, w);
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        __private::cdr_decode_seq(r).map(SeqI32)
    }
}

/// IDL `short grid[2][3]`: Cyclone writes a multi-dimensional array as one
/// flat array (no DHEADER when the element is primitive). `[[i16; 3]; 2]`
/// does not, yet (see `multidim_array_of_primitives_as_cyclone` in cdr_golden.rs).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Grid(pub [[i16; 3]; 2]);

impl IpcMessage for Grid {
    type Key = Self;
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        Self::cdr_decode(r)
    }
    const FORMAT: &'static str = "[short:2,3]";
    const TYPE_NAME: &'static str = "Grid";
    const IPC_MIN_SIZE: usize = 12;
    const CDR_MIN_SIZE: usize = 12;
    fn ipc_encode(&self, _: &mut ipc::Writer) {}
    fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Err(ipc::DecodeError::Format("CDR-only test type".into()))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        let d = w.begin_array(true);
        for row in &self.0 {
            i16::cdr_encode_slice(row, w);
        }
        w.end_dheader(d);
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        let d = r.begin_array(true)?;
        let mut g = [[0i16; 3]; 2];
        for row in &mut g {
            for x in row.iter_mut() {
                *x = r.read_i16()?;
            }
        }
        r.end_dheader(d);
        Ok(Grid(g))
    }
}

/// `@final struct Prims` (every primitive, char and an enum).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Prims {
    pub a: i8,
    pub b: u8,
    pub c: i16,
    pub d: u16,
    pub e: i32,
    pub f: u32,
    pub g: i64,
    pub h: u64,
    pub i: f32,
    pub j: f64,
    pub k: bool,
    pub l: char,
    pub m: Color,
}
cdr_struct!(Prims, Extensibility::Final, [a: val = 0, false; b: val = 1, false; c: val = 2, false; d: val = 3, false;
    e: val = 4, false; f: val = 5, false; g: val = 6, false; h: val = 7, false; i: val = 8, false; j: val = 9, false;
    k: val = 10, false; l: val = 11, false; m: val = 12, false], keys []);

/// `@final struct Point { int32 x; double y; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Point {
    pub x: i32,
    pub y: f64,
}
cdr_struct!(Point, Extensibility::Final, [x: val = 0, false; y: val = 1, false], keys []);

/// `@final struct Strings { string empty, hello; uint8 b; sequence<string> list; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Strings {
    pub empty: String,
    pub hello: String,
    pub b: u8,
    pub list: Vec<String>,
}
cdr_struct!(Strings, Extensibility::Final, [empty: val = 0, false; hello: val = 1, false; b: val = 2, false; list: seq = 3, false], keys []);

/// `@final struct Seqs` (sequences of primitives, booleans, enums).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Seqs {
    pub i32: Vec<i32>,
    pub i16: Vec<i16>,
    pub u8: Vec<u8>,
    pub f64: Vec<f64>,
    pub flags: Vec<bool>,
    pub colors: Vec<Color>,
    pub empty: Vec<i64>,
}
cdr_struct!(Seqs, Extensibility::Final, [i32: seq = 0, false; i16: seq = 1, false; u8: seq = 2, false; f64: seq = 3, false;
    flags: seq = 4, false; colors: seq = 5, false; empty: seq = 6, false], keys []);

/// `@final struct Nested` (nested struct, sequences and arrays of structs,
/// a 2-D array, an array of strings, a sequence of sequences).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Nested {
    pub tag: u8,
    pub p: Point,
    pub pts: Vec<Point>,
    pub arr: [Point; 2],
    pub grid: Grid,
    pub names: [String; 2],
    pub seqseq: Vec<SeqI32>,
}
cdr_struct!(Nested, Extensibility::Final, [tag: val = 0, false; p: val = 1, false; pts: seq = 2, false; arr: val = 3, false;
    grid: val = 4, false; names: val = 5, false; seqseq: seq = 6, false], keys []);

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

/// `@final struct Keyed { @key int32 id; @key string name; double value; }`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Keyed {
    pub id: i32,
    pub name: String,
    pub value: f64,
}
cdr_struct!(Keyed, Extensibility::Final, [id: val = 0, false; name: val = 1, false; value: val = 2, false],
    keys [id: val = 0; name: val = 1]);

/// `@mutable struct MutKeyed { @key int32 id; string value; }`. Cyclone does
/// not set must-understand on key members (for RTI's sake).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MutKeyed {
    pub id: i32,
    pub value: String,
}
cdr_struct!(MutKeyed, Extensibility::Mutable, [id: val = 0, false; value: val = 1, false], keys [id: val = 0]);

/// `struct HelloWorld { int32 id; string msg; }`, final.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HelloWorld {
    pub id: i32,
    pub msg: String,
}
cdr_struct!(HelloWorld, Extensibility::Final, [id: val = 0, false; msg: val = 1, false], keys []);

/// The same, `@appendable` (captured from Cyclone 11).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HelloAppendable {
    pub id: i32,
    pub msg: String,
}
cdr_struct!(HelloAppendable, Extensibility::Appendable, [id: val = 0, false; msg: val = 1, false], keys []);

/// The same, `@mutable` (captured from Cyclone 11).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HelloMutable {
    pub id: i32,
    pub msg: String,
}
cdr_struct!(HelloMutable, Extensibility::Mutable, [id: val = 0, false; msg: val = 1, false], keys []);

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

/// Reads a fixture: `#` comment lines, then hex.
pub fn fixture(name: &str) -> Vec<u8> {
    let path = format!(
        "{}/tests/fixtures/cdr/{name}.hex",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let hex: String = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .flat_map(|l| l.chars())
        .filter(|c| !c.is_whitespace())
        .collect();
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
        .collect()
}
