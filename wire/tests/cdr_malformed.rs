//! Malformed input: the decoder returns an error (never panics, never
//! allocates for counts the input cannot hold) and tolerates what DDS
//! tolerates (unknown optional members, appended members).

mod cdr_types;

use cdr_types::*;
use courier_wire::cdr::{self, DecodeError, Encoding, Extensibility, Writer};
use courier_wire::IpcMessage;
use proptest::prelude::*;

const SUFFIXES: [&str; 4] = ["x1le", "x1be", "x2le", "x2be"];

/// Every proper prefix of a golden payload fails to decode.
fn truncations<T: IpcMessage + std::fmt::Debug>(case: &str) {
    for s in SUFFIXES {
        let golden = fixture(&format!("{case}_{s}"));
        cdr::from_slice::<T>(&golden).unwrap();
        for n in 0..golden.len() {
            let r = cdr::from_slice::<T>(&golden[..n]);
            assert!(
                r.is_err(),
                "{case}_{s} truncated to {n} bytes decoded as {r:?}"
            );
        }
    }
}

#[test]
fn truncated_at_every_position() {
    truncations::<Prims>("prims");
    truncations::<Strings>("strings");
    truncations::<Seqs>("seqs");
    truncations::<Nested>("nested");
    truncations::<App>("appendable");
    truncations::<Mut>("mutable");
    truncations::<Mut>("mutable_absent");
    truncations::<Opt>("optional_present");
    truncations::<Opt>("optional_absent");
    truncations::<Keyed>("keyed");
    truncations::<MutKeyed>("mutkeyed");
}

fn set_u32(b: &mut [u8], at: usize, v: u32, le: bool) {
    let x = if le { v.to_le_bytes() } else { v.to_be_bytes() };
    b[at..at + 4].copy_from_slice(&x);
}

#[test]
fn bad_encapsulation_header() {
    assert_eq!(
        cdr::from_slice::<i32>(&[0, 1]),
        Err(DecodeError::MissingHeader(2))
    );
    assert_eq!(
        cdr::from_slice::<i32>(&[]),
        Err(DecodeError::MissingHeader(0))
    );
    for id in [
        0x0004u16, 0x0005, 0x000c, 0x0010, 0x0011, 0x0015, 0x8001, 0xffff,
    ] {
        let mut b = id.to_be_bytes().to_vec();
        b.extend_from_slice(&[0, 0, 1, 0, 0, 0]);
        assert_eq!(
            cdr::from_slice::<i32>(&b),
            Err(DecodeError::UnknownRepresentation(id)),
            "{id:#06x}"
        );
    }
}

#[test]
fn dheader_past_the_end() {
    // D_CDR2_LE HelloAppendable: DHEADER claims more than there is
    let mut b = fixture("pcap_dcdr2_le_appendable");
    set_u32(&mut b, 4, 0x7fff_fff0, true);
    assert!(matches!(
        cdr::from_slice::<HelloAppendable>(&b),
        Err(DecodeError::BadLength {
            what: "DHEADER",
            ..
        })
    ));
    // DHEADER shorter than the members: the string runs past its region
    let mut b = fixture("pcap_dcdr2_le_appendable");
    set_u32(&mut b, 4, 10, true);
    assert!(cdr::from_slice::<HelloAppendable>(&b).is_err());
}

#[test]
fn sequence_count_past_the_end_does_not_allocate() {
    for s in SUFFIXES {
        let mut b = fixture(&format!("seqs_{s}"));
        let le = s.ends_with("le");
        // the first member is sequence<int32>: its count is at offset 4 (after the header)
        set_u32(&mut b, 4, u32::MAX, le);
        assert!(
            matches!(
                cdr::from_slice::<Seqs>(&b),
                Err(DecodeError::CountTooLarge { .. })
            ),
            "{s}"
        );
        // strings: a length of 4 GiB
        let mut b = fixture(&format!("strings_{s}"));
        set_u32(&mut b, 4, u32::MAX - 1, le);
        assert!(
            matches!(
                cdr::from_slice::<Strings>(&b),
                Err(DecodeError::CountTooLarge { .. })
            ),
            "{s}"
        );
    }
    // sequence of structs in XCDR2: DHEADER fits but the count does not
    let mut w = Writer::with_header(Encoding::Xcdr2Le, Extensibility::Final);
    let d = w.begin_dheader();
    w.write_u32(0x1000_0000);
    w.end_dheader(d);
    let b = w.into_vec();
    assert!(cdr::from_slice::<Vec2>(&b).is_err());
}

/// `sequence<Point>` as a top-level type.
#[derive(Debug, PartialEq)]
struct Vec2(Vec<Point>);
impl IpcMessage for Vec2 {
    type Key = Self;
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        Self::cdr_decode(r)
    }
    const FORMAT: &'static str = "<{int, double}:1>";
    const TYPE_NAME: &'static str = "Vec2";
    const IPC_MIN_SIZE: usize = 4;
    const CDR_MIN_SIZE: usize = 4;
    fn ipc_encode(&self, _: &mut courier_wire::ipc::Writer) {}
    fn ipc_decode(
        _: &mut courier_wire::ipc::Reader<'_>,
    ) -> Result<Self, courier_wire::ipc::DecodeError> {
        Err(courier_wire::ipc::DecodeError::Format("CDR only".into()))
    }
    fn cdr_encode(&self, w: &mut Writer) {
        courier_wire::__private::cdr_encode_seq(&self.0, w);
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        courier_wire::__private::cdr_decode_seq(r).map(Vec2)
    }
}

#[test]
fn emheader_and_parameter_lengths_past_the_end() {
    // PL_CDR2: the string member's LC 5 length (= string length) is too big
    let mut b = fixture("pcap_plcdr2_le_mutable");
    set_u32(&mut b, 16, 0x0100_0000, true);
    assert!(matches!(
        cdr::from_slice::<HelloMutable>(&b),
        Err(DecodeError::BadLength {
            what: "EMHEADER",
            ..
        })
    ));
    // LC 4 NEXTINT too big (member `p`, a struct, in the Mut golden)
    let golden = fixture("mutable_x2le");
    let at = find_u32(&golden, 0x4000_0007, true).expect("EMHEADER of p");
    let mut b = golden.clone();
    set_u32(&mut b, at + 4, 0xffff_fff0, true);
    assert!(matches!(
        cdr::from_slice::<Mut>(&b),
        Err(DecodeError::BadLength { .. })
    ));
    // LC 7 count * 8 overflowing the region
    let at = find_u32(&golden, 0x7000_000b, true).expect("EMHEADER of sf64");
    let mut b = golden.clone();
    set_u32(&mut b, at + 4, 0xffff_ffff, true);
    assert!(matches!(
        cdr::from_slice::<Mut>(&b),
        Err(DecodeError::BadLength { .. })
    ));
    // XCDR1 extended parameter length too big
    let mut b = fixture("mutable_x1le");
    set_u32(&mut b, 12, 0x7fff_ffff, true);
    assert!(matches!(
        cdr::from_slice::<Mut>(&b),
        Err(DecodeError::BadLength { .. })
    ));
    // XCDR1 optional member length too big
    let mut b = fixture("optional_present_x1le");
    set_u32(&mut b, 16, 1000, true);
    assert!(matches!(
        cdr::from_slice::<Opt>(&b),
        Err(DecodeError::BadLength { .. })
    ));
    // XCDR1 optional member without PL header
    let mut b = fixture("optional_present_x1le");
    b[8] = 0;
    assert!(matches!(
        cdr::from_slice::<Opt>(&b),
        Err(DecodeError::Malformed { .. })
    ));
}

fn find_u32(b: &[u8], v: u32, le: bool) -> Option<usize> {
    let x = if le { v.to_le_bytes() } else { v.to_be_bytes() };
    (4..b.len().saturating_sub(3))
        .step_by(4)
        .find(|&i| b[i..i + 4] == x)
}

/// A newer version of `HelloMutable` / `HelloAppendable` with an extra member.
#[derive(Debug, Clone, PartialEq, Default)]
struct HelloV2 {
    id: i32,
    msg: String,
    extra: u64,
}

fn hello_v2(ext: Extensibility, extra_id: u32, must_understand: bool, enc: Encoding) -> Vec<u8> {
    let v = HelloV2 {
        id: 5,
        msg: "v2".into(),
        extra: 99,
    };
    let mut w = Writer::with_header(enc, ext);
    let s = w.begin_struct(ext);
    let m = s.begin_member(&mut w, 0, false);
    v.id.cdr_encode(&mut w);
    s.end_member(&mut w, m);
    let m = s.begin_member(&mut w, extra_id, must_understand);
    v.extra.cdr_encode(&mut w);
    s.end_member(&mut w, m);
    let m = s.begin_member(&mut w, 1, false);
    v.msg.cdr_encode(&mut w);
    s.end_member(&mut w, m);
    s.end(&mut w);
    w.into_vec()
}

#[test]
fn mutable_unknown_members() {
    let want = HelloMutable {
        id: 5,
        msg: "v2".into(),
    };
    for enc in [
        Encoding::Xcdr1Le,
        Encoding::Xcdr1Be,
        Encoding::Xcdr2Le,
        Encoding::Xcdr2Be,
    ] {
        // unknown, not must-understand: skipped (XCDR1 ids above 0x3f00 too)
        for id in [7, 0x3f05, 0x0fff_fff0] {
            let b = hello_v2(Extensibility::Mutable, id, false, enc);
            assert_eq!(
                cdr::from_slice::<HelloMutable>(&b),
                Ok(want.clone()),
                "{enc:?} {id}"
            );
        }
        // unknown and must-understand: an error
        let b = hello_v2(Extensibility::Mutable, 7, true, enc);
        assert!(
            matches!(
                cdr::from_slice::<HelloMutable>(&b),
                Err(DecodeError::UnknownMustUnderstand { id: 7, .. })
            ),
            "{enc:?}"
        );
    }
}

#[test]
fn appendable_tolerates_appended_members() {
    // v1 reader, v2 writer with a member appended at the end
    for enc in [Encoding::Xcdr2Le, Encoding::Xcdr2Be] {
        let mut w = Writer::with_header(enc, Extensibility::Appendable);
        let s = w.begin_struct(Extensibility::Appendable);
        for (id, f) in [(0u32, 0u8), (1, 1), (2, 2)] {
            let m = s.begin_member(&mut w, id, false);
            match f {
                0 => 5i32.cdr_encode(&mut w),
                1 => String::from("v2").cdr_encode(&mut w),
                _ => 1.5f64.cdr_encode(&mut w),
            }
            s.end_member(&mut w, m);
        }
        s.end(&mut w);
        let b = w.into_vec();
        assert_eq!(
            cdr::from_slice::<HelloAppendable>(&b),
            Ok(HelloAppendable {
                id: 5,
                msg: "v2".into()
            })
        );
        // also inside a sequence: the next element starts after the DHEADER region
        let items = vec![
            AppInner {
                v: 1,
                s: "a".into(),
            },
            AppInner {
                v: 2,
                s: "b".into(),
            },
        ];
        let app = App {
            id: 1,
            inner: AppInner::default(),
            d: 0.0,
            items,
        };
        let bytes = cdr::to_vec(&app, enc);
        assert_eq!(cdr::from_slice::<App>(&bytes).unwrap(), app);
    }
}

#[test]
fn depth_is_limited() {
    // a linked list deeper than MAX_DEPTH, through optional pointers
    for enc in [Encoding::Xcdr1Le, Encoding::Xcdr2Le] {
        let mut n = Node { v: 0, next: None };
        for _ in 0..cdr::MAX_DEPTH + 10 {
            n = Node {
                v: 1,
                next: Some(Box::new(n)),
            };
        }
        let b = cdr::to_vec(&n, enc);
        // drop the list iteratively (a deep Box chain would overflow on drop)
        let mut next = n.next.take();
        while let Some(mut x) = next {
            next = x.next.take();
        }
        assert!(
            matches!(
                cdr::from_slice::<Node>(&b),
                Err(DecodeError::TooDeep { .. })
            ),
            "{enc:?}"
        );
    }
    // a deep tree through sequences, built as raw bytes: XCDR1 `count 1` repeated
    let mut b = vec![0, 1, 0, 0];
    for _ in 0..100_000 {
        b.extend_from_slice(&1u32.to_le_bytes());
    }
    assert!(matches!(
        cdr::from_slice::<Tree>(&b),
        Err(DecodeError::TooDeep { .. })
    ));
    // XCDR2: DHEADER + count per level
    let mut b = vec![0, 9, 0, 0];
    let levels = 50_000u32;
    for i in 0..levels {
        let rest = (levels - i) * 12;
        b.extend_from_slice(&(rest - 4).to_le_bytes()); // struct DHEADER
        b.extend_from_slice(&(rest - 8).to_le_bytes()); // sequence DHEADER
        b.extend_from_slice(&1u32.to_le_bytes()); // count
    }
    assert!(matches!(
        cdr::from_slice::<Tree>(&b),
        Err(DecodeError::TooDeep { .. })
    ));
}

#[test]
fn trailing_bytes_beyond_padding_are_an_error() {
    let mut b = fixture("point_x1le");
    b.extend_from_slice(&[0; 4]);
    assert!(matches!(
        cdr::from_slice::<Point>(&b),
        Err(DecodeError::TrailingBytes { .. })
    ));
}

#[test]
fn invalid_values() {
    let mut b = fixture("prims_x1le");
    let k = b.len() - 8; // bool k, char l, pad, enum m
    b[k] = 2;
    assert!(matches!(
        cdr::from_slice::<Prims>(&b),
        Err(DecodeError::InvalidBool { byte: 2, .. })
    ));
    let mut b = fixture("prims_x1le");
    let n = b.len();
    b[n - 4] = 7;
    assert!(matches!(
        cdr::from_slice::<Prims>(&b),
        Err(DecodeError::InvalidEnum { value: 7, .. })
    ));
    // string without NUL, invalid UTF-8
    let b = [0, 1, 0, 0, 2, 0, 0, 0, b'a', b'b'];
    assert!(matches!(
        cdr::from_slice::<String>(&b),
        Err(DecodeError::UnterminatedString { .. })
    ));
    let b = [0, 1, 0, 0, 2, 0, 0, 0, 0xff, 0];
    assert!(matches!(
        cdr::from_slice::<String>(&b),
        Err(DecodeError::InvalidUtf8 { .. })
    ));
}

fn no_panic<T: IpcMessage>(b: &[u8]) {
    if let Ok(v) = cdr::from_slice::<T>(b) {
        let enc = cdr::Reader::with_header(b).unwrap().encoding();
        let again = cdr::to_vec(&v, enc);
        let w: T = cdr::from_slice(&again).expect("own encoding decodes");
        assert_eq!(cdr::to_vec(&w, enc), again);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Arbitrary bytes, and golden payloads with random bytes changed, never panic.
    #[test]
    fn random_bytes_never_panic(id in 0u16..12, body in prop::collection::vec(any::<u8>(), 0..200)) {
        let mut b = id.to_be_bytes().to_vec();
        b.extend_from_slice(&[0, 0]);
        b.extend_from_slice(&body);
        no_panic::<Mut>(&b);
        no_panic::<App>(&b);
        no_panic::<Opt>(&b);
        no_panic::<Nested>(&b);
        no_panic::<Tree>(&b);
    }

    #[test]
    fn mutated_goldens_never_panic(which in 0usize..4, s in 0usize..4, edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4)) {
        let case = ["mutable", "appendable", "optional_present", "nested"][which];
        let mut b = fixture(&format!("{case}_{}", SUFFIXES[s]));
        for (i, v) in edits {
            let i = 4 + i.index(b.len() - 4);
            b[i] = v;
        }
        no_panic::<Mut>(&b);
        no_panic::<App>(&b);
        no_panic::<Opt>(&b);
        no_panic::<Nested>(&b);
    }
}

#[test]
fn xcdr1_short_parameter_headers_and_pid_ignore() {
    // PL_CDR_LE as writers using the short form send it (RTI, older Cyclone)
    let b = [
        0x00, 0x03, 0x00, 0x00, // PL_CDR_LE
        0x03, 0x3f, 0x04, 0x00, 0xaa, 0xbb, 0xcc, 0xdd, // PID_IGNORE, 4 bytes
        0x00, 0x00, 0x04, 0x00, 0x05, 0x00, 0x00, 0x00, // id 0: 5
        0x01, 0x00, 0x08, 0x00, 0x03, 0x00, 0x00, 0x00, b'v', b'2', 0, 0, // id 1: "v2"
        0x07, 0x00, 0x04, 0x00, 0x01, 0x02, 0x03, 0x04, // unknown id 7, not must-understand
        0x02, 0x3f, 0x00, 0x00, // sentinel without FLAG_MU
    ];
    assert_eq!(
        cdr::from_slice::<HelloMutable>(&b),
        Ok(HelloMutable {
            id: 5,
            msg: "v2".into()
        })
    );
    let mut mu = b;
    mu[33] = 0x40; // id 7 with FLAG_MU
    assert!(matches!(
        cdr::from_slice::<HelloMutable>(&mu),
        Err(DecodeError::UnknownMustUnderstand { id: 7, .. })
    ));
    let mut bad = b;
    bad[22] = 0x20; // parameter length 0x20 past the end
    assert!(matches!(
        cdr::from_slice::<HelloMutable>(&bad),
        Err(DecodeError::BadLength { .. })
    ));
}
