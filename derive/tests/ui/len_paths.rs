use courier_derive::IpcMessage;

type Count = i32;

mod num {
    #[allow(non_camel_case_types)]
    pub type u32 = std::primitive::u32;
}

#[derive(IpcMessage)]
struct Alias {
    n: Count,
    #[ipc(len = "n")]
    v: Vec<u8>,
}

#[derive(IpcMessage)]
struct OtherPath {
    n: num::u32,
    #[ipc(len = "n")]
    v: Vec<u8>,
}

#[derive(IpcMessage)]
struct NotAnInteger {
    n: f64,
    #[ipc(len = "n")]
    v: Vec<u8>,
}

#[derive(IpcMessage)]
struct DimAlias {
    rows: Count,
    cols: core::primitive::i16,
    #[ipc(len = "rows, cols")]
    m: courier_wire::Matrix<f64>,
}

fn main() {}
