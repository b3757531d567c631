//! `rtps_bench floor`: the round trip of bare UDP datagrams on loopback, no
//! protocol at all, with the same CPU placements as the RTPS table. Three
//! ways to wait for a datagram:
//!
//! - **blocking**: `recv_from` on a plain socket, as ddsperf's receive
//!   thread does, answering from the same thread;
//! - **tokio readiness**: a current-thread runtime waiting in `epoll_wait`
//!   for the socket, then one `recvmmsg` (a short batch means the socket is
//!   empty), as Courier's RTPS driver receives;
//! - **tokio `UdpSocket::recv_from`**: tries the socket first and waits in
//!   `epoll_wait` on `EAGAIN`, one system call more per wake-up.
//!
//! Their difference is what an async library pays for waiting in the
//! runtime's epoll instead of in the socket, before any work of its own.
//! Datagrams are 148 bytes, the size of Courier's 16 B sample.
//!
//! ```text
//! rtps_bench floor [--quick] [--reps R]
//! rtps_bench udp-pong --port P [--tokio|--tokio-readiness] &
//! rtps_bench udp-ping --port P [--tokio|--tokio-readiness] --secs 3
//! ```

use std::net::{SocketAddr, UdpSocket};
use std::process::Command;
use std::time::{Duration, Instant};

use super::{percentile, result_line, run_pair, Watchdog, PLACEMENTS};

const DATAGRAM: usize = 148;
/// A datagram of this length ends the pong.
const END_LEN: usize = 1;
const RETRY: Duration = Duration::from_millis(200);
const IDLE: Duration = Duration::from_secs(60);

#[derive(Clone, Copy, PartialEq)]
enum Wait {
    /// `recv_from` on a blocking socket.
    Blocking,
    /// `tokio::net::UdpSocket::recv_from`: tries the socket, and on
    /// `EAGAIN` waits in `epoll_wait` and tries again (three system calls
    /// per wake-up with the send).
    Tokio,
    /// tokio readiness as the RTPS driver uses it: wait in `epoll_wait`,
    /// one `recvmmsg` of up to 2, and a short batch means the socket is
    /// empty (two system calls per wake-up with the send).
    TokioReadiness,
}

/// Options of the roles here: `udp-*` take `--port` and a way of waiting,
/// `sync-*` take `--domain` and `--size`.
struct Opts {
    port: u16,
    domain: u32,
    size: usize,
    wait: Wait,
    secs: f64,
    warmup: f64,
}

fn parse(args: &[String]) -> Result<Opts, String> {
    let mut o = Opts {
        port: 0,
        domain: 0,
        size: 16,
        wait: Wait::Blocking,
        secs: 3.0,
        warmup: 0.5,
    };
    let mut it = args.iter();
    let num = |v: Option<&String>, what: &str| -> Result<f64, String> {
        v.and_then(|s| s.parse::<f64>().ok())
            .ok_or_else(|| format!("{what} needs a number"))
    };
    while let Some(a) = it.next() {
        match a.as_str() {
            "--port" => o.port = num(it.next(), "--port")? as u16,
            "--domain" => o.domain = num(it.next(), "--domain")? as u32,
            "--size" => o.size = num(it.next(), "--size")? as usize,
            "--secs" => o.secs = num(it.next(), "--secs")?,
            "--warmup" => o.warmup = num(it.next(), "--warmup")?,
            "--tokio" => o.wait = Wait::Tokio,
            "--tokio-readiness" => o.wait = Wait::TokioReadiness,
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(o)
}

/// Runs role `udp-ping` or `udp-pong`; `None` for any other name.
pub fn role(name: &str, args: &[String]) -> Option<Result<(), String>> {
    let f: fn(&Opts) -> Result<(), String> = match name {
        "udp-ping" => ping,
        "udp-pong" => pong,
        _ => return None,
    };
    Some(parse(args).and_then(|o| {
        if o.port == 0 {
            return Err("--port P is required".into());
        }
        f(&o)
    }))
}

/// A socket in one of the two tokio ways of waiting.
enum AsyncSock {
    Tokio(tokio::net::UdpSocket),
    Ready {
        fd: tokio::io::unix::AsyncFd<UdpSocket>,
        /// Room for the second datagram of a batch.
        second: Vec<u8>,
        /// The second datagram of a batch of two, not yet returned: its
        /// length (in `second`) and sender.
        stash: Option<(usize, SocketAddr)>,
    },
}

impl AsyncSock {
    fn new(sock: UdpSocket, wait: Wait) -> Result<Self, String> {
        sock.set_nonblocking(true).map_err(|e| e.to_string())?;
        Ok(match wait {
            Wait::TokioReadiness => AsyncSock::Ready {
                fd: register(sock)?,
                second: vec![0; 2048],
                stash: None,
            },
            _ => {
                AsyncSock::Tokio(tokio::net::UdpSocket::from_std(sock).map_err(|e| e.to_string())?)
            }
        })
    }

    async fn recv_from(&mut self, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr)> {
        match self {
            AsyncSock::Tokio(s) => s.recv_from(buf).await,
            AsyncSock::Ready { fd, second, stash } => {
                if let Some((len, from)) = stash.take() {
                    buf[..len].copy_from_slice(&second[..len]);
                    return Ok((len, from));
                }
                loop {
                    let mut guard = fd.readable().await?;
                    match recv2(fd.get_ref(), buf, second) {
                        Ok((first, None)) => {
                            // fewer than asked for: the socket is empty
                            guard.clear_ready();
                            return Ok(first);
                        }
                        Ok((first, Some(next))) => {
                            *stash = Some(next);
                            return Ok(first);
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => guard.clear_ready(),
                        Err(e) => return Err(e),
                    }
                }
            }
        }
    }

    async fn send_to(&self, buf: &[u8], to: SocketAddr) -> std::io::Result<usize> {
        match self {
            AsyncSock::Tokio(s) => s.send_to(buf, to).await,
            AsyncSock::Ready { fd, .. } => loop {
                match fd.get_ref().send_to(buf, to) {
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        fd.writable().await?.clear_ready()
                    }
                    r => return r,
                }
            },
        }
    }
}

#[allow(unsafe_code)]
fn register(sock: UdpSocket) -> Result<tokio::io::unix::AsyncFd<UdpSocket>, String> {
    // SAFETY: the `AsyncFd` owns the socket, whose descriptor stays open and
    // the same until the `AsyncFd` is dropped.
    unsafe { tokio::io::unix::AsyncFd::register(sock) }.map_err(|e| e.into_parts().1.to_string())
}

/// One `recvmmsg` of up to two datagrams: the first, and the second if
/// there was one.
#[allow(unsafe_code)]
#[allow(clippy::type_complexity)]
fn recv2(
    s: &UdpSocket,
    a: &mut [u8],
    b: &mut [u8],
) -> std::io::Result<((usize, SocketAddr), Option<(usize, SocketAddr)>)> {
    use std::os::fd::AsRawFd;
    // SAFETY: zeroed C structs are valid; every pointer below points into
    // locals or into `a`/`b`, all alive for the whole call.
    unsafe {
        let mut addrs: [libc::sockaddr_in; 2] = std::mem::zeroed();
        let mut iov = [
            libc::iovec {
                iov_base: a.as_mut_ptr().cast(),
                iov_len: a.len(),
            },
            libc::iovec {
                iov_base: b.as_mut_ptr().cast(),
                iov_len: b.len(),
            },
        ];
        let mut msgs: [libc::mmsghdr; 2] = std::mem::zeroed();
        for i in 0..2 {
            msgs[i].msg_hdr.msg_name = (&mut addrs[i] as *mut libc::sockaddr_in).cast();
            msgs[i].msg_hdr.msg_namelen = std::mem::size_of::<libc::sockaddr_in>() as u32;
            msgs[i].msg_hdr.msg_iov = &mut iov[i];
            msgs[i].msg_hdr.msg_iovlen = 1;
        }
        let n = libc::recvmmsg(
            s.as_raw_fd(),
            msgs.as_mut_ptr(),
            2,
            libc::MSG_DONTWAIT,
            std::ptr::null_mut(),
        );
        if n < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let from = |i: usize| {
            SocketAddr::from((
                u32::from_be(addrs[i].sin_addr.s_addr).to_be_bytes(),
                u16::from_be(addrs[i].sin_port),
            ))
        };
        let first = (msgs[0].msg_len as usize, from(0));
        let second = (n == 2).then(|| (msgs[1].msg_len as usize, from(1)));
        Ok((first, second))
    }
}

fn pong(o: &Opts) -> Result<(), String> {
    let at = SocketAddr::from(([127, 0, 0, 1], o.port));
    let sock = UdpSocket::bind(at).map_err(|e| format!("udp-pong: bind {at}: {e}"))?;
    let mut buf = [0u8; 2048];
    let mut n = 0u64;
    if o.wait == Wait::Blocking {
        sock.set_read_timeout(Some(IDLE))
            .map_err(|e| e.to_string())?;
        loop {
            let (len, from) = sock
                .recv_from(&mut buf)
                .map_err(|e| format!("udp-pong: {e} (no ping for {IDLE:?}?)"))?;
            sock.send_to(&buf[..len], from).map_err(|e| e.to_string())?;
            n += 1;
            if len == END_LEN {
                break;
            }
        }
    } else {
        current_thread()?.block_on(async {
            let mut sock = AsyncSock::new(sock, o.wait)?;
            let idle = Watchdog::start(IDLE);
            loop {
                let (len, from) = tokio::select! {
                    biased;
                    r = sock.recv_from(&mut buf) => r.map_err(|e| e.to_string())?,
                    _ = idle.expired() => return Err(format!("udp-pong: no ping for {IDLE:?}")),
                };
                idle.kick();
                sock.send_to(&buf[..len], from)
                    .await
                    .map_err(|e| e.to_string())?;
                n += 1;
                if len == END_LEN {
                    return Ok(());
                }
            }
        })?;
    }
    println!("RESULT role=udp-pong echoed={n}");
    Ok(())
}

fn current_thread() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()
        .map_err(|e| e.to_string())
}

fn ping(o: &Opts) -> Result<(), String> {
    let to = SocketAddr::from(([127, 0, 0, 1], o.port));
    let sock = UdpSocket::bind(("127.0.0.1", 0)).map_err(|e| format!("udp-ping: bind: {e}"))?;
    let clock = Instant::now();
    let mut rtts: Vec<u64> = Vec::with_capacity(1 << 20);
    let mut retries = 0u64;
    let mut msg = [0x5au8; DATAGRAM];
    let mut buf = [0u8; 2048];
    let total = Duration::from_secs_f64(o.warmup + o.secs);
    let warmup = Duration::from_secs_f64(o.warmup);
    let mut seq = 0u64;
    if o.wait == Wait::Blocking {
        sock.set_read_timeout(Some(RETRY))
            .map_err(|e| e.to_string())?;
        while clock.elapsed() < total {
            seq += 1;
            msg[..8].copy_from_slice(&seq.to_le_bytes());
            let t = Instant::now();
            sock.send_to(&msg, to).map_err(|e| e.to_string())?;
            loop {
                match sock.recv_from(&mut buf) {
                    Ok((len, _)) if len >= 8 && buf[..8] == seq.to_le_bytes() => {
                        if clock.elapsed() >= warmup {
                            rtts.push(t.elapsed().as_nanos() as u64);
                        }
                        break;
                    }
                    Ok(_) => {} // a late answer to a retried ping
                    Err(_) => {
                        retries += 1;
                        break;
                    }
                }
            }
        }
        let _ = sock.send_to(&[0], to);
    } else {
        current_thread()?.block_on(async {
            let mut sock = AsyncSock::new(sock, o.wait)?;
            let retry = Watchdog::start(RETRY);
            while clock.elapsed() < total {
                seq += 1;
                msg[..8].copy_from_slice(&seq.to_le_bytes());
                retry.kick();
                let t = Instant::now();
                sock.send_to(&msg, to).await.map_err(|e| e.to_string())?;
                loop {
                    let r = tokio::select! {
                        biased;
                        r = sock.recv_from(&mut buf) => r,
                        _ = retry.expired() => {
                            retries += 1;
                            break;
                        }
                    };
                    match r {
                        Ok((len, _)) if len >= 8 && buf[..8] == seq.to_le_bytes() => {
                            if clock.elapsed() >= warmup {
                                rtts.push(t.elapsed().as_nanos() as u64);
                            }
                            break;
                        }
                        Ok(_) => {}
                        Err(e) => return Err(e.to_string()),
                    }
                }
            }
            let _ = sock.send_to(&[0], to).await;
            Ok(())
        })?;
    }
    print_rtts("udp-ping", rtts, retries);
    Ok(())
}

/// The ping roles' RESULT line.
fn print_rtts(role: &str, mut rtts: Vec<u64>, retries: u64) {
    rtts.sort_unstable();
    println!(
        "RESULT role={role} n={} median_us={:.2} p99_us={:.2} retries={retries}",
        rtts.len(),
        percentile(&rtts, 0.5) / 1e3,
        percentile(&rtts, 0.99) / 1e3,
    );
}

/// A port no one holds on 127.0.0.1 right now.
fn free_port() -> Result<u16, String> {
    let s = UdpSocket::bind(("127.0.0.1", 0)).map_err(|e| e.to_string())?;
    Ok(s.local_addr().map_err(|e| e.to_string())?.port())
}

/// `rtps_bench floor`: every way of waiting, both placements, `reps`
/// alternating runs each; prints the table.
pub fn table(exe: &std::path::Path, reps: usize, quick: bool) {
    let (secs, warmup) = if quick { (0.3, 0.2) } else { (3.0, 0.5) };
    // (label, roles, the flag that picks the way of waiting)
    let rows: [(&str, (&str, &str), Option<&str>); 4] = [
        (
            "a blocking `recv_from` (as ddsperf)",
            ("udp-ping", "udp-pong"),
            None,
        ),
        (
            "tokio, `epoll_wait` + one `recvmmsg` (as Courier's driver)",
            ("udp-ping", "udp-pong"),
            Some("--tokio-readiness"),
        ),
        (
            "tokio, `UdpSocket::recv_from`",
            ("udp-ping", "udp-pong"),
            Some("--tokio"),
        ),
        (
            "Courier's RTPS ping/pong (16 B sample) in a blocking loop, no runtime",
            ("sync-ping", "sync-pong"),
            None,
        ),
    ];
    let mut cells = vec![vec![Vec::new(); PLACEMENTS.len()]; rows.len()];
    let mut domain = 200;
    for _ in 0..reps {
        for (p, pl) in PLACEMENTS.iter().enumerate() {
            for (m, (_, (ping, pong), flag)) in rows.iter().enumerate() {
                // a free port for the bare UDP pong, a fresh domain for RTPS
                let at = if ping.starts_with("sync") {
                    domain = if domain >= 210 { 200 } else { domain + 1 };
                    ["--domain".to_string(), domain.to_string()]
                } else {
                    match free_port() {
                        Ok(port) => ["--port".to_string(), port.to_string()],
                        Err(e) => {
                            eprintln!("floor: no free port: {e}");
                            continue;
                        }
                    }
                };
                let cmd = |cpu: &str, role: &str| {
                    let mut c = Command::new("taskset");
                    c.arg("-c").arg(cpu).arg(exe).arg(role);
                    c.args(&at)
                        .args(["--secs", &secs.to_string()])
                        .args(["--warmup", &warmup.to_string()]);
                    if let Some(f) = flag {
                        c.arg(f);
                    }
                    c
                };
                let limit = Duration::from_secs_f64(secs + warmup + 30.0);
                match run_pair(cmd(pl.cpus.1, pong), cmd(pl.cpus.0, ping), limit) {
                    Ok((a, _)) => match result_line(&a)
                        .and_then(|m| m.get("median_us").and_then(|v| v.parse::<f64>().ok()))
                    {
                        Some(v) => cells[m][p].push(v),
                        None => eprintln!("floor {} {}: no result:\n{a}", ping, pl.name),
                    },
                    Err(e) => eprintln!("floor {} {}: {e}", ping, pl.name),
                }
            }
        }
    }
    println!(
        "\nRound trips on loopback with no runtime or no protocol: bare UDP, \
         {DATAGRAM}-byte datagrams, three ways of waiting; and Courier's RTPS code \
         waiting as ddsperf does. Median of {reps} alternating runs (their range in brackets)\n"
    );
    println!(
        "| waiting in | {} |",
        PLACEMENTS.map(|p| p.name).join(" | ")
    );
    println!("|---|{}", "---|".repeat(PLACEMENTS.len()));
    for (m, (name, _, _)) in rows.iter().enumerate() {
        let row: Vec<String> = cells[m]
            .iter_mut()
            .map(|v| {
                if v.is_empty() {
                    return "failed (see stderr)".into();
                }
                v.sort_by(f64::total_cmp);
                format!(
                    "{:.1} µs [runs {:.1}–{:.1}]",
                    v[(v.len() - 1) / 2],
                    v[0],
                    v[v.len() - 1]
                )
            })
            .collect();
        println!("| {name} | {} |", row.join(" | "));
    }
}

// ---------------------------------------------------------------------------
// Courier's RTPS protocol in a blocking loop

/// `sync-ping` / `sync-pong`: the same ping/pong as the RTPS table (topics,
/// types, QoS, CDR encode and decode of [`super::Data`]), but driven the way
/// ddsperf is: `courier_wire`'s sans-I/O participant in a plain loop that
/// blocks in `recv_from` on the user-data socket and answers from there,
/// with no runtime. Not a library feature: a measurement of what the
/// protocol code costs when the waiting is done as Cyclone does it.
pub fn sync_role(name: &str, args: &[String]) -> Option<Result<(), String>> {
    let ping = match name {
        "sync-ping" => true,
        "sync-pong" => false,
        _ => return None,
    };
    Some(parse(args).and_then(|o| {
        if o.domain > 232 {
            return Err("--domain must be 0..=232".into());
        }
        sync::run(ping, &o)
    }))
}

mod sync {
    use std::net::UdpSocket;
    use std::time::{Duration, Instant, SystemTime};

    use courier::cdr;
    use courier::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History, Reliability};
    use courier::rtps::participant::{
        guid_prefix, Change, Config, EndpointConfig, Event, Participant,
    };
    use courier::rtps::{Guid, Locator};

    use super::super::{Data, END, PING, PONG};
    use super::Opts;

    const LO: [u8; 4] = [127, 0, 0, 1];
    const TYPE: &str = "courier::bench::Data";

    struct Node {
        p: Participant,
        meta: UdpSocket,
        user: UdpSocket,
        buf: Vec<u8>,
        turns: u32,
        /// The user socket's receive time limit.
        timeout: Duration,
    }

    impl Node {
        /// A participant on the first free participant index.
        fn new(domain: u32, seed: u8) -> Result<Node, String> {
            for index in 0..20 {
                let mut entropy = [seed; 10];
                entropy[..4].copy_from_slice(&std::process::id().to_le_bytes());
                let cfg = Config::udpv4(domain, index, guid_prefix(entropy), LO)
                    .ok_or("no ports for this domain")?
                    .with_unicast_peers(&[LO], 9);
                let port = |l: &Locator| l.socket_addr().map(|a| a.port());
                let (Some(mp), Some(up)) = (
                    cfg.metatraffic_unicast.first().and_then(port),
                    cfg.default_unicast.first().and_then(port),
                ) else {
                    return Err("no unicast locators".into());
                };
                let (Ok(meta), Ok(user)) = (
                    UdpSocket::bind(("127.0.0.1", mp)),
                    UdpSocket::bind(("127.0.0.1", up)),
                ) else {
                    continue; // index taken
                };
                meta.set_nonblocking(true).map_err(|e| e.to_string())?;
                return Ok(Node {
                    p: Participant::new(cfg, Instant::now(), SystemTime::now()),
                    meta,
                    user,
                    buf: vec![0; 65_536],
                    turns: 0,
                    timeout: Duration::ZERO,
                });
            }
            Err("no free participant index".into())
        }

        fn send_all(&mut self) {
            while let Some(d) = self.p.poll_transmit() {
                if let Some(a) = d.destination.socket_addr().filter(|a| a.ip().is_loopback()) {
                    let _ = self.user.send_to(&d.payload, a);
                }
            }
        }

        /// After a turn of the loop: sends what is pending; after a
        /// receive that timed out, and every 1024 turns, also reads the
        /// discovery socket and fires timeouts (true then).
        fn between_turns(&mut self, got: bool) -> bool {
            self.send_all();
            self.turns = self.turns.wrapping_add(1);
            if got && self.turns % 1024 != 0 {
                return false;
            }
            self.meta();
            self.timeouts();
            self.send_all();
            true
        }

        fn timeouts(&mut self) {
            let now = Instant::now();
            if self.p.poll_timeout().is_some_and(|t| t <= now) {
                self.p.handle_timeout(now);
            }
        }

        /// Discovery traffic waiting on the metatraffic socket (not blocking).
        fn meta(&mut self) {
            while let Ok((n, from)) = self.meta.recv_from(&mut self.buf) {
                let src = match from {
                    std::net::SocketAddr::V4(a) => Locator::udpv4(a.ip().octets(), from.port()),
                    _ => continue,
                };
                self.p.handle_datagram(src, &self.buf[..n], Instant::now());
            }
        }

        /// One datagram from the user socket, blocking up to `wait`.
        fn user(&mut self, wait: Duration) -> bool {
            let wait = wait.max(Duration::from_micros(100));
            if self.timeout != wait {
                // a system call: only when the limit changes
                let _ = self.user.set_read_timeout(Some(wait));
                self.timeout = wait;
            }
            match self.user.recv_from(&mut self.buf) {
                Ok((n, from)) => {
                    let src = match from {
                        std::net::SocketAddr::V4(a) => Locator::udpv4(a.ip().octets(), from.port()),
                        _ => return false,
                    };
                    self.p.handle_datagram(src, &self.buf[..n], Instant::now());
                    true
                }
                Err(_) => false,
            }
        }
    }

    pub(super) fn run(ping: bool, o: &Opts) -> Result<(), String> {
        let mut n = Node::new(o.domain, if ping { 1 } else { 2 })?;
        let now = Instant::now();
        let mut wq = EndpointQos::writer_default();
        wq.reliability = Reliability::Reliable(RtpsDuration::ZERO);
        wq.history = History::KeepLast(1);
        let mut rq = EndpointQos::reader_default();
        rq.reliability = Reliability::Reliable(RtpsDuration::ZERO);
        let (out, inp) = if ping { (PING, PONG) } else { (PONG, PING) };
        let w =
            n.p.create_writer(EndpointConfig::writer(out, TYPE).qos(wq), now)
                .map_err(|e| e.to_string())?;
        let r =
            n.p.create_reader(EndpointConfig::reader(inp, TYPE).qos(rq), now)
                .map_err(|e| e.to_string())?;
        // discovery: both matches, both ways, within 20 s
        let (mut wm, mut rm) = (false, false);
        let give_up = Instant::now() + Duration::from_secs(20);
        while !(wm && rm) {
            if Instant::now() > give_up {
                return Err("no match within 20 s".into());
            }
            n.send_all();
            n.meta();
            n.user(Duration::from_millis(1));
            n.timeouts();
            while let Some(e) = n.p.poll_event() {
                match e {
                    Event::WriterMatched { writer, .. } if writer == w => wm = true,
                    Event::ReaderMatched { reader, .. } if reader == r => rm = true,
                    _ => {}
                }
            }
        }
        if ping {
            ping_loop(&mut n, w, o)
        } else {
            pong_loop(&mut n, w)
        }
    }

    /// Samples received, decoded.
    fn received(n: &mut Node) -> Vec<Data> {
        let mut v = Vec::new();
        while let Some(e) = n.p.poll_event() {
            if let Event::SampleReceived(s) = e {
                if let Ok(d) = cdr::from_slice::<Data>(s.data()) {
                    v.push(d);
                }
            }
        }
        v
    }

    fn write(n: &mut Node, w: Guid, d: &Data) {
        let bytes = cdr::to_vec(d, cdr::Encoding::Xcdr1Le);
        let _ = n.p.write(w, Change::alive(&bytes), Instant::now());
        n.send_all();
    }

    fn pong_loop(n: &mut Node, w: Guid) -> Result<(), String> {
        let mut echoed = 0u64;
        let mut quiet_since = Instant::now();
        loop {
            let got = n.user(Duration::from_millis(10));
            for d in received(n) {
                write(n, w, &d);
                echoed += 1;
                quiet_since = Instant::now();
                if d.seq == END {
                    n.send_all();
                    println!("RESULT role=sync-pong echoed={echoed}");
                    return Ok(());
                }
            }
            if n.between_turns(got) && quiet_since.elapsed() > Duration::from_secs(60) {
                return Err("sync-pong: no ping for 60 s".into());
            }
        }
    }

    fn ping_loop(n: &mut Node, w: Guid, o: &Opts) -> Result<(), String> {
        let clock = Instant::now();
        let mut v = Data::ping(o.size);
        let mut rtts: Vec<u64> = Vec::with_capacity(1 << 20);
        let mut retries = 0u64;
        let warmup = Duration::from_secs_f64(o.warmup);
        let total = Duration::from_secs_f64(o.warmup + o.secs);
        while clock.elapsed() < total {
            v.seq = (v.seq + 1) % END;
            v.ts_ns = clock.elapsed().as_nanos() as u64;
            write(n, w, &v);
            let sent = Instant::now();
            'wait: loop {
                let got = n.user(Duration::from_millis(10));
                for d in received(n) {
                    if d.seq == v.seq {
                        let rtt = (clock.elapsed().as_nanos() as u64).saturating_sub(d.ts_ns);
                        if clock.elapsed() >= warmup {
                            rtts.push(rtt);
                        }
                        n.send_all();
                        break 'wait;
                    }
                }
                n.between_turns(got);
                if sent.elapsed() > Duration::from_millis(200) {
                    retries += 1;
                    break;
                }
            }
        }
        v.seq = END;
        write(n, w, &v);
        // let pong's last answer come (and acknowledge it)
        let end = Instant::now() + Duration::from_millis(500);
        while Instant::now() < end {
            n.user(Duration::from_millis(10));
            if received(n).iter().any(|d| d.seq == END) {
                break;
            }
            n.send_all();
        }
        super::print_rtts("sync-ping", rtts, retries);
        Ok(())
    }
}
