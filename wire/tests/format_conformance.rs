//! `courier_wire::format`: golden bytes from captures of the C IPC 3.9.1
//! library, facts of the C parser, malformed input, and property tests.

use courier_wire::format::{
    self, decode_formatter, encode_formatter, equivalent, parse, parse_with, Format,
    FormatRegistry, ParseError, Primitive, ResolveError, MAX_NESTING,
};
use courier_wire::ipc::{ByteOrder, DecodeError, Reader, Writer};
use proptest::prelude::*;

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.chars().filter(|c| !c.is_whitespace()).collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn p(s: &str) -> Format {
    parse(s).unwrap_or_else(|e| panic!("{s:?}: {e}"))
}

fn prim(p: Primitive) -> Format {
    Format::Primitive(p)
}

fn encode(f: &Format) -> Vec<u8> {
    let mut w = Writer::new();
    encode_formatter(Some(f), &mut w);
    w.into_vec()
}

fn decode_le(bytes: &[u8]) -> Result<Option<Format>, DecodeError> {
    let mut r = Reader::new(bytes, ByteOrder::Little);
    let f = decode_formatter(&mut r)?;
    r.finish()?;
    Ok(f)
}

// ---------------------------------------------------------------------------
// Golden bytes. All captures are little-endian (x86-64); the hex is the
// message data after the 28-byte header.
// ---------------------------------------------------------------------------

/// fixtures/ipc/demo-central/decoded-fullhex.txt t=0.000288, central's first
/// handshake frame: the formatter of the msgInfo query format.
const HANDSHAKE_QUERY: &str = "02000000 03000000 00000000 07000000 00000000 07000000";

/// Same capture, t=0.000302: the second handshake frame, the msgInfo reply format.
const HANDSHAKE_REPLY: &str =
    "03000000 5a 02000000 06000000 00000000 01000000 00000000 07000000 00000000 01000000 \
     00000000 08000000 00000000 08000000";

/// demo-central t=0.000538: x_ipc_classInfoMsg reply `*{int, format}` for class 8:
/// `[8, {{int, {int, int}}, {int, {int, int}}, *{int, int, int, int, int}}]`.
const CLASS_INFO_8: &str = "5a08000000 02000000 04000000 02000000 03000000 00000000 01000000 02000000 03000000 \
     00000000 01000000 00000000 01000000 02000000 03000000 00000000 01000000 02000000 03000000 00000000 01000000 \
     00000000 01000000 03000000 5a 02000000 06000000 00000000 01000000 00000000 01000000 00000000 01000000 \
     00000000 01000000 00000000 01000000";

/// demo-central t=2.993807: msgInfo reply for `response1`:
/// `[105, 'response1', 15, '{int, <byte:1>}', T2 expanded]`.
const MSG_INFO_RESPONSE1: &str = "5a69000000 09000000 726573706f6e736531 0f000000 \
     02000000 03000000 00000000 01000000 05000000 03000000 00000000 05000000 01000000 \
     02000000 05000000 00000000 07000000 00000000 01000000 05000000 03000000 02000000 05000000 00000000 01000000 \
     08000000 02000000 03000000 04000000 04000000 00000000 04000000 02000000 03000000 00000000 04000000 02000000 \
     08000000 06000000 03000000 07000000 5761697456616c 07000000 53656e6456616c 0a000000 5265636569766556616c \
     09000000 4c697374656e56616c";

/// demo-central t=0.002306: msgInfo reply for `query1`.
const MSG_INFO_QUERY1: &str = "5a6f000000 06000000 717565727931 0f000000 \
     02000000 03000000 00000000 01000000 05000000 03000000 00000000 05000000 01000000 \
     02000000 05000000 00000000 01000000 08000000 02000000 03000000 04000000 04000000 00000000 04000000 02000000 \
     03000000 00000000 04000000";

/// demo-central t=0.001085: msgInfo reply for `V_get_X_IPC_BROADCAST_MSG_VAR`
/// (NULL query format, reply `{int, int, <string:2>}`).
const MSG_INFO_BROADCAST_VAR: &str = "5a77000000 1d000000 565f6765745f585f4950435f42524f4144434153545f4d53475f564152 \
     03000000 ffffffff 02000000 04000000 00000000 01000000 00000000 01000000 05000000 03000000 00000000 07000000 02000000";

/// demo-central t=0.002084: msgInfo reply for `x_ipc_directMsgQuery`.
const MSG_INFO_DIRECT_QUERY: &str = "5a93000000 14000000 785f6970635f6469726563744d73675175657279 03000000 \
     00000000 07000000 02000000 03000000 00000000 01000000 05000000 03000000 02000000 07000000 00000000 01000000 \
     00000000 01000000 00000000 01000000 00000000 01000000 00000000 07000000 00000000 07000000 01000000";

/// wiretest-central t=0.202819: msgInfo reply for `fixedMsg` (`[byte:8]`, `{int, int}`).
const MSG_INFO_FIXED: &str =
    "5a74000000 08000000 66697865644d7367 0f000000 04000000 03000000 00000000 05000000 \
     08000000 02000000 03000000 00000000 01000000 00000000 01000000";

/// wiretest-central t=0.202938: msgInfo reply for `emptyMsg` (both formats NULL).
const MSG_INFO_EMPTY: &str = "5a73000000 08000000 656d7074794d7367 0f000000 ffffffff ffffffff";

struct MsgInfo {
    id: i32,
    name: String,
    class: i32,
    msg: Option<Format>,
    res: Option<Format>,
}

/// Decodes a msgInfo reply `*{int, string, int, format, format}`.
fn msg_info(hexs: &str) -> MsgInfo {
    let bytes = hex(hexs);
    let mut r = Reader::new(&bytes, ByteOrder::Little);
    assert_eq!(r.read_u8().unwrap(), b'Z');
    let id = r.read_i32().unwrap();
    let name = r.read_str().unwrap().to_string();
    let class = r.read_i32().unwrap();
    let msg = decode_formatter(&mut r).unwrap();
    let res = decode_formatter(&mut r).unwrap();
    r.finish().unwrap();
    MsgInfo {
        id,
        name,
        class,
        msg,
        res,
    }
}

/// Re-encodes a decoded msgInfo reply; must give the captured bytes back.
fn msg_info_bytes(m: &MsgInfo) -> Vec<u8> {
    let mut w = Writer::new();
    w.write_u8(b'Z');
    w.write_i32(m.id);
    w.write_str(&m.name);
    w.write_i32(m.class);
    encode_formatter(m.msg.as_ref(), &mut w);
    encode_formatter(m.res.as_ref(), &mut w);
    w.into_vec()
}

#[test]
fn golden_handshake_formatters() {
    let q = p("{string, string}");
    assert_eq!(encode(&q), hex(HANDSHAKE_QUERY));
    assert_eq!(decode_le(&hex(HANDSHAKE_QUERY)).unwrap(), Some(q));

    let r = p("*{int, string, int, format, format}");
    assert_eq!(encode(&r), hex(HANDSHAKE_REPLY));
    assert_eq!(decode_le(&hex(HANDSHAKE_REPLY)).unwrap(), Some(r));
}

#[test]
fn golden_class_info_reply() {
    let bytes = hex(CLASS_INFO_8);
    let mut r = Reader::new(&bytes, ByteOrder::Little);
    assert_eq!(r.read_u8().unwrap(), b'Z');
    assert_eq!(r.read_i32().unwrap(), 8);
    let f = decode_formatter(&mut r).unwrap().unwrap();
    r.finish().unwrap();
    assert_eq!(
        f.to_string(),
        "{{int, {int, int}}, {int, {int, int}}, *{int, int, int, int, int}}"
    );
    assert_eq!(f, p(&f.to_string()));
    assert_eq!(encode(&f), hex(CLASS_INFO_8)[5..]);
}

#[test]
fn golden_msg_info_replies() {
    let cases = [
        (
            MSG_INFO_RESPONSE1,
            105,
            "response1",
            "{int, <byte:1>}",
            "{string, int, <{int, {enum : 3}, [double:2,3], double}:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
        ),
        (
            MSG_INFO_QUERY1,
            111,
            "query1",
            "{int, <byte:1>}",
            "{int, {enum : 3}, [double:2,3], double}",
        ),
        (
            MSG_INFO_BROADCAST_VAR,
            119,
            "V_get_X_IPC_BROADCAST_MSG_VAR",
            "",
            "{int, int, <string:2>}",
        ),
        (
            MSG_INFO_DIRECT_QUERY,
            147,
            "x_ipc_directMsgQuery",
            "string",
            "{int, <{int, int, int, int, string, string}:1>}",
        ),
        (MSG_INFO_FIXED, 116, "fixedMsg", "[byte:8]", "{int, int}"),
        (MSG_INFO_EMPTY, 115, "emptyMsg", "", ""),
    ];
    for (bytes, id, name, msg, res) in cases {
        let m = msg_info(bytes);
        assert_eq!((m.id, m.name.as_str()), (id, name));
        let show = |f: &Option<Format>| f.as_ref().map(|f| f.to_string()).unwrap_or_default();
        assert_eq!(show(&m.msg), msg, "{name} msgFormat");
        assert_eq!(show(&m.res), res, "{name} resFormat");
        // The printed forms parse back to the decoded trees...
        assert_eq!(p(msg), m.msg.clone().unwrap_or(Format::Empty));
        assert_eq!(p(res), m.res.clone().unwrap_or(Format::Empty));
        // ...and re-encoding gives the captured bytes.
        assert_eq!(msg_info_bytes(&m), hex(bytes), "{name}");
    }
}

#[test]
fn golden_named_formats_expand_as_central_does() {
    // module1/module2 of the manual register T1 and T2 and define query1 and
    // response1 with them; central's msgInfo replies carry the expansions.
    let mut reg = FormatRegistry::new();
    reg.define("T1", "{int, {enum : 3}, [double:2,3], double}")
        .unwrap();
    reg.define(
        "T2",
        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
    )
    .unwrap();
    let t2 = parse_with("T2", &reg).unwrap();
    assert_eq!(Some(t2.clone()), msg_info(MSG_INFO_RESPONSE1).res);
    assert_eq!(reg.resolve(&Format::Named("T2".into())).unwrap(), t2);
    assert_eq!(
        Some(parse_with("T1", &reg).unwrap()),
        msg_info(MSG_INFO_QUERY1).res
    );
}

#[test]
fn marshalling_examples_of_ipc_md() {
    // The canonical forms of ipc.md §10 E4/E5 and the DESIGN examples.
    for s in [
        "{int, {enum : 3}, [double:2,3], double}",
        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
        "*int",
        "{int, *!}",
        "[int:17,42]",
        "{int, int, <int:1,2>}",
        "{string, int, <int:2>, {enum Red, Green, Blue}, boolean}",
        "{int, <byte:1>}",
        "[string:2]",
        "{}",
        "5",
        "long",
    ] {
        assert_eq!(p(s).to_string(), s);
    }
    assert_eq!(
        p("{int , int,<int:1 ,2 >}").to_string(),
        "{int, int, <int:1,2>}"
    );
    assert_eq!(p("[int: 17, 42]").to_string(), "[int:17,42]");
    assert_eq!(p("{enum A,B,C}").to_string(), "{enum A, B, C}");
    assert_eq!(p("{enum:8}").to_string(), "{enum : 8}");
}

// ---------------------------------------------------------------------------
// Facts of the C parser.
// ---------------------------------------------------------------------------

#[test]
fn every_primitive_by_name_and_code() {
    let names = [
        "char", "byte", "ubyte", "short", "ushort", "twobyte", "int", "uint", "long", "ulong",
        "float", "double", "boolean", "string", "format",
    ];
    for n in names {
        let f = p(n);
        let Format::Primitive(prim) = f else {
            panic!("{n}")
        };
        assert_eq!(prim.name(), n);
        assert_eq!(Primitive::from_code(prim.code()), Some(prim));
        assert_eq!(decode_le(&encode(&f)).unwrap(), Some(f));
    }
    // The C lexer is case-sensitive: `Boolean` (as the manual spells it once) is a name.
    assert_eq!(p("Boolean"), Format::Named("Boolean".into()));
    assert!(matches!(
        parse_with("Boolean", &FormatRegistry::new()),
        Err(ParseError::UnknownName { pos: 0, .. })
    ));
}

#[test]
fn composites() {
    assert_eq!(p(""), Format::Empty);
    assert_eq!(p(" \t "), Format::Empty);
    assert_eq!(p("{}"), Format::Struct(vec![]));
    assert_eq!(
        p("[5:int]"),
        Format::FixedArray {
            elem: Box::new(prim(Primitive::Int)),
            dims: vec![5]
        }
    );
    assert_eq!(p("[5:int]"), p("[int:5]"));
    // Old form with a byte-count element; the printer keeps it that way.
    let f = p("[5:3]");
    assert_eq!(
        f,
        Format::FixedArray {
            elem: Box::new(Format::Length(3)),
            dims: vec![5]
        }
    );
    assert_eq!(f.to_string(), "[5:3]");
    let f = p("[3:5,6]");
    assert_eq!(
        f,
        Format::FixedArray {
            elem: Box::new(Format::Length(3)),
            dims: vec![5, 6]
        }
    );
    assert_eq!(f.to_string(), "[3:5,6]");
    assert_eq!(
        p("{enum : 3}"),
        Format::Enum {
            names: vec![],
            max: 3
        }
    );
    assert_eq!(
        p("{enum A, B, C, D}"),
        Format::Enum {
            names: vec!["A".into(), "B".into(), "C".into(), "D".into()],
            max: 3
        }
    );
    assert_eq!(
        p("**int"),
        Format::Pointer(Box::new(Format::Pointer(Box::new(prim(Primitive::Int)))))
    );
    assert_eq!(
        p("{int, *!}"),
        Format::Struct(vec![prim(Primitive::Int), Format::SelfPointer])
    );
    assert_eq!(
        p("{<int:2>, uint}"),
        Format::Struct(vec![
            Format::VarArray {
                elem: Box::new(prim(Primitive::Int)),
                dims: vec![2]
            },
            prim(Primitive::UInt)
        ])
    );
    assert_eq!(p("{T, <int:1>}").to_string(), "{T, <int:1>}");
}

// ---------------------------------------------------------------------------
// Malformed input.
// ---------------------------------------------------------------------------

fn err(s: &str) -> ParseError {
    match parse(s) {
        Ok(f) => panic!("{s:?} parsed as {f:?}"),
        Err(e) => e,
    }
}

#[test]
fn malformed_strings() {
    let cases: &[(&str, usize, &str)] = &[
        (
            "{int",
            4,
            "expected ',' or '}' after a struct field, found end of input",
        ),
        ("{int,", 5, "expected a format, found end of input"),
        (
            "{int}}",
            5,
            "expected end of input after the format, found '}'",
        ),
        ("}", 0, "expected a format, found '}'"),
        (
            "[int]",
            4,
            "expected ':' after the element format of an array, found ']'",
        ),
        (
            "[int:2,3}",
            8,
            "expected ',' or ']' after an array dimension, found '}'",
        ),
        (
            "[int:]",
            5,
            "expected an array dimension (a number), found ']'",
        ),
        (
            "[int:x]",
            5,
            "expected an array dimension (a number), found name 'x'",
        ),
        (
            "[5 int]",
            3,
            "expected ':' after the size of an old-style array '[n:format]', found name 'int'",
        ),
        (
            "[5:int",
            6,
            "expected ']' after the element format of '[n:format]', found end of input",
        ),
        (
            "{enum}",
            5,
            "expected ':' or an enum value name after '{enum', found '}'",
        ),
        (
            "{enum :}",
            7,
            "expected the largest enum value (a number) after '{enum :', found '}'",
        ),
        (
            "{enum : -1}",
            8,
            "expected the largest enum value (a number) after '{enum :', found name '-1'",
        ),
        (
            "{enum A, 3}",
            9,
            "expected an enum value name after ',', found number 3",
        ),
        (
            "{enum A B}",
            8,
            "expected '}' to close the enum, found name 'B'",
        ),
        (
            "{int, <int:1}",
            12,
            "expected ',' or '>' after a variable array dimension, found '}'",
        ),
        ("*", 1, "expected a format, found end of input"),
        ("!", 0, "expected a format, found '!'"),
        (
            "int int",
            4,
            "expected end of input after the format, found name 'int'",
        ),
    ];
    for &(s, pos, msg) in cases {
        let e = err(s);
        assert_eq!(e.pos(), Some(pos), "{s:?}: {e}");
        assert_eq!(e.to_string(), format!("at byte {pos}: {msg}"), "{s:?}");
    }
}

#[test]
fn numbers_out_of_range() {
    assert!(matches!(
        err("2147483648"),
        ParseError::NumberTooLarge { pos: 0, .. }
    ));
    assert_eq!(p("2147483647"), Format::Length(i32::MAX as u32));
    assert!(matches!(
        err("[int:99999999999999999999999]"),
        ParseError::NumberTooLarge { pos: 5, .. }
    ));
    assert!(matches!(
        err("{enum : 4294967296}"),
        ParseError::NumberTooLarge { pos: 8, .. }
    ));
    let long = format!("[int:{}]", "9".repeat(100_000));
    let e = err(&long);
    assert!(e.to_string().len() < 200, "error message is bounded");
}

#[test]
fn misplaced_var_arrays_and_self_pointers() {
    assert_eq!(err("<int:1>"), ParseError::VarArrayOutsideStruct { pos: 0 });
    assert_eq!(
        err("{int, [<int:1>:2]}"),
        ParseError::VarArrayOutsideStruct { pos: 7 }
    );
    assert_eq!(
        err("{int, *<int:1>}"),
        ParseError::VarArrayOutsideStruct { pos: 7 }
    );
    assert_eq!(err("*!"), ParseError::SelfPointerOutsideStruct { pos: 0 });
    assert_eq!(
        err("{int, **!}"),
        ParseError::SelfPointerOutsideStruct { pos: 7 }
    );
    assert_eq!(
        err("[*!:2]"),
        ParseError::SelfPointerOutsideStruct { pos: 1 }
    );
}

#[test]
fn var_array_dimensions_are_checked() {
    assert_eq!(
        err("{int, <int:3>}"),
        ParseError::DimensionOutOfRange {
            pos: 6,
            index: 3,
            fields: 2
        }
    );
    assert!(matches!(
        err("{int, <int:0>}"),
        ParseError::DimensionOutOfRange { index: 0, .. }
    ));
    assert_eq!(
        err("{string, <int:1>}"),
        ParseError::DimensionNotInteger {
            pos: 9,
            index: 1,
            found: "string".into()
        }
    );
    assert!(matches!(
        err("{double, <int:1>}"),
        ParseError::DimensionNotInteger { .. }
    ));
    assert!(matches!(
        err("{boolean, <int:1>}"),
        ParseError::DimensionNotInteger { .. }
    ));
    assert!(matches!(
        err("{{enum : 3}, <int:1>}"),
        ParseError::DimensionNotInteger { .. }
    ));
    assert!(matches!(
        err("{<int:1>}"),
        ParseError::DimensionNotInteger { .. }
    ));
    for t in [
        "byte", "ubyte", "short", "ushort", "int", "uint", "long", "ulong",
    ] {
        p(&format!("{{{t}, <double:1>}}"));
    }
    // Unknown names may turn out to be integers; resolving checks them.
    let f = p("{N, <int:1>}");
    let mut reg = FormatRegistry::new();
    reg.define("N", "int").unwrap();
    assert!(reg.resolve(&f).is_ok());
    reg.define("N", "string").unwrap();
    assert!(matches!(
        reg.resolve(&f),
        Err(ResolveError::DimensionNotInteger { index: 1, .. })
    ));
    assert!(matches!(
        parse_with("{N, <int:1>}", &reg),
        Err(ParseError::DimensionNotInteger { pos: 4, .. })
    ));
}

#[test]
fn deep_nesting_is_bounded() {
    for open in ["{", "[", "*", "{int, <"] {
        let s = open.repeat(200_000);
        assert!(
            matches!(
                err(&s),
                ParseError::TooDeep {
                    max: MAX_NESTING,
                    ..
                }
            ),
            "{open}"
        );
    }
    // Exactly at the limit is fine.
    let s = format!("{}int", "*".repeat(MAX_NESTING));
    assert!(parse(&s).is_ok());
    let s = format!("{}int", "*".repeat(MAX_NESTING + 1));
    assert!(matches!(err(&s), ParseError::TooDeep { pos, .. } if pos == MAX_NESTING));
}

#[test]
fn malformed_formatters() {
    let bad = |h: &str| decode_le(&hex(h)).unwrap_err();
    // Truncated everywhere.
    let full = hex(HANDSHAKE_REPLY);
    for n in 0..full.len() {
        assert!(decode_le(&full[..n]).is_err(), "prefix {n}");
    }
    assert!(matches!(
        bad("02000000 ffffff7f"),
        DecodeError::CountTooLarge { .. }
    ));
    assert!(matches!(
        bad("02000000 00000000"),
        DecodeError::NegativeCount { .. }
    ));
    assert!(matches!(
        bad("04000000 02000000 00000000 01000000"),
        DecodeError::Format(_)
    ));
    assert!(matches!(
        bad("04000000 03000000 00000000 01000000 ffffffff"),
        DecodeError::NegativeCount { .. }
    ));
    assert!(matches!(
        bad("01000000 ffffffff"),
        DecodeError::NegativeCount { .. }
    ));
    assert!(matches!(
        bad("08000000 ffffff7f 00000000"),
        DecodeError::CountTooLarge { .. }
    ));
    assert!(matches!(bad("00000000 0a000000"), DecodeError::Format(_)));
    assert!(matches!(bad("00000000 14000000"), DecodeError::Format(_)));
    assert!(matches!(bad("06000000"), DecodeError::Format(_)));
    assert!(matches!(bad("09000000"), DecodeError::Format(_)));
    assert!(matches!(
        bad("07000000 05000000 ff"),
        DecodeError::CountTooLarge { .. }
    ));
    assert!(matches!(
        bad("07000000 01000000 ff"),
        DecodeError::InvalidUtf8 { .. }
    ));
    // Deep pointer chains.
    let mut deep = Vec::new();
    for _ in 0..100_000 {
        deep.extend_from_slice(&hex("03000000 5a"));
    }
    deep.extend_from_slice(&hex("00000000 01000000"));
    assert!(matches!(
        decode_le(&deep),
        Err(DecodeError::TooDeep {
            max: MAX_NESTING,
            ..
        })
    ));
}

#[test]
fn big_endian_formatters() {
    let f = p("{int, [double:2,3], {enum A, B}}");
    let le = encode(&f);
    // Swap every int32 of this (string-free) encoding except the enum names.
    let mut w = Writer::new();
    w.write_bytes(&le);
    let bytes = hex(
        "00000002 00000004 00000000 00000001 00000004 00000004 00000000 00000004 00000002 00000003 \
         00000008 00000004 00000001 00000001 41 00000001 42",
    );
    let mut r = Reader::new(&bytes, ByteOrder::Big);
    assert_eq!(decode_formatter(&mut r).unwrap(), Some(f));
    r.finish().unwrap();
}

// ---------------------------------------------------------------------------
// Registry, resolution and equality.
// ---------------------------------------------------------------------------

#[test]
fn registry_names() {
    let mut reg = FormatRegistry::new();
    for bad in ["", "int", "enum", "1x", "a b", "a,b", "*p", "{x}"] {
        assert!(
            matches!(reg.define(bad, "int"), Err(ParseError::InvalidName { .. })),
            "{bad:?}"
        );
    }
    assert!(matches!(
        reg.define("E", ""),
        Err(ParseError::EmptyDefinition { .. })
    ));
    assert!(reg.define("E", "{int").is_err());
    reg.insert("P", p("{double, double}")).unwrap();
    assert_eq!(reg.get("P"), Some(&p("{double, double}")));
    assert_eq!(reg.len(), 1);
}

#[test]
fn recursive_and_unknown_names() {
    let mut reg = FormatRegistry::new();
    reg.define("List", "{int, *List}").unwrap();
    assert_eq!(
        reg.resolve(&Format::Named("List".into())).unwrap(),
        p("{int, *List}")
    );
    assert_eq!(
        parse_with("{string, *List}", &reg).unwrap(),
        p("{string, *{int, *List}}")
    );
    reg.define("A", "{int, *B}").unwrap();
    reg.define("B", "{char, *A}").unwrap();
    assert_eq!(reg.resolve(&p("A")).unwrap(), p("{int, *{char, *A}}"));
    assert_eq!(
        reg.resolve(&p("{int, Nope}")),
        Err(ResolveError::UnknownName {
            name: "Nope".into()
        })
    );
    reg.define("C", "{int, Nope}").unwrap();
    let e = parse_with("[C:2]", &reg).unwrap_err();
    assert_eq!(e.pos(), Some(1));
    assert_eq!(
        e.to_string(),
        "at byte 1: named format 'C' cannot be expanded: unknown format name 'Nope'"
    );
}

#[test]
fn expansion_is_bounded() {
    // Doubling definitions.
    let mut reg = FormatRegistry::new();
    reg.define("D0", "{int, int}").unwrap();
    for i in 1..40 {
        reg.define(&format!("D{i}"), &format!("{{D{0}, D{0}}}", i - 1))
            .unwrap();
    }
    assert!(matches!(
        reg.resolve(&p("D39")),
        Err(ResolveError::TooLarge { .. })
    ));
    // Long chains of names.
    let mut reg = FormatRegistry::new();
    for i in 0..5000 {
        reg.define(&format!("N{i}"), &format!("N{}", i + 1))
            .unwrap();
    }
    reg.define("N5000", "int").unwrap();
    assert!(matches!(
        reg.resolve(&p("N0")),
        Err(ResolveError::TooDeep { .. })
    ));
    assert!(matches!(
        parse_with("N0", &reg),
        Err(ParseError::Name { pos: 0, .. })
    ));
    assert_eq!(reg.resolve(&p("N4900")).unwrap(), p("int"));
    // Hand-built trees that no parser produces are rejected.
    let r = FormatRegistry::new();
    assert_eq!(
        r.resolve(&Format::SelfPointer),
        Err(ResolveError::SelfPointerOutsideStruct)
    );
    assert_eq!(
        r.resolve(&Format::Struct(vec![Format::Empty])),
        Err(ResolveError::EmptyInComposite)
    );
}

#[test]
fn equality_as_ipc_check_msg_formats() {
    let mut reg = FormatRegistry::new();
    reg.define("T1", "{int, {enum : 3}, [double:2,3], double}")
        .unwrap();
    let eq = |a: &str, b: &str| equivalent(&p(a), &p(b), &reg);
    assert!(eq("T1", "{int, {enum : 3}, [double:2,3], double}"));
    assert!(eq(
        "{int , T1}",
        "{int, {int, {enum:3}, [double : 2, 3], double}}"
    ));
    assert!(eq("[5:int]", "[int:5]"));
    assert!(eq("", ""));
    assert!(!eq("", "int"));
    assert!(!eq("[int:2,3]", "[[int:3]:2]"));
    assert!(!eq("[int:6]", "[int:2,3]"));
    assert!(!eq("{enum : 3}", "{enum A, B, C, D}"));
    assert!(!eq("{enum A, B}", "{enum a, b}"));
    assert!(!eq("{enum : 3}", "{enum : 4}"));
    assert!(!eq("int", "uint"));
    assert!(!eq("long", "ulong"));
    assert!(!eq("{int}", "int"));
    assert!(!eq("4", "int"));
    assert!(!eq("Unknown", "Unknown"));
    assert!(reg.equivalent(&p("*T1"), &p("*{int, {enum : 3}, [double:2,3], double}")));
}

// ---------------------------------------------------------------------------
// Properties.
// ---------------------------------------------------------------------------

fn name() -> impl Strategy<Value = String> {
    "[A-Za-z_][A-Za-z0-9_]{0,6}".prop_filter("a format name", |s| {
        s != "enum" && Primitive::from_name(s).is_none()
    })
}

fn leaf() -> impl Strategy<Value = Format> {
    prop_oneof![
        (0..Primitive::ALL.len()).prop_map(|i| Format::Primitive(Primitive::ALL[i])),
        (0u32..=i32::MAX as u32).prop_map(Format::Length),
        name().prop_map(Format::Named),
        (0i32..=i32::MAX).prop_map(|max| Format::Enum { names: vec![], max }),
        prop::collection::vec("[A-Za-z_][A-Za-z0-9_*!]{0,6}", 1..5).prop_map(|names| {
            Format::Enum {
                max: names.len() as i32 - 1,
                names,
            }
        }),
    ]
}

fn int_field() -> impl Strategy<Value = Format> {
    prop::sample::select(vec![
        Primitive::Byte,
        Primitive::UByte,
        Primitive::Short,
        Primitive::UShort,
        Primitive::Int,
        Primitive::UInt,
        Primitive::Long,
        Primitive::ULong,
    ])
    .prop_map(Format::Primitive)
}

fn any_format() -> impl Strategy<Value = Format> {
    leaf().prop_recursive(5, 64, 6, |inner| {
        prop_oneof![
            inner.clone().prop_map(|f| Format::Pointer(Box::new(f))),
            (inner.clone(), prop::collection::vec(0u32..=i32::MAX as u32, 1..4))
                .prop_map(|(e, dims)| Format::FixedArray { elem: Box::new(e), dims }),
            (
                prop::collection::vec(prop_oneof![4 => inner.clone(), 1 => int_field(), 1 => Just(Format::SelfPointer)], 0..6),
                prop::option::of((inner, prop::collection::vec(any::<prop::sample::Index>(), 1..3), int_field())),
            )
                .prop_map(|(mut fields, var)| {
                    if let Some((elem, picks, int)) = var {
                        let ints: Vec<usize> = fields
                            .iter()
                            .enumerate()
                            .filter(|(_, f)| matches!(f, Format::Primitive(p) if p.is_integer()))
                            .map(|(i, _)| i + 1)
                            .collect();
                        let ints = if ints.is_empty() {
                            fields.push(int);
                            vec![fields.len()]
                        } else {
                            ints
                        };
                        let dims = picks.iter().map(|ix| *ix.get(&ints) as u32).collect();
                        fields.push(Format::VarArray { elem: Box::new(elem), dims });
                    }
                    Format::Struct(fields)
                }),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn print_parse_round_trip(f in any_format()) {
        let s = f.to_string();
        prop_assert_eq!(parse(&s).map_err(|e| format!("{s}: {e}")), Ok(f.clone()));
    }

    #[test]
    fn formatter_round_trip(f in any_format()) {
        let bytes = encode(&f);
        let mut r = Reader::native(&bytes);
        prop_assert_eq!(decode_formatter(&mut r), Ok(Some(f)));
        prop_assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn resolve_without_names_is_identity(f in any_format()) {
        fn named(f: &Format) -> bool {
            match f {
                Format::Named(_) => true,
                Format::Struct(fs) => fs.iter().any(named),
                Format::Pointer(x) => named(x),
                Format::FixedArray { elem, .. } | Format::VarArray { elem, .. } => named(elem),
                _ => false,
            }
        }
        let has_names = named(&f);
        let reg = FormatRegistry::new();
        if has_names {
            prop_assert!(reg.resolve(&f).is_err());
        } else {
            prop_assert_eq!(reg.resolve(&f), Ok(f.clone()));
            prop_assert!(equivalent(&f, &f, &reg));
        }
    }

    #[test]
    fn arbitrary_strings_never_panic(s in "[{}\\[\\]<>*!,: a-z0-9]{0,40}") {
        if let Ok(f) = parse(&s) {
            prop_assert_eq!(parse(&f.to_string()), Ok(f.clone()));
            let _ = f.c_size();
            let _ = f.fixed_wire_size();
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..200)) {
        let mut r = Reader::native(&bytes);
        if let Ok(Some(f)) = decode_formatter(&mut r) {
            let used = bytes.len() - r.remaining();
            let again = encode(&f);
            // Pointer flags other than 'Z' decode as present and re-encode as 'Z'.
            prop_assert_eq!(again.len(), used);
        }
    }
}

#[test]
fn format_module_is_reexported() {
    let _ = format::MAX_NESTING;
}
