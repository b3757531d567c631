//! `session-bench processes`' relay floor: the four process hops of a
//! routed IPC round trip (module A → relay → module B → relay → module A)
//! through a relay that has no IPC logic at all. It reads a frame (the
//! 28-byte IPC header gives the length of what follows) and writes it to
//! the other connection; one blocking thread per direction, as cheap as a
//! relaying process gets. The two ends send and answer frames of the size
//! a C module's 4 B message has (header + `{int, <ubyte:1>}`), so the floor
//! holds only what any central must pay: two wake-ups and two
//! read-then-write passes through a third process, on the same transport.
//! The ends do less than the C library does per message, so the floor is
//! a lower bound for the C-client cells, not their twin.
//!
//! ```text
//! session-bench relay --tcp PORT [--unix PATH]   # first connection: the answering end
//! session-bench raw-pong --tcp PORT | --unix PATH
//! session-bench raw-ping --tcp PORT | --unix PATH --count N --size S   # prints median_us=
//! ```

use std::io::{self, Read, Write};
use std::net::{Ipv4Addr, Shutdown, TcpListener, TcpStream};
use std::os::unix::net::{UnixListener, UnixStream};
use std::time::Instant;

/// `HEADER_SIZE` of the IPC frame (ipc.md §2).
const HEADER: usize = 28;
/// Frames longer than this end the relay with an error (no unbounded
/// allocation on a corrupt header).
const MAX_FRAME: usize = 64 << 20;
/// Round trips before the timed ones.
const WARM_UP: usize = 200;

/// A connected byte stream of either kind.
enum Conn {
    Tcp(TcpStream),
    Unix(UnixStream),
}

impl Conn {
    fn try_clone(&self) -> io::Result<Conn> {
        Ok(match self {
            Conn::Tcp(s) => Conn::Tcp(s.try_clone()?),
            Conn::Unix(s) => Conn::Unix(s.try_clone()?),
        })
    }

    fn shutdown(&self) {
        let _ = match self {
            Conn::Tcp(s) => s.shutdown(Shutdown::Both),
            Conn::Unix(s) => s.shutdown(Shutdown::Both),
        };
    }
}

impl Read for Conn {
    fn read(&mut self, b: &mut [u8]) -> io::Result<usize> {
        match self {
            Conn::Tcp(s) => s.read(b),
            Conn::Unix(s) => s.read(b),
        }
    }
}

impl Write for Conn {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        match self {
            Conn::Tcp(s) => s.write(b),
            Conn::Unix(s) => s.write(b),
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Where the ends reach the relay.
enum Addr {
    Tcp(u16),
    Unix(String),
}

fn connect(a: &Addr) -> io::Result<Conn> {
    Ok(match a {
        Addr::Tcp(p) => {
            let s = TcpStream::connect((Ipv4Addr::LOCALHOST, *p))?;
            s.set_nodelay(true)?;
            Conn::Tcp(s)
        }
        Addr::Unix(p) => Conn::Unix(UnixStream::connect(p)?),
    })
}

/// Reads one whole frame into `buf` (header and body); false at a clean
/// end of stream before a header.
fn read_frame(c: &mut Conn, buf: &mut Vec<u8>) -> io::Result<bool> {
    buf.resize(HEADER, 0);
    let mut got = 0;
    while got < HEADER {
        match c.read(&mut buf[got..])? {
            0 if got == 0 => return Ok(false),
            0 => return Err(io::ErrorKind::UnexpectedEof.into()),
            n => got += n,
        }
    }
    let field = |i: usize| i32::from_be_bytes([buf[i], buf[i + 1], buf[i + 2], buf[i + 3]]);
    let (class_total, msg_total) = (field(0), field(4));
    let body = usize::try_from(class_total)
        .ok()
        .zip(usize::try_from(msg_total).ok())
        .map(|(a, b)| a + b)
        .filter(|&n| n <= MAX_FRAME)
        .ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::InvalidData,
                format!("bad frame lengths {class_total} + {msg_total}"),
            )
        })?;
    buf.resize(HEADER + body, 0);
    c.read_exact(&mut buf[HEADER..])?;
    Ok(true)
}

/// A frame as a C module sends a 4 B message: header, then the data.
fn frame(size: usize) -> Vec<u8> {
    let data = 4 + size;
    let mut f = vec![0u8; HEADER + data];
    f[4..8].copy_from_slice(&(data as i32).to_be_bytes());
    f[HEADER..HEADER + 4].copy_from_slice(&(size as i32).to_be_bytes());
    f
}

fn parse(
    role: &str,
    args: impl Iterator<Item = String>,
) -> (Option<u16>, Option<String>, usize, usize) {
    let (mut tcp, mut unix, mut count, mut size) = (None, None, 5000, 4);
    let mut args = args;
    while let Some(a) = args.next() {
        let v = args.next();
        let num = || -> usize {
            v.as_deref()
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| {
                    eprintln!("{role}: {a} needs a number (got {v:?})");
                    std::process::exit(2)
                })
        };
        match a.as_str() {
            "--tcp" => tcp = Some(num() as u16),
            "--unix" => unix = v.clone(),
            "--count" => count = num(),
            "--size" => size = num(),
            other => {
                eprintln!("{role}: unknown argument {other:?}");
                std::process::exit(2)
            }
        }
    }
    (tcp, unix, count, size)
}

fn end_addr(role: &str, tcp: Option<u16>, unix: Option<String>) -> Addr {
    match (tcp, unix) {
        (_, Some(p)) => Addr::Unix(p),
        (Some(p), None) => Addr::Tcp(p),
        (None, None) => {
            eprintln!("{role}: --tcp PORT or --unix PATH");
            std::process::exit(2)
        }
    }
}

/// `session-bench relay`: accepts the answering end, then the timing end
/// (on the TCP port or the UNIX socket, whichever each uses), and copies
/// frames between them until either closes.
pub fn relay(args: impl Iterator<Item = String>) {
    let (tcp, unix, _, _) = parse("relay", args);
    let tl = tcp.map(|p| TcpListener::bind((Ipv4Addr::LOCALHOST, p)).expect("relay: bind TCP"));
    let ul = unix.map(|p| {
        let _ = std::fs::remove_file(&p);
        UnixListener::bind(&p).expect("relay: bind the UNIX socket")
    });
    let accept = || -> Conn {
        match (&tl, &ul) {
            (_, Some(u)) => Conn::Unix(u.accept().expect("relay: accept").0),
            (Some(t), None) => {
                let s = t.accept().expect("relay: accept").0;
                let _ = s.set_nodelay(true);
                Conn::Tcp(s)
            }
            (None, None) => {
                eprintln!("relay: --tcp PORT or --unix PATH");
                std::process::exit(2)
            }
        }
    };
    let b = accept();
    let a = accept();
    let (a2, b2) = (a.try_clone().expect("clone"), b.try_clone().expect("clone"));
    let pump = |mut from: Conn, mut to: Conn| {
        let mut buf = Vec::with_capacity(4096);
        while let Ok(true) = read_frame(&mut from, &mut buf) {
            if to.write_all(&buf).is_err() {
                break;
            }
        }
        from.shutdown();
        to.shutdown();
    };
    let t = std::thread::spawn(move || pump(a, b2));
    pump(b, a2);
    let _ = t.join();
}

/// `session-bench raw-pong`: answers every frame with itself.
pub fn raw_pong(args: impl Iterator<Item = String>) {
    let (tcp, unix, _, _) = parse("raw-pong", args);
    let mut c = connect(&end_addr("raw-pong", tcp, unix)).expect("raw-pong: connect");
    let mut buf = Vec::new();
    while let Ok(true) = read_frame(&mut c, &mut buf) {
        if c.write_all(&buf).is_err() {
            break;
        }
    }
}

/// `session-bench raw-ping`: `count` timed round trips after a warm-up;
/// prints `median_us=` as `ping` does.
pub fn raw_ping(args: impl Iterator<Item = String>) {
    let (tcp, unix, count, size) = parse("raw-ping", args);
    let mut c = connect(&end_addr("raw-ping", tcp, unix)).expect("raw-ping: connect");
    let f = frame(size);
    let mut buf = Vec::new();
    let mut rtts = Vec::with_capacity(count);
    for i in 0..WARM_UP + count {
        let t0 = Instant::now();
        c.write_all(&f).expect("raw-ping: write");
        match read_frame(&mut c, &mut buf) {
            Ok(true) => {}
            other => {
                eprintln!("raw-ping: no answer ({other:?})");
                std::process::exit(1)
            }
        }
        if i >= WARM_UP {
            rtts.push(t0.elapsed().as_secs_f64() * 1e6);
        }
    }
    rtts.sort_by(f64::total_cmp);
    println!("median_us={:.2} count={count}", rtts[count / 2]);
}
