//! Round trips and throughput through the Session API, routed through a
//! central and direct (module to module), printed as a table — like
//! zenoh's z_ping/z_pong, usable as a tool.
//!
//! ```text
//! cargo run --release -p courier-examples --bin session-bench            # embedded centrals
//! cargo run --release -p courier-examples --bin session-bench -- --url ipc://127.0.0.1:1381
//! ```
//! With `--url` the given central is used for the routed column only (start
//! a second one with `-c` and pass `--direct-url` for the direct column).
//! Every number is the median of three runs after a warm-up.

#[path = "appendix_a.rs"]
mod appendix;

use std::time::{Duration, Instant};

use courier::{IpcMessage, Session};
use courier_broker::{CentralServer, Config};
use futures::StreamExt;

const T: Duration = Duration::from_secs(30);

/// `{int, <ubyte:1>}`: a payload of any size.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: i32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

#[derive(Clone, Copy)]
enum Kind {
    Pub,
    Query,
    Throughput,
}

struct Pair {
    a: Session,
    b: Session,
}

async fn pair(url: &str, tag: &str) -> Pair {
    let a = Session::builder(url)
        .name(format!("bench-a-{tag}"))
        .connect()
        .await
        .expect("connect a");
    let b = Session::builder(url)
        .name(format!("bench-b-{tag}"))
        .connect()
        .await
        .expect("connect b");
    Pair { a, b }
}

static RUN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

/// Seconds per operation. Every run uses fresh message names, so no
/// subscription of an earlier run is still being torn down.
async fn run(p: &Pair, kind: Kind, size: usize, count: usize) -> f64 {
    let n = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let (ping, pong, ask, answer) = (
        format!("ping{n}"),
        format!("pong{n}"),
        format!("ask{n}"),
        format!("answer{n}"),
    );
    for m in [&ping, &pong, &ask, &answer] {
        p.a.define::<Blob>(m).await.expect("define");
    }
    let payload = Blob {
        n: size as i32,
        data: vec![7u8; size],
    };
    match kind {
        Kind::Pub => {
            let mut pings = p.b.subscribe::<Blob>(&ping).await.unwrap();
            let mut pongs = p.a.subscribe::<Blob>(&pong).await.unwrap();
            p.a.num_handlers(&ping).await.unwrap();
            p.b.num_handlers(&pong).await.unwrap();
            let b = p.b.clone();
            let pong2 = pong.clone();
            let echo = tokio::spawn(async move {
                for _ in 0..count {
                    let s = pings.next().await.unwrap().unwrap();
                    b.publish(&pong2, &s.value).await.unwrap();
                }
            });
            // The broadcast lists settle before timing.
            tokio::time::sleep(Duration::from_millis(50)).await;
            let start = Instant::now();
            for _ in 0..count {
                p.a.publish(&ping, &payload).await.unwrap();
                tokio::time::timeout(T, pongs.next())
                    .await
                    .unwrap()
                    .unwrap()
                    .unwrap();
            }
            let secs = start.elapsed().as_secs_f64();
            echo.await.unwrap();
            secs / count as f64
        }
        Kind::Query => {
            let mut reqs = p.b.serve::<Blob, Blob>(&ask, &answer).await.unwrap();
            p.a.num_handlers(&ask).await.unwrap();
            let srv = tokio::spawn(async move {
                for _ in 0..count {
                    let r = reqs.next().await.unwrap().unwrap();
                    let v = r.value.clone();
                    r.reply(&v).await.unwrap();
                }
            });
            let start = Instant::now();
            for _ in 0..count {
                let r: Blob = p.a.query(&ask, &payload).timeout(T).await.unwrap();
                assert_eq!(r.data.len(), size);
            }
            let secs = start.elapsed().as_secs_f64();
            srv.await.unwrap();
            secs / count as f64
        }
        Kind::Throughput => {
            let mut pings = p.b.subscribe::<Blob>(&ping).await.unwrap();
            p.a.num_handlers(&ping).await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
            let recv = tokio::spawn(async move {
                for _ in 0..count {
                    tokio::time::timeout(T, pings.next())
                        .await
                        .unwrap()
                        .unwrap()
                        .unwrap();
                }
                Instant::now()
            });
            let start = Instant::now();
            for _ in 0..count {
                p.a.publish(&ping, &payload).await.unwrap();
            }
            let end = recv.await.unwrap();
            (end - start).as_secs_f64() / count as f64
        }
    }
}

/// One loopback TCP round trip, no protocol (the reference for direct mode).
async fn raw_tcp_rtt(count: usize) -> f64 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    let echo = tokio::spawn(async move {
        let (mut s, _) = l.accept().await.unwrap();
        s.set_nodelay(true).unwrap();
        let mut b = [0u8; 4];
        for _ in 0..count {
            s.read_exact(&mut b).await.unwrap();
            s.write_all(&b).await.unwrap();
        }
    });
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.set_nodelay(true).unwrap();
    let mut b = [0u8; 4];
    let start = Instant::now();
    for _ in 0..count {
        s.write_all(&b).await.unwrap();
        s.read_exact(&mut b).await.unwrap();
    }
    let secs = start.elapsed().as_secs_f64();
    echo.await.unwrap();
    secs / count as f64
}

async fn median(p: &Pair, kind: Kind, size: usize, count: usize) -> f64 {
    run(p, kind, size, (count / 10).max(1)).await;
    let mut v = Vec::new();
    for _ in 0..3 {
        v.push(run(p, kind, size, count).await);
    }
    v.sort_by(f64::total_cmp);
    v[1]
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let mut url = None;
    let mut direct_url = None;
    let mut quick = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--url" => url = args.next(),
            "--direct-url" => direct_url = args.next(),
            "--quick" => quick = true,
            "-h" | "--help" => {
                println!(
                    "usage: session-bench [--url ipc://H:P] [--direct-url ipc://H:P] [--quick]"
                );
                return;
            }
            other => {
                eprintln!("unknown argument {other:?} (try --help)");
                std::process::exit(2);
            }
        }
    }
    let mut centrals = Vec::new();
    let start = |direct: bool| async move {
        let mut cfg = Config::default();
        cfg.direct = direct;
        CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .config(cfg)
            .spawn()
            .await
            .expect("start central")
    };
    let routed_url = match url {
        Some(u) => u,
        None => {
            let c = start(false).await;
            let u = format!("ipc://{}", c.local_addr());
            centrals.push(c);
            u
        }
    };
    let direct_url = match direct_url {
        Some(u) => u,
        None => {
            let c = start(true).await;
            let u = format!("ipc://{}", c.local_addr());
            centrals.push(c);
            u
        }
    };
    let q = if quick { 10 } else { 1 };
    let routed = pair(&routed_url, "r").await;
    let direct = pair(&direct_url, "d").await;
    let mut tcp: Vec<f64> = Vec::new();
    for _ in 0..3 {
        tcp.push(raw_tcp_rtt(5000 / q).await);
    }
    tcp.sort_by(f64::total_cmp);
    println!("| case | routed (via central) | direct |");
    println!("|---|---|---|");
    println!(
        "| raw loopback TCP round trip, 4 B (reference) | | {:.1} µs |",
        tcp[1] * 1e6
    );
    let cases: [(&str, Kind, usize, usize); 6] = [
        ("publish->publish RTT, 4 B", Kind::Pub, 4, 2000),
        ("publish->publish RTT, 1 MiB", Kind::Pub, 1 << 20, 100),
        ("query->reply RTT, 4 B", Kind::Query, 4, 2000),
        ("query->reply RTT, 1 MiB", Kind::Query, 1 << 20, 100),
        ("one-way throughput, 4 B", Kind::Throughput, 4, 20_000),
        (
            "one-way throughput, 64 KiB",
            Kind::Throughput,
            64 << 10,
            2000,
        ),
    ];
    for (name, kind, size, count) in cases {
        let count = (count / q).max(5);
        let r = median(&routed, kind, size, count).await;
        let d = median(&direct, kind, size, count).await;
        let cell = |s: f64| match kind {
            Kind::Throughput => format!("{:.0} msg/s ({:.1} MB/s)", 1.0 / s, size as f64 / s / 1e6),
            _ => format!("{:.1} µs", s * 1e6),
        };
        println!("| {name} | {} | {} |", cell(r), cell(d));
    }
    for s in [routed.a, routed.b, direct.a, direct.b] {
        s.close().await;
    }
    for c in centrals {
        c.shutdown().await;
    }
    let _ = appendix::appendix_a;
}
