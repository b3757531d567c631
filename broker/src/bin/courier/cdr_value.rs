//! A dynamic [`Value`] in DDS's CDR, through an IPC format, laid out as
//! `#[derive(IpcMessage)]` lays out a type of that format (final
//! extensibility): so `courier echo --format` and `courier pub --format`
//! speak any DDS type whose layout an IPC format describes.
//!
//! Written as XCDR1 little-endian (what Courier's sessions send); read in
//! either version and byte order. A variable array is a `sequence<T>`
//! beside its size fields (flat, row-major, for `<T:k1,k2>`). A pointer
//! (`*T`, `*!`) is an `@optional` member, as the derive lays out
//! `Option<Box<T>>` (`cdr::write_optional`: in XCDR1 a parameter header
//! with the member's id, its index in the struct). `format` fields have no
//! CDR layout here and are refused up front.

use courier::cdr::{Encoding, Extensibility, Reader, Writer};
use courier::format::{Format, Primitive};
use courier::ipc::Value;
use courier::ShapeError;

/// Why `fmt` has no CDR layout here, if it has none.
pub fn check(fmt: &Format) -> Result<(), String> {
    let refuse = |what: &str| {
        Err(format!(
            "{what} has no CDR layout for --format on rtps:// (format fields are IPC only)"
        ))
    };
    match fmt {
        Format::Primitive(Primitive::Format) => refuse("a format field"),
        Format::Named(n) => refuse(&format!("named format `{n}`")),
        Format::Struct(fs) => fs.iter().try_for_each(check),
        Format::FixedArray { elem, .. } | Format::VarArray { elem, .. } | Format::Pointer(elem) => {
            check(elem)
        }
        _ => Ok(()),
    }
}

/// The size of a CDR primitive of this format (what XCDR2 writes no
/// `DHEADER` before arrays and sequences of).
fn primitive(f: &Format) -> Option<usize> {
    match f {
        Format::Primitive(p) => match p {
            Primitive::Char | Primitive::Byte | Primitive::UByte | Primitive::Boolean => Some(1),
            Primitive::Short | Primitive::UShort | Primitive::TwoByte => Some(2),
            Primitive::Int | Primitive::UInt | Primitive::Float => Some(4),
            Primitive::Long | Primitive::ULong | Primitive::Double => Some(8),
            Primitive::String | Primitive::Format => None,
        },
        _ => None,
    }
}

/// `value` of format `fmt` as a CDR sample (encapsulation header first).
pub fn encode(fmt: &Format, value: &Value) -> Result<Vec<u8>, String> {
    check(fmt)?;
    let mut w = Writer::with_header(Encoding::Xcdr1Le, Extensibility::Final);
    enc(fmt, value, &mut w, None)?;
    Ok(w.into_vec())
}

fn mismatch(f: &Format, v: &Value) -> String {
    format!("expected a value of {f}, found {}", v.kind())
}

/// Writes `v` of format `f`; `this` is the innermost struct around it
/// (what a `*!` points at).
fn enc(f: &Format, v: &Value, w: &mut Writer, this: Option<&Format>) -> Result<(), String> {
    match (f, v) {
        (Format::Empty, Value::Empty) => {}
        (Format::Primitive(p), v) => match (p, v) {
            (Primitive::Char, Value::Char(x)) | (Primitive::UByte, Value::UByte(x)) => {
                w.write_u8(*x)
            }
            (Primitive::Byte, Value::Byte(x)) => w.write_i8(*x),
            (Primitive::Short, Value::Short(x)) => w.write_i16(*x),
            (Primitive::UShort, Value::UShort(x)) | (Primitive::TwoByte, Value::TwoByte(x)) => {
                w.write_u16(*x)
            }
            (Primitive::Int, Value::Int(x)) => w.write_i32(*x),
            (Primitive::UInt, Value::UInt(x)) => w.write_u32(*x),
            (Primitive::Long, Value::Long(x)) => w.write_i64(*x),
            (Primitive::ULong, Value::ULong(x)) => w.write_u64(*x),
            (Primitive::Float, Value::Float(x)) => w.write_f32(*x),
            (Primitive::Double, Value::Double(x)) => w.write_f64(*x),
            (Primitive::Boolean, Value::Boolean(x)) => w.write_bool(*x),
            (Primitive::String, Value::String(s)) => w.write_string(s.as_deref().unwrap_or("")),
            _ => return Err(mismatch(f, v)),
        },
        (Format::Length(n), Value::Bytes(b)) => {
            if b.len() != *n as usize {
                return Err(format!("expected {n} bytes, found {}", b.len()));
            }
            let d = w.begin_array(true);
            w.write_bytes(b);
            w.end_dheader(d);
        }
        (Format::Struct(fs), Value::Struct(vs)) => {
            if fs.len() != vs.len() {
                return Err(format!("expected {} fields, found {}", fs.len(), vs.len()));
            }
            // members as the derive writes them: an optional one (a
            // pointer) says its id, the field's index, in XCDR1
            let st = w.begin_struct(Extensibility::Final);
            for (i, (fi, vi)) in fs.iter().zip(vs).enumerate() {
                // a variable array's size fields must say its length, as
                // the derive writes them
                if let (Format::VarArray { dims, .. }, Value::VarArray(items)) = (fi, vi) {
                    check_sizes(dims, vs, items.len())
                        .map_err(|e| format!("field {}: {e}", i + 1))?;
                }
                let m = st.begin_member(w, i as u32, false);
                let r = enc(fi, vi, w, Some(f));
                st.end_member(w, m);
                r.map_err(|e| format!("field {}: {e}", i + 1))?;
            }
            st.end(w);
        }
        (Format::Pointer(target), Value::Pointer(p)) => enc_pointer(target, p, w, this)?,
        (Format::SelfPointer, Value::Pointer(p)) => {
            let target = this.ok_or("a self pointer `*!` outside a struct points at nothing")?;
            enc_pointer(target, p, w, this)?
        }
        (Format::FixedArray { elem, dims }, Value::Array(_)) => {
            let d = w.begin_array(primitive(elem).is_some());
            enc_flat(elem, dims, v, w, this)?;
            w.end_dheader(d);
        }
        (Format::VarArray { elem, .. }, Value::VarArray(items)) => {
            let d = w.begin_sequence(items.len(), primitive(elem));
            for x in items {
                enc(elem, x, w, this)?;
            }
            w.end_dheader(d);
        }
        (Format::Enum { .. }, Value::Enum(n)) => w.write_i32(*n),
        _ => return Err(mismatch(f, v)),
    }
    Ok(())
}

/// A pointer's target `p` of format `target`, as the derive writes an
/// `Option<Box<T>>`.
fn enc_pointer(
    target: &Format,
    p: &Option<Box<Value>>,
    w: &mut Writer,
    this: Option<&Format>,
) -> Result<(), String> {
    let mut r = Ok(());
    courier::cdr::write_optional(w, p.as_deref(), |v, w| r = enc(target, v, w, this));
    r.map_err(|e| format!("pointee: {e}"))
}

/// That the size fields `dims` (1-based) of a struct's values `vs` say
/// `len` elements.
fn check_sizes(dims: &[u32], vs: &[Value], len: usize) -> Result<(), String> {
    let sizes: Vec<Option<i128>> = dims
        .iter()
        .map(|&k| {
            vs.get((k as usize).wrapping_sub(1))
                .and_then(Value::as_integer)
        })
        .collect();
    let product = sizes
        .iter()
        .try_fold(1i128, |p, n| n.map(|n| p.saturating_mul(n)));
    if product == Some(len as i128) {
        return Ok(());
    }
    let fields: Vec<String> = dims.iter().map(u32::to_string).collect();
    let says: Vec<String> = sizes
        .iter()
        .map(|n| n.map_or("nothing".into(), |n| n.to_string()))
        .collect();
    Err(format!(
        "variable array has {len} element(s), but its size field{} {} say{} {}",
        if dims.len() == 1 { "" } else { "s" },
        fields.join(", "),
        if dims.len() == 1 { "s" } else { "" },
        says.join(" × ")
    ))
}

/// What is wrong with a received `<T:k1,k2,…>` of `len` elements whose
/// size fields `dims` (1-based; integers, as the format parser checks) are
/// among `vs`, if anything.
fn shape_error(dims: &[u32], vs: &[Value], len: usize) -> Option<ShapeError> {
    let mut shape = Vec::with_capacity(dims.len());
    for (d, &k) in dims.iter().enumerate() {
        let n = vs
            .get((k as usize).wrapping_sub(1))
            .and_then(Value::as_integer)
            .unwrap_or(0);
        if n < 0 {
            return Some(ShapeError::Negative {
                dim: d + 1,
                value: n,
            });
        }
        shape.push(u64::try_from(n).unwrap_or(u64::MAX));
    }
    let expected = shape.iter().try_fold(1u64, |p, &n| p.checked_mul(n));
    match expected {
        Some(e) if e == len as u64 => None,
        Some(expected) => Some(ShapeError::Length {
            shape,
            expected,
            found: len,
        }),
        None => Some(ShapeError::TooLarge { shape }),
    }
}

/// The elements of a (multi-dimensional) fixed array, flat.
fn enc_flat(
    elem: &Format,
    dims: &[u32],
    v: &Value,
    w: &mut Writer,
    this: Option<&Format>,
) -> Result<(), String> {
    let Value::Array(items) = v else {
        return Err(format!("expected an array, found {}", v.kind()));
    };
    let Some((&n, rest)) = dims.split_first() else {
        return enc(elem, v, w, this);
    };
    if items.len() != n as usize {
        return Err(format!("expected {n} elements, found {}", items.len()));
    }
    for x in items {
        if rest.is_empty() {
            enc(elem, x, w, this)?;
        } else {
            enc_flat(elem, rest, x, w, this)?;
        }
    }
    Ok(())
}

/// A CDR sample (encapsulation header first) as a value of format `fmt`.
pub fn decode(fmt: &Format, data: &[u8]) -> Result<Value, String> {
    check(fmt)?;
    let mut r = Reader::with_header(data).map_err(|e| e.to_string())?;
    let v = dec(fmt, &mut r, None).map_err(|e| e.to_string())?;
    r.finish_padding().map_err(|e| e.to_string())?;
    Ok(v)
}

type DecodeResult = Result<Value, courier::cdr::DecodeError>;

/// Reads a value of format `f`; `this` is the innermost struct around it
/// (what a `*!` points at).
fn dec(f: &Format, r: &mut Reader<'_>, this: Option<&Format>) -> DecodeResult {
    Ok(match f {
        Format::Empty => Value::Empty,
        Format::Primitive(p) => match p {
            Primitive::Char => Value::Char(r.read_u8()?),
            Primitive::Byte => Value::Byte(r.read_i8()?),
            Primitive::UByte => Value::UByte(r.read_u8()?),
            Primitive::Short => Value::Short(r.read_i16()?),
            Primitive::UShort => Value::UShort(r.read_u16()?),
            Primitive::TwoByte => Value::TwoByte(r.read_u16()?),
            Primitive::Int => Value::Int(r.read_i32()?),
            Primitive::UInt => Value::UInt(r.read_u32()?),
            Primitive::Long => Value::Long(r.read_i64()?),
            Primitive::ULong => Value::ULong(r.read_u64()?),
            Primitive::Float => Value::Float(r.read_f32()?),
            Primitive::Double => Value::Double(r.read_f64()?),
            Primitive::Boolean => Value::Boolean(r.read_bool()?),
            Primitive::String => {
                let s = r.read_str()?;
                Value::String((!s.is_empty()).then(|| s.to_string()))
            }
            // refused by check()
            Primitive::Format => Value::Format(None),
        },
        Format::Length(n) => {
            let d = r.begin_array(true)?;
            let b = r.take(*n as usize)?.to_vec();
            r.end_dheader(d);
            Value::Bytes(b)
        }
        Format::Struct(fs) => {
            let st = r.begin_struct(Extensibility::Final)?;
            let mut vs = Vec::with_capacity(fs.len());
            let mut arrays = Vec::new();
            for fi in fs {
                if let Format::VarArray { dims, .. } = fi {
                    arrays.push((vs.len(), dims, r.position()));
                }
                vs.push(dec(fi, r, Some(f))?);
            }
            st.end(r)?;
            // the elements of `<T:k1,k2>` must fit its shape, as the derive
            // requires; a one-dimensional count is just a field in DDS
            for (i, dims, offset) in arrays {
                if let (true, Value::VarArray(items)) = (dims.len() > 1, &vs[i]) {
                    if let Some(error) = shape_error(dims, &vs, items.len()) {
                        return Err(courier::cdr::DecodeError::Shape {
                            offset,
                            error: Box::new(error),
                        });
                    }
                }
            }
            Value::Struct(vs)
        }
        Format::FixedArray { elem, dims } => {
            let d = r.begin_array(primitive(elem).is_some())?;
            let v = dec_flat(elem, dims, r, this)?;
            r.end_dheader(d);
            v
        }
        Format::VarArray { elem, .. } => {
            let prim = primitive(elem);
            let d = if prim.is_some() {
                None
            } else {
                r.begin_dheader()?
            };
            let n = r.read_len(prim.unwrap_or(1))?;
            let mut items = Vec::with_capacity(n.min(4096));
            for _ in 0..n {
                items.push(dec(elem, r, this)?);
            }
            r.end_dheader(d);
            Value::VarArray(items)
        }
        Format::Enum { .. } => Value::Enum(r.read_i32()?),
        Format::Pointer(target) => dec_pointer(target, r, this)?,
        Format::SelfPointer => match this {
            Some(target) => dec_pointer(target, r, this)?,
            // the format parser takes `*!` only inside a struct
            None => Value::Pointer(None),
        },
        // refused by check()
        Format::Named(_) => Value::Pointer(None),
    })
}

/// A pointer to a value of format `target`, read as the derive reads an
/// `Option<Box<T>>`.
fn dec_pointer(target: &Format, r: &mut Reader<'_>, this: Option<&Format>) -> DecodeResult {
    let p = courier::cdr::read_optional(r, |r| dec(target, r, this))?;
    Ok(Value::Pointer(p.map(Box::new)))
}

fn dec_flat(
    elem: &Format,
    dims: &[u32],
    r: &mut Reader<'_>,
    this: Option<&Format>,
) -> DecodeResult {
    let Some((&n, rest)) = dims.split_first() else {
        return dec(elem, r, this);
    };
    let min = primitive(elem).unwrap_or(1);
    if (n as usize).saturating_mul(min) > r.remaining() {
        return Err(courier::cdr::DecodeError::CountTooLarge {
            offset: r.position(),
            count: u64::from(n),
            remaining: r.remaining(),
        });
    }
    let mut items = Vec::with_capacity(n as usize);
    for _ in 0..n {
        items.push(dec_flat(elem, rest, r, this)?);
    }
    Ok(Value::Array(items))
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier::IpcMessage;

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Point {
        x: f64,
        y: f64,
    }

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(numeric)]
    enum Status {
        Wait,
        Send,
    }

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Sample {
        name: String,
        flag: bool,
        c: char,
        b: i8,
        s: i16,
        n: i32,
        #[ipc(len = "n")]
        points: Vec<Point>,
        m: [[u16; 3]; 2],
        status: Status,
        big: u64,
        k: i32,
        #[ipc(len = "k")]
        bytes: Vec<u8>,
    }

    fn sample() -> Sample {
        Sample {
            name: "hi".into(),
            flag: true,
            c: 'x',
            b: -2,
            s: -300,
            n: 2,
            points: vec![Point { x: 0.5, y: 1.0 }, Point { x: 1.5, y: 2.0 }],
            m: [[1, 2, 3], [4, 5, 6]],
            status: Status::Send,
            big: u64::MAX,
            k: 3,
            bytes: vec![7, 8, 9],
        }
    }

    /// The dynamic codec lays a value out as the derive does: the same
    /// bytes out (XCDR1), the same value in (XCDR1 and XCDR2, both byte
    /// orders).
    #[test]
    fn the_layout_is_the_derives() {
        let fmt = courier::format::parse(
            "{string, boolean, char, byte, short, int, <{double, double}:6>, [ushort:2,3], \
             {enum Wait, Send}, ulong, int, <ubyte:11>}",
        )
        .unwrap();
        let v = Value::from_ipc_bytes(
            &fmt,
            &courier::ipc::to_vec(&sample()),
            courier::ipc::ByteOrder::NATIVE,
        )
        .unwrap();
        let derived = courier::cdr::to_vec(&sample(), courier::cdr::Encoding::Xcdr1Le);
        assert_eq!(encode(&fmt, &v).unwrap(), derived);
        for enc in [
            courier::cdr::Encoding::Xcdr1Le,
            courier::cdr::Encoding::Xcdr1Be,
            courier::cdr::Encoding::Xcdr2Le,
            courier::cdr::Encoding::Xcdr2Be,
        ] {
            let bytes = courier::cdr::to_vec(&sample(), enc);
            assert_eq!(decode(&fmt, &bytes).unwrap(), v, "{enc:?}");
        }
    }

    #[test]
    fn what_has_no_layout_is_refused() {
        for f in ["format", "{int, *format}"] {
            let e = check(&courier::format::parse(f).unwrap()).unwrap_err();
            assert!(e.contains("has no CDR layout"), "{f}: {e}");
        }
        let f = courier::format::parse("{int, <int:1>}").unwrap();
        let bad = Value::Struct(vec![Value::Int(2), Value::VarArray(vec![Value::Int(1)])]);
        let e = encode(&f, &bad).unwrap_err();
        assert!(e.contains("size field 1 says 2"), "{e}");
        assert!(decode(&f, &[0, 1, 0, 0, 1]).is_err());
    }

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Scan {
        seq: i32,
        origin: Point,
        opt: Option<Box<Point>>,
        ok: bool,
        more: Option<Box<i32>>,
    }

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct List {
        v: u8,
        next: Option<Box<List>>,
    }

    /// The bytes of `value` (IPC format `fmt`) encoded dynamically are the
    /// derive's (XCDR1), and the derive's bytes in every encoding decode to
    /// the same value.
    fn same_as_the_derive<T: IpcMessage>(fmt: &str, value: &T) {
        let fmt = courier::format::parse(fmt).unwrap();
        let v = Value::from_ipc_bytes(
            &fmt,
            &courier::ipc::to_vec(value),
            courier::ipc::ByteOrder::NATIVE,
        )
        .unwrap();
        assert_eq!(
            encode(&fmt, &v).unwrap(),
            courier::cdr::to_vec(value, courier::cdr::Encoding::Xcdr1Le),
            "{fmt}"
        );
        for enc in [
            courier::cdr::Encoding::Xcdr1Le,
            courier::cdr::Encoding::Xcdr1Be,
            courier::cdr::Encoding::Xcdr2Le,
            courier::cdr::Encoding::Xcdr2Be,
        ] {
            let bytes = courier::cdr::to_vec(value, enc);
            assert_eq!(decode(&fmt, &bytes).unwrap(), v, "{fmt} {enc:?}");
        }
    }

    /// A pointer `*T` is an `@optional` member, as the derive lays out
    /// `Option<Box<T>>`: in XCDR1 a parameter header with the member id
    /// (the field's index) and the length (0: absent), golden bytes here.
    #[test]
    fn pointers_are_optional_members_as_the_derive_lays_them_out() {
        let point = Some(Box::new(Point { x: 9.0, y: 8.0 }));
        let scan = |opt, more| Scan {
            seq: 7,
            origin: Point { x: 1.5, y: -2.5 },
            opt,
            ok: true,
            more,
        };
        let fmt = "{int, {double, double}, *{double, double}, boolean, *int}";
        assert_eq!(Scan::FORMAT, "{int, Point, *Point, boolean, *int}");
        same_as_the_derive(fmt, &scan(point.clone(), Some(Box::new(-1))));
        same_as_the_derive(fmt, &scan(None, None));
        // golden: member 2 present (16 bytes), member 4 absent
        let v = Value::Struct(vec![
            Value::Int(7),
            Value::Struct(vec![Value::Double(1.5), Value::Double(-2.5)]),
            Value::Pointer(Some(Box::new(Value::Struct(vec![
                Value::Double(9.0),
                Value::Double(8.0),
            ])))),
            Value::Boolean(true),
            Value::Pointer(None),
        ]);
        let mut want = vec![0, 1, 0, 0, 7, 0, 0, 0, 0, 0, 0, 0];
        want.extend_from_slice(&1.5f64.to_le_bytes());
        want.extend_from_slice(&(-2.5f64).to_le_bytes());
        want.extend_from_slice(&[0x01, 0x7f, 8, 0, 2, 0, 0, 0, 16, 0, 0, 0]);
        want.extend_from_slice(&9.0f64.to_le_bytes());
        want.extend_from_slice(&8.0f64.to_le_bytes());
        want.extend_from_slice(&[1, 0, 0, 0]);
        want.extend_from_slice(&[0x01, 0x7f, 8, 0, 4, 0, 0, 0, 0, 0, 0, 0]);
        let fmt = courier::format::parse(fmt).unwrap();
        assert_eq!(encode(&fmt, &v).unwrap(), want);
        assert_eq!(
            want,
            courier::cdr::to_vec(&scan(point, None), courier::cdr::Encoding::Xcdr1Le)
        );
        // `*!` points at the struct around it
        let list = List {
            v: 1,
            next: Some(Box::new(List {
                v: 2,
                next: Some(Box::new(List { v: 3, next: None })),
            })),
        };
        same_as_the_derive("{ubyte, *!}", &list);
        same_as_the_derive("*{ubyte, *!}", &Some(Box::new(list)));
    }

    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Grid {
        label: String,
        rows: u32,
        cols: i64,
        #[ipc(len = "rows, cols")]
        cells: courier::Matrix<Point>,
    }

    /// `<T:k1,k2>` as the derive lays it out: the size fields, then one
    /// flat sequence; elements that do not fit the shape are an error both ways.
    #[test]
    fn multi_dimensional_arrays_are_laid_out_as_the_derives() {
        let g = Grid {
            label: "g".into(),
            rows: 2,
            cols: 1,
            cells: courier::Matrix::new(
                [2, 1],
                vec![Point { x: 1.0, y: 2.0 }, Point { x: 3.0, y: 4.0 }],
            )
            .unwrap(),
        };
        assert_eq!(Grid::FORMAT, "{string, uint, long, <Point:2,3>}");
        let fmt = courier::format::parse("{string, uint, long, <{double, double}:2,3>}").unwrap();
        let v = Value::from_ipc_bytes(
            &fmt,
            &courier::ipc::to_vec(&g),
            courier::ipc::ByteOrder::NATIVE,
        )
        .unwrap();
        assert_eq!(
            encode(&fmt, &v).unwrap(),
            courier::cdr::to_vec(&g, courier::cdr::Encoding::Xcdr1Le)
        );
        for enc in [
            courier::cdr::Encoding::Xcdr1Be,
            courier::cdr::Encoding::Xcdr2Le,
        ] {
            assert_eq!(
                decode(&fmt, &courier::cdr::to_vec(&g, enc)).unwrap(),
                v,
                "{enc:?}"
            );
        }
        // a value whose sizes do not fit its elements
        let Value::Struct(mut fields) = v else {
            panic!()
        };
        fields[2] = Value::Long(3);
        let bad = Value::Struct(fields);
        assert_eq!(
            encode(&fmt, &bad).unwrap_err(),
            "field 4: variable array has 2 element(s), but its size fields 2, 3 say 2 × 3"
        );
        // bytes whose sizes do not fit their elements
        let mut wrong = g.clone();
        wrong.cols = 2; // ignored by the derive
        wrong.cells = courier::Matrix::new([1, 2], wrong.cells.into_vec()).unwrap();
        let mut bytes = courier::cdr::to_vec(&wrong, courier::cdr::Encoding::Xcdr1Le);
        bytes[12] = 2; // rows (payload byte 8): 1 -> 2, so 2 x 2 for 2 elements at byte 24
        assert_eq!(
            decode(&fmt, &bytes).unwrap_err(),
            "variable array at byte 24: shape [2, 2] holds 4 elements, but 2 were given"
        );
    }
}
