use courier_derive::IpcMessage;

#[derive(IpcMessage)]
enum Negative {
    Below = -1,
    Zero = 0,
}

#[derive(IpcMessage)]
enum Carrying {
    Empty,
    Point { x: f64, y: f64 },
    Id(i32),
}

#[derive(IpcMessage)]
union Raw {
    i: i32,
    f: f32,
}

fn main() {}
