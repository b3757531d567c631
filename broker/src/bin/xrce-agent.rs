//! `xrce-agent`: a DDS-XRCE agent with MicroXRCEAgent's command line,
//! bridging XRCE clients into one DDS participant.
//!
//! ```text
//! xrce-agent udp4 -p 8888 [-v 4] [-r refs.xml] [-d [7400]] [-m dds]
//! xrce-agent tcp4 -p 8888
//! xrce-agent serial --dev /dev/ttyUSB0 -b 115200
//! xrce-agent pseudoterminal [--dev /tmp/xrce-pty]
//! xrce-agent udp4 -p 8888 tcp4 -p 8889 --domain 3 --interface lo --peers 127.0.0.1
//! ```
//! Several transports may follow one another; options apply to the whole
//! agent wherever they stand. Beyond MicroXRCEAgent's: `--bind` (the
//! address UDP, TCP and discovery listen on; default every interface, as
//! MicroXRCEAgent), and the DDS participant's `--domain`, `--interface`,
//! `--peers`, `--multicast on|off` and `--any-domain`; and `--state <file>`,
//! which keeps clients' sessions and objects so that a restarted agent
//! serves them again.
//!
//! Exit status (`--help` says it too): 2 for a wrong command line, which
//! includes a file, directory or device it names that is not there (the
//! references file, `--state`'s directory, a serial device, a
//! pseudo-terminal link's directory), checked before anything starts; 1
//! when the agent cannot start for another reason (a port in use).

use std::net::{IpAddr, Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use courier::rtps_backend::RtpsOptions;
use courier_broker::xrce_agent::{Transport, XrceAgent};

/// `println!` that does not panic when stdout is gone (a supervisor's log
/// pipe closed before the start-up lines): what the agent prints is for
/// people and scripts, and a closed pipe must not stop it.
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}
use courier_wire::xrce::bridge::Profiles;

const AFTER_HELP: &str = "\
Several transports may be given one after another, e.g. `xrce-agent udp4 -p 8888 tcp4 -p 8889`.
The options other than a transport's own (-p, --dev, --baudrate) are the whole agent's: they
apply to every transport and to its one DDS participant, whichever transport they follow; one
given twice with different values is an error.

Exit status: 0 stopped by Ctrl-C, SIGTERM or SIGHUP; 2 the command line is wrong: a bad option,
or a file, directory or device it names that is not there or cannot be used (-r's
references file, missing or not valid; --state's directory; serial --dev; pseudoterminal
--dev's directory); 1 the agent could not start for another reason (a port in use, the
DDS participant, a state file in use by another agent or damaged, a serial device that
does not open).";

const TRANSPORTS: [&str; 4] = ["udp4", "tcp4", "serial", "pseudoterminal"];
const UNSUPPORTED: [&str; 5] = ["udp6", "tcp6", "multiserial", "canfd", "termios"];

#[derive(Parser, Debug)]
#[command(
    name = "xrce-agent",
    version,
    about = "A DDS-XRCE agent: XRCE clients' entities in one DDS participant",
    after_help = AFTER_HELP
)]
struct Chunk {
    #[command(subcommand)]
    transport: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// UDP over IPv4.
    Udp4(Net),
    /// TCP over IPv4.
    Tcp4(Net),
    /// A serial device.
    Serial(Serial),
    /// A new pseudo-terminal (its path is printed).
    Pseudoterminal(Pty),
}

#[derive(Args, Debug)]
struct Net {
    /// Port to listen on (0: any free port, printed).
    #[arg(short = 'p', long)]
    port: u16,
    #[command(flatten)]
    common: Common,
}

#[derive(Args, Debug)]
struct Serial {
    /// The serial device.
    #[arg(short = 'D', long = "dev")]
    dev: PathBuf,
    /// Baud rate.
    #[arg(short = 'b', long = "baudrate", default_value_t = 115_200)]
    baud: u32,
    #[command(flatten)]
    common: Common,
}

#[derive(Args, Debug)]
struct Pty {
    /// A symbolic link to make to the new pseudo-terminal.
    #[arg(short = 'D', long = "dev")]
    dev: Option<PathBuf>,
    /// Baud rate (a pseudo-terminal has none; accepted for MicroXRCEAgent's command lines).
    #[arg(short = 'b', long = "baudrate")]
    baud: Option<u32>,
    #[command(flatten)]
    common: Common,
}

#[derive(Args, Debug, Default, Clone)]
struct Common {
    /// Verbosity 0 (nothing) to 6 (everything), as MicroXRCEAgent's; default 4. RUST_LOG, when set, is used instead.
    #[arg(short = 'v', long = "verbose", value_parser = clap::value_parser!(u8).range(0..=6))]
    verbose: Option<u8>,
    /// References file (Fast DDS profiles XML) for CREATE by reference.
    #[arg(short = 'r', long = "refs")]
    refs: Option<PathBuf>,
    /// Answer discovery on this UDP port (default 7400) and 239.255.0.2.
    #[arg(short = 'd', long = "discovery", num_args = 0..=1, default_missing_value = "7400")]
    discovery: Option<u16>,
    /// Middleware: only `dds`.
    #[arg(short = 'm', long = "middleware")]
    middleware: Option<String>,
    /// Address UDP, TCP and discovery listen on (default 0.0.0.0).
    #[arg(long)]
    bind: Option<Ipv4Addr>,
    /// DDS domain id of the agent's participant (default 0; at most 232,
    /// the highest the standard port mapping allows).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=232))]
    domain: Option<u32>,
    /// Network interface (name or IPv4 address) of the DDS participant.
    #[arg(long)]
    interface: Option<String>,
    /// Unicast discovery peers of the DDS participant (ip or ip:port, comma-separated).
    #[arg(long, value_delimiter = ',')]
    peers: Vec<String>,
    /// SPDP multicast discovery: on or off (default on unless --peers).
    #[arg(long, value_parser = on_off)]
    multicast: Option<bool>,
    /// Take XRCE participants of any domain id into the agent's domain.
    #[arg(long)]
    any_domain: bool,
    /// Keep clients' sessions and objects in this file and serve them again
    /// after a restart (give the transports in the same order).
    #[arg(long)]
    state: Option<PathBuf>,
    /// Delete the session of a client that said nothing for this long, as
    /// its DELETE would (default: never, as eProsima's agent: a client that
    /// only subscribes best effort may be silent for hours). Whatever this
    /// is, at the most sessions (1024) a new client takes the place of the
    /// one silent the longest, if silent for a minute.
    #[arg(long, value_name = "SECS", value_parser = clap::value_parser!(u64).range(1..=31_536_000))]
    client_timeout: Option<u64>,
}

fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" | "true" | "yes" | "1" => Ok(true),
        "off" | "false" | "no" | "0" => Ok(false),
        _ => Err(format!("{s:?}: expected on or off")),
    }
}

/// `a` and `b`, the same option from two transports' parts: one value for
/// the agent, or an error naming both.
fn one<T: PartialEq + std::fmt::Debug>(
    name: &str,
    a: Option<T>,
    b: Option<T>,
) -> Result<Option<T>, String> {
    match (a, b) {
        (Some(a), Some(b)) if a != b => Err(format!(
            "{name} is given twice, as {a:?} and {b:?}: it applies to the whole agent (every \
             transport and its one DDS participant), whichever transport it follows; give it \
             once"
        )),
        (a, b) => Ok(b.or(a)),
    }
}

impl Common {
    /// Takes in the options of another transport's part: they are the
    /// agent's, so one given twice must agree (the last used to win,
    /// silently: `udp4 --bind 127.0.0.1 … tcp4 --bind 127.0.0.2` bound
    /// both to 127.0.0.2).
    fn merge(&mut self, o: Common) -> Result<(), String> {
        // every field named: an option left out of the merge is a compile
        // error, not an option silently ignored
        let Common {
            verbose,
            refs,
            discovery,
            middleware,
            bind,
            domain,
            interface,
            peers,
            multicast,
            any_domain,
            state,
            client_timeout,
        } = o;
        self.verbose = one("-v/--verbose", self.verbose, verbose)?;
        self.refs = one("-r/--refs", self.refs.take(), refs)?;
        self.discovery = one("-d/--discovery", self.discovery, discovery)?;
        self.middleware = one("-m/--middleware", self.middleware.take(), middleware)?;
        self.bind = one("--bind", self.bind, bind)?;
        self.domain = one("--domain", self.domain, domain)?;
        self.interface = one("--interface", self.interface.take(), interface)?;
        self.peers.extend(peers);
        self.multicast = one("--multicast", self.multicast, multicast)?;
        self.any_domain |= any_domain;
        self.state = one("--state", self.state.take(), state)?;
        self.client_timeout = one("--client-timeout", self.client_timeout, client_timeout)?;
        Ok(())
    }
}

/// What the command line asks for.
struct Plan {
    transports: Vec<Cmd>,
    common: Common,
}

/// Splits the arguments at each transport name and parses each part.
fn parse(args: Vec<String>) -> Result<Plan, clap::Error> {
    let mut chunks: Vec<Vec<String>> = Vec::new();
    let mut pre: Vec<String> = Vec::new();
    for a in args.into_iter().skip(1) {
        if TRANSPORTS.contains(&a.as_str()) {
            chunks.push(vec![a]);
        } else if let Some(c) = chunks.last_mut() {
            c.push(a);
        } else {
            pre.push(a);
        }
    }
    if let Some(u) = pre
        .iter()
        .chain(chunks.iter().flatten())
        .find(|a| UNSUPPORTED.contains(&a.as_str()))
    {
        return Err(clap::Error::raw(
            clap::error::ErrorKind::InvalidSubcommand,
            format!(
                "the {u} transport is not supported (these are: {})\n",
                TRANSPORTS.join(", ")
            ),
        ));
    }
    // options and no transport (`xrce-agent -p 8888`): a transport comes
    // first, as in MicroXRCEAgent's command line
    if let Some(o) = pre
        .iter()
        .find(|a| a.starts_with('-') && !matches!(a.as_str(), "-h" | "--help" | "-V" | "--version"))
        .filter(|_| chunks.is_empty())
    {
        return Err(clap::Error::raw(
            clap::error::ErrorKind::MissingSubcommand,
            format!(
                "{o} comes after a transport: name the transport first (one of {}), e.g. \
                 xrce-agent udp4 -p 8888\n",
                TRANSPORTS.join(", ")
            ),
        ));
    }
    if chunks.is_empty() {
        // let clap say what is missing (or print help/version)
        let mut v = vec!["xrce-agent".to_string()];
        v.extend(pre);
        Chunk::try_parse_from(v)?;
        unreachable!("clap requires a transport");
    }
    if let Some(first) = chunks.first_mut() {
        // options before the first transport belong to it
        let mut v = vec![first.remove(0)];
        v.append(&mut pre);
        v.append(first);
        *first = v;
    }
    let mut plan = Plan {
        transports: Vec::new(),
        common: Common::default(),
    };
    for c in chunks {
        let mut v = vec!["xrce-agent".to_string()];
        v.extend(c);
        let chunk = Chunk::try_parse_from(v)?;
        let common = match &chunk.transport {
            Cmd::Udp4(n) | Cmd::Tcp4(n) => n.common.clone(),
            Cmd::Serial(s) => s.common.clone(),
            Cmd::Pseudoterminal(p) => p.common.clone(),
        };
        plan.common
            .merge(common)
            .map_err(|e| clap::Error::raw(clap::error::ErrorKind::ArgumentConflict, e + "\n"))?;
        plan.transports.push(chunk.transport);
    }
    Ok(plan)
}

fn level(v: u8) -> tracing::level_filters::LevelFilter {
    use tracing::level_filters::LevelFilter as L;
    match v {
        0 => L::OFF,
        1 | 2 => L::ERROR,
        3 => L::WARN,
        4 => L::INFO,
        5 => L::DEBUG,
        _ => L::TRACE,
    }
}

/// Whether the files, directories and devices the command line names are
/// there: a path that is not is a mistake of the command line (exit 2), as
/// a references file that is not, not a failure of the agent.
fn check_paths(plan: &Plan) -> Result<(), String> {
    /// The directory `p` is to be made in.
    fn dir_of(p: &Path) -> &Path {
        match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        }
    }
    /// Why the agent could not write the state file `f` (there already,
    /// or to be made in its directory), if it could not: a read-only file
    /// or directory is the command line's mistake, said before anything
    /// starts, not a failure of the database later.
    fn not_writable(f: &Path) -> Option<String> {
        use std::os::unix::ffi::OsStrExt as _;
        let (target, what) = if f.exists() {
            (f, "the file")
        } else {
            (dir_of(f), "its directory")
        };
        let c = std::ffi::CString::new(target.as_os_str().as_bytes()).ok()?;
        // SAFETY: access(2) reads the NUL-terminated path and nothing else.
        #[allow(unsafe_code)]
        let r = unsafe { libc::access(c.as_ptr(), libc::W_OK) };
        (r != 0).then(|| {
            format!(
                "{what} cannot be written ({})",
                std::io::Error::last_os_error()
            )
        })
    }
    /// Why `d` cannot hold a new file, if it cannot.
    fn not_a_dir(d: &Path) -> Option<String> {
        match std::fs::metadata(d) {
            Ok(m) if m.is_dir() => None,
            Ok(_) => Some(format!("{} is not a directory", d.display())),
            Err(e) => Some(format!("directory {}: {e}", d.display())),
        }
    }
    if let Some(state) = &plan.common.state {
        if state.is_dir() {
            return Err(format!(
                "state file {}: it is a directory (--state names the file to keep clients' \
                 sessions in)",
                state.display()
            ));
        }
        if let Some(why) = not_a_dir(dir_of(state)) {
            return Err(format!("state file {}: {why}", state.display()));
        }
        if let Some(why) = not_writable(state) {
            return Err(format!("state file {}: {why}", state.display()));
        }
    }
    for t in &plan.transports {
        match t {
            Cmd::Serial(s) => {
                if let Err(e) = std::fs::metadata(&s.dev) {
                    return Err(format!("cannot open serial {}: {e}", s.dev.display()));
                }
            }
            Cmd::Pseudoterminal(Pty {
                dev: Some(link), ..
            }) => {
                if let Some(why) = not_a_dir(dir_of(link)) {
                    return Err(format!(
                        "cannot make the link {} to the pseudo-terminal: {why}",
                        link.display()
                    ));
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// The agent's settings, or what is wrong with them.
fn build(
    plan: &Plan,
) -> Result<(Vec<Transport>, RtpsOptions, Profiles, Option<SocketAddrV4>), String> {
    let c = &plan.common;
    if let Some(m) = &c.middleware {
        if m != "dds" {
            return Err(format!(
                "middleware {m:?} is not supported: this agent always bridges into DDS (-m dds)"
            ));
        }
    }
    check_paths(plan)?;
    let bind = c.bind.unwrap_or(Ipv4Addr::UNSPECIFIED);
    let transports = plan
        .transports
        .iter()
        .map(|t| match t {
            Cmd::Udp4(n) => Transport::Udp(SocketAddr::new(IpAddr::V4(bind), n.port)),
            Cmd::Tcp4(n) => Transport::Tcp(SocketAddr::new(IpAddr::V4(bind), n.port)),
            Cmd::Serial(s) => Transport::Serial {
                device: s.dev.clone(),
                baud: s.baud,
            },
            Cmd::Pseudoterminal(p) => Transport::Pseudoterminal {
                link: p.dev.clone(),
            },
        })
        .collect();
    let mut rtps = RtpsOptions::default();
    rtps.domain = c.domain.unwrap_or(0);
    rtps.interface = c.interface.clone();
    rtps.peers = c.peers.clone();
    rtps.multicast = c.multicast.unwrap_or(c.peers.is_empty());
    let profiles = match &c.refs {
        None => Profiles::new(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("references file {}: {e}", path.display()))?;
            let p = Profiles::parse(&text)
                .map_err(|e| format!("references file {}: {e}", path.display()))?;
            // a file of other XML (or a typo in every element name) is no
            // error of the XML, but no reference will be found in it
            match p.len() {
                0 => tracing::warn!(
                    "references file {} defines no profiles (participant, topic, data_writer, \
                     data_reader, requester or replier elements with a profile_name): every \
                     CREATE by reference will be refused",
                    path.display()
                ),
                n => tracing::info!("references file {}: {n} profile(s)", path.display()),
            }
            p
        }
    };
    let discovery = c.discovery.map(|p| SocketAddrV4::new(bind, p));
    Ok((transports, rtps, profiles, discovery))
}

fn main() -> ExitCode {
    let plan = match parse(std::env::args().collect()) {
        Ok(p) => p,
        Err(e) => e.exit(),
    };
    // RUST_LOG, when set, says more precisely what -v says
    courier_broker::logging::init(level(plan.common.verbose.unwrap_or(4)), false);
    let (transports, rtps, profiles, discovery) = match build(&plan) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("xrce-agent: {e}");
            return ExitCode::from(2);
        }
    };
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("xrce-agent: {e}");
            return ExitCode::FAILURE;
        }
    };
    rt.block_on(async move {
        let domain = rtps.domain;
        let mut b = XrceAgent::builder()
            .rtps(rtps)
            .profiles(profiles)
            .any_domain(plan.common.any_domain)
            .client_timeout(
                plan.common
                    .client_timeout
                    .map(std::time::Duration::from_secs),
            );
        for t in transports {
            b = b.transport(t);
        }
        if let Some(d) = discovery {
            b = b.discovery(d);
        }
        if let Some(s) = &plan.common.state {
            b = b.state(s);
        }
        // the handlers are in place before anything says the agent is
        // ready: a signal sent right after "ready" stops it cleanly (a
        // SIGHUP before them killed it: status 129)
        let stop = stop_signals();
        let agent = match b.spawn().await {
            Ok(a) => a,
            Err(e) => {
                eprintln!("xrce-agent: {e}");
                return ExitCode::FAILURE;
            }
        };
        for a in agent.udp_addrs() {
            say!("udp4 {a}");
        }
        for a in agent.tcp_addrs() {
            say!("tcp4 {a}");
        }
        for p in agent.serial_paths() {
            say!("serial {}", p.display());
        }
        if let Some(a) = agent.discovery_addr() {
            say!("discovery {a}");
        }
        say!("rtps {} domain {domain}", agent.rtps_addr());
        say!("ready");
        stop.await;
        agent.shutdown().await;
        ExitCode::SUCCESS
    })
}

/// Ctrl-C, SIGTERM or SIGHUP (a closed terminal, a dropped ssh session):
/// each stops the agent cleanly, so that `--state` holds what a graceful
/// stop leaves. Under `nohup` SIGHUP stays ignored. The handlers are
/// installed when this is called; the future is ready at the first signal.
fn stop_signals() -> impl std::future::Future<Output = ()> {
    use tokio::signal::unix::{signal, SignalKind};
    let term = signal(SignalKind::terminate()).ok();
    let hup = if courier_broker::signals::sighup_ignored() {
        None
    } else {
        signal(SignalKind::hangup()).ok()
    };
    let int = signal(SignalKind::interrupt()).ok();
    async move {
        async fn recv(s: Option<tokio::signal::unix::Signal>) {
            match s {
                Some(mut s) => {
                    s.recv().await;
                }
                None => std::future::pending().await,
            }
        }
        tokio::select! {
            () = recv(int) => {}
            () = recv(term) => {}
            () = recv(hup) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(args: &[&str]) -> Plan {
        let mut v = vec!["xrce-agent".to_string()];
        v.extend(args.iter().map(|a| a.to_string()));
        parse(v).unwrap_or_else(|e| panic!("{args:?}: {e}"))
    }

    /// Every option reaches the plan, on whichever transport it is given
    /// (--client-timeout was parsed and then dropped by the merge).
    #[test]
    fn options_of_any_transport_reach_the_plan() {
        let p = plan(&[
            "udp4",
            "-p",
            "0",
            "--client-timeout",
            "5",
            "tcp4",
            "-p",
            "0",
        ]);
        assert_eq!(p.common.client_timeout, Some(5));
        let p = plan(&[
            "udp4", "-p", "0", "tcp4", "-p", "0", "--state", "s.db", "-v", "2",
        ]);
        assert_eq!(
            p.common.state.as_deref(),
            Some(std::path::Path::new("s.db"))
        );
        assert_eq!(p.common.verbose, Some(2));
        assert_eq!(p.transports.len(), 2);
    }

    /// An agent option given after two transports with different values
    /// is refused, naming both (audit 16: the last won silently, and UDP
    /// listened on the address and joined the domain given for TCP); the
    /// same value twice is fine.
    #[test]
    fn an_agent_option_given_twice_differently_is_refused() {
        let args = |bind2: &str, domain2: &str| {
            let mut v: Vec<String> = ["xrce-agent", "udp4", "-p", "0", "--bind", "127.0.0.1"]
                .iter()
                .map(|s| s.to_string())
                .collect();
            v.extend(
                [
                    "--domain", "197", "tcp4", "-p", "0", "--bind", bind2, "--domain", domain2,
                ]
                .map(String::from),
            );
            v
        };
        let e = parse(args("127.0.0.2", "197")).err().expect("refused");
        assert_eq!(e.kind(), clap::error::ErrorKind::ArgumentConflict);
        let text = e.to_string();
        assert!(
            text.contains("--bind is given twice, as 127.0.0.1 and 127.0.0.2"),
            "{text}"
        );
        let e = parse(args("127.0.0.1", "198")).err().expect("refused");
        assert!(
            e.to_string()
                .contains("--domain is given twice, as 197 and 198"),
            "{e}"
        );
        let p = parse(args("127.0.0.1", "197")).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(p.common.bind, Some(std::net::Ipv4Addr::LOCALHOST));
        assert_eq!(p.transports.len(), 2);
    }
}
