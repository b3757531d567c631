//! Property tests: every value survives a CDR round trip in all four
//! encodings (XCDR1/XCDR2 × LE/BE), with and without encapsulation header.

mod cdr_types;

use cdr_types::*;
use courier_wire::cdr::{self, Encoding};
use courier_wire::IpcMessage;
use proptest::prelude::*;

const ALL: [Encoding; 4] = [
    Encoding::Xcdr1Le,
    Encoding::Xcdr1Be,
    Encoding::Xcdr2Le,
    Encoding::Xcdr2Be,
];

fn round_trip<T: IpcMessage + PartialEq + std::fmt::Debug>(v: &T) -> Result<(), TestCaseError> {
    for enc in ALL {
        let b = cdr::to_vec(v, enc);
        let back: T =
            cdr::from_slice(&b).map_err(|e| TestCaseError::fail(format!("{enc:?}: {e}")))?;
        prop_assert_eq!(&back, v, "{:?}", enc);
        // the same with 0–3 bytes of padding, as DDS writers send it
        let mut padded = b.clone();
        padded.resize(b.len().div_ceil(4) * 4, 0);
        prop_assert_eq!(&cdr::from_slice::<T>(&padded).unwrap(), v);
        // a buffer sized in advance changes nothing in the bytes, whatever the hint
        for hint in [0, 1, b.len(), 4 * b.len()] {
            prop_assert_eq!(
                &cdr::to_vec_with_capacity(v, enc, hint),
                &b,
                "hint {}",
                hint
            );
        }
        let h = cdr::to_vec_headerless(v, enc);
        prop_assert_eq!(&h[..], &b[4..], "headerless bytes, {:?}", enc);
        prop_assert_eq!(&cdr::from_slice_headerless::<T>(&h, enc).unwrap(), v);
    }
    Ok(())
}

fn f64s() -> impl Strategy<Value = f64> {
    prop::num::f64::NORMAL
        | prop::num::f64::ZERO
        | prop::num::f64::SUBNORMAL
        | prop::num::f64::INFINITE
}

fn f32s() -> impl Strategy<Value = f32> {
    prop::num::f32::NORMAL | prop::num::f32::ZERO | prop::num::f32::INFINITE
}

fn color() -> impl Strategy<Value = Color> {
    prop_oneof![Just(Color::Red), Just(Color::Green), Just(Color::Blue)]
}

fn point() -> impl Strategy<Value = Point> {
    (any::<i32>(), f64s()).prop_map(|(x, y)| Point { x, y })
}

fn latin1() -> impl Strategy<Value = char> {
    (0u8..=255).prop_map(char::from)
}

fn prims() -> impl Strategy<Value = Prims> {
    (
        (
            any::<i8>(),
            any::<u8>(),
            any::<i16>(),
            any::<u16>(),
            any::<i32>(),
            any::<u32>(),
            any::<i64>(),
        ),
        (
            any::<u64>(),
            f32s(),
            f64s(),
            any::<bool>(),
            latin1(),
            color(),
        ),
    )
        .prop_map(|((a, b, c, d, e, f, g), (h, i, j, k, l, m))| Prims {
            a,
            b,
            c,
            d,
            e,
            f,
            g,
            h,
            i,
            j,
            k,
            l,
            m,
        })
}

fn app_inner() -> impl Strategy<Value = AppInner> {
    (any::<i16>(), ".{0,8}").prop_map(|(v, s)| AppInner { v, s })
}

fn boxed<T: std::fmt::Debug + Clone + 'static>(
    s: impl Strategy<Value = T>,
) -> impl Strategy<Value = Option<Box<T>>> {
    prop::option::of(s.prop_map(Box::new))
}

fn mutable() -> impl Strategy<Value = Mut> {
    (
        (
            any::<i8>(),
            any::<i16>(),
            any::<i32>(),
            any::<i64>(),
            ".{0,10}",
            color(),
            any::<bool>(),
            point(),
        ),
        (
            prop::collection::vec(any::<i32>(), 0..5),
            prop::collection::vec(any::<i16>(), 0..5),
            prop::collection::vec(any::<u8>(), 0..9),
            prop::collection::vec(f64s(), 0..4),
            prop::collection::vec(point(), 0..3),
            any::<[i32; 2]>(),
            [".{0,4}", ".{0,4}"],
            boxed(any::<i32>()),
            boxed(point()),
        ),
    )
        .prop_map(
            |(
                (a, b, c, d, s, color, flag, p),
                (si32, si16, su8, sf64, spts, arr, sarr, opt, optp),
            )| Mut {
                a,
                b,
                c,
                d,
                s,
                color,
                flag,
                p,
                si32,
                si16,
                su8,
                sf64,
                spts,
                arr,
                sarr,
                opt,
                optp,
            },
        )
}

fn nested() -> impl Strategy<Value = Nested> {
    (
        any::<u8>(),
        point(),
        prop::collection::vec(point(), 0..4),
        [point(), point()],
        any::<[[i16; 3]; 2]>(),
        [".{0,5}", ".{0,5}"],
        prop::collection::vec(
            prop::collection::vec(any::<i32>(), 0..4).prop_map(SeqI32),
            0..4,
        ),
    )
        .prop_map(|(tag, p, pts, arr, grid, names, seqseq)| Nested {
            tag,
            p,
            pts,
            arr,
            grid: Grid(grid),
            names,
            seqseq,
        })
}

fn node() -> impl Strategy<Value = Node> {
    let leaf = any::<u8>().prop_map(|v| Node { v, next: None });
    leaf.prop_recursive(8, 16, 1, |inner| {
        (any::<u8>(), boxed(inner)).prop_map(|(v, next)| Node { v, next })
    })
}

fn tree() -> impl Strategy<Value = Tree> {
    Just(Tree::default()).prop_recursive(4, 32, 4, |inner| {
        prop::collection::vec(inner, 0..4).prop_map(|children| Tree { children })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn primitives(p in prims()) {
        round_trip(&p)?;
        round_trip(&p.g)?;
        round_trip(&p.c)?;
        round_trip(&p.l)?;
        round_trip(&p.k)?;
        round_trip(&p.j)?;
    }

    #[test]
    fn strings(s in ".{0,40}", list in prop::collection::vec(".{0,6}", 0..5), b in any::<u8>()) {
        round_trip(&s)?;
        round_trip(&Strings { empty: String::new(), hello: s, b, list })?;
    }

    #[test]
    fn sequences(i32 in prop::collection::vec(any::<i32>(), 0..8),
                 i16 in prop::collection::vec(any::<i16>(), 0..8),
                 u8 in prop::collection::vec(any::<u8>(), 0..8),
                 f64 in prop::collection::vec(f64s(), 0..8),
                 flags in prop::collection::vec(any::<bool>(), 0..8),
                 colors in prop::collection::vec(color(), 0..8),
                 empty in prop::collection::vec(any::<i64>(), 0..3)) {
        round_trip(&Seqs { i32, i16, u8, f64, flags, colors, empty })?;
    }

    #[test]
    fn nested_structs(n in nested(), items in prop::collection::vec(app_inner(), 0..4), inner in app_inner(), id in any::<i32>(), d in f64s()) {
        round_trip(&n)?;
        round_trip(&App { id, inner, d, items })?;
    }

    #[test]
    fn mutable_structs(m in mutable()) {
        round_trip(&m)?;
    }

    #[test]
    fn optionals(a in any::<u8>(), x in boxed(any::<i32>()), d in boxed(f64s()), s in boxed(".{0,6}"), z in any::<i16>()) {
        round_trip(&Opt { a, x, d, s, z })?;
    }

    #[test]
    fn recursive_types(n in node(), t in tree()) {
        round_trip(&n)?;
        round_trip(&t)?;
    }
}

/// With the size of the last sample as the hint, a large sample is
/// written without growing its buffer (room for the envelope included).
#[test]
fn a_sized_buffer_takes_the_sample_and_its_tail_room_without_growing() {
    let v: String = "x".repeat(4096);
    let first = cdr::to_vec(&v, Encoding::Xcdr1Le);
    let again = cdr::to_vec_with_capacity(&v, Encoding::Xcdr1Le, first.len());
    assert_eq!(again, first);
    assert!(
        again.capacity() >= first.len() + cdr::TAIL_ROOM
            && again.capacity() < first.len() + 2 * cdr::TAIL_ROOM,
        "capacity {} for {} bytes",
        again.capacity(),
        first.len()
    );
}
