use courier_derive::IpcMessage;

#[derive(IpcMessage)]
struct Key {
    #[ipc(key = true)]
    id: i32,
    #[ipc(must_understand = false)]
    b: i32,
    #[ipc(char = 1)]
    c: u8,
    #[ipc(key(x))]
    d: i32,
}

#[derive(IpcMessage)]
#[ipc(numeric = true)]
enum Numeric {
    X,
}

fn main() {}
