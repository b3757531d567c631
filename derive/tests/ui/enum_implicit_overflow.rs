use courier_derive::IpcMessage;

#[derive(IpcMessage)]
enum E {
    A = 2147483647,
    B,
}

#[derive(IpcMessage)]
enum F {
    A = 2147483646,
    B,
    C,
}

fn main() {}
