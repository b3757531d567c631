//! The dynamic `Value` against the C library's own marshalling and printing
//! (`tests/fixtures/ipc/c-marshall.tsv`: `IPC_marshall` bytes and
//! `IPC_printData` output of the CMU IPC 3.9.1 C library, see its header):
//! every row's bytes decode (little-endian) and re-encode to the same bytes,
//! decode the same from big-endian input, and print as C printed them.

#[path = "ipc_support.rs"]
mod support;

use courier_wire::format::{parse, Format, FormatRegistry};
use courier_wire::ipc::{
    decode_value_with, encode_value_with, print_value_with, ByteOrder, PrintOptions, Reader, Value,
    Writer,
};

/// `IPC_printData`: the central-log layout with no indent and no final newline.
const PRINT_DATA: PrintOptions = PrintOptions {
    indent: 0,
    line_length: Some(80),
    max_lines: Some(5),
    trailing_newline: false,
};

fn unescape(s: &str) -> String {
    let mut out = String::new();
    let mut it = s.chars();
    while let Some(c) = it.next() {
        if c == '\\' {
            match it.next() {
                Some('n') => out.push('\n'),
                Some('t') => out.push('\t'),
                Some('\\') => out.push('\\'),
                Some(o) => panic!("unknown escape \\{o}"),
                None => panic!("trailing backslash"),
            }
        } else {
            out.push(c);
        }
    }
    out
}

#[test]
fn c_marshall_oracle() {
    let mut reg = FormatRegistry::new();
    reg.define("T1", "{int, {enum : 3}, [double:2,3], double}")
        .unwrap();
    reg.define(
        "T2",
        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
    )
    .unwrap();
    reg.define("Point", "{double, double}").unwrap();
    let resolve = |n: &str| reg.get(n);

    let mut rows = 0;
    for line in include_str!("fixtures/ipc/c-marshall.tsv").lines() {
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        let cols: Vec<&str> = line.split('\t').collect();
        assert_eq!(cols.len(), 4, "{line}");
        let (fs, cvalue, hex, printed) = (cols[0], cols[1], cols[2], unescape(cols[3]));
        let f: Format = parse(fs).unwrap();
        let bytes = support::hex(hex);

        let mut r = Reader::new(&bytes, ByteOrder::Little);
        let v = decode_value_with(&f, &mut r, &resolve)
            .unwrap_or_else(|e| panic!("{fs} {cvalue}: {e}"));
        assert_eq!(r.remaining(), 0, "{fs} {cvalue}");
        let mut w = Writer::new();
        encode_value_with(&f, &v, &mut w, &resolve).unwrap();
        if cvalue == "2" && fs == "boolean" {
            // Any non-zero boolean is TRUE; it is sent back as 1.
            assert_eq!(w.as_bytes(), [1, 0, 0, 0]);
        } else {
            assert_eq!(w.as_bytes(), &bytes[..], "{fs} {cvalue}");
        }

        // The same value from a big-endian host.
        let expanded = courier_wire::format::parse_with(fs, &reg).unwrap();
        let mut be = Vec::new();
        support::encode_be(&expanded, &v, None, &mut be);
        let vb = Value::from_ipc_bytes(&expanded, &be, ByteOrder::Big).unwrap();
        if !cvalue.contains("nan") {
            assert_eq!(vb, v, "{fs} {cvalue} big-endian");
        }

        // IPC_printData printed the C value before marshalling; decoding
        // turns "" and empty var arrays into NULL, which print as such.
        let mut want = printed.clone();
        if cvalue.contains("\"\"") {
            want = want.replace("\"\"", "\"NULL\"");
        }
        if cvalue.contains("(non-NULL pointer)") {
            want = want.replace("<>", "NULL");
        }
        let got = print_value_with(&f, &v, &PRINT_DATA, Some(&resolve));
        assert_eq!(got, want, "{fs} {cvalue}");
        rows += 1;
    }
    assert!(rows >= 90, "{rows} rows");
}
