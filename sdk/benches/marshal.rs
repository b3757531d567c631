//! Marshalling throughput: IPC and CDR encode + decode of the manual's T1
//! and T2, a 1 MiB byte array and a 100 000-double array, next to memcpy of
//! the same bytes measured in the same run.
//!
//! `cargo bench -p courier --bench marshal` runs criterion, then prints a
//! table (GB/s = 10^9 bytes of marshalled data per second) from criterion's
//! estimates. `-- --quick` gives a faster, noisier run.

use std::hint::black_box;
use std::time::Duration;

use courier::cdr::{self, Encoding};
use courier::{ipc, IpcMessage};
use criterion::{BenchmarkId, Criterion, Throughput};

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(numeric)]
enum Status {
    Wait,
    Send,
    Receive,
    Listen,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[allow(clippy::enum_variant_names)] // the manual's names
enum StatusEnum {
    WaitVal,
    SendVal,
    ReceiveVal,
    ListenVal,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T1 {
    i1: i32,
    status: Status,
    matrix: [[f64; 3]; 2],
    d1: f64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct T2 {
    str1: String,
    count: i32,
    #[ipc(len = "count")]
    t1: Vec<T1>,
    status: StatusEnum,
}

/// `{int, <ubyte:1>}`: a 1 MiB blob.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    len: i32,
    #[ipc(len = "len")]
    data: Vec<u8>,
}

/// `{int, <double:1>}`: 100 000 doubles.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Doubles {
    n: i32,
    #[ipc(len = "n")]
    v: Vec<f64>,
}

fn t1() -> T1 {
    T1 {
        i1: 666,
        status: Status::Send,
        matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]],
        d1: std::f64::consts::PI,
    }
}

type Case = (&'static str, Box<dyn Fn(&mut Criterion)>);

fn cases() -> Vec<Case> {
    vec![
        ("T1", Box::new(|c| bench_type(c, "T1", t1()))),
        (
            "T2",
            Box::new(|c| {
                bench_type(
                    c,
                    "T2",
                    T2 {
                        str1: "Hello, world".into(),
                        count: 1,
                        t1: vec![t1()],
                        status: StatusEnum::ReceiveVal,
                    },
                )
            }),
        ),
        (
            "bytes_1MiB",
            Box::new(|c| {
                let data: Vec<u8> = (0..1 << 20).map(|i| i as u8).collect();
                bench_memcpy(c, "bytes_1MiB", &data);
                bench_type(
                    c,
                    "bytes_1MiB",
                    Blob {
                        len: data.len() as i32,
                        data,
                    },
                )
            }),
        ),
        (
            "doubles_100k",
            Box::new(|c| {
                let v: Vec<f64> = (0..100_000).map(|i| i as f64 * 0.5).collect();
                let raw: Vec<u8> = v.iter().flat_map(|x| x.to_ne_bytes()).collect();
                bench_memcpy(c, "doubles_100k", &raw);
                bench_type(
                    c,
                    "doubles_100k",
                    Doubles {
                        n: v.len() as i32,
                        v,
                    },
                )
            }),
        ),
    ]
}

/// Baselines: memcpy into a reused buffer, and into a freshly allocated one
/// (what `to_vec` must do too).
fn bench_memcpy(c: &mut Criterion, name: &str, data: &[u8]) {
    let mut g = c.benchmark_group(name);
    g.throughput(Throughput::Bytes(data.len() as u64));
    let mut dst = vec![0u8; data.len()];
    g.bench_function("memcpy", |b| {
        b.iter(|| {
            dst.copy_from_slice(black_box(data));
            black_box(&dst);
        })
    });
    g.bench_function("memcpy_alloc", |b| {
        b.iter(|| black_box(black_box(data).to_vec()))
    });
    g.finish();
}

fn bench_type<T: IpcMessage + PartialEq + std::fmt::Debug>(c: &mut Criterion, name: &str, v: T) {
    let ipc_bytes = ipc::to_vec(&v);
    assert_eq!(ipc::from_slice::<T>(&ipc_bytes).unwrap(), v);
    let mut g = c.benchmark_group(name);
    g.throughput(Throughput::Bytes(ipc_bytes.len() as u64));
    g.bench_function("ipc_encode", |b| {
        b.iter(|| black_box(ipc::to_vec(black_box(&v))))
    });
    let mut w = ipc::Writer::with_capacity(ipc_bytes.len());
    g.bench_function("ipc_encode_reuse", |b| {
        b.iter(|| {
            let mut buf = std::mem::take(&mut w).into_vec();
            buf.clear();
            w = ipc::Writer::from_vec(buf);
            black_box(&v).ipc_encode(&mut w);
            black_box(w.as_bytes());
        })
    });
    g.bench_function("ipc_decode", |b| {
        b.iter(|| black_box(ipc::from_slice::<T>(black_box(&ipc_bytes)).unwrap()))
    });
    g.finish();
    for enc in [Encoding::Xcdr1Le, Encoding::Xcdr2Le] {
        let bytes = cdr::to_vec(&v, enc);
        assert_eq!(cdr::from_slice::<T>(&bytes).unwrap(), v);
        let tag = match enc {
            Encoding::Xcdr1Le => "xcdr1",
            _ => "xcdr2",
        };
        let mut g = c.benchmark_group(name);
        g.throughput(Throughput::Bytes(bytes.len() as u64));
        g.bench_function(BenchmarkId::new("cdr_encode", tag), |b| {
            b.iter(|| black_box(cdr::to_vec(black_box(&v), enc)))
        });
        g.bench_function(BenchmarkId::new("cdr_decode", tag), |b| {
            b.iter(|| black_box(cdr::from_slice::<T>(black_box(&bytes)).unwrap()))
        });
        g.finish();
    }
}

/// Reads criterion's mean estimate (ns) for a benchmark id.
fn mean_ns(group: &str, bench: &str) -> Option<f64> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../target/criterion")
        .join(group)
        .join(bench.replace('/', std::path::MAIN_SEPARATOR_STR))
        .join("new/estimates.json");
    let text = std::fs::read_to_string(dir).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v["mean"]["point_estimate"].as_f64()
}

fn print_table(sizes: &[(&str, usize, usize, usize)]) {
    let benches = [
        "ipc_encode",
        "ipc_encode_reuse",
        "ipc_decode",
        "cdr_encode/xcdr1",
        "cdr_decode/xcdr1",
        "cdr_encode/xcdr2",
        "cdr_decode/xcdr2",
        "memcpy",
        "memcpy_alloc",
    ];
    println!();
    println!("| data | operation | bytes | time/op | GB/s | × memcpy |");
    println!("|---|---|---:|---:|---:|---:|");
    for &(group, ipc_len, cdr1_len, cdr2_len) in sizes {
        let memcpy = mean_ns(group, "memcpy").map(|ns| ipc_len as f64 / ns);
        for b in benches {
            let Some(ns) = mean_ns(group, b) else {
                continue;
            };
            let len = if b.ends_with("xcdr1") {
                cdr1_len
            } else if b.ends_with("xcdr2") {
                cdr2_len
            } else {
                ipc_len
            };
            let gbs = len as f64 / ns;
            let ratio = memcpy
                .map(|m| format!("{:.2}", gbs / m))
                .unwrap_or_else(|| "-".into());
            let time = if ns >= 1e6 {
                format!("{:.2} ms", ns / 1e6)
            } else if ns >= 1e3 {
                format!("{:.2} µs", ns / 1e3)
            } else {
                format!("{ns:.1} ns")
            };
            println!("| {group} | {b} | {len} | {time} | {gbs:.2} | {ratio} |");
        }
    }
}

fn sizes_of<T: IpcMessage>(v: &T) -> (usize, usize, usize) {
    (
        ipc::to_vec(v).len(),
        cdr::to_vec(v, Encoding::Xcdr1Le).len(),
        cdr::to_vec(v, Encoding::Xcdr2Le).len(),
    )
}

fn main() {
    let mut c = Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .configure_from_args();
    for (_, f) in cases() {
        f(&mut c);
    }
    c.final_summary();
    let t2 = T2 {
        str1: "Hello, world".into(),
        count: 1,
        t1: vec![t1()],
        status: StatusEnum::ReceiveVal,
    };
    let blob = Blob {
        len: 1 << 20,
        data: vec![0; 1 << 20],
    };
    let doubles = Doubles {
        n: 100_000,
        v: vec![0.0; 100_000],
    };
    let s = [
        ("T1", sizes_of(&t1())),
        ("T2", sizes_of(&t2)),
        ("bytes_1MiB", sizes_of(&blob)),
        ("doubles_100k", sizes_of(&doubles)),
    ];
    let rows: Vec<_> = s.iter().map(|(n, (a, b, c))| (*n, *a, *b, *c)).collect();
    print_table(&rows);
}
