use courier_derive::IpcMessage;

#[derive(IpcMessage)]
struct Inner {
    x: i32,
}

#[derive(IpcMessage)]
struct K {
    #[ipc(key)]
    o: Option<Box<Inner>>,
    #[ipc(key)]
    f: f64,
}

#[derive(IpcMessage)]
struct List {
    #[ipc(key)]
    next: Option<Box<List>>,
}

fn main() {}
