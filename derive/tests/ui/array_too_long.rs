use courier_derive::IpcMessage;

// more elements than C's int can count: refused when the format is built
#[derive(IpcMessage)]
struct Huge {
    d: [u8; 3_000_000_000],
}

fn main() {
    let _ = <Huge as courier_wire::IpcMessage>::FORMAT;
}
