//! `#[derive(IpcMessage)]`: format strings and IPC marshalling, checked
//! against the IPC manual's Appendix A types and the bytes the C library
//! produces (ipc.md §10 E4, E5 and E7, captured from CMU IPC 3.9 on a
//! little-endian host).

use courier::ipc::{self, ByteOrder, DecodeError};
use courier::{IpcMessage, Matrix, NamedFormats, NdVec};

/// `typedef enum { WaitVal, SendVal, ReceiveVal, ListenVal } STATUS_ENUM`,
/// written in T1 as `{enum : 3}`.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(numeric)]
enum Status {
    Wait,
    Send,
    Receive,
    Listen,
}

/// The same enum in its symbolic form, as T2 writes it.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[allow(clippy::enum_variant_names)] // the manual's names: they are the format
enum StatusEnum {
    WaitVal,
    SendVal,
    ReceiveVal,
    ListenVal,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T1 {
    i1: i32,
    status: Status,
    matrix: [[f64; 3]; 2],
    d1: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T2 {
    str1: String,
    count: i32,
    #[ipc(len = "count")]
    t1: Vec<T1>,
    status: StatusEnum,
}

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn t1() -> T1 {
    T1 {
        i1: 666,
        status: Status::Send,
        matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]],
        d1: std::f64::consts::PI,
    }
}

/// ipc.md §10 E4: the user bytes of query1 (after the two length words).
const E4: &str = "9a020000 01000000
    00000000 00000000  00000000 0000f03f  00000000 00000040
    00000000 0000f03f  00000000 00000040  00000000 00000840
    182d4454 fb210940";

/// ipc.md §10 E5: the user bytes of response1 (after the two length words).
fn e5() -> Vec<u8> {
    let mut b = hex("0c000000 48656c6c 6f2c2077 6f726c64 01000000 01000000");
    b.extend(hex(E4));
    b.extend(hex("02000000"));
    b
}

/// Checks encode (on little-endian hosts, where the captures come from) and
/// decode (everywhere, reading the bytes as little-endian).
fn golden<T: IpcMessage + PartialEq + std::fmt::Debug>(value: &T, bytes: &[u8]) {
    if cfg!(target_endian = "little") {
        assert_eq!(ipc::to_vec(value), bytes, "encoding of {value:?}");
    }
    assert_eq!(
        &ipc::from_slice_with_order::<T>(bytes, ByteOrder::Little).unwrap(),
        value
    );
    assert_eq!(&ipc::from_slice::<T>(&ipc::to_vec(value)).unwrap(), value);
}

#[test]
fn appendix_a_formats() {
    assert_eq!(Status::FORMAT, "{enum : 3}");
    assert_eq!(
        StatusEnum::FORMAT,
        "{enum WaitVal, SendVal, ReceiveVal, ListenVal}"
    );
    assert_eq!(StatusEnum::FIELD_FORMAT, StatusEnum::FORMAT);
    assert_eq!(StatusEnum::FORMAT_NAME, None);
    assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
    assert_eq!(T1::FIELD_FORMAT, "T1");
    assert_eq!(T1::FORMAT_NAME, Some("T1"));
    assert_eq!(
        T2::FORMAT,
        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}"
    );
    assert_eq!(T1::IPC_MIN_SIZE, 64);
    assert_eq!(T2::IPC_MIN_SIZE, 5 + 4 + 4 + 4);
    assert!(T1::TYPE_NAME.ends_with("::T1"), "{}", T1::TYPE_NAME);
    assert_eq!(T1::KEYS, &[] as &[&str]);

    let named = NamedFormats::of::<T2>();
    assert_eq!(named.get("T1"), Some(T1::FORMAT));
    assert_eq!(named.get("T2"), Some(T2::FORMAT));
    assert_eq!(named.len(), 2);
    assert_eq!(
        NamedFormats::of::<T1>().iter().collect::<Vec<_>>(),
        [("T1", T1::FORMAT)]
    );
}

#[test]
fn e4_t1_bytes() {
    golden(&t1(), &hex(E4));
    assert_eq!(hex(E4).len(), 64);
}

#[test]
fn e5_t2_bytes() {
    let t2 = T2 {
        str1: "Hello, world".into(),
        count: 1,
        t1: vec![t1()],
        status: StatusEnum::ReceiveVal,
    };
    golden(&t2, &e5());
    assert_eq!(e5().len(), 92);
}

#[test]
fn var_array_count_comes_from_the_vec() {
    // The count field's own value is ignored on encode.
    let t2 = T2 {
        str1: "Hello, world".into(),
        count: 99,
        t1: vec![t1()],
        status: StatusEnum::ReceiveVal,
    };
    if cfg!(target_endian = "little") {
        assert_eq!(ipc::to_vec(&t2), e5());
    }
    let back = ipc::from_slice::<T2>(&ipc::to_vec(&t2)).unwrap();
    assert_eq!(back.count, 1);
}

#[test]
fn var_array_count_mismatch_is_an_error() {
    let mut b = e5();
    b[16] = 2; // the int field says 2, the array's own count says 1
    match ipc::from_slice_with_order::<T2>(&b, ByteOrder::Little) {
        Err(DecodeError::CountMismatch {
            offset: 20,
            expected: 2,
            found: 1,
        }) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn invalid_enum_names_the_type() {
    let mut b = hex(E4);
    b[4] = 4;
    match ipc::from_slice_with_order::<T1>(&b, ByteOrder::Little) {
        Err(DecodeError::InvalidEnum {
            offset: 4,
            value: 4,
            type_name,
        }) => assert!(type_name.ends_with("::Status"), "{type_name}"),
        other => panic!("{other:?}"),
    }
}

// ---- ipc.md §10 E7 ----

/// `{char, double, short}`.
#[derive(IpcMessage, Debug, PartialEq)]
struct CharDoubleShort {
    #[ipc(char)]
    c: u8,
    d: f64,
    s: i16,
}

/// `{int, *!}`: a linked list.
#[derive(IpcMessage, Debug, PartialEq)]
struct List {
    v: i32,
    next: Option<Box<List>>,
}

/// The same list spelled with `Self`.
#[derive(IpcMessage, Debug, PartialEq)]
struct List2 {
    v: i32,
    next: Option<Box<Self>>,
}

#[derive(IpcMessage, Debug, PartialEq)]
enum Color {
    Red,
    Green,
    Blue,
}

/// `{string, int, <int:2>, {enum Red, Green, Blue}, boolean}`.
#[derive(IpcMessage, Debug, PartialEq)]
struct Mixed {
    s: String,
    n: i32,
    #[ipc(len = "n")]
    v: Vec<i32>,
    color: Color,
    ok: bool,
}

/// `{int, <byte:1>}` (IPC_VARIABLE_LENGTH).
#[derive(IpcMessage, Debug, PartialEq)]
struct VarBytes {
    len: i32,
    #[ipc(len = "len")]
    data: Vec<i8>,
}

/// `{int, int, <double:1,2>}`: a 2-dimensional variable array whose count
/// is the product of two fields.
#[derive(IpcMessage, Debug, PartialEq)]
struct Grid {
    rows: i32,
    cols: i32,
    #[ipc(len = "rows, cols")]
    cells: Matrix<f64>,
}

/// Size fields after the array, of other widths, and three dimensions.
#[derive(IpcMessage, Debug, PartialEq)]
struct Cube {
    label: String,
    #[ipc(len = "x, y, z")]
    v: NdVec<i16, 3>,
    z: u64,
    y: u32,
    x: i64,
}

#[test]
fn e7_two_dimensional_var_array() {
    assert_eq!(Grid::FORMAT, "{int, int, <double:1,2>}");
    let g = Grid {
        rows: 2,
        cols: 3,
        cells: Matrix::new([2, 3], vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]).unwrap(),
    };
    let mut bytes = hex("02000000 03000000 06000000");
    for d in [0.0f64, 1.0, 2.0, 3.0, 4.0, 5.0] {
        bytes.extend(d.to_le_bytes());
    }
    golden(&g, &bytes);
    // what the dynamic codec (C's layout) makes of the derive's bytes
    let fmt = courier::format::parse(Grid::FORMAT).unwrap();
    let v = ipc::Value::from_ipc_bytes(&fmt, &ipc::to_vec(&g), ByteOrder::NATIVE).unwrap();
    let ipc::Value::Struct(fields) = &v else {
        panic!("{v:?}")
    };
    assert_eq!(fields[0].as_integer(), Some(2));
    assert_eq!(fields[1].as_integer(), Some(3));
    let cells: Vec<f64> = fields[2]
        .as_slice()
        .unwrap()
        .iter()
        .map(|c| c.as_f64().unwrap())
        .collect();
    assert_eq!(cells, [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
}

#[test]
fn nd_var_array_size_fields_come_from_the_shape() {
    // the size fields' own values are ignored on encode, as a `Vec`'s count field's is
    let g = Grid {
        rows: 7,
        cols: -1,
        cells: Matrix::new([3, 1], vec![1.0, 2.0, 3.0]).unwrap(),
    };
    let back = ipc::from_slice::<Grid>(&ipc::to_vec(&g)).unwrap();
    assert_eq!((back.rows, back.cols), (3, 1));
    assert_eq!(back.cells, g.cells);

    assert_eq!(Cube::FORMAT, "{string, <short:5,4,3>, ulong, uint, long}");
    let c = Cube {
        label: "c".into(),
        v: NdVec::from_fn([2, 3, 4], |[i, j, k]| (i * 100 + j * 10 + k) as i16).unwrap(),
        z: 0,
        y: 0,
        x: 0,
    };
    let back = ipc::from_slice::<Cube>(&ipc::to_vec(&c)).unwrap();
    assert_eq!((back.x, back.y, back.z), (2, 3, 4));
    assert_eq!(back.v[[1, 2, 3]], 123);
    assert_eq!(back.v, c.v);
    // an empty dimension: no elements, the other sizes still sent
    let e = Grid {
        rows: 0,
        cols: 0,
        cells: Matrix::new([0, 9], vec![]).unwrap(),
    };
    assert_eq!(ipc::to_vec(&e)[..12], hex("00000000 09000000 00000000")[..]);
    assert_eq!(
        ipc::from_slice::<Grid>(&ipc::to_vec(&e))
            .unwrap()
            .cells
            .shape(),
        [0, 9]
    );
}

#[test]
fn nd_var_array_shape_errors_name_the_problem() {
    let decode = |h: &str| ipc::from_slice_with_order::<Grid>(&hex(h), ByteOrder::Little);
    // 2 × 3 say the size fields, 5 elements came
    let mut b = hex("02000000 03000000 05000000");
    b.extend([0u8; 40]);
    let e = ipc::from_slice_with_order::<Grid>(&b, ByteOrder::Little).unwrap_err();
    assert_eq!(
        e,
        DecodeError::Shape {
            offset: 8,
            error: Box::new(courier::ShapeError::Length {
                shape: vec![2, 3],
                expected: 6,
                found: 5
            })
        }
    );
    assert_eq!(
        e.to_string(),
        "variable array at byte 8: shape [2, 3] holds 6 elements, but 5 were given"
    );
    // a negative size field, even with no elements
    assert_eq!(
        decode("02000000 ffffffff 00000000")
            .unwrap_err()
            .to_string(),
        "variable array at byte 8: dimension 2 of the shape is -1: a size cannot be negative"
    );
    // size fields whose product overflows, with no elements
    assert!(matches!(
        decode("00000100 00000100 00000000"),
        Err(DecodeError::Shape { error, .. }) if matches!(*error, courier::ShapeError::TooLarge { .. })
    ));
    // the array's own count promising more than there is
    assert!(matches!(
        decode("02000000 03000000 ffffff7f"),
        Err(DecodeError::CountTooLarge { .. })
    ));
    // the same for size fields that come after the array
    let c = Cube {
        label: String::new(),
        v: NdVec::filled([1, 2, 2], 5).unwrap(),
        z: 0,
        y: 0,
        x: 0,
    };
    let mut b = ipc::to_vec(&c);
    let n = b.len();
    b[n - 8] = 3; // x = 3
    assert!(matches!(
        ipc::from_slice::<Cube>(&b),
        Err(DecodeError::Shape { error, .. })
            if matches!(*error, courier::ShapeError::Length { expected: 12, found: 4, .. })
    ));
}

#[test]
fn e7_char_double_short() {
    assert_eq!(CharDoubleShort::FORMAT, "{char, double, short}");
    golden(
        &CharDoubleShort {
            c: b'x',
            d: 2.0,
            s: 7,
        },
        &hex("78 00000000 00000040 0700"),
    );
}

#[test]
fn e7_self_pointer() {
    assert_eq!(List::FORMAT, "{int, *!}");
    assert_eq!(List2::FORMAT, "{int, *!}");
    assert_eq!(List::IPC_MIN_SIZE, 5);
    let list = List {
        v: 1,
        next: Some(Box::new(List { v: 2, next: None })),
    };
    golden(&list, &hex("01000000 5a 02000000 00"));
    let list2 = List2 {
        v: 1,
        next: Some(Box::new(List2 { v: 2, next: None })),
    };
    golden(&list2, &hex("01000000 5a 02000000 00"));
    assert_eq!(
        NamedFormats::of::<List>().iter().collect::<Vec<_>>(),
        [("List", "{int, *!}")]
    );
}

#[test]
fn e7_mixed() {
    assert_eq!(
        Mixed::FORMAT,
        "{string, int, <int:2>, {enum Red, Green, Blue}, boolean}"
    );
    golden(
        &Mixed {
            s: "ab".into(),
            n: 3,
            v: vec![10, 20, 30],
            color: Color::Green,
            ok: true,
        },
        &hex("02000000 6162 03000000 03000000 0a000000 14000000 1e000000 01000000 01000000"),
    );
}

#[test]
fn e7_var_bytes() {
    assert_eq!(VarBytes::FORMAT, "{int, <byte:1>}");
    golden(
        &VarBytes {
            len: 3,
            data: vec![1, 2, 3],
        },
        &hex("03000000 03000000 010203"),
    );
}

// ---- the rest of the mapping ----

/// A tuple struct: fields are named by index.
#[derive(IpcMessage, Debug, PartialEq)]
struct Pair(u32, #[ipc(len = "0")] Vec<u16>);

/// The empty message.
#[derive(IpcMessage, Debug, PartialEq)]
struct Ping;

/// Generic structs are written inline.
#[derive(IpcMessage, Debug, PartialEq)]
struct Stamped<T> {
    t: f64,
    v: T,
}

#[derive(IpcMessage, Debug, PartialEq, Clone, Copy)]
#[ipc(name = "point_t", type_name = "geometry::Point")]
struct Point {
    x: f32,
    y: f32,
}

/// Length field after the array, pointers, `Option<String>`, `char`, named formats.
#[derive(IpcMessage, Debug, PartialEq)]
struct Misc {
    #[ipc(len = "n")]
    pts: Vec<Point>,
    n: u8,
    origin: Option<Box<Point>>,
    label: Option<String>,
    initial: char,
    corners: [Point; 2],
    big: u64,
}

/// Explicit discriminants give the numeric form with the largest value.
#[derive(IpcMessage, Debug, PartialEq)]
enum Sparse {
    A = 2,
    B = 7,
    C,
}

#[derive(IpcMessage, Debug, PartialEq)]
struct Nested {
    inner: Stamped<Point>,
    #[ipc(len = "k")]
    items: Vec<Stamped<i16>>,
    k: i64,
    sparse: Sparse,
}

#[test]
fn tuple_and_unit_structs() {
    assert_eq!(Pair::FORMAT, "{uint, <ushort:1>}");
    golden(&Pair(2, vec![5, 6]), &hex("02000000 02000000 0500 0600"));
    assert_eq!(Ping::FORMAT, "");
    assert_eq!(Ping::FORMAT_NAME, None);
    assert!(ipc::to_vec(&Ping).is_empty());
    assert_eq!(ipc::from_slice::<Ping>(&[]).unwrap(), Ping);
}

#[test]
fn generic_structs() {
    assert_eq!(<Stamped<i32>>::FORMAT, "{double, int}");
    assert_eq!(<Stamped<i32>>::FIELD_FORMAT, "{double, int}");
    assert_eq!(<Stamped<i32>>::FORMAT_NAME, None);
    assert!(
        <Stamped<i32>>::TYPE_NAME.ends_with("::Stamped<int32>"),
        "{}",
        <Stamped<i32>>::TYPE_NAME
    );
    assert_eq!(<Stamped<T1>>::FORMAT, "{double, T1}");
    assert_eq!(
        NamedFormats::of::<Stamped<T1>>().get("T1"),
        Some(T1::FORMAT)
    );
    let v = Stamped { t: 1.5, v: t1() };
    assert_eq!(ipc::from_slice::<Stamped<T1>>(&ipc::to_vec(&v)).unwrap(), v);
}

#[test]
fn names_pointers_and_trailing_length() {
    assert_eq!(Point::FORMAT, "{float, float}");
    assert_eq!(Point::FIELD_FORMAT, "point_t");
    assert_eq!(Point::TYPE_NAME, "geometry::Point");
    assert_eq!(
        Misc::FORMAT,
        "{<point_t:2>, ubyte, *point_t, string, char, [point_t:2], ulong}"
    );
    let named = NamedFormats::of::<Misc>();
    assert_eq!(
        named.iter().map(|(n, _)| n).collect::<Vec<_>>(),
        ["Misc", "point_t"]
    );
    assert_eq!(
        Nested::FORMAT,
        "{{double, point_t}, <{double, short}:3>, long, {enum : 8}}"
    );
    assert!(NamedFormats::of::<Nested>().contains("point_t"));

    let p = Point { x: 1.0, y: -2.0 };
    let m = Misc {
        pts: vec![p, p, p],
        n: 0, // ignored on encode
        origin: Some(Box::new(p)),
        label: None,
        initial: 'é',
        corners: [p, Point { x: 0.5, y: 0.25 }],
        big: u64::MAX,
    };
    let bytes = ipc::to_vec(&m);
    assert_eq!(&bytes[..4], &3i32.to_ne_bytes());
    assert_eq!(bytes[4 + 3 * 8], 3); // the u8 length field
    let back = ipc::from_slice::<Misc>(&bytes).unwrap();
    assert_eq!(back, Misc { n: 3, ..m });
}

#[test]
fn explicit_discriminants() {
    assert_eq!(Sparse::FORMAT, "{enum : 8}");
    assert_eq!(ipc::to_vec(&Sparse::C), 8i32.to_ne_bytes());
    assert_eq!(
        ipc::from_slice::<Sparse>(&7i32.to_ne_bytes()).unwrap(),
        Sparse::B
    );
    assert!(matches!(
        ipc::from_slice::<Sparse>(&3i32.to_ne_bytes()),
        Err(DecodeError::InvalidEnum { value: 3, .. })
    ));
    let n = Nested {
        inner: Stamped {
            t: 0.0,
            v: Point { x: 1.0, y: 2.0 },
        },
        items: vec![Stamped { t: 1.0, v: -3 }],
        k: 1,
        sparse: Sparse::A,
    };
    assert_eq!(ipc::from_slice::<Nested>(&ipc::to_vec(&n)).unwrap(), n);
}

#[test]
fn hostile_input_is_rejected() {
    // A count that promises more than the input holds.
    let b = hex("ffffff7f ffffff7f 00");
    assert!(matches!(
        ipc::from_slice_with_order::<VarBytes>(&b, ByteOrder::Little),
        Err(DecodeError::CountTooLarge { .. })
    ));
    // A deep list is bounded by MAX_DEPTH, not by the stack.
    let mut deep = Vec::new();
    for _ in 0..(ipc::MAX_DEPTH + 5) {
        deep.extend_from_slice(&1i32.to_ne_bytes());
        deep.push(b'Z');
    }
    deep.extend_from_slice(&1i32.to_ne_bytes());
    deep.push(0);
    let r = std::thread::Builder::new()
        .stack_size(2 << 20) // the default thread stack: the limit must hold within it
        .spawn(move || ipc::from_slice::<List>(&deep).map(|_| ()))
        .unwrap()
        .join()
        .unwrap();
    assert!(matches!(r, Err(DecodeError::TooDeep { .. })), "{r:?}");
}

/// Mutually recursive named formats: referenced by name, collected once.
#[derive(IpcMessage, Debug, PartialEq)]
struct TreeA {
    v: i16,
    b: Option<Box<TreeB>>,
}

#[derive(IpcMessage, Debug, PartialEq)]
struct TreeB {
    a: Option<Box<TreeA>>,
    w: f32,
}

#[test]
fn mutual_recursion() {
    assert_eq!(TreeA::FORMAT, "{short, *TreeB}");
    assert_eq!(TreeB::FORMAT, "{*TreeA, float}");
    let named = NamedFormats::of::<TreeA>();
    assert_eq!(
        named.iter().collect::<Vec<_>>(),
        [("TreeA", TreeA::FORMAT), ("TreeB", TreeB::FORMAT)]
    );
    let t = TreeA {
        v: 1,
        b: Some(Box::new(TreeB {
            a: Some(Box::new(TreeA { v: 2, b: None })),
            w: 0.5,
        })),
    };
    golden(&t, &hex("0100 5a 5a 0200 00 0000003f"));
    for enc in [
        courier::cdr::Encoding::Xcdr1Le,
        courier::cdr::Encoding::Xcdr2Be,
    ] {
        let c = courier::cdr::to_vec(&t, enc);
        assert_eq!(courier::cdr::from_slice::<TreeA>(&c).unwrap(), t);
    }
}

/// Recursion through a variable array is bounded by the depth limit too.
#[derive(IpcMessage, Debug, PartialEq)]
struct Node {
    n: i32,
    #[ipc(len = "n")]
    children: Vec<Node>,
}

#[test]
fn recursion_through_vec_is_bounded() {
    assert_eq!(Node::FORMAT, "{int, <Node:1>}");
    let leaf = || Node {
        n: 0,
        children: vec![],
    };
    let tree = Node {
        n: 2,
        children: vec![
            leaf(),
            Node {
                n: 1,
                children: vec![leaf()],
            },
        ],
    };
    assert_eq!(ipc::from_slice::<Node>(&ipc::to_vec(&tree)).unwrap(), tree);
    // Hostile: each level is `1, 1` (field, array count), nested past the limit.
    let mut deep = Vec::new();
    for _ in 0..(ipc::MAX_DEPTH + 5) {
        deep.extend_from_slice(&1i32.to_ne_bytes());
        deep.extend_from_slice(&1i32.to_ne_bytes());
    }
    let r = std::thread::Builder::new()
        .stack_size(2 << 20) // the default thread stack: the limit must hold within it
        .spawn(move || ipc::from_slice::<Node>(&deep).map(|_| ()))
        .unwrap()
        .join()
        .unwrap();
    assert!(matches!(r, Err(DecodeError::TooDeep { .. })), "{r:?}");
}

/// A `Vec` longer than its length field's type can say would go out cut
/// short (both encoders send no more than the field holds);
/// `check_lengths`, which a session runs before it encodes, names it,
/// here, in a nested struct, in an array element and in a `Vec` element.
#[test]
fn check_lengths_names_a_vec_its_length_field_cannot_say() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Obstacles {
        n: u8,
        #[ipc(len = "n")]
        xs: Vec<f32>,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Scene {
        name: String,
        near: Obstacles,
        pair: [Obstacles; 2],
        k: i32,
        #[ipc(len = "k")]
        more: Vec<Obstacles>,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Flat {
        a: i32,
        b: [f64; 3],
    }
    const { assert!(!Flat::CHECKS_LENGTHS && Obstacles::CHECKS_LENGTHS && Scene::CHECKS_LENGTHS) };
    let ok = Obstacles {
        n: 0,
        xs: vec![0.5; 255],
    };
    let long = Obstacles {
        n: 0,
        xs: vec![0.5; 300],
    };
    assert_eq!(ok.check_lengths(), Ok(()));
    let e = long.check_lengths().unwrap_err();
    assert_eq!(
        e.to_string(),
        "field `xs` has 300 elements, more than its length field `n` (u8) can say (255)"
    );
    // what the encoder does with it: 255 of the 300 go out
    let back: Obstacles = courier::ipc::from_slice(&courier::ipc::to_vec(&long)).unwrap();
    assert_eq!(back.xs.len(), 255);
    let scene = |near: &Obstacles, second: &Obstacles, last: &Obstacles| Scene {
        name: "s".into(),
        near: near.clone(),
        pair: [ok.clone(), second.clone()],
        k: 0,
        more: vec![ok.clone(), last.clone()],
    };
    assert_eq!(scene(&ok, &ok, &ok).check_lengths(), Ok(()));
    for s in [
        scene(&long, &ok, &ok),
        scene(&ok, &long, &ok),
        scene(&ok, &ok, &long),
    ] {
        assert_eq!(s.check_lengths().unwrap_err().length(), 300);
    }
    // a recursive type checks through itself
    let deep = Node {
        n: 0,
        children: vec![Node {
            n: 0,
            children: vec![],
        }],
    };
    const { assert!(Node::CHECKS_LENGTHS) };
    assert_eq!(deep.check_lengths(), Ok(()));
}

/// A `char` is one byte in IPC and in the IDL the derive declares: one
/// above U+00FF is named by `check_lengths` (a session refuses to send it)
/// with the field that holds it, in arrays and `Vec`s and nested structs
/// too; Latin-1 passes. `ipc::to_vec`, which does not check, still sends
/// `'?'`. Before, every session sent `'?'` without a word.
#[test]
fn check_lengths_names_a_char_one_byte_cannot_carry() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Key {
        c: char,
        n: i32,
        #[ipc(len = "n")]
        more: Vec<char>,
        grid: [[char; 2]; 2],
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Outer {
        inner: Key,
    }
    const { assert!(Key::CHECKS_LENGTHS && Outer::CHECKS_LENGTHS) };
    let key = |c: char, m: char, g: char| Key {
        c,
        n: 1,
        more: vec![m],
        grid: [['a', 'b'], ['c', g]],
    };
    assert_eq!(key('é', 'ÿ', '\0').check_lengths(), Ok(()));
    let e = key('€', 'a', 'a').check_lengths().unwrap_err();
    assert_eq!(
        e,
        courier::LengthError::NotLatin1 {
            field: "c",
            value: '€'
        }
    );
    assert_eq!(
        e.to_string(),
        "field `c` holds '€' (U+20AC), which a one-byte char (IPC and DDS `char`, Latin-1) \
         cannot carry: use a String, or #[ipc(char)] u8 for raw bytes"
    );
    assert_eq!(
        key('a', 'Ā', 'a').check_lengths().unwrap_err().field(),
        "more"
    );
    assert_eq!(
        key('a', 'a', '😀').check_lengths().unwrap_err().field(),
        "grid"
    );
    let outer = Outer {
        inner: key('a', 'a', '😀'),
    };
    assert_eq!(outer.check_lengths().unwrap_err().field(), "grid");
    // a message that is one char
    let e = '€'.check_lengths().unwrap_err();
    assert!(e.to_string().starts_with("the value holds '€'"), "{e}");
    assert_eq!('ÿ'.check_lengths(), Ok(()));
    // unchecked encoders send '?'
    assert_eq!(courier::ipc::to_vec(&'€'), b"?");
}

/// `#[ipc(bound = N)]` (IDL `string<N>`, `sequence<T, N>`): a `String` of
/// more than N bytes or a `Vec` of more than N elements is named by
/// `check_lengths`, through nesting too; the formats and encodings do not
/// change (IPC has no bounds).
#[test]
fn check_lengths_names_a_string_or_vec_over_its_bound() {
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Label {
        #[ipc(bound = 5)]
        text: String,
        n: i32,
        #[ipc(len = "n", bound = 3)]
        codes: Vec<i32>,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Unbounded {
        text: String,
        n: i32,
        #[ipc(len = "n")]
        codes: Vec<i32>,
    }
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Outer {
        labels: [Label; 2],
    }
    const { assert!(Label::CHECKS_LENGTHS && Outer::CHECKS_LENGTHS) };
    assert_eq!(Label::FORMAT, Unbounded::FORMAT);
    let label = |text: &str, codes: usize| Label {
        text: text.into(),
        n: 0,
        codes: vec![7; codes],
    };
    assert_eq!(label("12345", 3).check_lengths(), Ok(()));
    // bytes, as CDR counts them: "é" is two
    let e = label("1234é", 3).check_lengths().unwrap_err();
    assert_eq!(
        e,
        courier::LengthError::Bound {
            field: "text",
            len: 6,
            unit: "bytes",
            bound: 5
        }
    );
    assert_eq!(
        e.to_string(),
        "field `text` has 6 bytes, more than its bound of 5"
    );
    let e = label("ok", 4).check_lengths().unwrap_err();
    assert_eq!(
        e.to_string(),
        "field `codes` has 4 elements, more than its bound of 3"
    );
    let outer = Outer {
        labels: [label("ok", 1), label("too long", 1)],
    };
    assert_eq!(outer.check_lengths().unwrap_err().field(), "text");
    // the bytes are those of the unbounded type
    let v = Unbounded {
        text: "12345".into(),
        n: 3,
        codes: vec![7; 3],
    };
    assert_eq!(
        courier::ipc::to_vec(&label("12345", 3)),
        courier::ipc::to_vec(&v)
    );
    assert_eq!(
        courier::cdr::to_vec(&label("12345", 3), courier::cdr::Encoding::Xcdr1Le),
        courier::cdr::to_vec(&v, courier::cdr::Encoding::Xcdr1Le)
    );
}
