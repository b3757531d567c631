//! The README's first command: the IPC manual's Appendix A, live.
//!
//! 1. Prints the Appendix A message types: their IPC format strings
//!    (generated at compile time by `#[derive(IpcMessage)]`), their IPC
//!    bytes (identical to what the C library marshals) and their CDR bytes.
//! 2. Starts Courier's `central` in-process on a free port of 127.0.0.1 and
//!    runs module1 and module2 of Appendix A against it, each on its own
//!    thread: module1 publishes `message1` and queries `query1`; module2
//!    handles them, publishes `message2` from inside its query handler and
//!    responds with `response1`. Central's own log (the C central's format)
//!    is printed as it happens.
//!
//! (The modules use Courier's IPC module state machine directly; the async
//! `Session` API will replace that here.)

use std::sync::mpsc;
use std::time::Duration;

use courier::cdr::{self, Encoding};
use courier::ipc::module::{Event, MsgLength};
use courier::{ipc, IpcMessage, NamedFormats};
use courier_broker::{CentralServer, LogSink};

#[path = "client.rs"]
mod client;
use client::Client;

#[path = "appendix_a.rs"]
mod appendix;
use appendix::{appendix_a, T1, T2};

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

/// `IPC_defineFormat` for every named format `T` uses, then `IPC_defineMsg`.
fn define<T: IpcMessage>(c: &mut Client, msg: &str) {
    for (name, fmt) in NamedFormats::of::<T>().iter() {
        c.conn.define_format(name, fmt).unwrap();
    }
    c.conn
        .define_msg(msg, MsgLength::Variable, Some(T::FORMAT))
        .unwrap();
}

/// Appendix A's module2: handles message1 and query1.
fn module2(addr: String, ready: mpsc::Sender<()>) {
    let mut m = Client::connect(&addr, "module2");
    println!("module2 | connected");
    define::<String>(&mut m, "message2");
    define::<T2>(&mut m, "response1");
    m.conn.subscribe("message1", "HND-message1").unwrap();
    m.conn.subscribe("query1", "HND-query1").unwrap();
    m.sync();
    ready.send(()).unwrap();
    let mut handled = 0;
    while handled < 3 {
        if let Event::Delivery {
            delivery,
            msg,
            dispatch_ref,
            data,
            ..
        } = m.next_event()
        {
            handled += 1;
            match msg.as_str() {
                "message1" => {
                    let v: i32 = ipc::from_slice(&data).expect("message1 is an int");
                    println!("module2 | msg1Handler: Receiving message1 ({v})");
                    m.conn.ack(delivery).unwrap();
                }
                "query1" => {
                    let t1: T1 = ipc::from_slice(&data).expect("query1 is a T1");
                    println!("module2 | queryHandler: Receiving query1 {t1:?}");
                    println!("module2 |   IPC_publishData(message2, \"Hello, world\")");
                    let s = ipc::to_vec(&String::from("Hello, world"));
                    m.conn.publish("message2", &s, dispatch_ref).unwrap();
                    let (_, t2) = appendix_a();
                    println!("module2 |   IPC_respondData(response1, T2)");
                    m.conn
                        .respond(delivery, "response1", &ipc::to_vec(&t2))
                        .unwrap();
                }
                other => println!("module2 | unexpected {other}"),
            }
            m.settle();
        }
    }
    m.close();
    println!("module2 | disconnected");
}

/// Appendix A's module1: publishes message1, queries query1.
fn module1(addr: String) {
    let mut m = Client::connect(&addr, "module1");
    println!("module1 | connected");
    define::<i32>(&mut m, "message1");
    define::<T1>(&mut m, "query1");
    m.conn.subscribe("message2", "HND-message2").unwrap();
    m.sync();
    let (t1, t2) = appendix_a();
    println!("module1 | IPC_publishData(message1, 42)");
    m.conn
        .publish("message1", &ipc::to_vec(&42i32), -1)
        .unwrap();
    m.settle();
    println!("module1 | IPC_queryResponseData(query1, {t1:?})");
    let q = m.conn.query("query1", &ipc::to_vec(&t1), -1).unwrap();
    let (mut got_reply, mut got_msg2) = (false, false);
    while !(got_reply && got_msg2) {
        match m.next_event() {
            Event::Delivery {
                delivery,
                msg,
                data,
                ..
            } if msg == "message2" => {
                let s: String = ipc::from_slice(&data).expect("message2 is a string");
                println!("module1 | msg2Handler: Receiving message2 ({s})");
                m.conn.ack(delivery).unwrap();
                got_msg2 = true;
            }
            Event::Reply {
                query,
                reply_msg,
                data,
                ..
            } if query == q => {
                let r: T2 = ipc::from_slice(&data).expect("the reply is a T2");
                println!("module1 | Received response ({reply_msg}): {r:?}");
                assert_eq!(r, t2);
                got_reply = true;
            }
            _ => {}
        }
    }
    println!("module1 | IPC_publishData(message1, 42)");
    m.conn
        .publish("message1", &ipc::to_vec(&42i32), -1)
        .unwrap();
    m.settle();
    m.close();
    println!("module1 | disconnected");
}

fn main() {
    let (t1, t2) = appendix_a();
    println!("Courier: the IPC manual's Appendix A messages\n");
    show("message1 (int)", &42i32);
    show("message2 (string)", &String::from("Hello, world"));
    show("query1 (T1)", &t1);
    show("response1 (T2)", &t2);

    println!("Appendix A live: Courier's central in-process, module1 and module2 on threads\n");
    live();
}

/// Central in-process plus module1 and module2 on threads, until both finish.
fn live() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    let mut config = courier_broker::Config::default();
    config.terminal_log = courier_broker::LogOptions::parse("msid", false).expect("log options");
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind([127, 0, 0, 1].into())
                .port(0)
                .config(config)
                .log_sink(LogSink::new(|target, line: &str| {
                    if target.terminal {
                        println!("central | {line}");
                    }
                }))
                .spawn(),
        )
        .expect("start central");
    let addr = central.local_addr().to_string();
    println!("central | listening on {addr}");
    // Central runs on this thread's runtime while the modules run.
    let (ready_tx, ready_rx) = mpsc::channel();
    let a2 = addr.clone();
    let m2 = std::thread::spawn(move || module2(a2, ready_tx));
    let m1 = std::thread::spawn(move || {
        ready_rx.recv().expect("module2 ready");
        module1(addr)
    });
    rt.block_on(async {
        while !(m1.is_finished() && m2.is_finished()) {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    });
    m1.join().expect("module1");
    m2.join().expect("module2");
    rt.block_on(central.shutdown());
    println!("central | stopped");
}

#[cfg(test)]
mod tests {
    /// The README's first command: it must run to the end (module1 asserts
    /// the reply it gets), within a bound.
    #[test]
    fn the_demo_runs() {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            super::live();
            tx.send(()).unwrap();
        });
        rx.recv_timeout(std::time::Duration::from_secs(60))
            .expect("the demo finished within 60 s");
    }
}
