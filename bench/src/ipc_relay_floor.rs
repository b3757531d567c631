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
//! The relay comes in four shapes (`--kind`), so that the floor can also
//! tell what the shape of a central's loop costs, apart from its IPC work:
//! - `threads`: one blocking thread per direction (the cheapest relay);
//! - `poll`: one thread that sleeps in `poll(2)` on both connections and
//!   copies whichever is readable, the shape of C's central (a `select`
//!   loop);
//! - `epoll`: the same loop asleep in `epoll_wait(2)`;
//! - `tokio`: one task on a current-thread tokio runtime built as
//!   `central` builds its own, woken through the runtime's reactor, the
//!   shape of Courier's central without its IPC logic.
//!
//! `--work-ns N` makes the relay spin N ns on each frame before writing it:
//! the CPU a central's own logic spends on a message, to measure what each
//! microsecond of it costs a round trip.
//!
//! ```text
//! session-bench relay --tcp PORT | --unix PATH [--kind threads|poll|epoll|tokio] [--work-ns N]   # first connection: the answering end
//! session-bench raw-pong --tcp PORT | --unix PATH
//! session-bench raw-ping --tcp PORT | --unix PATH --count N --size S   # prints median_us=
//! ```

use std::io::{self, Read, Write};
use std::net::{Ipv4Addr, Shutdown, TcpListener, TcpStream};
use std::os::fd::{AsRawFd, FromRawFd, RawFd};
use std::os::unix::net::{UnixListener, UnixStream};
use std::time::{Duration, Instant};

use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

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

    fn set_nonblocking(&self) -> io::Result<()> {
        match self {
            Conn::Tcp(s) => s.set_nonblocking(true),
            Conn::Unix(s) => s.set_nonblocking(true),
        }
    }

    /// `read` through a shared reference (both std streams allow it): the
    /// tokio relay reads through its readiness guard's `&Conn`.
    fn read_shared(&self, b: &mut [u8]) -> io::Result<usize> {
        match self {
            Conn::Tcp(s) => (&*s).read(b),
            Conn::Unix(s) => (&*s).read(b),
        }
    }

    fn write_shared(&self, b: &[u8]) -> io::Result<usize> {
        match self {
            Conn::Tcp(s) => (&*s).write(b),
            Conn::Unix(s) => (&*s).write(b),
        }
    }
}

impl AsRawFd for Conn {
    fn as_raw_fd(&self) -> RawFd {
        match self {
            Conn::Tcp(s) => s.as_raw_fd(),
            Conn::Unix(s) => s.as_raw_fd(),
        }
    }
}

impl Read for Conn {
    fn read(&mut self, b: &mut [u8]) -> io::Result<usize> {
        self.read_shared(b)
    }
}

impl Write for Conn {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        self.write_shared(b)
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

/// The length of the body that follows a frame's 28-byte header, checked
/// against `MAX_FRAME`.
fn body_len(header: &[u8]) -> io::Result<usize> {
    let field =
        |i: usize| i32::from_be_bytes([header[i], header[i + 1], header[i + 2], header[i + 3]]);
    let (class_total, msg_total) = (field(0), field(4));
    usize::try_from(class_total)
        .ok()
        .zip(usize::try_from(msg_total).ok())
        .map(|(a, b)| a + b)
        .filter(|&n| n <= MAX_FRAME)
        .ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::InvalidData,
                format!("bad frame lengths {class_total} + {msg_total}"),
            )
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
    let body = body_len(buf)?;
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

/// How the relay process is built (see the module's text).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Kind {
    Threads,
    Poll,
    Epoll,
    Tokio,
}

impl Kind {
    pub const ALL: [Kind; 4] = [Kind::Threads, Kind::Poll, Kind::Epoll, Kind::Tokio];

    pub fn arg(self) -> &'static str {
        match self {
            Kind::Threads => "threads",
            Kind::Poll => "poll",
            Kind::Epoll => "epoll",
            Kind::Tokio => "tokio",
        }
    }

    /// The row's name in `session-bench processes`' floor table.
    pub fn describe(self) -> &'static str {
        match self {
            Kind::Threads => "relay floor: a blocking thread per direction",
            Kind::Poll => "relay floor: one thread in poll(2), C central's shape",
            Kind::Epoll => "relay floor: one thread in epoll_wait(2)",
            Kind::Tokio => "relay floor: one tokio task, Courier central's shape",
        }
    }
}

struct Opts {
    tcp: Option<u16>,
    unix: Option<String>,
    count: usize,
    size: usize,
    kind: Kind,
    /// Busy work per frame before the relay writes it (`--work-ns`).
    work: Duration,
}

fn parse(role: &str, args: impl Iterator<Item = String>) -> Opts {
    let mut o = Opts {
        tcp: None,
        unix: None,
        count: 5000,
        size: 4,
        kind: Kind::Threads,
        work: Duration::ZERO,
    };
    let mut args = args;
    let fail = |m: String| -> ! {
        eprintln!("{role}: {m}");
        std::process::exit(2)
    };
    while let Some(a) = args.next() {
        let v = args.next();
        let num = || -> usize {
            v.as_deref()
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| fail(format!("{a} needs a number (got {v:?})")))
        };
        match a.as_str() {
            "--tcp" => {
                o.tcp = Some(
                    u16::try_from(num())
                        .unwrap_or_else(|_| fail(format!("--tcp {v:?} is not a port"))),
                )
            }
            "--unix" => o.unix = v.clone(),
            "--count" => o.count = num(),
            "--size" => o.size = num(),
            "--work-ns" => o.work = Duration::from_nanos(num() as u64),
            "--kind" => {
                o.kind = Kind::ALL
                    .into_iter()
                    .find(|k| Some(k.arg()) == v.as_deref())
                    .unwrap_or_else(|| {
                        fail(format!(
                            "--kind is threads, poll, epoll or tokio (got {v:?})"
                        ))
                    })
            }
            other => fail(format!("unknown argument {other:?}")),
        }
    }
    o
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
    let o = parse("relay", args);
    let tl = o
        .tcp
        .map(|p| TcpListener::bind((Ipv4Addr::LOCALHOST, p)).expect("relay: bind TCP"));
    let ul = o.unix.map(|p| {
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
    let r = match o.kind {
        Kind::Threads => relay_threads(a, b, o.work),
        Kind::Poll => relay_poll(a, b, o.work),
        Kind::Epoll => relay_epoll(a, b, o.work),
        Kind::Tokio => relay_tokio(a, b, o.work),
    };
    if let Err(e) = r {
        eprintln!("relay: {e}");
        std::process::exit(1)
    }
}

/// Spins for `work` (nothing for zero): the CPU a central's own logic
/// spends on a frame, for measuring what that costs a round trip.
fn busy(work: Duration) {
    if work.is_zero() {
        return;
    }
    let t0 = Instant::now();
    while t0.elapsed() < work {
        std::hint::spin_loop();
    }
}

fn relay_threads(a: Conn, b: Conn, work: Duration) -> io::Result<()> {
    let (a2, b2) = (a.try_clone()?, b.try_clone()?);
    let pump = move |mut from: Conn, mut to: Conn| {
        let mut buf = Vec::with_capacity(4096);
        while let Ok(true) = read_frame(&mut from, &mut buf) {
            busy(work);
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
    Ok(())
}

/// Reads a frame from `from` (blocking: a frame that has started to arrive
/// is read whole, as C's central reads one) and writes it to `to`; false
/// at a clean end of stream.
fn copy_frame(
    from: &mut Conn,
    to: &mut Conn,
    buf: &mut Vec<u8>,
    work: Duration,
) -> io::Result<bool> {
    if !read_frame(from, buf)? {
        return Ok(false);
    }
    busy(work);
    to.write_all(buf)?;
    Ok(true)
}

/// One thread asleep in `poll(2)` on both connections.
fn relay_poll(mut a: Conn, mut b: Conn, work: Duration) -> io::Result<()> {
    let mut buf = Vec::with_capacity(4096);
    let mut fds = [a.as_raw_fd(), b.as_raw_fd()].map(|fd| libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    });
    loop {
        // SAFETY: `fds` is an array of two initialised `pollfd`.
        if unsafe { libc::poll(fds.as_mut_ptr(), 2, -1) } < 0 {
            retry_on_eintr()?;
            continue;
        }
        for (i, fd) in fds.iter().enumerate() {
            if fd.revents == 0 {
                continue;
            }
            let (from, to) = if i == 0 {
                (&mut a, &mut b)
            } else {
                (&mut b, &mut a)
            };
            if !copy_frame(from, to, &mut buf, work)? {
                return Ok(());
            }
        }
    }
}

/// Ok when the last system call was interrupted by a signal (try again),
/// its error otherwise.
fn retry_on_eintr() -> io::Result<()> {
    let e = io::Error::last_os_error();
    match e.kind() {
        io::ErrorKind::Interrupted => Ok(()),
        _ => Err(e),
    }
}

/// One thread asleep in `epoll_wait(2)` on both connections (level
/// triggered, read interest only): tells the poll relay's shape from the
/// system call tokio's reactor sleeps in.
fn relay_epoll(mut a: Conn, mut b: Conn, work: Duration) -> io::Result<()> {
    // SAFETY: plain system calls on descriptors this function owns or
    // borrows for its whole run; `evs` outlives every `epoll_wait`.
    let ep = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
    if ep < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `ep` was just created and is owned by nothing else.
    let _ep = unsafe { std::os::fd::OwnedFd::from_raw_fd(ep) };
    for (i, fd) in [a.as_raw_fd(), b.as_raw_fd()].into_iter().enumerate() {
        let mut ev = libc::epoll_event {
            events: libc::EPOLLIN as u32,
            u64: i as u64,
        };
        // SAFETY: as above; `ev` is a valid event for the call.
        if unsafe { libc::epoll_ctl(ep, libc::EPOLL_CTL_ADD, fd, &mut ev) } < 0 {
            return Err(io::Error::last_os_error());
        }
    }
    let mut buf = Vec::with_capacity(4096);
    let mut evs = [libc::epoll_event { events: 0, u64: 0 }; 2];
    loop {
        // SAFETY: `evs` has room for the 2 events asked for.
        let n = unsafe { libc::epoll_wait(ep, evs.as_mut_ptr(), 2, -1) };
        if n < 0 {
            retry_on_eintr()?;
            continue;
        }
        for e in &evs[..n as usize] {
            let (from, to) = if e.u64 == 0 {
                (&mut a, &mut b)
            } else {
                (&mut b, &mut a)
            };
            if !copy_frame(from, to, &mut buf, work)? {
                return Ok(());
            }
        }
    }
}

/// One task on a current-thread runtime built and entered as `central`
/// enters its own (the task spawned, `block_on` waiting for it), woken
/// through the reactor; non-blocking reads into a buffer per connection,
/// whole frames written straight to the other connection.
fn relay_tokio(a: Conn, b: Conn, work: Duration) -> io::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        tokio::spawn(async move {
            a.set_nonblocking()?;
            b.set_nonblocking()?;
            // Read readiness only, as central registers its modules: write
            // interest would wake the relay each time a peer takes in what
            // it was sent (a UNIX socket reports room on every read). With
            // both interests this relay was 1.14-1.31x the poll relay over
            // the UNIX socket; with read interest only, at par.
            let a = register(a, Interest::READABLE)?;
            let b = register(b, Interest::READABLE)?;
            let (mut abuf, mut bbuf) = (Pending::new(), Pending::new());
            loop {
                let open = tokio::select! {
                    g = a.readable() => pump_nb(g?, &b, &mut abuf, work).await?,
                    g = b.readable() => pump_nb(g?, &a, &mut bbuf, work).await?,
                };
                if !open {
                    return Ok(());
                }
            }
        })
        .await
        .map_err(io::Error::other)?
    })
}

/// `conn` in the current runtime's reactor with `interest`.
fn register(conn: Conn, interest: Interest) -> io::Result<AsyncFd<Conn>> {
    // SAFETY: the `Conn` owns its descriptor and is moved into the
    // `AsyncFd`, which deregisters it before the descriptor closes.
    unsafe { AsyncFd::register_with_interest(conn, interest) }.map_err(|e| e.into_parts().1)
}

/// What a connection has read and not yet relayed: a buffer zeroed once
/// (zeroing it per read cost the relay more than its system calls) and
/// grown only for a frame that does not fit.
struct Pending {
    buf: Vec<u8>,
    filled: usize,
}

impl Pending {
    fn new() -> Pending {
        Pending {
            buf: vec![0; 4096],
            filled: 0,
        }
    }
}

/// Reads what `from` has into `p` and writes every whole frame in it to
/// `to`; false once `from` has closed.
async fn pump_nb(
    mut g: tokio::io::unix::AsyncFdReadyGuard<'_, Conn>,
    to: &AsyncFd<Conn>,
    p: &mut Pending,
    work: Duration,
) -> io::Result<bool> {
    let room = p.buf.len() - p.filled;
    let n = match g.try_io(|c| c.get_ref().read_shared(&mut p.buf[p.filled..])) {
        Ok(Ok(0)) => return Ok(false),
        Ok(Ok(n)) => n,
        Ok(Err(e)) => return Err(e),
        Err(_would_block) => 0,
    };
    // A short read emptied the socket: wait for the next edge instead of
    // reading once more to see `WouldBlock` (as tokio's own streams do).
    if n > 0 && n < room {
        g.clear_ready();
    }
    drop(g);
    p.filled += n;
    let mut start = 0;
    while p.filled - start >= HEADER {
        let end = start + HEADER + body_len(&p.buf[start..])?;
        if end > p.filled {
            if end - start > p.buf.len() {
                p.buf.resize(end - start, 0);
            }
            break;
        }
        busy(work);
        let mut out = &p.buf[start..end];
        while !out.is_empty() {
            match to.get_ref().write_shared(out) {
                Ok(n) => out = &out[n..],
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    // Write interest only while a write waits for room, on
                    // a duplicate descriptor (one registration per
                    // descriptor), as central does.
                    let w = register(to.get_ref().try_clone()?, Interest::WRITABLE)?;
                    let _ready = w.writable().await?;
                }
                Err(e) => return Err(e),
            }
        }
        start = end;
    }
    p.buf.copy_within(start..p.filled, 0);
    p.filled -= start;
    Ok(true)
}

/// `session-bench raw-pong`: answers every frame with itself.
pub fn raw_pong(args: impl Iterator<Item = String>) {
    let o = parse("raw-pong", args);
    let mut c = connect(&end_addr("raw-pong", o.tcp, o.unix)).expect("raw-pong: connect");
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
    let Opts {
        tcp,
        unix,
        count,
        size,
        ..
    } = parse("raw-ping", args);
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
