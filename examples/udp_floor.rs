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

struct Opts {
    port: u16,
    wait: Wait,
    secs: f64,
    warmup: f64,
}

fn parse(args: &[String]) -> Result<Opts, String> {
    let mut o = Opts {
        port: 0,
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
            "--secs" => o.secs = num(it.next(), "--secs")?,
            "--warmup" => o.warmup = num(it.next(), "--warmup")?,
            "--tokio" => o.wait = Wait::Tokio,
            "--tokio-readiness" => o.wait = Wait::TokioReadiness,
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    if o.port == 0 {
        return Err("--port P is required".into());
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
    Some(parse(args).and_then(|o| f(&o)))
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
    rtts.sort_unstable();
    println!(
        "RESULT role=udp-ping n={} median_us={:.2} p99_us={:.2} retries={retries}",
        rtts.len(),
        percentile(&rtts, 0.5) / 1e3,
        percentile(&rtts, 0.99) / 1e3,
    );
    Ok(())
}

/// A port no one holds on 127.0.0.1 right now.
fn free_port() -> Result<u16, String> {
    let s = UdpSocket::bind(("127.0.0.1", 0)).map_err(|e| e.to_string())?;
    Ok(s.local_addr().map_err(|e| e.to_string())?.port())
}

/// `rtps_bench floor`: both ways of waiting, both placements, `reps`
/// alternating runs each; prints the table.
pub fn table(exe: &std::path::Path, reps: usize, quick: bool) {
    let (secs, warmup) = if quick { (0.3, 0.2) } else { (3.0, 0.5) };
    let modes = [
        ("a blocking `recv_from` (as ddsperf)", None),
        (
            "tokio, `epoll_wait` + one `recvmmsg` (as Courier's driver)",
            Some("--tokio-readiness"),
        ),
        ("tokio, `UdpSocket::recv_from`", Some("--tokio")),
    ];
    let mut cells = vec![vec![Vec::new(); PLACEMENTS.len()]; modes.len()];
    for _ in 0..reps {
        for (p, pl) in PLACEMENTS.iter().enumerate() {
            for (m, (_, flag)) in modes.iter().enumerate() {
                let port = match free_port() {
                    Ok(p) => p,
                    Err(e) => {
                        eprintln!("floor: no free port: {e}");
                        continue;
                    }
                };
                let cmd = |cpu: &str, role: &str| {
                    let mut c = Command::new("taskset");
                    c.arg("-c").arg(cpu).arg(exe).arg(role);
                    c.args(["--port", &port.to_string()])
                        .args(["--secs", &secs.to_string()])
                        .args(["--warmup", &warmup.to_string()]);
                    if let Some(f) = flag {
                        c.arg(f);
                    }
                    c
                };
                let limit = Duration::from_secs_f64(secs + warmup + 30.0);
                match run_pair(
                    cmd(pl.cpus.1, "udp-pong"),
                    cmd(pl.cpus.0, "udp-ping"),
                    limit,
                ) {
                    Ok((a, _)) => match result_line(&a)
                        .and_then(|m| m.get("median_us").and_then(|v| v.parse::<f64>().ok()))
                    {
                        Some(v) => cells[m][p].push(v),
                        None => eprintln!("floor {}: no result:\n{a}", pl.name),
                    },
                    Err(e) => eprintln!("floor {}: {e}", pl.name),
                }
            }
        }
    }
    println!(
        "\nUDP round trip on loopback, {DATAGRAM}-byte datagrams, no protocol; \
         median of {reps} alternating runs (their range in brackets)\n"
    );
    println!(
        "| waiting in | {} |",
        PLACEMENTS.map(|p| p.name).join(" | ")
    );
    println!("|---|{}", "---|".repeat(PLACEMENTS.len()));
    for (m, (name, _)) in modes.iter().enumerate() {
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
