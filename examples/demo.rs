//! The README's first command: the IPC manual's Appendix A, live.
//!
//! 1. Prints the Appendix A message types: their IPC format strings
//!    (generated at compile time by `#[derive(IpcMessage)]`), their IPC
//!    bytes (identical to what the C library marshals) and their CDR bytes.
//! 2. Starts Courier's `central` in-process on a free port of 127.0.0.1 and
//!    runs Appendix A's module1 and module2 against it as two `Session`s
//!    (module1 over TCP, module2 over an in-process link to central):
//!    module1 publishes `message1` and queries `query1`; module2 handles
//!    them, publishes `message2` while answering and replies `response1`.
//!    Central's own log (in the C central's format) is printed as it
//!    happens.

use std::time::Duration;

use courier::cdr::{self, Encoding};
use courier::{ipc, IpcMessage, NamedFormats, Session};
use courier_broker::{CentralServer, LogSink};
use futures::StreamExt;

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

/// Appendix A's module2: handles message1 and query1 (three messages).
/// It runs in the process that hosts central, so it connects over an
/// in-process link (`CentralHandle::session`) instead of a socket.
async fn module2(
    session: courier::SessionBuilder,
    ready: tokio::sync::oneshot::Sender<()>,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let s = session.connect().await?;
    println!("module2 | connected (in-process link to central)");
    s.define::<String>("message2").await?;
    s.define::<T2>("response1").await?;
    let mut msg1 = s.subscribe::<i32>("message1").await?;
    let mut queries = s.serve::<T1, T2>("query1", "response1").await?;
    s.num_handlers("query1").await?; // central has both subscriptions now
    let _ = ready.send(());
    let mut handled = 0;
    while handled < 3 {
        tokio::select! {
            Some(m) = msg1.next() => {
                println!("module2 | msg1Handler: Receiving message1 ({})", m?.value);
                handled += 1;
            }
            Some(q) = queries.next() => {
                let req = q?;
                println!("module2 | queryHandler: Receiving query1 {:?}", req.value);
                println!("module2 |   publish(message2, \"Hello, world\")");
                s.publish("message2", &String::from("Hello, world")).await?;
                println!("module2 |   reply(response1, T2)");
                req.reply(&appendix_a().1).await?;
                handled += 1;
            }
        }
    }
    s.close().await;
    println!("module2 | disconnected");
    Ok(())
}

/// Appendix A's module1: publishes message1, queries query1.
async fn module1(url: String) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let s = Session::builder(url).name("module1").connect().await?;
    println!("module1 | connected (TCP, as a C module would)");
    s.ipc()?.define_formats::<T2>().await?;
    s.define::<i32>("message1").await?;
    s.define::<T1>("query1").await?;
    let mut msg2 = s.subscribe::<String>("message2").await?;
    let (t1, t2) = appendix_a();
    println!("module1 | publish(message1, 42)");
    s.publish("message1", &42i32).await?;
    println!("module1 | query(query1, {t1:?})");
    let r: T2 = s
        .query("query1", &t1)
        .timeout(Duration::from_secs(10))
        .await?;
    println!("module1 | Received response: {r:?}");
    assert_eq!(r, t2);
    let m = tokio::time::timeout(Duration::from_secs(10), msg2.next())
        .await?
        .ok_or("message2 stream ended")??;
    println!("module1 | msg2Handler: Receiving message2 ({})", m.value);
    println!("module1 | publish(message1, 42)");
    s.publish("message1", &42i32).await?;
    s.close().await;
    println!("module1 | disconnected");
    Ok(())
}

fn main() {
    let (t1, t2) = appendix_a();
    println!("Courier: the IPC manual's Appendix A messages\n");
    show("message1 (int)", &42i32);
    show("message2 (string)", &String::from("Hello, world"));
    show("query1 (T1)", &t1);
    show("response1 (T2)", &t2);

    println!("Appendix A live: Courier's central in-process, module1 and module2 as Sessions\n");
    live();
}

/// Central in-process plus module1 and module2, until both finish.
fn live() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime");
    rt.block_on(async {
        let mut config = courier_broker::Config::default();
        config.terminal_log =
            courier_broker::LogOptions::parse("msid", false).expect("log options");
        let central = CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .config(config)
            .log_sink(LogSink::new(|target, line: &str| {
                if target.terminal {
                    println!("central | {line}");
                }
            }))
            .spawn()
            .await
            .expect("start central");
        let url = format!("ipc://{}", central.local_addr());
        println!("central | listening on {}", central.local_addr());
        let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
        let m2 = tokio::spawn(module2(central.session("module2"), ready_tx));
        ready_rx.await.expect("module2 ready");
        module1(url).await.expect("module1");
        m2.await.expect("module2 task").expect("module2");
        central.shutdown().await;
        println!("central | stopped");
    });
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
