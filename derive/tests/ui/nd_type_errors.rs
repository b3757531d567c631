use courier_derive::IpcMessage;
use courier_wire::{IpcMessage as _, NdVec};

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct WrongDimensions {
    x: i32,
    y: i32,
    #[ipc(len = "x, y")]
    cube: NdVec<f32, 3>,
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct NotAnArray {
    x: i32,
    y: i32,
    #[ipc(len = "x, y")]
    flat: [f32; 6],
}

#[derive(IpcMessage)]
#[ipc(crate = "::courier_wire")]
struct MatrixWithoutSizes {
    rows: i32,
    cols: i32,
    cells: courier_wire::Matrix<f64>,
}

fn main() {
    let _ = WrongDimensions::FORMAT;
    let _ = NotAnArray::FORMAT;
    let _ = MatrixWithoutSizes::FORMAT;
}
