//! The message types of the IPC manual's Appendix A (`module.h`), shared
//! by the module1, module2 and module3 examples (through the examples'
//! library) and by courier-bench's `session-bench`, which includes this file.
#![allow(dead_code)] // each includer uses part of it

use courier::IpcMessage;

/// `typedef enum { WaitVal, SendVal, ReceiveVal, ListenVal } STATUS_ENUM`,
/// written in T1 as `{enum : 3}`.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(numeric)]
pub enum Status {
    /// `WaitVal`.
    Wait,
    /// `SendVal`.
    Send,
    /// `ReceiveVal`.
    Receive,
    /// `ListenVal`.
    Listen,
}

/// The same enum in its symbolic form, as T2 writes it.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[allow(clippy::enum_variant_names)] // the manual's names
pub enum StatusEnum {
    /// `WaitVal`.
    WaitVal,
    /// `SendVal`.
    SendVal,
    /// `ReceiveVal`.
    ReceiveVal,
    /// `ListenVal`.
    ListenVal,
}

/// `T1_TYPE`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
pub struct T1 {
    /// `int i1`.
    pub i1: i32,
    /// `STATUS_ENUM status`.
    pub status: Status,
    /// `double matrix[2][3]`.
    pub matrix: [[f64; 3]; 2],
    /// `double d1`.
    pub d1: f64,
}

/// `T2_TYPE`: a string, a count, a variable array of T1 and a status.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
pub struct T2 {
    /// `char *str1`.
    pub str1: String,
    /// `int count`: the length of `t1`.
    pub count: i32,
    /// `T1_PTR t1`: `count` elements.
    #[ipc(len = "count")]
    pub t1: Vec<T1>,
    /// `STATUS_ENUM status`.
    pub status: StatusEnum,
}

/// The values module1 and module2 send.
pub fn appendix_a() -> (T1, T2) {
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
    (t1, t2)
}
