//! Golden tests of the dynamic IPC `Value` against the C library's bytes:
//! every example of ipc.md §10 (E1–E8, every row of E7), every frame with
//! formatted data in the captures (copied to `tests/fixtures/ipc/`), big-endian
//! input, and the C central's data log (`central.log` of the captures).

#[path = "ipc_support.rs"]
mod support;

use courier_wire::format::Format;
use courier_wire::ipc::{
    self, log_data, print_value, ByteOrder, DecodeError, Reader, Value, Writer,
};
use support::{encode_be, entries, fmt, hex, inner_bytes, Entry};

const WRAP: &str = "{int, <byte:1>}";

/// Decodes `bytes` (little-endian, as all captures are) with `f`, checks that
/// every byte is used and that re-encoding gives the same bytes.
fn round_trip(f: &Format, bytes: &[u8]) -> Value {
    let v = Value::from_ipc_bytes(f, bytes, ByteOrder::Little)
        .unwrap_or_else(|e| panic!("decode {f:?} from {bytes:02x?}: {e}"));
    assert_eq!(v.to_ipc_bytes(f).unwrap(), bytes, "re-encode of {v:?}");
    // And the same data from a big-endian host decodes to the same value.
    let mut be = Vec::new();
    encode_be(f, &v, None, &mut be);
    assert_eq!(be.len(), bytes.len());
    let vb = Value::from_ipc_bytes(f, &be, ByteOrder::Big).unwrap();
    assert_eq!(vb, v, "big-endian decode");
    v
}

/// A `{int, <byte:1>}` body: returns the user bytes after checking the wrapper.
fn unwrap_body(body: &[u8]) -> Vec<u8> {
    let v = round_trip(&fmt(WRAP), body);
    let inner = inner_bytes(&v);
    assert_eq!(
        v,
        Value::Struct(vec![Value::Int(inner.len() as i32), wrap_items(&inner)])
    );
    inner
}

fn wrap_items(b: &[u8]) -> Value {
    Value::VarArray(b.iter().map(|&x| Value::Byte(x as i8)).collect())
}

fn frame_body(frame_hex: &str) -> (Vec<u8>, Vec<u8>) {
    let frame = hex(frame_hex);
    let e = Entry {
        comment: String::new(),
        format: String::new(),
        payload: None,
        frame,
    };
    let (order, data) = e.data();
    assert_eq!(order, ByteOrder::Little);
    let class_total = u32::from_be_bytes(e.frame[0..4].try_into().unwrap()) as usize;
    (e.frame[28..28 + class_total].to_vec(), data.to_vec())
}

fn t1_value() -> Value {
    let row = |a: f64| {
        Value::Array(vec![
            Value::Double(a),
            Value::Double(a + 1.0),
            Value::Double(a + 2.0),
        ])
    };
    Value::Struct(vec![
        Value::Int(666),
        Value::Enum(1),
        Value::Array(vec![row(0.0), row(1.0)]),
        Value::Double(std::f64::consts::PI),
    ])
}

const T1: &str = "{int, {enum : 3}, [double:2,3], double}";
const T2: &str = "{string, int, <{int, {enum : 3}, [double:2,3], double}:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}";

#[test]
fn e1_publish_int() {
    let (_, body) = frame_body(
        "00000000 0000000c ffffffff 00000074 2200000f ffffffff 00000038 04000000 04000000 2a000000",
    );
    let inner = unwrap_body(&body);
    assert_eq!(round_trip(&fmt("int"), &inner), Value::Int(42));
}

#[test]
fn e2_delivery_with_class_data() {
    let (class, body) = frame_body(
        "0000000c 0000000c ffffffff 000000c6 2200000f ffffffff 00000001 08000000 6d657373 61676531 04000000 04000000 2a000000",
    );
    assert_eq!(
        round_trip(&fmt("string"), &class),
        Value::String(Some("message1".into()))
    );
    assert_eq!(round_trip(&fmt("int"), &unwrap_body(&body)), Value::Int(42));
}

#[test]
fn e3_publish_string() {
    let (_, body) = frame_body(
        "00000000 00000018 00000005 0000006a 2200000f ffffffff 00000025 10000000 10000000 0c000000 48656c6c 6f2c2077 6f726c64",
    );
    let inner = unwrap_body(&body);
    assert_eq!(inner.len(), 16);
    assert_eq!(
        round_trip(&fmt("string"), &inner),
        Value::String(Some("Hello, world".into()))
    );
}

const E4: &str = "00000000 00000048 ffffffff 0000006f 22000003 ffffffff 00000039
    40000000 40000000 9a020000 01000000
    00000000 00000000 00000000 0000f03f 00000000 00000040
    00000000 0000f03f 00000000 00000040 00000000 00000840
    182d4454 fb210940";

#[test]
fn e4_query_t1() {
    let (_, body) = frame_body(E4);
    let inner = unwrap_body(&body);
    assert_eq!(inner.len(), 64);
    assert_eq!(round_trip(&fmt(T1), &inner), t1_value());
}

const E5: &str = "0000000d 00000064 00000005 ffffffff 2200000b 00000005 ffffffff
    09000000 72657370 6f6e7365 31
    5c000000 5c000000
    0c000000 48656c6c 6f2c2077 6f726c64
    01000000
    01000000
    9a020000 01000000
    00000000 00000000 00000000 0000f03f 00000000 00000040
    00000000 0000f03f 00000000 00000040 00000000 00000840
    182d4454 fb210940
    02000000";

#[test]
fn e5_reply_t2() {
    let (class, body) = frame_body(E5);
    assert_eq!(
        round_trip(&fmt("string"), &class),
        Value::String(Some("response1".into()))
    );
    let inner = unwrap_body(&body);
    assert_eq!(inner.len(), 92);
    let want = Value::Struct(vec![
        Value::String(Some("Hello, world".into())),
        Value::Int(1),
        Value::VarArray(vec![t1_value()]),
        Value::Enum(2),
    ]);
    assert_eq!(round_trip(&fmt(T2), &inner), want);
    assert_eq!(
        print_value(&fmt(T2), &want),
        "{\"Hello, world\", 1, <{666, 1, [[0.00, 1.00, 2.00], [1.00, 2.00, 3.00]], 3.14}>, ReceiveVal}"
    );
}

#[test]
fn e6_connect_query_and_reply() {
    let (_, q) = frame_body(
        "00000000 00000018 ffffffff 000000ad 22000003 ffffffff 0000000d 07000000 6d6f6475 6c653109 0000006c 6f63616c 686f7374",
    );
    assert_eq!(
        round_trip(&fmt("{string, string}"), &q),
        Value::Struct(vec![
            Value::String(Some("module1".into())),
            Value::String(Some("localhost".into()))
        ])
    );
    let (_, r) = frame_body(
        "00000000 0000000c 00000000 fffffffc 22000000 00000000 0000000d 03000000 09000000 00000000",
    );
    let f = fmt("{{int, int}, boolean}");
    assert_eq!(
        round_trip(&f, &r),
        Value::Struct(vec![
            Value::Struct(vec![Value::Int(3), Value::Int(9)]),
            Value::Boolean(false)
        ])
    );
    assert_eq!(
        round_trip(&f, &hex("03000000 09000000 01000000"))
            .to_ipc_bytes(&f)
            .unwrap()[8],
        1
    );
}

#[test]
fn e7_marshalling_table() {
    let s = |x: &str| Value::String(Some(x.into()));
    let rows: Vec<(&str, Value, &str)> = vec![
        ("string", Value::String(None), "00000000 5a"),
        ("long", Value::Long(0x0102030405060708), "08070605 04030201"),
        ("boolean", Value::Boolean(true), "01000000"),
        (
            "{char, double, short}",
            Value::Struct(vec![Value::Char(b'x'), Value::Double(2.0), Value::Short(7)]),
            "78 00000000 00000040 0700",
        ),
        ("[string:2]", Value::Array(vec![s("ab"), Value::String(None)]), "02000000 6162 00000000 5a"),
        ("*int", Value::Pointer(Some(Box::new(Value::Int(9)))), "5a 09000000"),
        ("*int", Value::Pointer(None), "00"),
        (
            "{int, *!}",
            Value::Struct(vec![
                Value::Int(1),
                Value::Pointer(Some(Box::new(Value::Struct(vec![Value::Int(2), Value::Pointer(None)])))),
            ]),
            "01000000 5a 02000000 00",
        ),
        (
            "{int, int, <double:1,2>}",
            Value::Struct(vec![
                Value::Int(2),
                Value::Int(3),
                Value::VarArray((1..=6).map(|i| Value::Double(i as f64)).collect()),
            ]),
            "02000000 03000000 06000000 000000000000f03f 0000000000000040 0000000000000840 0000000000001040 0000000000001440 0000000000001840",
        ),
        (
            "{string, int, <int:2>, {enum Red, Green, Blue}, boolean}",
            Value::Struct(vec![
                s("ab"),
                Value::Int(3),
                Value::VarArray(vec![Value::Int(10), Value::Int(20), Value::Int(30)]),
                Value::Enum(1),
                Value::Boolean(true),
            ]),
            "02000000 6162 03000000 03000000 0a000000 14000000 1e000000 01000000 01000000",
        ),
        (
            "{int, <byte:1>}",
            Value::Struct(vec![Value::Int(3), wrap_items(&[1, 2, 3])]),
            "03000000 03000000 010203",
        ),
    ];
    for (f, v, h) in rows {
        let f = fmt(f);
        let bytes = hex(h);
        assert_eq!(v.to_ipc_bytes(&f).unwrap(), bytes, "{f:?}");
        assert_eq!(round_trip(&f, &bytes), v, "{f:?}");
    }
    // "" is sent exactly like NULL and decodes to NULL.
    assert_eq!(
        Value::String(Some(String::new()))
            .to_ipc_bytes(&fmt("string"))
            .unwrap(),
        hex("00000000 5a")
    );
    // The C struct of {char, double, short} is 24 bytes; the wire has 11.
    assert_eq!(hex("78 00000000 00000040 0700").len(), 11);
}

#[test]
fn e8_fixed_and_empty_messages() {
    let (_, body) = frame_body(
        "00000000 00000008 ffffffff 00000074 2200000f ffffffff 0000003d 07000000 08000000",
    );
    let v = round_trip(&fmt("[byte:8]"), &body);
    let inner = inner_bytes(&v);
    assert_eq!(inner, body);
    assert_eq!(
        round_trip(&fmt("{int, int}"), &inner),
        Value::Struct(vec![Value::Int(7), Value::Int(8)])
    );
    let (_, empty) = frame_body("00000000 00000000 ffffffff 00000073 2200000f ffffffff 0000003f");
    assert!(empty.is_empty());
    assert_eq!(round_trip(&Format::Empty, &empty), Value::Empty);
}

/// Every fixture frame: the data decodes with its format and re-encodes to
/// the same bytes; user payloads inside `{int, <byte:1>}` / `[byte:N]` too.
#[test]
fn every_captured_frame_round_trips() {
    let files = [
        (
            "demo-central",
            include_str!("fixtures/ipc/demo-central.txt"),
        ),
        ("demo-direct", include_str!("fixtures/ipc/demo-direct.txt")),
        (
            "wiretest-central",
            include_str!("fixtures/ipc/wiretest-central.txt"),
        ),
        (
            "wiretest-direct",
            include_str!("fixtures/ipc/wiretest-direct.txt"),
        ),
        (
            "flowcontrol-capacity1",
            include_str!("fixtures/ipc/flowcontrol-capacity1.txt"),
        ),
        (
            "flowcontrol-capacity2",
            include_str!("fixtures/ipc/flowcontrol-capacity2.txt"),
        ),
    ];
    let mut payloads = 0;
    let mut frames = 0;
    let mut nulls = 0;
    for (name, text) in files {
        let es = entries(text);
        assert!(es.len() > 40, "{name}: {} entries", es.len());
        for e in es {
            let (order, data) = e.data();
            assert_eq!(order, ByteOrder::Little);
            if data.is_empty() {
                // msgTotal 0: the C sender passed NULL data (e.g. central's
                // "none" reply to directMsgQuery); nothing to decode.
                nulls += 1;
                continue;
            }
            let f = fmt(&e.format);
            let v = round_trip(&f, data);
            frames += 1;
            if e.format == WRAP {
                assert_eq!(unwrap_body(data).len() as i32 + 8, data.len() as i32);
            }
            if let Some(p) = &e.payload {
                let inner = inner_bytes(&v);
                let pf = fmt(p);
                round_trip(&pf, &inner);
                payloads += 1;
            }
        }
    }
    assert!(frames >= 600, "{frames}");
    assert!(nulls <= 10, "{nulls}");
    assert_eq!(payloads, 14);
}

fn find<'a>(es: &'a [Entry], stamp: &str) -> &'a Entry {
    es.iter()
        .find(|e| e.comment.starts_with(stamp))
        .unwrap_or_else(|| panic!("no entry {stamp}"))
}

/// What central logs for a frame: the data decoded with the user format.
fn logged(e: &Entry, user_format: &str) -> String {
    let (order, data) = e.data();
    let inner = if e.payload.is_some() {
        inner_bytes(&Value::from_ipc_bytes(&fmt(&e.format), data, order).unwrap())
    } else {
        data.to_vec()
    };
    let uf = fmt(user_format);
    log_data(&uf, &Value::from_ipc_bytes(&uf, &inner, order).unwrap())
}

/// Lines of `demo-central/central.log` (`central -ld`), reproduced from the
/// captured bytes of the frames they log.
#[test]
fn central_log_demo_central() {
    let es = entries(include_str!("fixtures/ipc/demo-central.txt"));
    // "Broadcast        message1:    module1 --> module2         (Sent)"
    assert_eq!(logged(find(&es, "[1.992917]"), "int"), "    42\n");
    // "Query              query1:    module1 --> module2         (Sent)"
    assert_eq!(
        logged(find(&es, "[2.993381]"), T1),
        "    {666, 1, [[0.00, 1.00, 2.00], [1.00, 2.00, 3.00]], 3.14}\n"
    );
    // "Broadcast        message2:    module2 --> module1         (Sent)"
    assert_eq!(
        logged(find(&es, "[2.993730]"), "string"),
        "    \"Hello, world\"\n"
    );
    // "  Reply           query1:    module2 --> module1        " (wrapped at 80 columns)
    assert_eq!(
        logged(find(&es, "[2.993971]"), T2),
        "    {\"Hello, world\", 1, <{666, 1, [[0.00, 1.00, 2.00], [1.00, 2.00, 3.00]], \n     3.14}>, ReceiveVal}\n"
    );
}

/// Lines of `wiretest-central/central.log`.
#[test]
fn central_log_wiretest_central() {
    let es = entries(include_str!("fixtures/ipc/wiretest-central.txt"));
    // "Inform    ipc_setMsgPriority:   wiretest --> X_IPC Server    (Sent)"
    assert_eq!(
        logged(find(&es, "[0.001544]"), "{string, int}"),
        "    {\"varMsg\", 7}\n"
    );
    // "Broadcast        fixedMsg:   wiretest --> wiretest        (Sent)"
    assert_eq!(
        logged(find(&es, "[0.202838]"), "{int, int}"),
        "    {7, 8}\n"
    );
    // "Broadcast          varMsg:   wiretest --> wiretest        (Sent)"
    assert_eq!(
        logged(
            find(&es, "[0.202968]"),
            "{string, int, <{double, double}:2>}"
        ),
        "    {\"pts\", 2, <{1.00, 2.00}, {3.00, 4.00}>}\n"
    );
    // Query 21 / Reply 42 / Query 5 / Reply 10
    assert_eq!(logged(find(&es, "[0.503800]"), "int"), "    21\n");
    assert_eq!(logged(find(&es, "[0.503923]"), "int"), "    42\n");
    assert_eq!(logged(find(&es, "[0.503971]"), "int"), "    5\n");
    assert_eq!(logged(find(&es, "[0.504008]"), "int"), "    10\n");
}

#[test]
fn decode_errors_on_hostile_data() {
    let t2 = fmt(T2);
    let (_, body) = frame_body(E5);
    let inner = &body[8..];
    // Every truncation fails cleanly.
    for n in 0..inner.len() {
        assert!(Value::from_ipc_bytes(&t2, &inner[..n], ByteOrder::Little).is_err());
    }
    // Var-array count that disagrees with field 2.
    let mut bad = inner.to_vec();
    bad[20] = 2;
    assert!(matches!(
        Value::from_ipc_bytes(&t2, &bad, ByteOrder::Little),
        Err(DecodeError::CountMismatch {
            offset: 20,
            expected: 1,
            found: 2
        })
    ));
    // Bad pointer flag.
    assert!(matches!(
        Value::from_ipc_bytes(&fmt("*int"), &[7, 0, 0, 0, 0], ByteOrder::Little),
        Err(DecodeError::InvalidPointerFlag { offset: 0, byte: 7 })
    ));
    // Trailing bytes are reported by from_ipc_bytes and left in the reader by decode_value.
    assert!(matches!(
        Value::from_ipc_bytes(&fmt("int"), &[1, 0, 0, 0, 9], ByteOrder::Little),
        Err(DecodeError::TrailingBytes {
            offset: 4,
            count: 1
        })
    ));
    let mut r = Reader::new(&[1, 0, 0, 0, 9], ByteOrder::Little);
    assert_eq!(
        ipc::decode_value(&fmt("int"), &mut r).unwrap(),
        Value::Int(1)
    );
    assert_eq!(r.remaining(), 1);
}

#[test]
fn encode_into_existing_writer() {
    let mut w = Writer::new();
    w.write_i32(5);
    ipc::encode_value(&fmt(T1), &t1_value(), &mut w).unwrap();
    assert_eq!(w.len(), 68);
}
