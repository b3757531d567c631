//! What Courier's examples share: the arguments every `cargo run --example`
//! program takes (in the style of zenoh's `z_*` programs), connecting with a
//! bound and a hint, a `main` that turns an error into a message and a
//! non-zero exit, and the message types of the IPC manual's Appendix A.
//!
//! The examples themselves are the files at the top of `examples/`; run one
//! from the repository root with `cargo run --example NAME -- --help`.

#![warn(missing_docs)]

use std::future::Future;
use std::process::ExitCode;
use std::time::Duration;

use courier::Session;

#[path = "../appendix_a.rs"]
pub mod appendix_a;

/// Any error an example reports (printed, then the example exits with 1).
pub type Error = Box<dyn std::error::Error + Send + Sync>;

/// The central a session URL without a host names (CMU IPC's default port).
pub const DEFAULT_ENDPOINT: &str = "ipc://127.0.0.1:1381";

/// The arguments of every example that talks to one endpoint.
#[derive(clap::Args, Debug, Clone)]
pub struct Common {
    /// Session URL: `ipc://host:port` (a central), `rtps://DOMAIN?interface=lo&peers=127.0.0.1`
    /// (DDS), `xrce+udp://host:port` (a DDS-XRCE agent).
    #[arg(short = 'e', long = "endpoint", default_value = DEFAULT_ENDPOINT)]
    pub endpoint: String,
    /// How long to wait for the connection (seconds).
    #[arg(long, default_value_t = 5.0, value_parser = seconds)]
    pub connect_timeout: f64,
}

/// Where a DDS participant joins: the RTPS examples' arguments. The
/// defaults keep every datagram on the loopback interface (unicast
/// discovery with 127.0.0.1, no multicast), so nothing leaves the machine.
#[derive(clap::Args, Debug, Clone)]
pub struct Rtps {
    /// DDS domain id (0 is every DDS implementation's default).
    #[arg(short, long, default_value_t = 0)]
    pub domain: u32,
    /// Network interface, by name or IPv4 address.
    #[arg(long, default_value = "lo")]
    pub interface: String,
    /// Unicast discovery peers (`ip` or `ip:port`), repeatable.
    #[arg(long = "peer", default_values_t = ["127.0.0.1".to_string()])]
    pub peers: Vec<String>,
    /// Also use the standard SPDP multicast discovery.
    #[arg(long)]
    pub multicast: bool,
    /// How long to wait for the participant to start (seconds).
    #[arg(long, default_value_t = 5.0, value_parser = seconds)]
    pub connect_timeout: f64,
}

/// The QoS choices of the RTPS examples (both ends: a reader and a writer
/// match when the writer offers at least what the reader asks).
#[derive(clap::Args, Debug, Clone)]
pub struct Qos {
    /// Best effort instead of reliable (a reliable reader ignores a best-effort writer).
    #[arg(long)]
    pub best_effort: bool,
    /// Transient local: the writer keeps its last sample for readers that join later.
    #[arg(long)]
    pub transient_local: bool,
}

impl Rtps {
    /// Joins the domain as participant `name`, pinned as the arguments say.
    pub async fn connect(&self, name: &str) -> Result<Session, Error> {
        let url = format!("rtps://{}", self.domain);
        let builder = Session::builder(&url)
            .name(name)
            .interface(&self.interface)
            .peers(self.peers.iter().cloned())
            .multicast(self.multicast);
        connect(builder, &url, self.connect_timeout).await
    }
}

/// Cyclone DDS's HelloWorld type (`HelloWorldData.idl`), so that `rtps_pub`
/// and `rtps_sub` talk with Cyclone's `HelloworldPublisher` and
/// `HelloworldSubscriber` on topic `HelloWorldData_Msg`:
///
/// ```idl
/// module HelloWorldData { struct Msg { @key long userID; string message; }; };
/// ```
#[derive(courier::IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "HelloWorldData::Msg")]
pub struct HelloWorld {
    /// `@key long userID`: one DDS instance per user id.
    #[ipc(key)]
    pub user_id: i32,
    /// `string message`.
    pub message: String,
}

/// Parses a positive number of seconds.
pub fn seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a positive number of seconds")),
    }
}

impl Common {
    /// Connects as module / participant `name-<pid>` (two `sub`s on one
    /// central are two modules: central refuses a second module of a name
    /// that is connected), within the connect timeout; the error says
    /// where it tried and what to check.
    pub async fn connect(&self, name: &str) -> Result<Session, Error> {
        let name = format!("{name}-{}", std::process::id());
        let builder = Session::builder(&self.endpoint).name(name);
        connect(builder, &self.endpoint, self.connect_timeout).await
    }
}

/// Connects with `builder` (made for `url`) within `secs` seconds; the
/// error names the URL and what to start when nothing answers there.
pub async fn connect(
    builder: courier::SessionBuilder,
    url: &str,
    secs: f64,
) -> Result<Session, Error> {
    match tokio::time::timeout(Duration::from_secs_f64(secs), builder.connect()).await {
        Ok(Ok(s)) => Ok(s),
        Ok(Err(e)) => {
            let hint = if answered(&e) { "" } else { start_hint(url) };
            Err(format!("cannot connect to {url}: {}{hint}", chain(&e)).into())
        }
        Err(_) => Err(format!("no connection to {url} within {secs} s{}", start_hint(url)).into()),
    }
}

/// Whether `e` says the URL or the options are wrong (or the peer answered
/// and refused), rather than that nothing answered there: starting a server
/// would not help.
fn answered(e: &courier::ConnectError) -> bool {
    use courier::ConnectError as E;
    matches!(
        e,
        E::UnknownScheme { .. } | E::Unsupported { .. } | E::BadUrl { .. } | E::Handshake { .. }
    )
}

/// What to start when nothing answers at `url`: a central for IPC, an agent
/// on the URL's transport for XRCE (nothing for DDS: peers come and go).
fn start_hint(url: &str) -> &'static str {
    if url.starts_with("ipc://") {
        " (is a central running? `cargo run -p courier-broker --bin central` starts one)"
    } else if url.starts_with("xrce+udp://") {
        " (is an agent running? `cargo run -p courier-broker --bin xrce-agent -- udp4 -p 8888` starts one)"
    } else if url.starts_with("xrce+tcp://") {
        " (is an agent running? `cargo run -p courier-broker --bin xrce-agent -- tcp4 -p 8888` starts one)"
    } else if url.starts_with("xrce+serial://") {
        " (does the device exist, with an agent at its other end? `cargo run -p courier-broker --bin xrce-agent -- serial --dev DEVICE` starts one)"
    } else {
        ""
    }
}

/// Runs an example: parses its arguments (a usage error exits with 2, as
/// clap does), runs `run` on a tokio runtime, and prints the error and
/// exits with 1 if it fails.
pub fn main<A, F>(name: &str, run: impl FnOnce(A) -> F) -> ExitCode
where
    A: clap::Parser,
    F: Future<Output = Result<(), Error>>,
{
    let args = A::parse();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("{name}: cannot start the tokio runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(run(args)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: {}", chain(&*e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes (`source()`), as one line: Courier's errors
/// name what failed and keep what caused it (central's refusal, an I/O
/// error) as their source.
pub fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cur = c.source();
    }
    s
}

/// The argument of the Appendix A modules: where central is.
#[derive(clap::Args, Debug, Clone)]
pub struct Central {
    /// Central's URL (`ipc://` alone: `CENTRALHOST`, else localhost:1381, as in C).
    #[arg(short = 'e', long = "endpoint", default_value = "ipc://")]
    pub endpoint: String,
}

impl Central {
    /// Connects as module `name`, within 10 s.
    pub async fn connect(&self, name: &str) -> Result<Session, Error> {
        let builder = Session::builder(&self.endpoint).name(name);
        connect(builder, &self.endpoint, 10.0).await
    }
}

/// The arguments of module2 and module3, which run until stopped.
#[derive(clap::Parser, Debug, Clone)]
pub struct Module {
    #[command(flatten)]
    /// Where central is.
    pub central: Central,
    /// Stop after this many seconds (default: at Ctrl-C).
    #[arg(long, value_parser = seconds)]
    pub seconds: Option<f64>,
}

/// Counts the rounds of a periodic example: the first at once, the next
/// one `period` later, up to `count` rounds (`None`: no limit), and none
/// after Ctrl-C.
pub struct Rounds {
    count: Option<u64>,
    done: u64,
    timer: courier::Timer,
}

impl Rounds {
    /// Rounds on `session`'s timer.
    pub fn new(session: &Session, count: Option<u64>, period: f64) -> Self {
        let timer = session.every(Duration::from_secs_f64(period));
        Rounds {
            count,
            done: 0,
            timer,
        }
    }

    /// The next round's number, or `None` once `count` rounds are done or
    /// Ctrl-C was pressed.
    pub async fn next(&mut self) -> Option<u64> {
        use futures::StreamExt;
        if self.count.is_some_and(|c| self.done >= c) {
            return None;
        }
        if self.done > 0 {
            until_ctrl_c(self.timer.next()).await?;
        }
        self.done += 1;
        Some(self.done - 1)
    }
}

/// `f`'s output, or `None` if Ctrl-C comes first.
pub async fn until_ctrl_c<T>(f: impl Future<Output = T>) -> Option<T> {
    tokio::select! {
        v = f => Some(v),
        _ = tokio::signal::ctrl_c() => None,
    }
}

/// Resolves on Ctrl-C, or after `secs` seconds when given: how the
/// examples that run until stopped end.
pub async fn stop_after(secs: Option<f64>) {
    match secs {
        Some(s) => tokio::time::sleep(Duration::from_secs_f64(s)).await,
        None => {
            let _ = tokio::signal::ctrl_c().await;
        }
    }
}
