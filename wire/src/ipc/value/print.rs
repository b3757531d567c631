//! Printing a [`Value`] the way the C `central` prints message data in its
//! data log (`central -ld`; `printData.c` of IPC 3.9).
//!
//! The rules, established from the C source and checked against the
//! captured `central.log` files:
//!
//! - structs `{a, b}`, fixed arrays `[a, b]` (one bracket level per
//!   dimension), variable arrays `<a, b>` (nested by their size fields; an
//!   empty one prints `NULL`, since C decodes it to a NULL pointer), pointers
//!   `*value` or `NULL`; items separated by `", "`;
//! - `int`, `short`, `long` in decimal (signed), `uint`, `ushort`, `ulong`
//!   unsigned; `float` and `double` with two decimals (`%.2f`: `3.14`,
//!   `nan`, `-inf`); `boolean` as `True`/`False`; `char` as the raw
//!   character; strings in double quotes without escaping, NULL (and `""`,
//!   which decodes to NULL) as `"NULL"`;
//! - `byte`, `ubyte`, `twobyte` and raw-length bytes in hex (`%#x`) of the
//!   value shifted into the high end of a 32-bit word, as the C code does on
//!   a little-endian host: byte 5 prints `0x5000000`, 0 prints `0`; raw
//!   bytes as `(0x1000000, 0x2000000)`;
//! - enums by name when the format has names and the value is in range,
//!   else as the number; `format` values as C prints formatters
//!   (`{int, [double : 2, 3]}`, NULL as `NULLFormat`);
//! - in the log layout ([`PrintOptions::CENTRAL_LOG`]): 4 spaces of indent,
//!   lines wrapped at 80 columns (a token that would leave fewer than its
//!   "keep" characters goes to the next line, indented one more), at most 5
//!   lines, then `...`.

use super::MAX_VALUE_DEPTH;
use super::{Ctx, Resolver, Value};
use crate::format::{Format, Primitive};

/// Characters kept on a line after an opening token (`DEFAULT_KEEP`).
const DEFAULT_KEEP: usize = 10;

/// Layout of printed values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrintOptions {
    /// Spaces before the first line (continuation lines get one more).
    pub indent: usize,
    /// Wrap lines at this many columns; `None` never wraps.
    pub line_length: Option<usize>,
    /// Print at most this many lines, then `...`; `None` prints everything.
    pub max_lines: Option<usize>,
    /// End the output with a newline.
    pub trailing_newline: bool,
}

impl PrintOptions {
    /// One line, no indent, no limit, no newline: `{666, 1, [[0.00, 1.00]], 3.14}`.
    pub const ONE_LINE: PrintOptions = PrintOptions {
        indent: 0,
        line_length: None,
        max_lines: None,
        trailing_newline: false,
    };

    /// Exactly the C central's data log: indent 4, 80 columns, 5 lines, final newline.
    pub const CENTRAL_LOG: PrintOptions = PrintOptions {
        indent: 4,
        line_length: Some(80),
        max_lines: Some(5),
        trailing_newline: true,
    };
}

impl Default for PrintOptions {
    fn default() -> Self {
        PrintOptions::ONE_LINE
    }
}

/// Prints `v` (of format `fmt`) on one line, as the C central's data log
/// writes it but without indent, wrapping or truncation:
/// `{"Hello, world", 1, <{666, 1, [[0.00, 1.00, 2.00], [1.00, 2.00, 3.00]], 3.14}>, ReceiveVal}`.
///
/// Parts of `v` that do not match `fmt` print as `?`.
pub fn print_value(fmt: &Format, v: &Value) -> String {
    print_value_with(fmt, v, &PrintOptions::ONE_LINE, None)
}

/// Prints `v` exactly as the C central's data log does (`central -ld`):
/// indented by 4, wrapped at 80 columns, at most 5 lines, ending with a newline.
pub fn log_data(fmt: &Format, v: &Value) -> String {
    print_value_with(fmt, v, &PrintOptions::CENTRAL_LOG, None)
}

/// Prints `v` with the given layout; `resolve` looks up named formats.
///
/// The C central writes raw bytes; bytes that are not UTF-8 (in `char`
/// fields or non-UTF-8 strings) are replaced by U+FFFD here.
pub fn print_value_with<'f, 'g: 'f>(
    fmt: &'f Format,
    v: &Value,
    opts: &PrintOptions,
    resolve: Option<Resolver<'_, 'g>>,
) -> String {
    let mut p = Printer {
        out: Vec::new(),
        cursor: 0,
        line: 0,
        truncated: false,
        opts,
    };
    let shorten = resolve.map(|r| move |n: &str| -> Option<&'f Format> { r(n) });
    let mut ctx = Ctx::new(shorten.as_ref().map(|s| s as Resolver<'_, 'f>));
    p.tab(opts.indent);
    p.data(&mut ctx, fmt, v, 0, 0);
    if opts.trailing_newline {
        p.newline();
    }
    String::from_utf8_lossy(&p.out).into_owned()
}

struct Printer<'o> {
    out: Vec<u8>,
    cursor: usize,
    line: usize,
    truncated: bool,
    opts: &'o PrintOptions,
}

/// `%#x`: `0` for zero, else `0x…` in lower case.
fn hex(x: u32) -> String {
    if x == 0 {
        "0".into()
    } else {
        format!("{x:#x}")
    }
}

/// `%.2f` as glibc prints it.
fn fixed2(x: f64) -> String {
    if x.is_nan() {
        if x.is_sign_negative() { "-nan" } else { "nan" }.into()
    } else {
        format!("{x:.2}")
    }
}

impl Printer<'_> {
    fn newline(&mut self) {
        self.out.push(b'\n');
        self.line += 1;
        self.cursor = 0;
    }

    fn tab(&mut self, pos: usize) {
        if !self.truncated && self.cursor < pos {
            self.out.resize(self.out.len() + (pos - self.cursor), b' ');
            self.cursor = pos;
        }
    }

    fn space(&mut self) {
        if self.truncated {
            return;
        }
        if self.opts.line_length == Some(self.cursor) {
            self.newline();
            self.tab(self.opts.indent);
        }
        self.out.push(b' ');
        self.cursor += 1;
    }

    /// `printString`: `None` prints `NULL`; C strings end at the first NUL.
    fn bytes(&mut self, s: Option<&[u8]>, keep: usize) {
        if self.truncated {
            return;
        }
        let s = s.map(|s| &s[..s.iter().position(|&b| b == 0).unwrap_or(s.len())]);
        let len = s.map_or(0, <[u8]>::len);
        if let Some(ll) = self.opts.line_length {
            if self.cursor + len + keep > ll {
                self.newline();
                self.tab(self.opts.indent + 1);
            }
        }
        if self.opts.max_lines.is_none_or(|m| self.line < m) {
            match s {
                Some(s) => {
                    self.out.extend_from_slice(s);
                    self.cursor += len;
                }
                None => {
                    self.out.extend_from_slice(b"NULL");
                    self.cursor += 4;
                }
            }
        } else {
            self.truncated = true;
            self.out.extend_from_slice(b"...");
        }
    }

    fn s(&mut self, s: &str, keep: usize) {
        self.bytes(Some(s.as_bytes()), keep);
    }

    fn comma_space(&mut self) {
        self.s(",", 0);
        self.space();
    }

    fn quoted(&mut self, s: Option<&[u8]>, keep: usize) {
        self.s("\"", keep);
        self.bytes(s, keep);
        self.s("\"", keep);
    }

    fn prim(&mut self, p: Primitive, v: &Value, keep: usize) {
        let text = match (p, v) {
            (Primitive::Char, Value::Char(c)) => return self.bytes(Some(&[*c]), keep),
            (Primitive::Byte, Value::Byte(b)) => hex(u32::from(*b as u8) << 24),
            (Primitive::UByte, Value::UByte(b)) => hex(u32::from(*b) << 24),
            (Primitive::TwoByte, Value::TwoByte(b)) => hex(u32::from(*b) << 16),
            (Primitive::Short, Value::Short(x)) => x.to_string(),
            (Primitive::UShort, Value::UShort(x)) => x.to_string(),
            (Primitive::Int, Value::Int(x)) => x.to_string(),
            (Primitive::UInt, Value::UInt(x)) => x.to_string(),
            (Primitive::Long, Value::Long(x)) => x.to_string(),
            (Primitive::ULong, Value::ULong(x)) => x.to_string(),
            (Primitive::Float, Value::Float(x)) => fixed2(f64::from(*x)),
            (Primitive::Double, Value::Double(x)) => fixed2(*x),
            (Primitive::Boolean, Value::Boolean(b)) => if *b { "True" } else { "False" }.into(),
            (Primitive::String, Value::String(s)) => {
                return self.quoted(s.as_deref().map(str::as_bytes), keep)
            }
            (Primitive::String, Value::Bytes(b)) => return self.quoted(Some(b), keep),
            (Primitive::Format, Value::Format(None)) => "NULLFormat".into(),
            (Primitive::Format, Value::Format(Some(f))) => return self.formatter(f, keep, 0),
            _ => "?".into(),
        };
        self.s(&text, keep);
    }

    /// `Print_Formatter1`: a format as the C log prints a `format` value
    /// (`{int, [double : 2, 3]}`, `*!`, `{enum : 3}`).
    fn formatter(&mut self, f: &Format, keep: usize, depth: usize) {
        if self.truncated {
            return;
        }
        if depth > MAX_VALUE_DEPTH {
            return self.s("...", keep);
        }
        match f {
            Format::Empty => self.s("NULLFormat", keep),
            Format::Length(n) => self.s(&n.to_string(), keep),
            Format::Primitive(p) => self.s(p.name(), keep),
            Format::Pointer(inner) => {
                self.s("*", DEFAULT_KEEP);
                self.formatter(inner, keep, depth + 1);
            }
            Format::SelfPointer => {
                self.s("*", DEFAULT_KEEP);
                self.s("!", keep);
            }
            Format::Struct(fs) => {
                self.s("{", DEFAULT_KEEP);
                for (i, ff) in fs.iter().enumerate() {
                    if self.truncated {
                        return;
                    }
                    let last = i + 1 == fs.len();
                    self.formatter(ff, if last { keep + 1 } else { 1 }, depth + 1);
                    if last {
                        self.s("}", keep);
                    } else {
                        self.comma_space();
                    }
                }
            }
            Format::FixedArray { elem, dims } => {
                self.array_formatter("[", elem, dims, "]", keep, depth)
            }
            Format::VarArray { elem, dims } => {
                self.array_formatter("<", elem, dims, ">", keep, depth)
            }
            Format::Named(n) => self.s(n, keep),
            Format::Enum { names, max } => {
                self.s("{enum ", DEFAULT_KEEP);
                if names.is_empty() {
                    self.s(": ", keep);
                    self.s(&max.to_string(), keep);
                } else {
                    for (i, n) in names.iter().enumerate() {
                        if self.truncated {
                            return;
                        }
                        let last = i + 1 == names.len();
                        self.s(n, if last { keep + 1 } else { 1 });
                        if !last {
                            self.comma_space();
                        }
                    }
                }
                self.s("}", keep);
            }
        }
    }

    fn array_formatter(
        &mut self,
        start: &str,
        elem: &Format,
        dims: &[u32],
        end: &str,
        keep: usize,
        depth: usize,
    ) {
        self.s(start, DEFAULT_KEEP);
        self.formatter(elem, keep, depth + 1);
        self.s(" : ", DEFAULT_KEEP);
        for (i, d) in dims.iter().enumerate() {
            if self.truncated {
                return;
            }
            let last = i + 1 == dims.len();
            self.s(&d.to_string(), if last { keep + 1 } else { 1 });
            if last {
                self.s(end, keep);
            } else {
                self.comma_space();
            }
        }
    }

    fn data<'f>(
        &mut self,
        ctx: &mut Ctx<'_, 'f>,
        f: &'f Format,
        v: &Value,
        keep: usize,
        depth: usize,
    ) {
        if self.truncated {
            return;
        }
        if depth > MAX_VALUE_DEPTH {
            return self.s("...", keep);
        }
        match (f, v) {
            (Format::Empty, _) => {}
            (Format::Primitive(p), _) => self.prim(*p, v, keep),
            (Format::Length(_), Value::Bytes(b)) => {
                self.s("(", DEFAULT_KEEP);
                for (i, x) in b.iter().enumerate() {
                    if self.truncated {
                        return;
                    }
                    let last = i + 1 == b.len();
                    self.s(&hex(u32::from(*x) << 24), if last { keep + 1 } else { 1 });
                    if last {
                        self.s(")", keep);
                    } else {
                        self.comma_space();
                    }
                }
            }
            (Format::Pointer(_) | Format::SelfPointer, Value::Pointer(None)) => {
                self.s("NULL", keep)
            }
            (Format::Pointer(inner), Value::Pointer(Some(x))) => {
                self.s("*", DEFAULT_KEEP);
                self.data(ctx, inner, x, keep, depth + 1);
            }
            (Format::SelfPointer, Value::Pointer(Some(x))) => match ctx.self_target() {
                Ok(target) => {
                    self.s("*", DEFAULT_KEEP);
                    self.data(ctx, target, x, keep, depth + 1);
                }
                Err(_) => self.s("?", keep),
            },
            (Format::Struct(fields), Value::Struct(vals)) if fields.len() == vals.len() => {
                self.s("{", DEFAULT_KEEP);
                ctx.structs.push(f);
                for (i, (ff, fv)) in fields.iter().zip(vals).enumerate() {
                    if self.truncated {
                        break;
                    }
                    let last = i + 1 == fields.len();
                    let next_keep = if last { keep + 1 } else { 1 };
                    match (ctx.resolve_named(ff), fv) {
                        (Ok(Format::VarArray { elem, dims }), Value::VarArray(items)) => {
                            self.var_array(ctx, elem, dims, vals, items, next_keep, depth + 1)
                        }
                        _ => self.data(ctx, ff, fv, next_keep, depth + 1),
                    }
                    if last {
                        self.s("}", keep);
                    } else {
                        self.comma_space();
                    }
                }
                ctx.structs.pop();
            }
            (Format::FixedArray { elem, dims }, _) => {
                self.fixed(ctx, elem, dims.len(), v, keep, depth + 1)
            }
            (Format::Enum { names, max }, Value::Enum(e)) => {
                match usize::try_from(*e)
                    .ok()
                    .filter(|_| *e <= *max)
                    .and_then(|i| names.get(i))
                {
                    Some(name) => self.s(name, keep),
                    None => self.s(&e.to_string(), keep),
                }
            }
            (Format::Named(_), _) => match ctx.resolve_named(f) {
                Ok(g) => self.data(ctx, g, v, keep, depth + 1),
                Err(_) => self.s("?", keep),
            },
            _ => self.s("?", keep),
        }
    }

    /// `printArrayData` over a fixed array value (nested once per dimension).
    fn fixed<'f>(
        &mut self,
        ctx: &mut Ctx<'_, 'f>,
        elem: &'f Format,
        ndims: usize,
        v: &Value,
        keep: usize,
        depth: usize,
    ) {
        if ndims == 0 {
            return self.data(ctx, elem, v, keep, depth);
        }
        let Value::Array(items) = v else {
            return self.s("?", keep);
        };
        self.s("[", DEFAULT_KEEP);
        for (i, it) in items.iter().enumerate() {
            if self.truncated {
                return;
            }
            let last = i + 1 == items.len();
            let next_keep = if last { keep + 1 } else { 1 };
            self.fixed(ctx, elem, ndims - 1, it, next_keep, depth + 1);
            if !last {
                self.comma_space();
            }
        }
        self.s("]", keep);
    }

    #[allow(clippy::too_many_arguments)]
    fn var_array<'f>(
        &mut self,
        ctx: &mut Ctx<'_, 'f>,
        elem: &'f Format,
        dims: &[u32],
        siblings: &[Value],
        items: &[Value],
        keep: usize,
        depth: usize,
    ) {
        if items.is_empty() {
            // C decodes a zero-length variable array to a NULL pointer.
            return self.s("NULL", keep);
        }
        let mut shape: Vec<usize> = Vec::with_capacity(dims.len());
        for &k in dims {
            let n = (k as usize)
                .checked_sub(1)
                .and_then(|i| siblings.get(i))
                .and_then(Value::as_integer)
                .and_then(|n| usize::try_from(n).ok());
            match n {
                Some(n) => shape.push(n),
                None => {
                    shape.clear();
                    break;
                }
            }
        }
        let product = shape.iter().try_fold(1usize, |a, &n| a.checked_mul(n));
        if shape.is_empty() || product != Some(items.len()) {
            shape = vec![items.len()];
        }
        self.flat(ctx, elem, &shape, items, keep, depth);
    }

    /// `printArrayData` over a flat, row-major element slice of the given shape.
    fn flat<'f>(
        &mut self,
        ctx: &mut Ctx<'_, 'f>,
        elem: &'f Format,
        shape: &[usize],
        items: &[Value],
        keep: usize,
        depth: usize,
    ) {
        let Some((&n, rest)) = shape.split_first() else {
            return;
        };
        self.s("<", DEFAULT_KEEP);
        let stride: usize = rest.iter().product();
        for i in 0..n {
            if self.truncated {
                return;
            }
            let last = i + 1 == n;
            let next_keep = if last { keep + 1 } else { 1 };
            if rest.is_empty() {
                if let Some(it) = items.get(i) {
                    self.data(ctx, elem, it, next_keep, depth + 1);
                }
            } else {
                let chunk = items.get(i * stride..(i + 1) * stride).unwrap_or(&[]);
                self.flat(ctx, elem, rest, chunk, next_keep, depth + 1);
            }
            if !last {
                self.comma_space();
            }
        }
        self.s(">", keep);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn c_number_formats() {
        assert_eq!(hex(0), "0");
        assert_eq!(hex(5 << 24), "0x5000000");
        assert_eq!(fixed2(0.125), "0.12");
        assert_eq!(fixed2(-0.0), "-0.00");
        assert_eq!(fixed2(f64::NAN), "nan");
        assert_eq!(fixed2(-f64::NAN), "-nan");
        assert_eq!(fixed2(f64::NEG_INFINITY), "-inf");
    }

    #[test]
    fn primitives_print_like_c() {
        let cases: Vec<(Primitive, Value, &str)> = vec![
            (Primitive::Char, Value::Char(b'x'), "x"),
            (Primitive::Char, Value::Char(0), ""),
            (Primitive::Byte, Value::Byte(-1), "0xff000000"),
            (Primitive::UByte, Value::UByte(0), "0"),
            (Primitive::TwoByte, Value::TwoByte(0x1234), "0x12340000"),
            (Primitive::Short, Value::Short(-3), "-3"),
            (Primitive::UShort, Value::UShort(65535), "65535"),
            (Primitive::UInt, Value::UInt(u32::MAX), "4294967295"),
            (
                Primitive::Long,
                Value::Long(i64::MIN),
                "-9223372036854775808",
            ),
            (Primitive::Float, Value::Float(2.5), "2.50"),
            (Primitive::Boolean, Value::Boolean(true), "True"),
            (Primitive::Boolean, Value::Boolean(false), "False"),
            (Primitive::String, Value::String(None), "\"NULL\""),
            (
                Primitive::String,
                Value::String(Some("a\"b".into())),
                "\"a\"b\"",
            ),
        ];
        for (p, v, want) in cases {
            assert_eq!(print_value(&Format::Primitive(p), &v), want, "{p:?}");
        }
    }

    #[test]
    fn composites_print_like_c() {
        let f = Format::Struct(vec![
            Format::Primitive(Primitive::Int),
            Format::Primitive(Primitive::Int),
            Format::VarArray {
                elem: Box::new(Format::Primitive(Primitive::Int)),
                dims: vec![1, 2],
            },
            Format::Pointer(Box::new(Format::Primitive(Primitive::Int))),
            Format::SelfPointer,
            Format::Length(2),
            Format::Enum {
                names: vec!["A".into(), "B".into()],
                max: 1,
            },
        ]);
        let v = Value::Struct(vec![
            Value::Int(2),
            Value::Int(2),
            Value::VarArray((1..=4).map(Value::Int).collect()),
            Value::Pointer(Some(Box::new(Value::Int(9)))),
            Value::Pointer(None),
            Value::Bytes(vec![1, 0]),
            Value::Enum(5),
        ]);
        assert_eq!(
            print_value(&f, &v),
            "{2, 2, <<1, 2>, <3, 4>>, *9, NULL, (0x1000000, 0), 5}"
        );
        let empty = Value::Struct(vec![
            Value::Int(0),
            Value::Int(2),
            Value::VarArray(vec![]),
            Value::Pointer(None),
            Value::Pointer(Some(Box::new(v.clone()))),
            Value::Bytes(vec![0, 0]),
            Value::Enum(1),
        ]);
        assert_eq!(
            print_value(&f, &empty),
            "{0, 2, NULL, NULL, *{2, 2, <<1, 2>, <3, 4>>, *9, NULL, (0x1000000, 0), 5}, (0, 0), B}"
        );
    }

    #[test]
    fn long_data_is_truncated_after_five_lines() {
        let f = Format::FixedArray {
            elem: Box::new(Format::Primitive(Primitive::Int)),
            dims: vec![200],
        };
        let v = Value::Array((0..200).map(|_| Value::Int(1234567)).collect());
        let out = log_data(&f, &v);
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(lines.len(), 6, "{out}");
        assert!(lines.iter().all(|l| l.len() <= 80));
        assert!(out.ends_with("...\n"));
        assert!(lines[1].starts_with("     1234567"));
    }
}
