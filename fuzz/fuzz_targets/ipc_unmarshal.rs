//! Fuzzes the dynamic IPC unmarshaller (`courier_wire::ipc::decode_value`):
//! the first byte picks one of a fixed set of formats (T1 and T2 of ipc.md
//! §10 E4/E5, the E7 rows, recursive lists, internal-message formats with
//! `format` fields), the rest is decoded in both byte orders. Decoding must
//! never panic; whatever decodes must re-encode (native order) to bytes of
//! the same length that decode to a value re-encoding to the same bytes, and
//! the printer must accept it.
#![no_main]

use courier_wire::format::{parse, Format, FormatRegistry};
use courier_wire::ipc::{
    decode_value_with, encode_value_with, log_data, print_value_with, ByteOrder, PrintOptions,
    Reader, Value, Writer,
};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

const FORMATS: &[&str] = &[
    // ipc.md §10 E4 / E5
    "{int, {enum : 3}, [double:2,3], double}",
    "{string, int, <{int, {enum : 3}, [double:2,3], double}:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}",
    // E7 rows
    "string",
    "long",
    "boolean",
    "{char, double, short}",
    "[string:2]",
    "*int",
    "{int, *!}",
    "{int, int, <double:1,2>}",
    "{string, int, <int:2>, {enum Red, Green, Blue}, boolean}",
    "{int, <byte:1>}",
    // recursive lists and trees, named and self-referential
    "List",
    "{string, *!, *!}",
    "{<List:2>, int}",
    // internal messages (ipc.md §6), with `format` fields
    "*{int, string, int, format, format}",
    "{int, int, <string:2>}",
    "{int, <{int, int, int, int, string, string}:1>}",
    "{*int, ushort, uint, ulong, byte, ubyte, twobyte, float, 3, [char:2,2], {enum : 300}}",
];

struct Set {
    registry: FormatRegistry,
    formats: Vec<Format>,
}

fn set() -> &'static Set {
    static SET: OnceLock<Set> = OnceLock::new();
    SET.get_or_init(|| {
        let mut registry = FormatRegistry::new();
        registry.define("List", "{int, *List}").unwrap();
        let formats = FORMATS.iter().map(|s| parse(s).unwrap()).collect();
        Set { registry, formats }
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let set = set();
    let f = &set.formats[pick as usize % set.formats.len()];
    let resolve = |n: &str| set.registry.get(n);
    for order in [ByteOrder::Little, ByteOrder::Big] {
        let mut r = Reader::new(rest, order);
        let Ok(v) = decode_value_with(f, &mut r, &resolve) else {
            continue;
        };
        let used = r.position();
        let mut w = Writer::new();
        encode_value_with(f, &v, &mut w, &resolve).expect("a decoded value re-encodes");
        let once = w.into_vec();
        assert_eq!(once.len(), used, "re-encoding changed the size");
        let mut r2 = Reader::new(&once, ByteOrder::NATIVE);
        let v2: Value = decode_value_with(f, &mut r2, &resolve).expect("re-encoded bytes decode");
        assert_eq!(r2.remaining(), 0);
        let mut w2 = Writer::new();
        encode_value_with(f, &v2, &mut w2, &resolve).unwrap();
        assert_eq!(
            w2.as_bytes(),
            &once[..],
            "encode/decode/encode is not stable"
        );
        if order == ByteOrder::NATIVE && !FORMATS[pick as usize % FORMATS.len()].contains("boolean")
        {
            // Only booleans (any non-zero is TRUE) and the string filler byte
            // are normalised; formats without them re-encode byte for byte
            // unless a zero-length string's filler was not 'Z'.
            let fillers_ok = once == rest[..used];
            if !fillers_ok {
                assert!(
                    FORMATS[pick as usize % FORMATS.len()].contains("string")
                        || FORMATS[pick as usize % FORMATS.len()].contains("format"),
                    "bytes changed on re-encode"
                );
            }
        }
        let _ = log_data(f, &v);
        let _ = print_value_with(f, &v, &PrintOptions::ONE_LINE, Some(&resolve));
    }
});
