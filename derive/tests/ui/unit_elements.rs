use courier_derive::IpcMessage;

#[derive(IpcMessage)]
struct Unit;

#[derive(IpcMessage)]
struct InVec {
    n: i32,
    #[ipc(len = "n")]
    v: Vec<Unit>,
}

#[derive(IpcMessage)]
struct InArray {
    a: [[Unit; 2]; 3],
}

#[derive(IpcMessage)]
struct InPointer {
    p: Option<Box<Unit>>,
}

#[derive(IpcMessage)]
struct Generic<T> {
    a: [T; 2],
}

#[derive(IpcMessage)]
struct GenericVec<T> {
    n: u32,
    #[ipc(len = "n")]
    v: Vec<T>,
}

#[derive(IpcMessage)]
struct Stamped<T> {
    stamp: f64,
    t: T,
}

const _: &str = <InVec as courier_wire::IpcMessage>::FORMAT;
const _: &str = <InArray as courier_wire::IpcMessage>::FORMAT;
const _: &str = <InPointer as courier_wire::IpcMessage>::FORMAT;
const _: &str = <Generic<()> as courier_wire::IpcMessage>::FORMAT;
const _: &str = <GenericVec<()> as courier_wire::IpcMessage>::FORMAT;
// the derive cannot see the array in the argument: courier-wire's array
// format refuses it
const _: &str = <Stamped<[Unit; 3]> as courier_wire::IpcMessage>::FORMAT;

fn main() {}
