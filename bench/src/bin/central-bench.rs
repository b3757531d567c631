//! Benchmark of an IPC central: round trips and one-way throughput between
//! two modules, run with the same clients against any number of centrals
//! (ours, the C one), printed as a table.
//!
//! ```text
//! central-bench --target courier=127.0.0.1:1400 --target c=127.0.0.1:1401 [--quick]
//! ```
//! Each target must be a running central (start ours with
//! `central -p1400 --bind 127.0.0.1 -lx -s -u`, the C one with `central -p1401 -lx -s -u`).
//!
//! The clients are Courier's sans-I/O IPC module state machine
//! (`courier::ipc::module`) on blocking sockets, one thread each, so the
//! client costs are identical for every central and small.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use courier::ipc::module::MsgLength;

#[path = "../client.rs"]
mod client;
use client::Client;

#[derive(Clone, Copy)]
enum Kind {
    PubRoundTrip,
    QueryRoundTrip,
    Throughput,
}

#[derive(Clone, Copy)]
struct Case {
    name: &'static str,
    kind: Kind,
    size: usize,
    count: usize,
}

/// Runs one case; returns (seconds per operation, bytes per second).
fn run(addr: &str, case: &Case) -> (f64, f64) {
    let addr = addr.to_string();
    let size = case.size;
    let count = case.count;
    let kind = case.kind;
    // The receiving side subscribes first, so the sender's broadcast list
    // (fetched at connect) already names the messages.
    let mut b = Client::connect(&addr, "bench-b");
    for m in ["ping", "pong", "ask", "answer"] {
        b.conn.define_msg(m, MsgLength::Variable, None).unwrap();
    }
    b.conn.subscribe("ping", "HND-ping").unwrap();
    b.conn.subscribe("ask", "HND-ask").unwrap();
    b.sync();
    let (tx, rx) = std::sync::mpsc::channel::<()>();
    let server = std::thread::spawn(move || {
        tx.send(()).unwrap();
        for _ in 0..count {
            let (d, k, data) = b.delivery();
            match (kind, k) {
                (Kind::PubRoundTrip, _) => {
                    b.conn.publish("pong", data.clone(), -1).unwrap();
                    b.conn.ack(d).unwrap();
                }
                (Kind::QueryRoundTrip, _) => b.conn.respond(d, "answer", data.clone()).unwrap(),
                (Kind::Throughput, _) => b.conn.ack(d).unwrap(),
            }
            b.flush();
        }
        let end = Instant::now();
        b.close();
        end
    });
    rx.recv().unwrap();
    let mut a = Client::connect(&addr, "bench-a");
    a.conn.subscribe("pong", "HND-pong").unwrap();
    a.sync();
    let payload = vec![7u8; size];
    let start = Instant::now();
    match kind {
        Kind::PubRoundTrip => {
            for _ in 0..count {
                a.conn.publish("ping", payload.clone(), -1).unwrap();
                let (d, _, data) = a.delivery();
                assert_eq!(data.len(), size);
                a.conn.ack(d).unwrap();
            }
        }
        Kind::QueryRoundTrip => {
            for _ in 0..count {
                a.conn.query("ask", payload.clone(), -1).unwrap();
                let data = a.reply();
                assert_eq!(data.len(), size);
            }
        }
        Kind::Throughput => {
            for _ in 0..count {
                a.conn.publish("ping", payload.clone(), -1).unwrap();
                a.settle();
            }
        }
    }
    let end = match kind {
        Kind::Throughput => server.join().unwrap(),
        _ => {
            let e = Instant::now();
            server.join().unwrap();
            e
        }
    };
    a.close();
    let secs = (end - start).as_secs_f64();
    let per_op = secs / count as f64;
    let bytes = match kind {
        Kind::Throughput => size as f64 * count as f64 / secs,
        _ => 2.0 * size as f64 * count as f64 / secs,
    };
    (per_op, bytes)
}

/// Reads exactly `buf.len()` bytes, polling a non-blocking socket without
/// ever sleeping (a busy-polling central's way of waiting).
fn spin_read(s: &mut TcpStream, buf: &mut [u8]) {
    let mut got = 0;
    while got < buf.len() {
        match s.read(&mut buf[got..]) {
            Ok(0) => panic!("relay floor: peer closed"),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::hint::spin_loop(),
            Err(e) => panic!("relay floor: {e}"),
        }
    }
}

/// The floor for any relaying central: A -> relay -> B -> relay -> A with
/// 4-byte messages over loopback TCP and no protocol at all (three threads;
/// A and B block, the relay blocks too or, with `spin`, polls without
/// sleeping as `central --busy-poll` does). Returns seconds per round trip.
fn relay_floor(count: usize, spin: bool) -> f64 {
    use std::net::TcpListener;
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap();
    let relay = std::thread::spawn(move || {
        let (mut a, _) = l.accept().unwrap();
        let (mut b, _) = l.accept().unwrap();
        a.set_nodelay(true).unwrap();
        b.set_nodelay(true).unwrap();
        a.set_nonblocking(spin).unwrap();
        b.set_nonblocking(spin).unwrap();
        let mut buf = [0u8; 4];
        let read = |s: &mut TcpStream, buf: &mut [u8; 4]| {
            if spin {
                spin_read(s, buf)
            } else {
                s.read_exact(buf).unwrap()
            }
        };
        for _ in 0..count {
            read(&mut a, &mut buf);
            b.write_all(&buf).unwrap();
            read(&mut b, &mut buf);
            a.write_all(&buf).unwrap();
        }
    });
    let mut a = TcpStream::connect(addr).unwrap();
    let mut b = TcpStream::connect(addr).unwrap();
    a.set_nodelay(true).unwrap();
    b.set_nodelay(true).unwrap();
    let echo = std::thread::spawn(move || {
        let mut buf = [0u8; 4];
        for _ in 0..count {
            b.read_exact(&mut buf).unwrap();
            b.write_all(&buf).unwrap();
        }
    });
    let start = Instant::now();
    let mut buf = [0u8; 4];
    for _ in 0..count {
        a.write_all(&buf).unwrap();
        a.read_exact(&mut buf).unwrap();
    }
    let secs = start.elapsed().as_secs_f64();
    echo.join().unwrap();
    relay.join().unwrap();
    secs / count as f64
}

fn main() {
    let mut targets: Vec<(String, String)> = Vec::new();
    let mut quick = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--target" => {
                let v = args.next().unwrap_or_default();
                match v.split_once('=') {
                    Some((n, addr)) => targets.push((n.into(), addr.into())),
                    None => {
                        eprintln!("--target wants name=host:port, got {v:?}");
                        std::process::exit(2);
                    }
                }
            }
            "--quick" => quick = true,
            "-h" | "--help" => {
                println!("usage: central-bench --target NAME=HOST:PORT [--target ...] [--quick]");
                return;
            }
            other => {
                eprintln!("unknown argument {other:?} (try --help)");
                std::process::exit(2);
            }
        }
    }
    if targets.is_empty() {
        eprintln!("no --target given (try --help)");
        std::process::exit(2);
    }
    let q = if quick { 10 } else { 1 };
    let cases = [
        Case {
            name: "publish->handler->publish RTT, 4 B",
            kind: Kind::PubRoundTrip,
            size: 4,
            count: 5000 / q,
        },
        Case {
            name: "publish->handler->publish RTT, 1 MiB",
            kind: Kind::PubRoundTrip,
            size: 1 << 20,
            count: 200 / q,
        },
        Case {
            name: "query/response RTT, 4 B",
            kind: Kind::QueryRoundTrip,
            size: 4,
            count: 5000 / q,
        },
        Case {
            name: "query/response RTT, 1 MiB",
            kind: Kind::QueryRoundTrip,
            size: 1 << 20,
            count: 200 / q,
        },
        Case {
            name: "one-way throughput, 4 B",
            kind: Kind::Throughput,
            size: 4,
            count: 50_000 / q,
        },
        Case {
            name: "one-way throughput, 64 KiB",
            kind: Kind::Throughput,
            size: 64 << 10,
            count: 5000 / q,
        },
    ];
    print!("| case |");
    for (n, _) in &targets {
        print!(" {n} |");
    }
    if targets.len() == 2 {
        print!(" {} / {} |", targets[0].0, targets[1].0);
    }
    println!();
    print!("|---|");
    for _ in 0..targets.len() + usize::from(targets.len() == 2) {
        print!("---|");
    }
    println!();
    for (spin, what) in [(false, "blocking"), (true, "busy-polling")] {
        let mut floors: Vec<f64> = (0..3).map(|_| relay_floor(5000 / q, spin)).collect();
        floors.sort_by(f64::total_cmp);
        println!(
            "| raw TCP relay floor, {what} relay (no protocol: A->relay->B->relay->A), 4 B | {:.1} µs |",
            floors[1] * 1e6
        );
    }
    let only = std::env::var("BENCH_ONLY").unwrap_or_default();
    for case in cases.iter().filter(|c| c.name.contains(only.as_str())) {
        print!("| {} |", case.name);
        let mut vals = Vec::new();
        for (_, addr) in &targets {
            // Warm up, then measure.
            let _ = run(
                addr,
                &Case {
                    count: (case.count / 10).max(1),
                    ..*case
                },
            );
            let (per_op, bps) = run(addr, case);
            let v = match case.kind {
                Kind::Throughput => {
                    print!(" {:.0} msg/s ({:.1} MB/s) |", 1.0 / per_op, bps / 1e6);
                    1.0 / per_op
                }
                _ => {
                    print!(" {:.1} µs |", per_op * 1e6);
                    per_op
                }
            };
            vals.push(v);
        }
        if vals.len() == 2 {
            print!(" {:.2}× |", vals[0] / vals[1]);
        }
        println!();
        std::thread::sleep(Duration::from_millis(50));
    }
}
