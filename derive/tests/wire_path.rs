//! The derive used from a crate that depends on `courier-wire` alone:
//! `#[ipc(crate = "::courier_wire")]` points generated code at it.

use courier_derive::IpcMessage;
use courier_wire::{cdr, ipc, IpcMessage as _, NamedFormats};

#[derive(IpcMessage, Debug, PartialEq)]
#[ipc(crate = "::courier_wire", numeric)]
enum Status {
    Wait,
    Send,
    Receive,
    Listen,
}

#[derive(IpcMessage, Debug, PartialEq)]
#[ipc(crate = "::courier_wire")]
struct T1 {
    i1: i32,
    status: Status,
    matrix: [[f64; 3]; 2],
    d1: f64,
}

#[derive(IpcMessage, Debug, PartialEq)]
#[ipc(crate = "::courier_wire", extensibility = "mutable")]
struct T2 {
    str1: String,
    count: i32,
    #[ipc(len = "count")]
    t1: Vec<T1>,
    status: Status,
}

#[test]
fn formats_and_round_trips() {
    assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
    assert_eq!(T2::FORMAT, "{string, int, <T1:2>, {enum : 3}}");
    assert_eq!(NamedFormats::of::<T2>().len(), 2);
    let t2 = T2 {
        str1: "Hello, world".into(),
        count: 1,
        t1: vec![T1 {
            i1: 666,
            status: Status::Send,
            matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]],
            d1: std::f64::consts::PI,
        }],
        status: Status::Receive,
    };
    let bytes = ipc::to_vec(&t2);
    assert_eq!(bytes.len(), 92);
    assert_eq!(ipc::from_slice::<T2>(&bytes).unwrap(), t2);
    for enc in [cdr::Encoding::Xcdr1Le, cdr::Encoding::Xcdr2Be] {
        assert_eq!(cdr::from_slice::<T2>(&cdr::to_vec(&t2, enc)).unwrap(), t2);
    }
}
