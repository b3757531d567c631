//! Fuzzes the CDR decoder: arbitrary bytes (the first two choose the
//! encapsulation: XCDR1/XCDR2, LE/BE, final/appendable/mutable ids) are
//! decoded as several types shaped like `#[derive(IpcMessage)]` output: a
//! final struct with optionals, appendable structs with nested appendable
//! sequences, a mutable struct with every length code, sequences, strings and
//! optionals, and recursive types. Decoding must never panic; whatever decodes
//! must re-encode to bytes that decode and re-encode to the same bytes.
//! The types are wire/tests/cdr_types/mod.rs's.
#![no_main]

// The types the `cdr_*` tests use, so that fuzzing and the tests exercise
// the same shapes (one definition, not a copy that drifts).
#[path = "../../wire/tests/cdr_types/mod.rs"]
mod cdr_types;

use cdr_types::{App, Mut, Node, Opt, Tree};
use courier_wire::cdr::{self, Encoding};
use courier_wire::IpcMessage;
use libfuzzer_sys::fuzz_target;

fn round_trip<T: IpcMessage>(data: &[u8]) {
    let Ok(v) = cdr::from_slice::<T>(data) else {
        return;
    };
    let enc = cdr::Reader::with_header(data)
        .expect("decoded, so the header is valid")
        .encoding();
    let once = cdr::to_vec(&v, enc);
    let again: T =
        cdr::from_slice(&once).unwrap_or_else(|e| panic!("own encoding does not decode: {e}"));
    assert_eq!(cdr::to_vec(&again, enc), once, "encoding is not stable");
    // the other encodings too
    for e in [
        Encoding::Xcdr1Le,
        Encoding::Xcdr1Be,
        Encoding::Xcdr2Le,
        Encoding::Xcdr2Be,
    ] {
        let b = cdr::to_vec(&v, e);
        let w: T = cdr::from_slice(&b).unwrap_or_else(|err| panic!("{e:?}: {err}"));
        assert_eq!(cdr::to_vec(&w, e), b);
    }
}

fuzz_target!(|data: &[u8]| {
    round_trip::<Opt>(data);
    round_trip::<App>(data);
    round_trip::<Mut>(data);
    round_trip::<Node>(data);
    round_trip::<Tree>(data);
});
