//! Fuzzes the IPC format-string parser and the formatter decoder.
//!
//! - Any UTF-8 input: `parse` must not panic; a format it accepts must print
//!   and parse back to the same tree, and its formatter encoding must decode
//!   back to it.
//! - The raw bytes: `decode_formatter` must not panic; what it accepts must
//!   re-encode to as many bytes as it read.
#![no_main]

use courier_wire::format::{decode_formatter, encode_formatter, parse, Format, FormatRegistry};
use courier_wire::ipc::{ByteOrder, Reader, Writer};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = std::str::from_utf8(data) {
        if let Ok(f) = parse(s) {
            let printed = f.to_string();
            let again = parse(&printed);
            assert_eq!(again.as_ref(), Ok(&f), "{s:?} printed as {printed:?}");
            let _ = f.fixed_wire_size();
            let _ = f.c_size();
            let _ = f.c_align();
            let reg = FormatRegistry::new();
            let _ = reg.resolve(&f);

            let mut w = Writer::new();
            encode_formatter(Some(&f), &mut w);
            let bytes = w.into_vec();
            let mut r = Reader::native(&bytes);
            let decoded = decode_formatter(&mut r).expect("own encoding decodes");
            assert_eq!(decoded.unwrap_or(Format::Empty), f);
            assert_eq!(r.remaining(), 0);
        }
    }

    for order in [ByteOrder::Little, ByteOrder::Big] {
        let mut r = Reader::new(data, order);
        if let Ok(Some(f)) = decode_formatter(&mut r) {
            let used = data.len() - r.remaining();
            let mut w = Writer::new();
            encode_formatter(Some(&f), &mut w);
            assert_eq!(w.len(), used);
            let _ = f.to_string();
            let _ = f.c_size();
        }
    }
});
