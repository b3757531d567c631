use courier_derive::IpcMessage;
use courier_wire::{Matrix, NdVec};

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct VecWithTwoSizes {
    rows: i32,
    cols: i32,
    #[ipc(len = "rows, cols")]
    cells: Vec<f64>,
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct BadSizeFields {
    rows: i32,
    narrow: i16,
    text: String,
    #[ipc(len = "rows,,narrow")]
    a: Matrix<f64>,
    #[ipc(len = "rows, narrow")]
    b: Matrix<f64>,
    #[ipc(len = "nope, text")]
    c: Matrix<f64>,
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct SharedSizes {
    n: u32,
    m: u64,
    #[ipc(len = "n, n")]
    square: Matrix<u8>,
    #[ipc(len = "m")]
    line: Vec<u8>,
    #[ipc(len = "m, n")]
    other: Matrix<u8>,
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct KeyedGrid {
    #[ipc(key)]
    x: i32,
    y: i32,
    #[ipc(key, len = "x, y")]
    g: NdVec<u8, 2>,
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct ForgotTheSizes {
    rows: i32,
    cols: i32,
    cells: Matrix<f64>,
    more: courier_wire::NdVec<u8, 3>,
}

fn main() {}
