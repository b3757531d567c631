//! What `xrce_bench` and `xrce_soak` share: the private network namespace
//! they run in, Courier's XRCE agent as a process of its own, and what
//! /proc says about a process (CPU time, resident memory).

use std::net::{Ipv4Addr, SocketAddr, UdpSocket};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

/// Set in the environment of the copy of the harness that runs inside the
/// namespace.
const INSIDE: &str = "COURIER_XRCE_BENCH_NETNS";

/// Runs the harness inside a new, private network namespace that has only
/// `lo` (`unshare -rn`, then `ip link set lo up`): eProsima's agent embeds a
/// Fast DDS participant that would otherwise send to the machine's real
/// interfaces. Returns `None` when this process already is that copy (go
/// on), or the exit code of the copy that ran.
pub fn enter_private_netns(args: &[String]) -> Option<ExitCode> {
    if std::env::var_os(INSIDE).is_some() {
        if let Err(e) = lo_only() {
            eprintln!("network namespace: {e}");
            return Some(ExitCode::FAILURE);
        }
        return None;
    }
    let exe = match std::env::current_exe() {
        Ok(e) => e,
        Err(e) => {
            eprintln!("cannot find my own executable: {e}");
            return Some(ExitCode::FAILURE);
        }
    };
    let status = Command::new("unshare")
        .arg("-rn")
        .arg(exe)
        .args(args)
        .env(INSIDE, "1")
        .status();
    match status {
        Ok(s) => Some(ExitCode::from(s.code().unwrap_or(1).clamp(0, 255) as u8)),
        Err(e) => {
            eprintln!(
                "cannot start `unshare -rn` (util-linux) for a private network namespace: {e}"
            );
            Some(ExitCode::FAILURE)
        }
    }
}

/// Brings `lo` up and checks that it is the only interface.
fn lo_only() -> Result<(), String> {
    let out = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .output()
        .map_err(|e| format!("cannot run ip (iproute2): {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "ip link set lo up: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    // /proc/self/net/dev is this namespace's (unlike /sys, still the host's)
    let dev = std::fs::read_to_string("/proc/self/net/dev").map_err(|e| e.to_string())?;
    let others: Vec<&str> = dev
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next())
        .map(str::trim)
        .filter(|n| *n != "lo")
        .collect();
    if others.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "interfaces besides lo: {others:?}; refusing to run"
        ))
    }
}

/// A free UDP port on 127.0.0.1 (bound and released; inside the private
/// namespace nobody else takes it meanwhile).
pub fn free_udp_port() -> Result<u16, String> {
    let s = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).map_err(|e| e.to_string())?;
    Ok(s.local_addr().map_err(|e| e.to_string())?.port())
}

/// Clock ticks per second of /proc's CPU times.
fn ticks_per_sec() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 {
        t as f64
    } else {
        100.0
    }
}

/// User plus system CPU time of process `pid` (all its threads), in
/// seconds; `None` once it is gone.
pub fn cpu_secs(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // after the command: state (3) … utime (14), stime (15)
    let f: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ut: u64 = f.get(11)?.parse().ok()?;
    let st: u64 = f.get(12)?.parse().ok()?;
    Some((ut + st) as f64 / ticks_per_sec())
}

/// Resident memory of process `pid` (VmRSS) in KiB.
pub fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// CPU seconds of several processes, summed; `None` if any is gone.
pub fn cpu_secs_of(pids: &[u32]) -> Option<f64> {
    pids.iter().map(|&p| cpu_secs(p)).sum()
}

/// A child process that is stopped (SIGTERM, then SIGKILL) when dropped.
pub struct Proc {
    pub name: String,
    pub child: Child,
    /// After [`Proc::wait_line`]: the rest of stdout, sent at its end.
    rest: Option<std::sync::mpsc::Receiver<String>>,
}

impl Proc {
    /// Starts `cmd` with stdout piped (for [`Proc::wait_line`]) and stderr
    /// to a file under the temporary directory, named after `name`.
    pub fn spawn(name: &str, mut cmd: Command) -> Result<Proc, String> {
        let log = std::env::temp_dir().join(format!(
            "xrce-bench-{}-{}.log",
            name.replace(' ', "_"),
            std::process::id()
        ));
        let err = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(err)
            .spawn()
            .map_err(|e| format!("cannot start {name} ({:?}): {e}", cmd.get_program()))?;
        Ok(Proc {
            name: name.to_string(),
            child,
            rest: None,
        })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Waits (at most `limit`) for a line of stdout that contains
    /// `prefix`, and returns it; reads stdout on a thread so that the
    /// bound holds however the child behaves.
    pub fn wait_line(&mut self, prefix: &str, limit: Duration) -> Result<String, String> {
        use std::io::BufRead;
        let out = self
            .child
            .stdout
            .take()
            .ok_or_else(|| format!("{}: stdout already taken", self.name))?;
        let (tx, rx) = std::sync::mpsc::channel();
        let (rest_tx, rest_rx) = std::sync::mpsc::channel();
        self.rest = Some(rest_rx);
        let prefix_owned = prefix.to_string();
        std::thread::spawn(move || {
            let mut r = std::io::BufReader::new(out);
            let mut line = String::new();
            let mut lines = Vec::new();
            loop {
                line.clear();
                match r.read_line(&mut line) {
                    Ok(0) | Err(_) => {
                        let _ = tx.send(Err(lines.join("")));
                        return;
                    }
                    Ok(_) if line.contains(prefix_owned.as_str()) => {
                        let _ = tx.send(Ok(line.trim_end().to_string()));
                        // keep reading, so that the child never blocks on a
                        // full pipe; the rest goes to `finish`
                        let mut rest = String::new();
                        while matches!(r.read_line(&mut rest), Ok(n) if n > 0) {}
                        let _ = rest_tx.send(rest);
                        return;
                    }
                    Ok(_) => lines.push(line.clone()),
                }
            }
        });
        match rx.recv_timeout(limit) {
            Ok(Ok(l)) => Ok(l),
            Ok(Err(out)) => Err(format!(
                "{} ended before printing {prefix:?} (stdout: {out:?}; stderr in {})",
                self.name,
                std::env::temp_dir().display()
            )),
            Err(_) => Err(format!(
                "{} printed no {prefix:?} within {limit:?}",
                self.name
            )),
        }
    }

    /// Waits at most `limit` for the process to end on its own; its
    /// stdout as a string. Killed if it does not end in time.
    pub fn finish(mut self, limit: Duration) -> Result<String, String> {
        use std::io::Read;
        let out = self.child.stdout.take();
        let rest = self.rest.take();
        let reader = std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(mut o) = out {
                let _ = o.read_to_string(&mut s);
            } else if let Some(r) = rest {
                // the child has ended (or was killed): its pipe closes
                s = r.recv_timeout(Duration::from_secs(10)).unwrap_or_default();
            }
            s
        });
        let t = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(_)) => break,
                Ok(None) if t.elapsed() < limit => std::thread::sleep(Duration::from_millis(10)),
                _ => {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    let s = reader.join().unwrap_or_default();
                    return Err(format!(
                        "{} did not finish within {limit:?} (stdout: {s:?})",
                        self.name
                    ));
                }
            }
        }
        Ok(reader.join().unwrap_or_default())
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(Some(_)) = self.child.try_wait() {
            return;
        }
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        unsafe {
            libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM);
        }
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(3) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The `courier-agent --port P [--domain D]` role: Courier's XRCE agent
/// (the library the `xrce-agent` binary runs, on the same current-thread
/// runtime) on UDP 127.0.0.1:P, its DDS participant on lo with unicast
/// discovery at 127.0.0.1 and no multicast. Prints `ready <addr>`, then
/// runs until SIGTERM or SIGINT.
pub fn courier_agent_role(args: &[String]) -> Result<(), String> {
    use courier::rtps_backend::RtpsOptions;
    use courier_broker::xrce_agent::{Transport, XrceAgent};
    let (mut port, mut domain) = (0u16, 0u32);
    let mut state: Option<std::path::PathBuf> = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        if a == "--state" {
            state = it.next().map(Into::into);
            if state.is_none() {
                return Err("courier-agent: --state needs a directory".into());
            }
            continue;
        }
        let v = it.next().and_then(|v| v.parse::<u32>().ok());
        match (a.as_str(), v) {
            ("--port", Some(p)) if p <= 65535 => port = p as u16,
            ("--domain", Some(d)) if d <= 232 => domain = d,
            _ => {
                return Err(format!(
                    "courier-agent: bad argument {a:?} (--port P --domain D [--state DIR])"
                ))
            }
        }
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    rt.block_on(async move {
        let mut rtps = RtpsOptions::default();
        rtps.domain = domain;
        rtps.interface = Some("127.0.0.1".into());
        rtps.peers = vec!["127.0.0.1".into()];
        rtps.multicast = false;
        let mut builder = XrceAgent::builder()
            .transport(Transport::Udp(SocketAddr::from((
                Ipv4Addr::LOCALHOST,
                port,
            ))))
            .rtps(rtps);
        if let Some(dir) = state {
            builder = builder.state(dir);
        }
        let agent = builder
            .spawn()
            .await
            .map_err(|e| format!("courier-agent: {e}"))?;
        println!("ready {}", agent.udp_addrs()[0]);
        use tokio::signal::unix::{signal, SignalKind};
        let mut term = signal(SignalKind::terminate()).map_err(|e| e.to_string())?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        agent.shutdown().await;
        Ok(())
    })
}
