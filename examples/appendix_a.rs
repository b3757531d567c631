//! The message types of the IPC manual's Appendix A (module.h), shared by
//! the examples.
#![allow(dead_code)]

use courier::IpcMessage;

/// `typedef enum { WaitVal, SendVal, ReceiveVal, ListenVal } STATUS_ENUM`,
/// written in T1 as `{enum : 3}`.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(numeric)]
pub enum Status {
    Wait,
    Send,
    Receive,
    Listen,
}

/// The same enum in its symbolic form, as T2 writes it.
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[allow(clippy::enum_variant_names)] // the manual's names
pub enum StatusEnum {
    WaitVal,
    SendVal,
    ReceiveVal,
    ListenVal,
}

/// `T1_TYPE`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
pub struct T1 {
    pub i1: i32,
    pub status: Status,
    pub matrix: [[f64; 3]; 2],
    pub d1: f64,
}

/// `T2_TYPE`: a string, a count, a variable array of T1 and a status.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
pub struct T2 {
    pub str1: String,
    pub count: i32,
    #[ipc(len = "count")]
    pub t1: Vec<T1>,
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

/// Resolves after the number of seconds given as the first argument, or on
/// Ctrl-C when there is none (how module2 and module3 end).
pub async fn stop_signal() {
    match std::env::args().nth(1).and_then(|a| a.parse::<u64>().ok()) {
        Some(secs) => tokio::time::sleep(std::time::Duration::from_secs(secs)).await,
        None => {
            let _ = tokio::signal::ctrl_c().await;
        }
    }
}
