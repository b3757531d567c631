//! `courier`: command-line tools over any session URL.
//!
//! - `courier ping <url> --publish|--subscribe …` — like ORTE's `orteping`:
//!   publishes `courier::Ping` samples every period, or subscribes and
//!   reports what arrives and every missed deadline;
//! - `courier spy <url> …` — like ORTE's `ortespy`: prints every discovered
//!   participant, publication and subscription with topic, type and QoS, and
//!   every sample of the matching topics (decoded when the type is known,
//!   hex otherwise).
//!
//! Output is one event per line, flushed, so that tests and scripts can
//! read it. Exit codes: 0 done, 1 runtime error, 64 usage error. Ctrl-C
//! (SIGINT) or SIGTERM prints `interrupted`, closes the session (DDS: the
//! participant says goodbye) and exits 0.
#![deny(unsafe_code)]

use std::collections::HashSet;
use std::io::Write;
use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime};

use courier::{DurabilityKind, EndpointInfo, History, ParticipantInfo, Reliability};
use courier::{IpcMessage, RecvError, Session, SessionEvent};
use futures::{FutureExt, StreamExt};

/// The sample `courier ping` sends (DDS type `courier::Ping`).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::Ping")]
struct Ping {
    seq: u32,
    /// Nanoseconds since the Unix epoch when sent.
    stamp_ns: u64,
    text: String,
}

const USAGE: &str = "\
usage: courier <command> <url> [options]

commands:
  ping <url> --publish|--subscribe   send or receive courier::Ping samples (like orteping)
  spy <url>                          print discovery and samples (like ortespy)
  help                               this text

<url> is any session URL: rtps://<domain>?interface=lo&peers=127.0.0.1, ipc://host:port,
xrce+udp://host:port (also xrce+tcp://, xrce+serial:///dev/ttyX?baud=115200).
`courier <command> --help` describes the command's options.";

const PING_USAGE: &str = "\
usage: courier ping <url> (--publish | --subscribe) [options]
  --topic NAME         topic (default ping)
  --period MS          publishing period (default 1000)
  --count N            stop after N samples sent or received (default: run until Ctrl-C)
  --size BYTES         text length of each sample (default 0, at most 16 MiB)
  --name NAME          participant / module name (default courier-ping)
DDS QoS (rtps:// and xrce+…://; refused on ipc://, which has none):
  --strength N         publisher: exclusive ownership with this strength;
                       subscriber: same as --exclusive
  --exclusive          subscriber: take samples from the strongest publisher only
  --deadline MS        publisher: offered deadline; subscriber: requested deadline,
                       each miss prints `deadline missed <total>`
  --min-separation MS  subscriber: minimum separation between samples
  --best-effort | --reliable   reliability (default reliable)
options also take --flag=value.
output, one event a line:
  ready                               the publication / subscription exists
  matched <n>                         publisher: readers now matched (DDS and IPC);
                                      subscriber: publications now matched (DDS)
  incompatible <guid> <reason>        an endpoint of the topic whose QoS does not match (DDS)
  sent <seq>
  received <seq> from <source> <bytes> B   <source>: writer GUID (DDS), ? (IPC)
  deadline missed <total>             subscriber with --deadline (DDS)
  skipped <reason>                    a sample that did not decode
  done                                --count reached (exit 0)
  interrupted                         Ctrl-C / SIGTERM: session closed (exit 0)";

const SPY_USAGE: &str = "\
usage: courier spy <url> [options]
  --topic PATTERN   fnmatch pattern of topics to print samples of (default *)
  --type PATTERN    fnmatch pattern of type names (default *)
  --count N         exit after N samples
  --duration SECS   exit after this long
  --name NAME       participant name (default courier-spy)
<url> must be rtps://... (pattern subscriptions need DDS; ipc:// is refused, exit 1).
options also take --flag=value.
output, one event a line (a name with blanks is quoted; an empty list is -):
  ready
  participant found|changed <guid prefix> name=<name> unicast=<addrs> multicast=<addrs>
  participant lost <guid prefix> goodbye|lease-expired
  publication|subscription found|changed <guid> topic=<topic> type=<type>
      reliability=reliable|best-effort durability=volatile|transient-local|transient|persistent
      history=keep-last(<n>)|keep-all deadline=<n>ms|infinite
      ownership=shared|exclusive(<strength>) partitions=[<p>,...]
  publication|subscription lost <guid>
  incompatible <guid> <reason>
  sample <topic> <type> from <writer guid> <bytes> B[ (disposed)|(unregistered)]: <value>
      <value>: courier::Ping { seq: <n>, stamp_ns: <n>, text: \"...\" }, or the first
      64 bytes in hex (… when more), or - when none
  interrupted                   Ctrl-C / SIGTERM: session closed (exit 0)";

/// A usage error: printed with the usage text, exit 64.
struct Usage(String);

/// Prints one line on stdout, flushed. When stdout is gone (`| head`), the
/// command stops as on a signal: it closes its session and exits.
fn out(line: impl std::fmt::Display) {
    let mut o = std::io::stdout().lock();
    if writeln!(o, "{line}").and_then(|()| o.flush()).is_err() {
        if let Some(tx) = STOP.get() {
            tx.send_replace(true);
        }
    }
}

/// Prints a diagnostic on stderr; a closed stderr is no reason to panic.
fn err(line: impl std::fmt::Display) {
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(cmd) = args.first() else {
        err(format_args!("courier: no command given\n{USAGE}"));
        return ExitCode::from(64);
    };
    let rest = &args[1..];
    let run = match cmd.as_str() {
        "help" | "--help" | "-h" => {
            out(USAGE);
            return ExitCode::SUCCESS;
        }
        "ping" => parse_ping(rest),
        "spy" => parse_spy(rest),
        other => Err(Usage(format!("unknown command {other:?}"))),
    };
    let cmd = match run {
        Ok(Cmd::Help(text)) => {
            out(text);
            return ExitCode::SUCCESS;
        }
        Ok(c) => c,
        Err(Usage(why)) => {
            err(format_args!("courier: {why}\n{}", usage_of(cmd)));
            return ExitCode::from(64);
        }
    };
    let rt = match tokio::runtime::Runtime::new() {
        Ok(rt) => rt,
        Err(e) => {
            err(format_args!("courier: cannot start the runtime: {e}"));
            return ExitCode::from(1);
        }
    };
    let r = rt.block_on(async {
        let stop = match Stop::watch() {
            Ok(s) => s,
            Err(e) => return Err(format!("cannot watch signals: {e}").into()),
        };
        match cmd {
            Cmd::Ping(o) => ping(o, stop).await,
            Cmd::Spy(o) => spy(o, stop).await,
            Cmd::Help(_) => Ok(()),
        }
    });
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            err(format_args!("courier: {e}"));
            ExitCode::from(1)
        }
    }
}

/// Set once the command is to stop (a signal, or stdout gone).
static STOP: std::sync::OnceLock<tokio::sync::watch::Sender<bool>> = std::sync::OnceLock::new();

/// SIGINT (Ctrl-C) or SIGTERM (or stdout gone): the command stops what it
/// does and closes its session (DDS: the participant says goodbye and
/// disposes its endpoints) instead of dying with the process.
struct Stop(tokio::sync::watch::Receiver<bool>);

impl Stop {
    /// Installs the handlers once, for the whole run: a signal that comes
    /// between two waits is not lost.
    fn watch() -> std::io::Result<Stop> {
        use tokio::signal::unix::{signal, SignalKind};
        let (mut int, mut term) = (
            signal(SignalKind::interrupt())?,
            signal(SignalKind::terminate())?,
        );
        let rx = STOP
            .get_or_init(|| tokio::sync::watch::channel(false).0)
            .subscribe();
        tokio::spawn(async move {
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
            }
            if let Some(tx) = STOP.get() {
                tx.send_replace(true);
            }
        });
        Ok(Stop(rx))
    }

    /// Resolves once a signal came (or stdout went).
    async fn wait(&mut self) {
        let _ = self.0.wait_for(|s| *s).await;
    }
}

/// How long closing may take after a signal before the process just exits.
const CLOSE_BOUND: Duration = Duration::from_secs(3);

/// Connects, or gives up quietly when a signal comes first.
async fn connect(url: &str, name: &str, stop: &mut Stop) -> Result<Option<Session>, Error> {
    tokio::select! {
        s = Session::builder(url).name(name).connect() => Ok(Some(s?)),
        _ = stop.wait() => Ok(None),
    }
}

/// Runs `body` on the session until it ends or a signal comes (then prints
/// `interrupted`), and closes the session either way.
async fn run_session<F>(s: Session, stop: &mut Stop, body: F) -> Result<(), Error>
where
    F: std::future::Future<Output = Result<(), Error>>,
{
    let r = tokio::select! {
        r = body => r,
        _ = stop.wait() => {
            out("interrupted");
            Ok(())
        }
    };
    let _ = tokio::time::timeout(CLOSE_BOUND, s.close()).await;
    r
}

fn usage_of(cmd: &str) -> &'static str {
    match cmd {
        "ping" => PING_USAGE,
        "spy" => SPY_USAGE,
        _ => USAGE,
    }
}

enum Cmd {
    Ping(PingOpts),
    Spy(SpyOpts),
    Help(&'static str),
}

#[derive(Debug)]
struct PingOpts {
    url: String,
    publish: bool,
    topic: String,
    period: Duration,
    count: Option<u64>,
    size: usize,
    strength: Option<i32>,
    /// Subscriber: exclusive ownership (also implied by `--strength`).
    exclusive: bool,
    deadline: Option<Duration>,
    min_separation: Option<Duration>,
    best_effort: bool,
    name: String,
}

#[derive(Debug)]
struct SpyOpts {
    url: String,
    topic: String,
    type_name: String,
    count: Option<u64>,
    duration: Option<Duration>,
    name: String,
}

/// Walks the arguments: options as `--flag value` or `--flag=value`, and
/// positionals.
struct Args<'a> {
    it: std::slice::Iter<'a, String>,
    /// The value given after `=` in the current option.
    inline: Option<&'a str>,
}

/// One argument.
enum Arg<'a> {
    Flag(&'a str),
    Positional(&'a str),
}

impl<'a> Args<'a> {
    fn new(a: &'a [String]) -> Self {
        Args {
            it: a.iter(),
            inline: None,
        }
    }

    /// The next argument; an option that takes no value but got one with
    /// `=` is an error.
    fn next(&mut self) -> Result<Option<Arg<'a>>, Usage> {
        if let Some(v) = self.inline.take() {
            return Err(Usage(format!(
                "an option got a value it takes none of: {v:?}"
            )));
        }
        let Some(a) = self.it.next() else {
            return Ok(None);
        };
        if !a.starts_with('-') || a == "-" {
            return Ok(Some(Arg::Positional(a)));
        }
        match a.split_once('=') {
            Some((f, v)) if f.starts_with("--") => {
                self.inline = Some(v);
                Ok(Some(Arg::Flag(f)))
            }
            _ => Ok(Some(Arg::Flag(a))),
        }
    }

    /// A flag without a value: refuses `--flag=value`.
    fn switch(&mut self, flag: &str) -> Result<(), Usage> {
        match self.inline.take() {
            Some(v) => Err(Usage(format!("{flag} takes no value (got {v:?})"))),
            None => Ok(()),
        }
    }

    fn value(&mut self, flag: &str) -> Result<&'a str, Usage> {
        if let Some(v) = self.inline.take() {
            return Ok(v);
        }
        self.it
            .next()
            .map(String::as_str)
            .ok_or_else(|| Usage(format!("{flag} needs a value")))
    }

    fn num<T: std::str::FromStr>(&mut self, flag: &str) -> Result<T, Usage> {
        let v = self.value(flag)?;
        v.parse()
            .map_err(|_| Usage(format!("{flag} {v:?}: not a valid number")))
    }

    /// A count: at least 1.
    fn count(&mut self, flag: &str) -> Result<u64, Usage> {
        match self.num(flag)? {
            0 => Err(Usage(format!("{flag} must be at least 1"))),
            n => Ok(n),
        }
    }

    fn millis(&mut self, flag: &str) -> Result<Duration, Usage> {
        Ok(Duration::from_millis(self.num(flag)?))
    }

    /// A period or deadline: at least 1 ms.
    fn positive_millis(&mut self, flag: &str) -> Result<Duration, Usage> {
        match self.millis(flag)? {
            d if d.is_zero() => Err(Usage(format!("{flag} must be at least 1 ms"))),
            d => Ok(d),
        }
    }
}

/// Whether `url` names a DDS session (the SDK takes every other URL as IPC).
fn is_dds(url: &str) -> bool {
    url.starts_with("rtps:")
}

fn positional(url: &mut String, a: &str) -> Result<(), Usage> {
    if url.is_empty() {
        *url = a.into();
        Ok(())
    } else {
        Err(Usage(format!("unexpected argument {a:?}")))
    }
}

/// Largest `--size`: big enough to exercise fragmentation, small enough not
/// to exhaust memory by a typo.
const MAX_SIZE: usize = 16 << 20;

fn parse_ping(a: &[String]) -> Result<Cmd, Usage> {
    if a.iter().any(|s| s == "--help" || s == "-h") {
        return Ok(Cmd::Help(PING_USAGE));
    }
    let mut o = PingOpts {
        url: String::new(),
        publish: false,
        topic: "ping".into(),
        period: Duration::from_secs(1),
        count: None,
        size: 0,
        strength: None,
        exclusive: false,
        deadline: None,
        min_separation: None,
        best_effort: false,
        name: "courier-ping".into(),
    };
    let (mut publish, mut subscribe) = (false, false);
    // QoS options given, which only a DDS session has
    let mut qos: Vec<&str> = Vec::new();
    let mut args = Args::new(a);
    while let Some(arg) = args.next()? {
        let f = match arg {
            Arg::Positional(p) => {
                positional(&mut o.url, p)?;
                continue;
            }
            Arg::Flag(f) => f,
        };
        match f {
            "--publish" => {
                args.switch(f)?;
                publish = true
            }
            "--subscribe" => {
                args.switch(f)?;
                subscribe = true
            }
            "--topic" => o.topic = args.value(f)?.into(),
            "--period" => o.period = args.positive_millis(f)?,
            "--count" => o.count = Some(args.count(f)?),
            "--size" => {
                o.size = args.num(f)?;
                if o.size > MAX_SIZE {
                    return Err(Usage(format!("{f} must be at most {MAX_SIZE}")));
                }
            }
            "--strength" => o.strength = Some(args.num(f)?),
            "--exclusive" => {
                args.switch(f)?;
                o.exclusive = true
            }
            "--deadline" => o.deadline = Some(args.positive_millis(f)?),
            "--min-separation" => o.min_separation = Some(args.millis(f)?),
            "--best-effort" => {
                args.switch(f)?;
                o.best_effort = true
            }
            "--reliable" => {
                args.switch(f)?;
                o.best_effort = false
            }
            "--name" => o.name = args.value(f)?.into(),
            _ => return Err(Usage(format!("unknown option {f:?}"))),
        }
        if matches!(
            f,
            "--strength" | "--exclusive" | "--deadline" | "--min-separation" | "--best-effort"
        ) {
            qos.push(f);
        }
    }
    if o.url.is_empty() {
        return Err(Usage("no session URL given".into()));
    }
    match (publish, subscribe) {
        (true, false) => o.publish = true,
        (false, true) => o.publish = false,
        _ => {
            return Err(Usage(
                "give exactly one of --publish and --subscribe".into(),
            ))
        }
    }
    if o.publish {
        if let Some(f) = qos
            .iter()
            .find(|f| matches!(**f, "--min-separation" | "--exclusive"))
        {
            return Err(Usage(format!("{f} is for --subscribe")));
        }
    }
    // The IPC backend takes no QoS and would ignore these silently: a
    // publisher that is not exclusive, a deadline that is never watched.
    if let Some(f) = qos
        .first()
        .filter(|_| !is_dds(&o.url) && !o.url.starts_with("xrce+"))
    {
        return Err(Usage(format!(
            "{f} is DDS QoS and needs an rtps:// session; {} is IPC, which has no QoS",
            o.url
        )));
    }
    Ok(Cmd::Ping(o))
}

fn parse_spy(a: &[String]) -> Result<Cmd, Usage> {
    if a.iter().any(|s| s == "--help" || s == "-h") {
        return Ok(Cmd::Help(SPY_USAGE));
    }
    let mut o = SpyOpts {
        url: String::new(),
        topic: "*".into(),
        type_name: "*".into(),
        count: None,
        duration: None,
        name: "courier-spy".into(),
    };
    let mut args = Args::new(a);
    while let Some(arg) = args.next()? {
        let f = match arg {
            Arg::Positional(p) => {
                positional(&mut o.url, p)?;
                continue;
            }
            Arg::Flag(f) => f,
        };
        match f {
            "--topic" => o.topic = args.value(f)?.into(),
            "--type" => o.type_name = args.value(f)?.into(),
            "--count" => o.count = Some(args.count(f)?),
            "--duration" => o.duration = Some(Duration::from_secs(args.count(f)?)),
            "--name" => o.name = args.value(f)?.into(),
            _ => return Err(Usage(format!("unknown option {f:?}"))),
        }
    }
    if o.url.is_empty() {
        return Err(Usage("no session URL given".into()));
    }
    Ok(Cmd::Spy(o))
}

type Error = Box<dyn std::error::Error>;

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

async fn ping(o: PingOpts, mut stop: Stop) -> Result<(), Error> {
    let Some(s) = connect(&o.url, &o.name, &mut stop).await? else {
        return Ok(());
    };
    let mut ev = s.events();
    if o.publish {
        run_session(s.clone(), &mut stop, ping_publish(&s, &o, &mut ev)).await
    } else {
        run_session(s.clone(), &mut stop, ping_subscribe(&s, &o, &mut ev)).await
    }
}

/// How long the last of `--count` samples may wait for every matched
/// reliable reader to acknowledge it.
const LAST_ACK_BOUND: Duration = Duration::from_secs(5);

/// How long `ping --subscribe` lets discovery settle before it counts the
/// publications it matches.
const SETTLE: Duration = Duration::from_millis(50);

/// Prints `matched <n>` when `n` differs from what was printed last.
struct Matched(Option<usize>);

impl Matched {
    fn set(&mut self, n: usize) {
        if self.0 != Some(n) {
            self.0 = Some(n);
            out(format_args!("matched {n}"));
        }
    }
}

fn incompatible_line(remote: courier::Guid, reason: &str) -> String {
    format!("incompatible {remote} {reason}")
}

async fn ping_publish(s: &Session, o: &PingOpts, ev: &mut courier::Events) -> Result<(), Error> {
    let mut b = s.publisher::<Ping>(&o.topic);
    if o.best_effort {
        b = b.best_effort();
    }
    if let Some(n) = o.strength {
        b = b.strength(n);
    }
    if let Some(d) = o.deadline {
        b = b.deadline(d);
    }
    let p = b.build().await?;
    // an XRCE agent tells its clients nothing of the readers matched
    let xrce = s.xrce().is_ok();
    if !xrce {
        s.watch_handlers(&o.topic).await?;
    }
    out("ready");
    // readers already matched when the publication was created (DDS: the
    // readers matched with our writer; IPC: the modules subscribing)
    let mut matched = Matched(None);
    let n = if xrce {
        0
    } else {
        s.num_handlers(&o.topic).await?
    };
    if n > 0 {
        matched.set(n.unsigned_abs() as usize);
    }
    let mut tick = tokio::time::interval(o.period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut seq = 0u32;
    loop {
        tokio::select! {
            _ = tick.tick() => {
                seq = seq.wrapping_add(1);
                let v = Ping { seq, stamp_ns: now_ns(), text: "x".repeat(o.size) };
                let last = o.count.is_some_and(|n| u64::from(seq) >= n);
                if last && (is_dds(&o.url) || xrce) && !o.best_effort {
                    // exiting right after the write could leave a reader
                    // without the last sample: wait for its acknowledgement
                    match p.publish(&v).timeout(LAST_ACK_BOUND).await {
                        Err(courier::PublishError::Timeout { after, .. }) => err(format_args!(
                            "courier: sample {seq} not acknowledged by every reader within {after:?}"
                        )),
                        r => r?,
                    }
                } else {
                    p.publish(&v).await?;
                }
                out(format_args!("sent {seq}"));
                if last {
                    break;
                }
            }
            Some(e) = ev.next() => match e {
                SessionEvent::HandlersChanged { msg, count } if msg == o.topic => {
                    matched.set(count.unsigned_abs() as usize)
                }
                SessionEvent::IncompatibleQos { msg, remote, reason } if msg == o.topic => {
                    out(incompatible_line(remote, &reason))
                }
                _ => {}
            },
        }
    }
    out("done");
    Ok(())
}

async fn ping_subscribe(s: &Session, o: &PingOpts, ev: &mut courier::Events) -> Result<(), Error> {
    let mut b = s.subscriber::<Ping>(&o.topic);
    if o.best_effort {
        b = b.best_effort();
    }
    if let Some(d) = o.deadline {
        b = b.deadline(d);
    }
    if let Some(d) = o.min_separation {
        b = b.minimum_separation(d);
    }
    if o.exclusive || o.strength.is_some() {
        b = b.exclusive();
    }
    let mut sub = b.build().await?;
    out("ready");
    // DDS: publications of our topic and type, less those whose QoS does not
    // match ours (the SDK reports no reader matches, only mismatches)
    let mut found = HashSet::new();
    let mut refused = HashSet::new();
    let mut matched = Matched(None);
    let mut recount: Option<tokio::time::Instant> = None;
    let mut n = 0u64;
    loop {
        tokio::select! {
            r = sub.next() => match r {
                None | Some(Err(RecvError::Disconnected)) => return Err("the session ended".into()),
                Some(Ok(smp)) => {
                    // a sample shows its publication matched: take the
                    // discovery events already in and count before printing
                    // it, so that `matched` comes first
                    while let Some(Some(e)) = ev.next().now_or_never() {
                        if pub_event(e, o, &mut found, &mut refused) && is_dds(&o.url) {
                            recount.get_or_insert_with(|| tokio::time::Instant::now() + SETTLE);
                        }
                    }
                    if recount.take().is_some() {
                        matched.set(found.difference(&refused).count());
                    }
                    n += 1;
                    out(format_args!(
                        "received {} from {} {} B",
                        smp.value.seq,
                        smp.source.as_deref().unwrap_or("?"),
                        smp.value.text.len()
                    ));
                    if o.count.is_some_and(|c| n >= c) {
                        break;
                    }
                }
                Some(Err(e)) => out(format_args!("skipped {e}")),
            },
            Some(e) = ev.next() => {
                if pub_event(e, o, &mut found, &mut refused) && is_dds(&o.url) {
                    // a publication's mismatch comes right after its
                    // discovery: count once both are in, not to print a
                    // match that is none
                    recount.get_or_insert_with(|| tokio::time::Instant::now() + SETTLE);
                }
            }
            _ = async { tokio::time::sleep_until(recount.unwrap()).await }, if recount.is_some() => {
                recount = None;
                matched.set(found.difference(&refused).count());
            }
        }
    }
    out("done");
    Ok(())
}

/// A session event for `ping --subscribe`: prints deadline misses and QoS
/// mismatches, follows the publications of the topic; whether the number of
/// matched publications may have changed.
fn pub_event(
    e: SessionEvent,
    o: &PingOpts,
    found: &mut HashSet<courier::Guid>,
    refused: &mut HashSet<courier::Guid>,
) -> bool {
    match e {
        SessionEvent::DeadlineMissed { msg, total } if msg == o.topic => {
            out(format_args!("deadline missed {total}"));
            false
        }
        SessionEvent::IncompatibleQos {
            msg,
            remote,
            reason,
        } if msg == o.topic => {
            refused.insert(remote);
            out(incompatible_line(remote, &reason));
            true
        }
        SessionEvent::PublicationFound(e) | SessionEvent::PublicationChanged(e)
            if e.topic == o.topic && e.type_name == Ping::TYPE_NAME =>
        {
            // a change is matched anew: a mismatch is reported again
            refused.remove(&e.guid);
            found.insert(e.guid);
            true
        }
        SessionEvent::PublicationLost(g) => found.remove(&g) | refused.remove(&g),
        _ => false,
    }
}

fn prefix_hex(g: courier::Guid) -> String {
    g.prefix().iter().map(|b| format!("{b:02x}")).collect()
}

fn qos_text(e: &EndpointInfo) -> String {
    let q = &e.qos;
    let rel = match q.reliability {
        Reliability::BestEffort => "best-effort",
        Reliability::Reliable => "reliable",
    };
    let dur = match q.durability {
        DurabilityKind::Volatile => "volatile",
        DurabilityKind::TransientLocal => "transient-local",
        DurabilityKind::Transient => "transient",
        DurabilityKind::Persistent => "persistent",
        _ => "other",
    };
    let hist = match q.history {
        History::KeepLast(n) => format!("keep-last({n})"),
        History::KeepAll => "keep-all".into(),
    };
    let dl = q
        .deadline
        .map_or("infinite".into(), |d| format!("{}ms", d.as_millis()));
    let own = q
        .exclusive
        .map_or("shared".into(), |s| format!("exclusive({s})"));
    format!(
        "reliability={rel} durability={dur} history={hist} deadline={dl} ownership={own} \
         partitions=[{}]",
        q.partitions.join(",")
    )
}

fn endpoint_line(kind: &str, what: &str, e: &EndpointInfo) -> String {
    format!(
        "{kind} {what} {} topic={} type={} {}",
        e.guid,
        word(&e.topic),
        word(&e.type_name),
        qos_text(e)
    )
}

/// A sample's bytes for `spy`: decoded when the type is known
/// (`courier::Ping`), else the first 64 bytes in hex (`…` when there are
/// more), `-` when there are none.
fn sample_text(type_name: &str, data: &[u8]) -> String {
    if type_name == Ping::TYPE_NAME {
        if let Ok(p) = courier::cdr::from_slice::<Ping>(data) {
            return format!(
                "courier::Ping {{ seq: {}, stamp_ns: {}, text: {:?} }}",
                p.seq, p.stamp_ns, p.text
            );
        }
    }
    if data.is_empty() {
        return "-".into();
    }
    let hex: String = data.iter().take(64).map(|b| format!("{b:02x}")).collect();
    if data.len() > 64 {
        format!("{hex}…")
    } else {
        hex
    }
}

/// A word of a line: as is, or quoted when it would not stay one word.
fn word(s: &str) -> String {
    if s.is_empty() || s.contains(|c: char| c.is_whitespace() || c == '"') {
        format!("{s:?}")
    } else {
        s.to_string()
    }
}

/// Socket addresses, or `-`.
fn locators(v: &[std::net::SocketAddr]) -> String {
    if v.is_empty() {
        "-".into()
    } else {
        v.iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
            .join(",")
    }
}

fn participant_line(what: &str, p: &ParticipantInfo) -> String {
    format!(
        "participant {what} {} name={} unicast={} multicast={}",
        prefix_hex(p.guid),
        p.name.as_deref().map_or("-".into(), word),
        locators(&p.unicast),
        locators(&p.multicast),
    )
}

async fn spy(o: SpyOpts, mut stop: Stop) -> Result<(), Error> {
    // every other URL is IPC, which refuses pattern subscriptions: say so
    // without connecting (central need not even run)
    if !is_dds(&o.url) {
        return Err(format!(
            "spy needs pattern subscriptions, which need a DDS session (rtps://...); {} is IPC",
            o.url
        )
        .into());
    }
    let Some(s) = connect(&o.url, &o.name, &mut stop).await? else {
        return Ok(());
    };
    run_session(s.clone(), &mut stop, spy_session(&s, &o)).await
}

async fn spy_session(s: &Session, o: &SpyOpts) -> Result<(), Error> {
    let mut ev = s.events();
    let mut samples = s
        .subscribe_pattern(&o.topic, &o.type_name)
        .await
        .map_err(|e| format!("spy needs pattern subscriptions: {e}"))?;
    out("ready");
    let until = o.duration.map(|d| Instant::now() + d);
    let mut n = 0u64;
    loop {
        let sleep = async {
            match until {
                Some(t) => tokio::time::sleep_until(t.into()).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = sleep => break,
            smp = samples.recv() => {
                let Some(smp) = smp else { break }; // the session ended
                let ty = smp.type_name.as_deref().unwrap_or("?");
                let state = match smp.state {
                    courier::InstanceState::Alive => "",
                    courier::InstanceState::Disposed => " (disposed)",
                    courier::InstanceState::Unregistered => " (unregistered)",
                };
                out(format_args!(
                    "sample {} {ty} from {} {} B{state}: {}",
                    smp.msg,
                    smp.source.as_deref().unwrap_or("?"),
                    smp.data.len(),
                    sample_text(ty, &smp.data)
                ));
                n += 1;
                if o.count.is_some_and(|c| n >= c) {
                    break;
                }
            }
            Some(e) = ev.next() => match e {
                SessionEvent::ParticipantFound(p) => out(participant_line("found", &p)),
                SessionEvent::ParticipantChanged(p) => out(participant_line("changed", &p)),
                SessionEvent::ParticipantLost { guid, disposed } => out(format_args!(
                    "participant lost {} {}",
                    prefix_hex(guid),
                    if disposed { "goodbye" } else { "lease-expired" }
                )),
                SessionEvent::PublicationFound(e) => out(endpoint_line("publication", "found", &e)),
                SessionEvent::PublicationChanged(e) => out(endpoint_line("publication", "changed", &e)),
                SessionEvent::PublicationLost(g) => {
                    out(format_args!("publication lost {g}"))
                }
                SessionEvent::SubscriptionFound(e) => out(endpoint_line("subscription", "found", &e)),
                SessionEvent::SubscriptionChanged(e) => out(endpoint_line("subscription", "changed", &e)),
                SessionEvent::SubscriptionLost(g) => {
                    out(format_args!("subscription lost {g}"))
                }
                SessionEvent::IncompatibleQos { remote, reason, .. } => {
                    out(incompatible_line(remote, &reason))
                }
                _ => {}
            },
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_print_decoded_or_as_bounded_hex() {
        let p = Ping {
            seq: 7,
            stamp_ns: 9,
            text: "hi".into(),
        };
        let data = courier::cdr::to_vec(&p, courier::cdr::Encoding::Xcdr1Le);
        assert_eq!(
            sample_text("courier::Ping", &data),
            "courier::Ping { seq: 7, stamp_ns: 9, text: \"hi\" }"
        );
        // an unknown type (or one that does not decode): hex, 64 bytes at most
        assert_eq!(sample_text("x::Y", &[0xab, 0x01]), "ab01");
        assert_eq!(sample_text("courier::Ping", &[0xab]), "ab");
        let long = sample_text("x::Y", &[0x5a; 65]);
        assert_eq!(long, format!("{}…", "5a".repeat(64)));
        assert_eq!(sample_text("x::Y", &[]), "-");
    }

    #[test]
    fn words_stay_words() {
        assert_eq!(word("talker"), "talker");
        assert_eq!(word("my rx"), "\"my rx\"");
        assert_eq!(word(""), "\"\"");
    }

    fn args(a: &[&str]) -> Vec<String> {
        a.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn ping_options_in_both_spellings() {
        let u = "rtps://205?interface=lo&peers=127.0.0.1";
        let Ok(Cmd::Ping(o)) = parse_ping(&args(&[
            u,
            "--subscribe",
            "--topic=t",
            "--deadline",
            "250",
            "--count=4",
            "--strength",
            "-2",
            "--best-effort",
        ])) else {
            panic!("parse")
        };
        assert_eq!(o.url, u);
        assert!(!o.publish && o.best_effort);
        assert_eq!(o.topic, "t");
        assert_eq!(o.deadline, Some(Duration::from_millis(250)));
        assert_eq!((o.count, o.strength), (Some(4), Some(-2)));
    }
}
