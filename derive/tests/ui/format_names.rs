#![allow(non_camel_case_types)]

use courier_derive::IpcMessage;

#[derive(IpcMessage)]
#[ipc(name = "int")]
struct NamedInt {
    a: f64,
}

#[derive(IpcMessage)]
#[ipc(name = "twobyte")]
struct NamedTwobyte {
    a: f64,
}

#[derive(IpcMessage)]
#[ipc(name = "enum")]
struct NamedEnum {
    a: f64,
}

#[derive(IpcMessage)]
#[ipc(name = "3D")]
struct ThreeD {
    a: f64,
}

#[derive(IpcMessage)]
#[ipc(name = "a b")]
struct Spaced {
    a: f64,
}

#[derive(IpcMessage)]
struct double {
    a: i32,
}

#[derive(IpcMessage)]
struct r#enum {
    a: i32,
}

// a primitive name given by the identifier is fine when `name` replaces it,
// and for what has no format name (generic and unit structs)
#[derive(IpcMessage)]
#[ipc(name = "Double")]
struct string {
    a: i32,
}

#[derive(IpcMessage)]
struct long<T> {
    t: T,
}

#[derive(IpcMessage)]
struct int;

fn main() {}
