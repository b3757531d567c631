//! The README's first command.
//!
//! Until the Session API lands this prints the IPC manual's Appendix A
//! message types: their IPC format strings (generated at compile time by
//! `#[derive(IpcMessage)]`), their IPC bytes (identical to what the C
//! library marshals) and their CDR bytes as DDS carries them.

use courier::cdr::{self, Encoding};
use courier::{ipc, IpcMessage, NamedFormats};

/// `typedef enum { WaitVal, SendVal, ReceiveVal, ListenVal } STATUS_ENUM`,
/// written in T1 as `{enum : 3}`.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(numeric)]
enum Status {
    Wait,
    Send,
    Receive,
    Listen,
}

/// The same enum in its symbolic form, as T2 writes it.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[allow(clippy::enum_variant_names)] // the manual's names
enum StatusEnum {
    WaitVal,
    SendVal,
    ReceiveVal,
    ListenVal,
}

/// `T1_TYPE`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T1 {
    i1: i32,
    status: Status,
    matrix: [[f64; 3]; 2],
    d1: f64,
}

/// `T2_TYPE`: a string, a count, a variable array of T1 and a status.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T2 {
    str1: String,
    count: i32,
    #[ipc(len = "count")]
    t1: Vec<T1>,
    status: StatusEnum,
}

fn hex(b: &[u8]) -> String {
    b.chunks(4)
        .map(|c| c.iter().map(|x| format!("{x:02x}")).collect::<String>())
        .collect::<Vec<_>>()
        .join(" ")
}

fn show<T: IpcMessage + std::fmt::Debug + PartialEq>(msg: &str, v: &T) {
    println!("{msg}: {v:?}");
    println!("  IPC format  {}", T::FORMAT);
    let named = NamedFormats::of::<T>();
    for (name, fmt) in named.iter() {
        println!("  named format {name} = {fmt}");
    }
    let bytes = ipc::to_vec(v);
    println!("  IPC bytes   ({:>3}) {}", bytes.len(), hex(&bytes));
    assert_eq!(&ipc::from_slice::<T>(&bytes).expect("round trip"), v);
    for enc in [Encoding::Xcdr1Le, Encoding::Xcdr2Le] {
        let c = cdr::to_vec(v, enc);
        println!("  {enc:?} ({:>3}) {}", c.len(), hex(&c));
        assert_eq!(&cdr::from_slice::<T>(&c).expect("round trip"), v);
    }
    println!();
}

fn main() {
    let t1 = T1 {
        i1: 666,
        status: Status::Send,
        matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]],
        d1: std::f64::consts::PI,
    };
    let t2 = T2 {
        str1: "Hello, world".into(),
        count: 1,
        t1: vec![t1.clone()],
        status: StatusEnum::ReceiveVal,
    };
    println!("Courier: the IPC manual's Appendix A messages\n");
    show("message1 (int)", &42i32);
    show("message2 (string)", &String::from("Hello, world"));
    show("query1 (T1)", &t1);
    show("response1 (T2)", &t2);
}
