use std::collections::HashMap;

use courier_derive::IpcMessage;

#[derive(IpcMessage)]
struct BadLen {
    count: i32,
    name: String,
    #[ipc(len = "cnt")]
    a: Vec<i32>,
    #[ipc(len = "name")]
    b: Vec<i32>,
}

#[derive(IpcMessage)]
#[ipc(nmae = "X")]
struct UnknownAttributes {
    #[ipc(length = "n", key)]
    n: i32,
}

#[derive(IpcMessage)]
struct Unsupported {
    map: HashMap<String, i32>,
    size: usize,
    maybe: Option<i32>,
    text: &'static str,
}

#[derive(IpcMessage)]
struct BadBound {
    #[ipc(bound = 5)]
    x: i32,
    #[ipc(bound = 0)]
    s: String,
    #[ipc(bound = 3)]
    a: [i32; 4],
    #[ipc(bound = "3")]
    v: Vec<i32>,
}

#[derive(IpcMessage)]
#[ipc(name = "A", name = "B")]
struct Twice {
    #[ipc(char, char)]
    c: u8,
    #[ipc(key)]
    #[ipc(key)]
    k: i32,
}

fn main() {}
