//! Property tests of the dynamic IPC `Value`: arbitrary (format, matching
//! value) pairs round-trip in both byte orders, and decoding random bytes
//! under random formats never panics.

#[path = "ipc_support.rs"]
mod support;

use courier_wire::format::{Format, Primitive};
use courier_wire::ipc::{print_value, ByteOrder, DecodeError, Reader, Value};
use proptest::prelude::*;

/// A struct field template: a plain field, or a size field (`int`)
/// immediately followed by the variable array it sizes.
#[derive(Debug, Clone)]
enum Field {
    Plain(Format),
    Counted(Format),
    SelfPtr,
}

fn prim() -> impl Strategy<Value = Primitive> {
    prop::sample::select(
        Primitive::ALL
            .iter()
            .copied()
            .filter(|p| *p != Primitive::Format)
            .collect::<Vec<_>>(),
    )
}

fn enum_format() -> impl Strategy<Value = Format> {
    prop_oneof![
        (0i32..5).prop_map(|max| Format::Enum { names: vec![], max }),
        prop::collection::vec("[A-Z][a-z]{0,5}", 1..4).prop_map(|names| Format::Enum {
            max: names.len() as i32 - 1,
            names
        }),
    ]
}

fn format() -> impl Strategy<Value = Format> {
    let leaf = prop_oneof![
        4 => prim().prop_map(Format::Primitive),
        1 => (0u32..4).prop_map(Format::Length),
        1 => enum_format(),
    ];
    leaf.prop_recursive(4, 24, 4, |inner| {
        let field = prop_oneof![
            4 => inner.clone().prop_map(Field::Plain),
            1 => inner.clone().prop_map(Field::Counted),
            1 => Just(Field::SelfPtr),
        ];
        prop_oneof![
            prop::collection::vec(field, 1..4).prop_map(build_struct),
            inner.clone().prop_map(|f| Format::Pointer(Box::new(f))),
            (inner, prop::collection::vec(0u32..3, 1..3)).prop_map(|(e, dims)| {
                Format::FixedArray {
                    elem: Box::new(e),
                    dims,
                }
            }),
        ]
    })
}

fn build_struct(fields: Vec<Field>) -> Format {
    let mut out = Vec::new();
    for f in fields {
        match f {
            Field::Plain(f) => out.push(f),
            Field::SelfPtr => out.push(Format::SelfPointer),
            Field::Counted(e) => {
                out.push(Format::Primitive(Primitive::Int));
                let k = out.len() as u32;
                out.push(Format::VarArray {
                    elem: Box::new(e),
                    dims: vec![k],
                });
            }
        }
    }
    Format::Struct(out)
}

fn prim_value(p: Primitive) -> BoxedStrategy<Value> {
    match p {
        Primitive::Char => any::<u8>().prop_map(Value::Char).boxed(),
        Primitive::Byte => any::<i8>().prop_map(Value::Byte).boxed(),
        Primitive::UByte => any::<u8>().prop_map(Value::UByte).boxed(),
        Primitive::Short => any::<i16>().prop_map(Value::Short).boxed(),
        Primitive::UShort => any::<u16>().prop_map(Value::UShort).boxed(),
        Primitive::TwoByte => any::<u16>().prop_map(Value::TwoByte).boxed(),
        Primitive::Int => any::<i32>().prop_map(Value::Int).boxed(),
        Primitive::UInt => any::<u32>().prop_map(Value::UInt).boxed(),
        Primitive::Long => any::<i64>().prop_map(Value::Long).boxed(),
        Primitive::ULong => any::<u64>().prop_map(Value::ULong).boxed(),
        // NaN != NaN: keep values comparable.
        Primitive::Float => any::<f32>()
            .prop_filter("not NaN", |x| !x.is_nan())
            .prop_map(Value::Float)
            .boxed(),
        Primitive::Double => any::<f64>()
            .prop_filter("not NaN", |x| !x.is_nan())
            .prop_map(Value::Double)
            .boxed(),
        Primitive::Boolean => any::<bool>().prop_map(Value::Boolean).boxed(),
        Primitive::String => prop_oneof![
            Just(Value::String(None)),
            "[^\u{0}]{1,8}".prop_map(|s| Value::String(Some(s))),
        ]
        .boxed(),
        Primitive::Format => Just(Value::Format(None)).boxed(),
    }
}

/// A value of `f`; `enclosing` is the struct a `*!` points to.
fn value(f: &Format, enclosing: Option<&Format>, depth: u32) -> BoxedStrategy<Value> {
    match f {
        Format::Empty => Just(Value::Empty).boxed(),
        Format::Primitive(p) => prim_value(*p),
        Format::Length(n) => prop::collection::vec(any::<u8>(), *n as usize)
            .prop_map(Value::Bytes)
            .boxed(),
        Format::Enum { .. } => any::<i32>().prop_map(Value::Enum).boxed(),
        Format::Pointer(t) => prop_oneof![
            1 => Just(Value::Pointer(None)),
            2 => value(t, None, depth).prop_map(|v| Value::Pointer(Some(Box::new(v)))),
        ]
        .boxed(),
        Format::SelfPointer => match (enclosing, depth) {
            (Some(s), d) if d > 0 => {
                let s = s.clone();
                prop_oneof![
                    2 => Just(Value::Pointer(None)),
                    1 => value(&s, None, d - 1).prop_map(|v| Value::Pointer(Some(Box::new(v)))),
                ]
                .boxed()
            }
            _ => Just(Value::Pointer(None)).boxed(),
        },
        Format::FixedArray { elem, dims } => {
            fn arr(
                elem: &Format,
                dims: &[u32],
                enc: Option<&Format>,
                depth: u32,
            ) -> BoxedStrategy<Value> {
                match dims.split_first() {
                    None => value(elem, enc, depth),
                    Some((&d, rest)) => {
                        prop::collection::vec(arr(elem, rest, enc, depth), d as usize)
                            .prop_map(Value::Array)
                            .boxed()
                    }
                }
            }
            arr(elem, dims, enclosing, depth)
        }
        Format::Struct(fields) => {
            // Generate field by field; a size field takes its value from the
            // var array that follows it.
            let mut parts: Vec<BoxedStrategy<Vec<Value>>> = Vec::new();
            let mut i = 0;
            while i < fields.len() {
                match fields.get(i + 1) {
                    Some(Format::VarArray { elem, .. }) => {
                        parts.push(
                            prop::collection::vec(value(elem, Some(f), depth), 0..4)
                                .prop_map(|items| {
                                    vec![Value::Int(items.len() as i32), Value::VarArray(items)]
                                })
                                .boxed(),
                        );
                        i += 2;
                    }
                    _ => {
                        parts.push(
                            value(&fields[i], Some(f), depth)
                                .prop_map(|v| vec![v])
                                .boxed(),
                        );
                        i += 1;
                    }
                }
            }
            parts
                .prop_map(|ps| Value::Struct(ps.into_iter().flatten().collect()))
                .boxed()
        }
        Format::VarArray { .. } | Format::Named(_) => unreachable!("not generated"),
    }
}

fn format_and_value() -> impl Strategy<Value = (Format, Value)> {
    format().prop_flat_map(|f| {
        let v = value(&f, None, 2);
        (Just(f), v)
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn encode_decode_round_trip((f, v) in format_and_value()) {
        let bytes = v.to_ipc_bytes(&f).unwrap();
        let back = Value::from_ipc_bytes(&f, &bytes, ByteOrder::NATIVE).unwrap();
        prop_assert_eq!(&back, &v);
        // A big-endian sender's bytes decode to the same value.
        let mut be = Vec::new();
        support::encode_be(&f, &v, None, &mut be);
        prop_assert_eq!(be.len(), bytes.len());
        prop_assert_eq!(&Value::from_ipc_bytes(&f, &be, ByteOrder::Big).unwrap(), &v);
        // The printer never fails.
        let _ = print_value(&f, &v);
    }

    /// Keeping only the first few array elements steps over the rest
    /// exactly: the reader ends where a full decode ends.
    #[test]
    fn a_prefix_decode_ends_where_a_full_decode_does((f, v) in format_and_value(), keep in 0usize..6) {
        let bytes = v.to_ipc_bytes(&f).unwrap();
        let mut r = Reader::new(&bytes, ByteOrder::NATIVE);
        let none = |_: &str| None;
        courier_wire::ipc::decode_value_prefix(&f, &mut r, &none, keep).unwrap();
        prop_assert_eq!(r.position(), bytes.len());
        let _ = print_value(&f, &v);
    }

    #[test]
    fn random_bytes_never_panic(f in format(), bytes in prop::collection::vec(any::<u8>(), 0..64), big in any::<bool>()) {
        let order = if big { ByteOrder::Big } else { ByteOrder::Little };
        let mut r = Reader::new(&bytes, order);
        match courier_wire::ipc::decode_value(&f, &mut r) {
            Ok(v) => {
                let used = r.position();
                let again = v.to_ipc_bytes(&f).unwrap();
                prop_assert_eq!(again.len(), used);
                if order == ByteOrder::NATIVE {
                    let v2 = Value::from_ipc_bytes(&f, &again, order).unwrap();
                    prop_assert_eq!(v2.to_ipc_bytes(&f).unwrap(), again);
                }
                let _ = courier_wire::ipc::log_data(&f, &v);
            }
            Err(e) => {
                let _: DecodeError = e;
            }
        }
    }
}

#[test]
fn formatter_values_print_like_c() {
    let t1 = support::fmt("{int, {enum : 3}, [double:2,3], double}");
    let v = Value::Format(Some(Box::new(t1)));
    let f = Format::Primitive(Primitive::Format);
    assert_eq!(
        print_value(&f, &v),
        "{int, {enum : 3}, [double : 2, 3], double}"
    );
    assert_eq!(print_value(&f, &Value::Format(None)), "NULLFormat");
    let bytes = v.to_ipc_bytes(&f).unwrap();
    assert_eq!(
        Value::from_ipc_bytes(&f, &bytes, ByteOrder::NATIVE).unwrap(),
        v
    );
}

/// The central's data log decodes only the first 4096 array elements of a
/// message: what it prints (five lines, then `...`) is the same as from the
/// whole value, even with 400 elements, for large arrays of every kind of
/// element.
#[test]
fn a_logged_prefix_prints_like_the_whole_value() {
    let cases: Vec<(&str, Value)> = vec![
        (
            "[float:262144]",
            Value::Array((0..262_144).map(|i| Value::Float(i as f32)).collect()),
        ),
        (
            "[char:100000]",
            Value::Array(
                (0..100_000)
                    .map(|i| Value::Char(b'a' + (i % 26) as u8))
                    .collect(),
            ),
        ),
        (
            "{int, <double:1>}",
            Value::Struct(vec![
                Value::Int(50_000),
                Value::VarArray((0..50_000).map(|i| Value::Double(i as f64)).collect()),
            ]),
        ),
        (
            "[{int, string}:5000]",
            Value::Array(
                (0..5000)
                    .map(|i| Value::Struct(vec![Value::Int(i), Value::String(None)]))
                    .collect(),
            ),
        ),
        (
            "[int:1000, 1000]",
            Value::Array(
                (0..1000)
                    .map(|_| Value::Array((0..1000).map(Value::Int).collect()))
                    .collect(),
            ),
        ),
    ];
    for (fs, v) in cases {
        let f = support::fmt(fs);
        let bytes = v.to_ipc_bytes(&f).unwrap();
        let full = courier_wire::ipc::log_data(&f, &v);
        assert!(full.ends_with("...\n"), "{fs}: not cut short:\n{full}");
        for keep in [400, 4096] {
            let mut r = Reader::new(&bytes, ByteOrder::NATIVE);
            let none = |_: &str| None;
            let p = courier_wire::ipc::decode_value_prefix(&f, &mut r, &none, keep).unwrap();
            assert_eq!(r.position(), bytes.len(), "{fs}");
            assert_eq!(
                courier_wire::ipc::log_data(&f, &p),
                full,
                "{fs}, {keep} elements"
            );
        }
    }
}
