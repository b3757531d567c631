//! The command line: clap's derive, with every session URL checked before
//! anything connects, and the checks clap cannot express (options one
//! backend has and the other has not) as usage errors too.

use clap::error::ErrorKind;
use clap::{ArgGroup, Args, CommandFactory, Parser, Subcommand, ValueEnum};

use courier::format::Format;
use courier::rtps_backend::RtpsOptions;

/// Largest `--size`: big enough to exercise fragmentation, small enough not
/// to exhaust memory by a typo.
pub const MAX_SIZE: u64 = 16 << 20;

const AFTER_HELP: &str = "\
Session URLs:
  ipc://HOST:PORT          a CMU IPC central (Courier's `central` or the C one); ipc:// alone
                           takes CENTRALHOST, then localhost:1381
  rtps://DOMAIN?OPTIONS    DDS over RTPS, e.g. rtps://0?interface=lo&peers=127.0.0.1
  xrce+udp://HOST:PORT     DDS through a DDS-XRCE agent (also xrce+tcp://, xrce+serial:///dev/…);
                           the agent says nothing of readers; echo, hz, bw and spy need --type
                           there (the agent creates typed readers); pub and call default to
                           courier::Ping without one, as on rtps://

Exit status: 0 done (also when its reader closes the pipe, `| head`); 1 a runtime
failure (the message says which), or stdout could not be written (`courier <command>:
cannot write to stdout: <error>`); 2 a usage error (a bad option, URL or VALUE: one
that does not fit its type); 128+N stopped by signal N before it was done (130
Ctrl-C, 143 SIGTERM, 129 SIGHUP: each ends the command as cleanly, a recording
is finished).
`courier <command> --help` describes a command and what it prints.";

/// Command-line tools over any Courier session URL.
#[derive(Parser, Debug)]
#[command(
    name = "courier",
    version,
    propagate_version = true,
    after_help = AFTER_HELP,
    arg_required_else_help = true
)]
pub struct Cli {
    /// Report what long waits wait for (connecting, discovery) on stderr:
    /// auto = when stderr is a terminal
    #[arg(long, global = true, value_enum, value_name = "WHEN", default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
    #[command(subcommand)]
    pub command: Command,
}

/// When long waits report progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ProgressMode {
    /// When stderr is a terminal.
    Auto,
    /// Always.
    Always,
    /// Never.
    Never,
}

impl Command {
    /// The subcommand's name, as typed (`courier <name>`).
    pub fn name(&self) -> &'static str {
        match self {
            Command::Call(_) => "call",
            Command::Echo(_) => "echo",
            Command::Hz(_) => "hz",
            Command::Bw(_) => "bw",
            Command::Pub(_) => "pub",
            Command::List(_) => "list",
            Command::Perf(_) => "perf",
            Command::Ping(_) => "ping",
            Command::Spy(_) => "spy",
            Command::Pong(_) => "pong",
            Command::Gen(_) => "gen",
            Command::Record(_) => "record",
            Command::Replay(_) => "replay",
            Command::Completions { .. } => "completions",
        }
    }
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Send one query and print its reply (like ros2 service call)
    #[command(after_help = CALL_OUTPUT)]
    Call(CallArgs),
    /// Print every sample of a topic, decoded (like ros2 topic echo)
    #[command(after_help = ECHO_OUTPUT)]
    Echo(EchoArgs),
    /// Report the rate of a topic's samples every second (like ros2 topic hz)
    #[command(after_help = HZ_OUTPUT)]
    Hz(RateArgs),
    /// Report the bandwidth and sizes of a topic's samples every second (like ros2 topic bw)
    #[command(after_help = BW_OUTPUT)]
    Bw(RateArgs),
    /// Publish a value (like ros2 topic pub)
    #[command(name = "pub", after_help = PUB_OUTPUT)]
    Pub(PubArgs),
    /// List participants and endpoints (DDS), or modules and messages (IPC)
    #[command(after_help = LIST_OUTPUT)]
    List(ListArgs),
    /// Throughput and one-way latency with ddsperf's samples (like ddsperf pub/sub)
    #[command(after_help = PERF_OUTPUT)]
    Perf(crate::perf::PerfArgs),
    /// Send or receive courier::Ping samples (like ORTE's orteping)
    #[command(after_help = PING_OUTPUT)]
    Ping(PingArgs),
    /// Print discovery and every sample of matching topics (like ORTE's ortespy)
    #[command(after_help = SPY_OUTPUT)]
    Spy(SpyArgs),
    /// Answer every courier::Ping with the same sample (for ping --rtt, like ddsperf pong)
    Pong(PongArgs),
    /// Generate Rust types from IPC formats, XDR or IDL (like IPC's xdrgen)
    #[command(after_help = crate::gen::GEN_HELP)]
    Gen(crate::gen::GenArgs),
    /// Record topics into an MCAP file (like ros2 bag record)
    #[command(after_help = RECORD_OUTPUT)]
    Record(RecordArgs),
    /// Play an MCAP recording back onto any session (like ros2 bag play)
    #[command(after_help = REPLAY_OUTPUT)]
    Replay(ReplayArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell)
    Completions {
        /// The shell
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
}

const PERF_OUTPUT: &str = "\
`courier perf sub URL` prints one line a second and a total at the end:
  received <samples/s> <Mbit/s> lost <n> size <bytes> latency n=… p50=… p99=… (us)
`courier perf pub URL` waits for --readers matched readers, then publishes as
fast as they take the samples (or at --rate) and prints `sent …` each second.
On DDS the samples are ddsperf's (topic DDSPerfRDataKS, type KeyedSeq,
keep-all; DDSPerfUDataKS with --best-effort), so either side can be Cyclone's
`ddsperf pub` / `ddsperf sub`. Latency is one way: publisher and subscriber must
share a clock. For round trips use `courier ping --rtt` with `courier pong`.
`ddsperf sub` takes a sample whose source time is odd for a ping to answer and,
finding no ddsperf peer to answer, prints `get_pong_writer: participant handle …
not found`; its counts are unaffected.";

const CALL_OUTPUT: &str = "\
REQUEST is JSON guided by the format (see `courier pub --help`), or text for a
string. The reply goes to stdout on one line, decoded as `courier echo` prints
samples (--json for JSON).
On ipc:// an IPC query (IPC_queryResponse): the request's format is --format or
the one central holds for QUERY, the reply's --reply-format or the one central
holds for the reply's message. On rtps:// and xrce+…:// a ROS 2 style service
call (topics rq/QUERYRequest and rr/QUERYReply) with types named by --type
(default courier::Ping: [seq, stamp_ns, \"text\"]) and --reply-type (default:
--type): ones Courier knows, or any laid out as --format / --reply-format (as
#[derive(IpcMessage)] lays it out).
The request/reply header (the sample identity that ties a reply to its request)
is Courier's to add to the request and take off the reply, never part of REQUEST
or the formats: on rtps:// as the URL's services= option says (auto: each peer's
own style; cyclonedds: rmw_cyclonedds's 16-byte client id and sequence number
before the body; fastrtps: inline QoS, as rmw_fastrtps), on xrce+…:// with the
agent. --format and --reply-format describe the request's and the reply's bodies
only, as the .srv file declares them; ROS 2's add_two_ints:
  courier call rtps://0 add_two_ints '[2, 3]' \\
    --type example_interfaces::srv::dds_::AddTwoInts_Request_ --format '{long, long}' \\
    --reply-type example_interfaces::srv::dds_::AddTwoInts_Response_ --reply-format '{long}'
A REQUEST that does not fit its type is a usage error (exit 2); exit 1 when no
reply comes within --timeout.";

const ECHO_OUTPUT: &str = "\
Each sample on one line of stdout: as central's data log prints data ({1, \"a\",
[0.50, 1.00]}), or with --json as JSON guided by the format ([1,\"a\",[0.5,1.0]]:
structs and arrays as arrays, enums by name, null for NULL pointers).
The format: on ipc:// --format, or the one central holds for the message; on
rtps:// --format (CDR laid out as #[derive(IpcMessage)] lays out that format;
no pointers), else the discovered type when Courier knows it (courier::Ping,
std_msgs::msg::dds_::String_); on xrce+…:// --type names the type the agent's
reader takes (with --format for one Courier does not know). Samples of other types print as hex
({\"hex\":\"…\"} with --json). Diagnostics and progress go to stderr.
A dispose or unregister of a keyed DDS instance (as `courier spy` marks (disposed)
and (unregistered); a writer that closes disposes what it leaves) is no sample: it
prints as a line of its own, not counted by --count (that of a topic without key
is not printed):
  (disposed) key=<key>          --json: {\"disposed\":true,\"key\":<key>}
  (unregistered) key=<key>      --json: {\"unregistered\":true,\"key\":<key>}
<key>: the key decoded through the format, as the whole sample or as the leading
fields its bytes fill (a format does not say which fields are keys; they usually
come first): key={1}, [1]; else its bytes in hex, encapsulation header first
({\"hex\":\"…\"}); key_hash=<32 hex digits> (\"key_hash\":\"…\") when the writer
sent only the key hash; key=- (null) when it sent neither.";

const LIST_OUTPUT: &str = "\
On rtps://, what discovery finds within --duration (default 2 s), by participant:
  participant <guid prefix> name=<name> unicast=<addrs> multicast=<addrs>
    publication|subscription <guid> topic=<topic> type=<type> <qos as spy prints it>
(a participant that announced itself while this one was still connecting shows as
`participant <guid prefix> name=? (announced before this listing began)`),
or with --watch every change as it comes, as `courier spy` prints discovery.
On ipc://, without --module/--message, every module (Courier's central only:
courier_getModules) and every message central lists (x_ipc_getMessages):
  module <name> host=<host> handlers=<n> waiting=<n>
  message <name> class=publish|query|… format=<format>|- handlers=<n> module=<first handler's>|-
(from the C central, which has no module list and whose x_ipc_getMessageInfo
crashes on a message subscribed but never defined, each message as --message
prints it). Finding nothing (no participant; no other module and no message),
it says so on stderr and lists nothing. With names:
  module <name> connected|not-connected          for each --module
  message <name> format=<format>|- handlers=<n>  for each --message (or: unknown)
  ready, then module <name> connected|disconnected and message <name> handlers=<n>
                                                  as they change, with --watch";

const PUB_OUTPUT: &str = "\
VALUE is JSON guided by the format ([1, \"a\", [0.5, 1]] for {int, string, [double:2]};
enums by name or number; null for a NULL pointer), or plain text for a string, a
char or an enum's name (hello world, Send), also when it is the only field of a
struct ({string}, as std_msgs::msg::dds_::String_). A VALUE that does not fit the
type is a usage error (exit 2).
The type: on ipc:// --format, else the format central holds for the message; on
rtps:// and xrce+…:// --type with --format (any DDS type whose layout an IPC
format describes, as #[derive(IpcMessage)] lays it out; no pointers), or --type
alone naming one Courier knows (courier::Ping: [seq, stamp_ns, \"text\"];
std_msgs::msg::dds_::String_: [\"text\"] or text), or without --type
courier::Ping (the samples of `courier ping`).
It waits for --wait subscribers first (a sample nobody subscribes is not sent on
IPC and reaches nobody on DDS), then publishes --count samples at --rate.
A DDS reader matches only a writer of its kind (keyed or not), which a format does
not say: the publication is keyed when the topic's readers all are.
Output, one event a line:
  ready                    the publication exists
  keyed, as the readers of <topic> are
                           (or not keyed; DDS) it was opened again so
  matched <n>              subscribers now matched
  incompatible <guid> <reason>   a subscription whose QoS or type does not match (DDS)
  sent <n>
  done                     --count reached (exit 0)
  interrupted while waiting for subscribers of … | after <n> samples sent
                           Ctrl-C / SIGTERM / SIGHUP (exit 130 / 143 / 129)";

const HZ_OUTPUT: &str = "\
Every second, over the last --window samples (one line, stdout):
  rate <r> Hz min <s> s max <s> s std dev <s> s window <n> gaps <n>
      min, max: shortest and longest interval between two samples;
      gaps: intervals longer than --gap (default: twice the mean interval)
  no new samples          none came in the last second
When --count or --duration ends it, a last report, or `no samples in <n> s` if
none came. Progress while nothing has come (discovery on DDS) goes to stderr.";

const BW_OUTPUT: &str = "\
Every second, over the last --window samples (one line, stdout):
  bw <rate>/s from <n> samples size mean <size> min <size> max <size> window <n>
      sizes as received: IPC data, or CDR with its 4-byte header and padding (DDS)
  no new samples          none came in the last second
When --count or --duration ends it, a last report.";

const PING_OUTPUT: &str = "\
Output, one event a line:
  ready                               the publication / subscription exists
  matched <n>                         publisher: readers now matched (DDS and IPC);
                                      subscriber: publications now matched (DDS)
  incompatible <guid> <reason>        an endpoint of the topic whose QoS or type does not match (DDS)
  sent <seq>
  received <seq> from <source> <bytes> B   <source>: writer GUID (DDS), ? (IPC)
  deadline missed <total>             subscriber with --deadline (DDS)
  offered deadline missed <total>     publisher with --deadline whose --period is longer (DDS)
  liveliness <guid> alive|not-alive alive=<n> not-alive=<n>
                                      subscriber with --liveliness or --lease: a publication's
                                      liveliness changed; <n>: the matched publications alive
                                      and not alive (DDS)
  liveliness lost <total>             publisher with a manual --liveliness whose --period is
                                      longer than its --lease (DDS)
  skipped <reason>                    a sample that did not decode
  done                                --count reached (exit 0)
  interrupted after <n> samples …     Ctrl-C / SIGTERM / SIGHUP: session closed (exit 130 / 143 / 129)
--rtt (with `courier pong` answering; latencies in microseconds):
  ready
  matched <n>                         pongs subscribing the topic
  rtt n=<k> min=<us> p50=<us> p90=<us> p99=<us> max=<us> mean=<us> lost=<l> (us)
                                      every second, over that second
  total n=<k> … lost=<l> (us)         over the whole run, then done
  interrupted after <k> round trips: n=<k> … (us)";

const SPY_OUTPUT: &str = "\
On rtps:// every sample of the topics matching --topic and --type, and discovery;
on xrce+…:// every sample of the topics named by --topic as the --type named (a
client learns nothing of discovery); on ipc:// every message named by --topic (no
patterns: a module sees only what it subscribes), decoded through the format central holds, and modules
connecting and disconnecting.
Output, one event a line (a name with blanks is quoted; an empty list is -):
  ready
  participant found|changed <guid prefix> name=<name> unicast=<addrs> multicast=<addrs>
  participant lost <guid prefix> goodbye|lease-expired
  publication|subscription found|changed <guid> topic=<topic> type=<type>
      reliability=reliable|best-effort durability=volatile|transient-local|transient|persistent
      history=keep-last(<n>)|keep-all deadline=<n>ms|infinite lifespan=<n>ms|infinite
      liveliness=automatic|manual-by-participant|manual-by-topic(<lease>ms|infinite)
      ownership=shared|exclusive(<strength>) partitions=[<p>,...]
      representation=[XCDR1|XCDR2,...] (a writer writes the first)
  publication|subscription lost <guid>
  incompatible <guid> <reason>
  module <name> connected|disconnected            (IPC)
  sample <topic> <type> from <writer guid> <bytes> B <encapsulation>[ (disposed)|(unregistered)]: <value>
      <encapsulation> (DDS): XCDR1|XCDR2 and the encapsulation id (CDR_LE, D_CDR2_LE,
      PL_CDR2_LE, ...), or - when there is none (a dispose with only a key hash)
      <value>: courier::Ping { seq: <n>, stamp_ns: <n>, text: \"...\" } in either
      representation, or the first
      64 bytes in hex (… when more), or - when none. On IPC <type> is the
      message's format (? when unknown), <writer guid> is ?, and <value> is printed
      as central's data log prints it
  interrupted after <n> samples       Ctrl-C / SIGTERM / SIGHUP: session closed (exit 130 / 143 / 129)";

const RECORD_OUTPUT: &str = "\
The file: MCAP (zstd chunks, closed at least once a second; a summary with
statistics, chunk and message indexes when the recording ends), one channel per
topic and type. Recorded on ipc://: message encoding `ipc` (IPC marshalling),
schema `ipc-format` holding the message's format string as central holds it.
Recorded on rtps://: message encoding `cdr`, schema named after the DDS type, in
OMG IDL (`omgidl`) when Courier knows the type's layout. Log time: when received;
publish time: the writer's source timestamp when it sent one.
On ipc:// name each message to record; on rtps:// TOPICS are fnmatch patterns
(default: every topic).
Output, one event a line:
  ready
  channel <topic> <encoding> <schema encoding>:<schema name>|-   a new channel
  recorded <n> messages on <k> channels in <file> (<bytes> B)    the file is finished
  done                                    --count or --duration reached (exit 0)
  interrupted after <n> messages recorded Ctrl-C / SIGTERM / SIGHUP: the file is
                                          finished all the same (exit 130 / 143 / 129)
Killed outright (or out of disk), the file ends without its summary and loses
at most its last second: courier replay reads what it holds; other MCAP tools
want `mcap recover` first.";

const REPLAY_OUTPUT: &str = "\
Samples are re-encoded for the session: a channel recorded on IPC goes onto DDS
as CDR laid out as #[derive(IpcMessage)] lays out its format, under the type
--type TOPIC=TYPE names; one recorded on DDS goes onto IPC when Courier knows its
layout (courier::Ping, std_msgs::msg::dds_::String_, or recorded with a format).
Output, one event a line:
  channel <topic> <how>     each channel replayed: ipc <format> | cdr <type> |
                            ipc->cdr <type> | cdr->ipc <format>
  ready                     the publications exist (then --wait)
  channel <topic> keyed, as its readers are   (or not keyed) opened again as
                            the topic's DDS readers want it (a recording does
                            not say whether a type is keyed)
  replayed <n> messages
  done
A progress bar on stderr when it is a terminal (--progress).
A damaged file (truncated, a bad chunk): each problem on stderr with the byte
where it is, what is intact is replayed, then exit 1.";

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Topics (IPC messages) to record; on rtps:// fnmatch patterns, default every topic
    #[arg(value_name = "TOPICS")]
    pub topics: Vec<String>,
    /// The MCAP file to write
    #[arg(short, long, value_name = "FILE.mcap")]
    pub output: std::path::PathBuf,
    /// Replace the file if it exists
    #[arg(long)]
    pub overwrite: bool,
    /// Stop after N messages (0: until interrupted, as without --count)
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Stop after this long
    #[arg(long, value_name = "SECS", value_parser = at_least_1)]
    pub duration: Option<u64>,
    /// Write chunks uncompressed
    #[arg(long)]
    pub no_compression: bool,
    /// Close a chunk once it holds this many bytes (uncompressed)
    #[arg(long, value_name = "BYTES", default_value_t = 1 << 20, value_parser = clap::value_parser!(u64).range(1..=1 << 30))]
    pub chunk_size: u64,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-record-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The MCAP file to play
    #[arg(value_name = "FILE.mcap")]
    pub file: std::path::PathBuf,
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Play at this many times the recorded rate
    #[arg(long, value_name = "X", default_value_t = 1.0, value_parser = factor)]
    pub rate: f64,
    /// Start over at the end, until interrupted
    #[arg(long = "loop")]
    pub r#loop: bool,
    /// Replay only this topic (repeat for more)
    #[arg(long, value_name = "NAME")]
    pub topic: Vec<String>,
    /// The DDS type of a topic (needed for channels recorded on IPC)
    #[arg(long = "type", value_name = "TOPIC=TYPE", value_parser = topic_type)]
    pub types: Vec<(String, String)>,
    /// Wait for this many subscribers of each topic before playing
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub wait: u32,
    /// DDS: keep the last --depth samples of each topic for readers that join late
    #[arg(long)]
    pub transient_local: bool,
    /// --transient-local: samples kept per topic
    #[arg(long, value_name = "N", default_value_t = 1000, requires = "transient_local", value_parser = at_least_1_u32)]
    pub depth: u32,
    /// IPC: define each message with its recorded format even when central
    /// holds a format for it that the recorded one does not fit (as C's
    /// IPC_defineMsg does; its subscribers of the old format then fail to
    /// decode). Without it that is refused
    #[arg(long)]
    pub redefine: bool,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-replay-%p")]
    pub name: String,
}

/// A whole number of at least 1 (clap's own range check would print the
/// open range as `1..18446744073709551615`).
pub fn at_least_1(s: &str) -> Result<u64, String> {
    match s.parse::<u64>() {
        Ok(0) => Err("expected 1 or more".into()),
        Ok(n) => Ok(n),
        Err(_) => Err("expected a whole number, 1 or more".into()),
    }
}

/// [`at_least_1`], of at most `u32::MAX`.
fn at_least_1_u32(s: &str) -> Result<u32, String> {
    let n = at_least_1(s)?;
    u32::try_from(n).map_err(|_| format!("expected at most {}", u32::MAX))
}

/// A replay's `--rate`: a factor above 0, at most a million.
fn factor(s: &str) -> Result<f64, String> {
    above_0_to_a_million(s, "a factor of the recorded rate")
}

/// A `--type TOPIC=TYPE`.
fn topic_type(s: &str) -> Result<(String, String), String> {
    match s.split_once('=') {
        Some((t, ty)) if !t.is_empty() && !ty.is_empty() => Ok((t.to_string(), ty.to_string())),
        _ => Err(format!("{s:?} is not TOPIC=TYPE")),
    }
}

#[derive(Args, Debug)]
pub struct CallArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// The query message (IPC) or service (DDS)
    pub query: String,
    /// The request: JSON, or text for a string
    #[arg(allow_hyphen_values = true)]
    pub request: String,
    /// The request's format (IPC default: the one central holds; DDS: the
    /// CDR layout of --type, the body only: Courier adds the ROS 2
    /// request header)
    #[arg(long, value_name = "FORMAT", value_parser = crate::values::parse_format)]
    pub format: Option<Format>,
    /// The reply's format (IPC default: the one central holds; DDS: the CDR
    /// layout of --reply-type, the body only: Courier takes the ROS 2
    /// reply header off)
    #[arg(long, value_name = "FORMAT", value_parser = crate::values::parse_format)]
    pub reply_format: Option<Format>,
    /// DDS: the request type (one Courier knows, or any with --format;
    /// default courier::Ping)
    #[arg(long = "type", value_name = "TYPE")]
    pub type_name: Option<String>,
    /// DDS: the reply type (default: --type)
    #[arg(long, value_name = "TYPE")]
    pub reply_type: Option<String>,
    /// How long to wait for the reply
    #[arg(long, value_name = "MS", default_value_t = 5000, value_parser = at_least_1)]
    pub timeout: u64,
    /// Print the reply as JSON
    #[arg(long)]
    pub json: bool,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-call-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct EchoArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Topic (IPC: message name)
    pub topic: String,
    /// Print each sample as JSON
    #[arg(long)]
    pub json: bool,
    /// The samples' IPC format (IPC default: the one central holds; DDS:
    /// its CDR layout, default: the discovered type if Courier knows it)
    #[arg(long, value_name = "FORMAT", value_parser = crate::values::parse_format)]
    pub format: Option<Format>,
    /// DDS: subscribe as this type name (required on xrce+…://, whose agent
    /// creates a typed reader; laid out as --format, or a type Courier knows)
    #[arg(long = "type", value_name = "TYPE")]
    pub type_name: Option<String>,
    /// Exit after N samples
    #[arg(long, value_name = "N", value_parser = at_least_1)]
    pub count: Option<u64>,
    /// Exit after this long
    #[arg(long, value_name = "SECS", value_parser = at_least_1)]
    pub duration: Option<u64>,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-echo-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct RateArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Topic (IPC: message name)
    pub topic: String,
    /// Samples the statistics are over
    #[arg(long, value_name = "N", default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(2..=1_000_000))]
    pub window: u64,
    /// hz: count intervals longer than this as gaps (default: twice the mean)
    #[arg(long, value_name = "MS", value_parser = at_least_1)]
    pub gap: Option<u64>,
    /// DDS: subscribe as this type (required on xrce+…://, whose agent
    /// creates a typed reader; a type Courier knows, or laid out as --format)
    #[arg(long = "type", value_name = "TYPE")]
    pub type_name: Option<String>,
    /// With --type: the type's layout as an IPC format, for a type Courier does not know
    #[arg(long, value_name = "FORMAT", value_parser = crate::values::parse_format, requires = "type_name")]
    pub format: Option<Format>,
    /// Exit after N samples
    #[arg(long, value_name = "N", value_parser = at_least_1)]
    pub count: Option<u64>,
    /// Exit after this long
    #[arg(long, value_name = "SECS", value_parser = at_least_1)]
    pub duration: Option<u64>,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-rate-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct PubArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Topic (IPC: message name)
    pub topic: String,
    /// The value: JSON, or plain text for a string, char or enum name (or a
    /// struct of one of them)
    #[arg(allow_hyphen_values = true)]
    pub value: String,
    /// The format (IPC: defines the message in central; DDS: the CDR layout
    /// of --type)
    #[arg(long, value_name = "FORMAT", value_parser = crate::values::parse_format)]
    pub format: Option<Format>,
    /// DDS: the type name (one Courier knows, or any with --format; default
    /// courier::Ping)
    #[arg(long = "type", value_name = "TYPE")]
    pub type_name: Option<String>,
    /// Samples to publish (0: until interrupted)
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub count: u64,
    /// Samples a second
    #[arg(long, value_name = "HZ", default_value_t = 1.0, value_parser = rate)]
    pub rate: f64,
    /// Wait for this many subscribers before the first sample
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub wait: u32,
    /// IPC: define the message with --format even when central holds a
    /// format for it that --format does not fit (as C's IPC_defineMsg
    /// does; its subscribers of the old format then fail to decode).
    /// Without it that is refused
    #[arg(long, requires = "format")]
    pub redefine: bool,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-pub-%p")]
    pub name: String,
}

/// A rate: a positive number of samples a second, at most a million.
fn rate(s: &str) -> Result<f64, String> {
    above_0_to_a_million(s, "a number of samples a second")
}

/// A number above 0 and at most a million, else an error saying `what`
/// was expected.
fn above_0_to_a_million(s: &str, what: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(r) if r > 0.0 && r <= 1e6 => Ok(r),
        _ => Err(format!("expected {what} above 0 and at most 1000000")),
    }
}

#[derive(Args, Debug)]
#[command(group(ArgGroup::new("mode").required(true).args(["publish", "subscribe", "rtt"])))]
pub struct PingArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Publish a sample every --period
    #[arg(long)]
    pub publish: bool,
    /// Subscribe and report what arrives
    #[arg(long)]
    pub subscribe: bool,
    /// Measure round trips through a `courier pong` (latency percentiles)
    #[arg(long)]
    pub rtt: bool,
    /// Topic
    #[arg(long, default_value = "ping")]
    pub topic: String,
    /// --rtt: the topic the answers come on
    #[arg(long, value_name = "TOPIC", default_value = "pong")]
    pub reply_topic: String,
    /// Publishing period (default 1000; --rtt: none, round trips back to back)
    #[arg(long, value_name = "MS", value_parser = at_least_1)]
    pub period: Option<u64>,
    /// --rtt: a ping not answered within this long counts as lost
    #[arg(long, value_name = "MS", default_value_t = 1000, value_parser = at_least_1)]
    pub timeout: u64,
    /// Stop after N samples sent or received, or N round trips (default: run
    /// until interrupted)
    #[arg(long, value_name = "N", value_parser = at_least_1)]
    pub count: Option<u64>,
    /// Text length of each sample
    #[arg(long, value_name = "BYTES", default_value_t = 0, value_parser = clap::value_parser!(u64).range(..=MAX_SIZE))]
    pub size: u64,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-ping-%p")]
    pub name: String,
    #[command(flatten)]
    pub qos: QosArgs,
}

/// DDS QoS of `ping` (refused on IPC, which has none).
#[derive(Args, Debug, Default)]
#[command(next_help_heading = "DDS QoS (rtps:// only)")]
pub struct QosArgs {
    /// Publisher: exclusive ownership with this strength; subscriber: as --exclusive
    #[arg(
        long,
        value_name = "N",
        allow_negative_numbers = true,
        conflicts_with = "rtt"
    )]
    pub strength: Option<i32>,
    /// Subscriber: take samples from the strongest publisher only
    #[arg(long, conflicts_with_all = ["publish", "rtt"])]
    pub exclusive: bool,
    /// Publisher: offered deadline; subscriber: requested deadline, each miss
    /// prints `deadline missed <total>`
    #[arg(long, value_name = "MS", value_parser = at_least_1, conflicts_with = "rtt")]
    pub deadline: Option<u64>,
    /// Subscriber: minimum separation between samples
    #[arg(long, value_name = "MS", conflicts_with_all = ["publish", "rtt"])]
    pub min_separation: Option<u64>,
    /// Publisher: offered liveliness (a manual kind is asserted by each
    /// sample, so a --period longer than the lease prints `liveliness lost
    /// <total>`); subscriber: requested, each publication's change prints
    /// `liveliness <guid> alive|not-alive ...`
    #[arg(long, value_enum, value_name = "KIND", conflicts_with = "rtt")]
    pub liveliness: Option<LivelinessArg>,
    /// The liveliness lease (default 1000 with --liveliness; alone: an
    /// automatic liveliness with this lease)
    #[arg(long, value_name = "MS", value_parser = at_least_1, conflicts_with = "rtt")]
    pub lease: Option<u64>,
    /// Best-effort reliability
    #[arg(long, overrides_with = "reliable", conflicts_with = "rtt")]
    pub best_effort: bool,
    /// Reliable (the default)
    #[arg(long, overrides_with = "best_effort")]
    pub reliable: bool,
}

/// A LIVELINESS kind, as `--liveliness` takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LivelinessArg {
    /// The session keeps it while the process runs.
    Automatic,
    /// Any sample of the session asserts it.
    ManualByParticipant,
    /// Only the publication's own samples assert it.
    ManualByTopic,
}

impl QosArgs {
    /// `--liveliness` and `--lease`: the kind and lease, if either is given.
    pub fn liveliness(&self) -> Option<courier::qos::Liveliness> {
        use courier::qos::LivelinessKind as K;
        if self.liveliness.is_none() && self.lease.is_none() {
            return None;
        }
        let kind = match self.liveliness.unwrap_or(LivelinessArg::Automatic) {
            LivelinessArg::Automatic => K::Automatic,
            LivelinessArg::ManualByParticipant => K::ManualByParticipant,
            LivelinessArg::ManualByTopic => K::ManualByTopic,
        };
        let lease = std::time::Duration::from_millis(self.lease.unwrap_or(1000));
        Some(courier::qos::Liveliness::new(kind, lease))
    }

    /// The QoS options given, by flag.
    fn given(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        if self.strength.is_some() {
            v.push("--strength");
        }
        if self.exclusive {
            v.push("--exclusive");
        }
        if self.deadline.is_some() {
            v.push("--deadline");
        }
        if self.min_separation.is_some() {
            v.push("--min-separation");
        }
        if self.liveliness.is_some() {
            v.push("--liveliness");
        }
        if self.lease.is_some() {
            v.push("--lease");
        }
        if self.best_effort {
            v.push("--best-effort");
        }
        v
    }
}

#[derive(Args, Debug)]
pub struct ListArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Print changes as they come, until interrupted or --duration
    #[arg(long)]
    pub watch: bool,
    /// How long to listen (default: 2 s, or for ever with --watch)
    #[arg(long, value_name = "SECS", value_parser = at_least_1)]
    pub duration: Option<u64>,
    /// IPC: whether this module is connected (repeat for more)
    #[arg(long, value_name = "NAME")]
    pub module: Vec<String>,
    /// IPC: this message's format and handlers (repeat for more)
    #[arg(long, value_name = "NAME")]
    pub message: Vec<String>,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-list-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct PongArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// The topic pings come on
    #[arg(long, default_value = "ping")]
    pub topic: String,
    /// The topic answers go on
    #[arg(long, value_name = "TOPIC", default_value = "pong")]
    pub reply_topic: String,
    /// Exit after answering N pings (ping --rtt's warm-up pings not counted)
    #[arg(long, value_name = "N", value_parser = at_least_1)]
    pub count: Option<u64>,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-pong-%p")]
    pub name: String,
}

#[derive(Args, Debug)]
pub struct SpyArgs {
    /// Session URL (ipc://…, rtps://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// DDS: fnmatch pattern of topics to print samples of (default *);
    /// IPC: a message to print (repeat for more)
    #[arg(long, value_name = "TOPIC")]
    pub topic: Vec<String>,
    /// DDS: fnmatch pattern of type names
    #[arg(long = "type", value_name = "PATTERN", default_value = "*")]
    pub type_name: String,
    /// Exit after N samples
    #[arg(long, value_name = "N", value_parser = at_least_1)]
    pub count: Option<u64>,
    /// Exit after this long
    #[arg(long, value_name = "SECS", value_parser = at_least_1)]
    pub duration: Option<u64>,
    /// Participant / module name (%p: this process's id; IPC module names must be unique)
    #[arg(long, default_value = "courier-spy-%p")]
    pub name: String,
}

/// The backend a session URL names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Ipc,
    Dds,
}

/// Whether a URL that [`session_url`] accepted names a DDS-XRCE agent.
pub fn is_xrce(url: &str) -> bool {
    url.get(..5)
        .is_some_and(|s| s.eq_ignore_ascii_case("xrce+"))
}

/// The scheme of a URL that [`session_url`] accepted, as messages name it:
/// `rtps://`, `xrce+udp://`.
pub fn scheme(url: &str) -> String {
    let s = url.split_once("://").map_or(url, |(s, _)| s);
    format!("{}://", s.to_ascii_lowercase())
}

/// The backend of a URL that [`session_url`] accepted.
pub fn kind(url: &str) -> Kind {
    match url.split_once("://") {
        Some((s, _)) if s.eq_ignore_ascii_case("ipc") => Kind::Ipc,
        _ => Kind::Dds,
    }
}

/// Checks a session URL before anything connects: a scheme this program
/// knows, and what that backend makes of the rest.
pub fn session_url(url: &str) -> Result<String, String> {
    let known = courier::scheme::known_schemes().join(", ");
    let Some((scheme, _)) = url.split_once("://") else {
        if url.ends_with(".mcap") {
            return Err(format!(
                "{url:?} is a recording, not a session URL (replay takes the file first: \
                 courier replay FILE.mcap URL; record writes one with -o FILE.mcap)"
            ));
        }
        if std::path::Path::new(url).exists() {
            return Err(format!("{url:?} is a path, not a session URL (SCHEME://…)"));
        }
        return Err(format!(
            "no scheme in {url:?}; a session URL is SCHEME://…, known schemes: {known} \
             (ipc://localhost:1381, rtps://0?interface=lo)"
        ));
    };
    match scheme.to_ascii_lowercase().as_str() {
        "ipc" => courier::ipc_backend::parse_url(url)
            .map(|_| url.to_string())
            .map_err(|why| format!("bad IPC URL: {why}")),
        "rtps" => RtpsOptions::from_url(url)
            .map(|_| url.to_string())
            .map_err(|e| e.to_string()),
        "xrce+udp" | "xrce+tcp" | "xrce+serial" => {
            courier::xrce_backend::XrceOptions::from_url(url)
                .map(|_| url.to_string())
                .map_err(|e| e.to_string())
        }
        _ => Err(format!(
            "unknown scheme {scheme:?} in {url:?}; known schemes: {known}"
        )),
    }
}

/// A usage error found only once connected (a VALUE that does not fit
/// the format central holds for the message): `main` prints it as
/// [`usage_error`] does, exit 2.
#[derive(Debug)]
pub struct LateUsage {
    /// The subcommand.
    pub sub: &'static str,
    /// What is wrong.
    pub msg: String,
}

impl std::fmt::Display for LateUsage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.msg)
    }
}

impl std::error::Error for LateUsage {}

/// `--redefine` replaces the format central holds: other backends have
/// none.
fn redefine_on_ipc(sub: &str, url: &str, redefine: bool) -> Result<(), clap::Error> {
    if redefine && kind(url) != Kind::Ipc {
        return Err(usage_error(
            sub,
            format!(
                "--redefine replaces the format central holds; {} has no central",
                scheme(url)
            ),
        ));
    }
    Ok(())
}

/// A usage error found after parsing: printed as clap prints its own, with
/// the subcommand's usage, exit 2.
pub fn usage_error(sub: &str, msg: impl std::fmt::Display) -> clap::Error {
    let mut cmd = Cli::command();
    cmd.build();
    match cmd.find_subcommand_mut(sub) {
        Some(s) => s.error(ErrorKind::ArgumentConflict, msg),
        None => cmd.error(ErrorKind::ArgumentConflict, msg),
    }
}

impl Cli {
    /// The checks clap cannot make: options of one backend given for the
    /// other.
    pub fn check(&self) -> Result<(), clap::Error> {
        match &self.command {
            Command::Ping(a) => {
                // The IPC backend takes no QoS and would ignore these
                // silently: a publisher that is not exclusive, a deadline
                // that is never watched.
                if let Some(f) = a.qos.given().first().filter(|_| kind(&a.url) == Kind::Ipc) {
                    return Err(usage_error(
                        "ping",
                        format!(
                            "{f} is DDS QoS and needs an rtps:// session; {} is IPC, which has no QoS",
                            a.url
                        ),
                    ));
                }
            }
            Command::Spy(a) => match kind(&a.url) {
                Kind::Ipc => {
                    if a.topic.is_empty() {
                        return Err(usage_error(
                            "spy",
                            "spy on ipc:// needs --topic MESSAGE for each message to print: \
                             patterns are for rtps:// (`courier list ipc://…` lists the messages)",
                        ));
                    }
                    if let Some(p) = a.topic.iter().find(|t| t.contains(['*', '?', '['])) {
                        return Err(usage_error(
                            "spy",
                            format!(
                                "--topic {p:?} is a pattern; on ipc:// name each message \
                                 (`courier list ipc://…` lists the messages)"
                            ),
                        ));
                    }
                    if a.type_name != "*" {
                        return Err(usage_error(
                            "spy",
                            "--type is for rtps:// sessions (IPC messages have no type names)",
                        ));
                    }
                }
                Kind::Dds if is_xrce(&a.url) => {
                    if a.topic.is_empty()
                        || a.topic.iter().any(|t| t.contains(['*', '?', '[']))
                        || a.type_name.contains(['*', '?', '['])
                    {
                        return Err(usage_error(
                            "spy",
                            "on xrce+…:// name each --topic and one --type: an XRCE client \
                             learns nothing of DDS discovery, so patterns cannot be matched",
                        ));
                    }
                }
                Kind::Dds => {
                    if a.topic.len() > 1 {
                        return Err(usage_error(
                            "spy",
                            "on rtps:// --topic takes one fnmatch pattern (use *, ?, [..])",
                        ));
                    }
                }
            },
            Command::Perf(a) => {
                let c = a.common();
                if c.best_effort && kind(&c.url) == Kind::Ipc {
                    return Err(usage_error(
                        "perf",
                        format!(
                            "--best-effort is DDS QoS and needs an rtps:// session; {} is IPC, \
                             which has no QoS",
                            c.url
                        ),
                    ));
                }
            }
            Command::Echo(a) => {
                if let (Some(f), Kind::Dds) = (&a.format, kind(&a.url)) {
                    crate::cdr_value::check(f).map_err(|e| usage_error("echo", e))?;
                }
                if a.type_name.is_some() && kind(&a.url) == Kind::Ipc {
                    return Err(usage_error(
                        "echo",
                        "--type is for DDS sessions (rtps://, xrce+…://); IPC messages have no \
                         type names",
                    ));
                }
                if a.type_name.is_none() && is_xrce(&a.url) {
                    return Err(usage_error(
                        "echo",
                        "on xrce+…:// the agent creates a typed DDS reader: give --type TYPE \
                         (with --format for a type Courier does not know)",
                    ));
                }
            }
            Command::Pub(a) => {
                match kind(&a.url) {
                    Kind::Ipc if a.type_name.is_some() => {
                        return Err(usage_error(
                            "pub",
                            "--type is for DDS sessions (rtps://, xrce+…://); on ipc:// give \
                             --format",
                        ))
                    }
                    Kind::Dds => {
                        if let Some(f) = &a.format {
                            if a.type_name.is_none() {
                                return Err(usage_error(
                                    "pub",
                                    format!(
                                        "--format on {} needs --type: the DDS type name \
                                         subscribers match on",
                                        scheme(&a.url)
                                    ),
                                ));
                            }
                            crate::cdr_value::check(f).map_err(|e| usage_error("pub", e))?;
                        }
                    }
                    Kind::Ipc => {}
                }
                redefine_on_ipc("pub", &a.url, a.redefine)?;
                // the VALUE, whenever the command line alone gives its type
                // (all but ipc:// without --format: central holds that one)
                if let Some(r) = crate::publish::encoder_offline(a) {
                    let (enc, _) = r.map_err(|e| usage_error("pub", e))?;
                    crate::publish::sample(&enc, a).map_err(|e| usage_error("pub", e))?;
                }
            }
            Command::Call(a) => {
                match kind(&a.url) {
                    Kind::Ipc if a.type_name.is_some() || a.reply_type.is_some() => {
                        return Err(usage_error(
                            "call",
                            "--type and --reply-type are for DDS sessions (rtps://, xrce+…://); \
                             on ipc:// give --format and --reply-format",
                        ))
                    }
                    Kind::Dds => {
                        if a.format.is_some() && a.type_name.is_none() {
                            return Err(usage_error(
                                "call",
                                format!(
                                    "--format on {} needs --type: the DDS type name the service \
                                     matches on",
                                    scheme(&a.url)
                                ),
                            ));
                        }
                        if a.reply_format.is_some()
                            && a.reply_type.is_none()
                            && a.type_name.is_none()
                        {
                            return Err(usage_error(
                                "call",
                                format!(
                                    "--reply-format on {} needs --reply-type (or --type)",
                                    scheme(&a.url)
                                ),
                            ));
                        }
                        for f in a.format.iter().chain(&a.reply_format) {
                            crate::cdr_value::check(f).map_err(|e| usage_error("call", e))?;
                        }
                    }
                    Kind::Ipc => {}
                }
                // the REQUEST, whenever the command line alone gives its type
                if let Some(r) = crate::call::request_offline(a) {
                    r.map_err(|e| usage_error("call", e))?;
                }
            }
            Command::List(a) if is_xrce(&a.url) => {
                return Err(usage_error(
                    "list",
                    "list does not run on xrce+…://: an XRCE client learns nothing of DDS \
                     discovery; list the DDS side (rtps://…), where the agent's entities are",
                ));
            }
            Command::List(a) => {
                if kind(&a.url) == Kind::Dds && !(a.module.is_empty() && a.message.is_empty()) {
                    return Err(usage_error(
                        "list",
                        "--module and --message are for ipc:// sessions; rtps:// lists what \
                         discovery finds",
                    ));
                }
            }
            Command::Record(a) if is_xrce(&a.url) => {
                return Err(usage_error(
                    "record",
                    "record does not run on xrce+…://: an XRCE client learns nothing of DDS \
                     discovery, so it knows no topic types to record; record the same topics on \
                     the DDS side (rtps://…), where the agent's entities are",
                ));
            }
            Command::Record(a) => {
                if kind(&a.url) == Kind::Ipc {
                    if a.topics.is_empty() {
                        return Err(usage_error(
                            "record",
                            "record on ipc:// needs the messages to record, by name \
                             (`courier list ipc://…` lists them)",
                        ));
                    }
                    if let Some(p) = a.topics.iter().find(|t| t.contains(['*', '?', '['])) {
                        return Err(usage_error(
                            "record",
                            format!(
                                "{p:?} is a pattern; on ipc:// name each message \
                                 (`courier list ipc://…` lists them)"
                            ),
                        ));
                    }
                }
            }
            Command::Replay(a) => {
                if kind(&a.url) == Kind::Ipc && a.transient_local {
                    return Err(usage_error(
                        "replay",
                        "--transient-local is DDS durability; ipc:// has none",
                    ));
                }
                redefine_on_ipc("replay", &a.url, a.redefine)?;
            }
            Command::Hz(a) | Command::Bw(a) => {
                let sub = if matches!(self.command, Command::Hz(_)) {
                    "hz"
                } else {
                    "bw"
                };
                if a.type_name.is_some() && kind(&a.url) == Kind::Ipc {
                    return Err(usage_error(
                        sub,
                        "--type is for DDS sessions (rtps://, xrce+…://); IPC messages have no \
                         type names",
                    ));
                }
                if sub == "bw" && a.gap.is_some() {
                    return Err(usage_error(
                        "bw",
                        "--gap is for `courier hz` (it counts gaps between samples); bw reports \
                         bandwidth and sizes",
                    ));
                }
                if a.type_name.is_none() && is_xrce(&a.url) {
                    return Err(usage_error(
                        sub,
                        "on xrce+…:// the agent creates a typed DDS reader: give --type TYPE \
                         (with --format for a type Courier does not know)",
                    ));
                }
            }
            Command::Pong(_) | Command::Gen(_) | Command::Completions { .. } => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(a: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("courier").chain(a.iter().copied()))
    }

    #[test]
    fn the_derive_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn ping_options_in_both_spellings() {
        let u = "rtps://205?interface=lo&peers=127.0.0.1";
        let cli = parse(&[
            "ping",
            u,
            "--subscribe",
            "--topic=t",
            "--deadline",
            "250",
            "--count=4",
            "--strength",
            "-2",
            "--best-effort",
        ])
        .unwrap();
        let Command::Ping(o) = cli.command else {
            panic!("parse")
        };
        assert_eq!(o.url, u);
        assert!(!o.publish && o.subscribe && o.qos.best_effort);
        assert_eq!(o.topic, "t");
        assert_eq!(o.qos.deadline, Some(250));
        assert_eq!((o.count, o.qos.strength), (Some(4), Some(-2)));
    }

    #[test]
    fn urls_are_checked_before_connecting() {
        let known = courier::scheme::known_schemes().join(", ");
        for (url, want) in [
            (
                "foo://x",
                format!("unknown scheme \"foo\" in \"foo://x\"; known schemes: {known}"),
            ),
            (
                "localhost:1381",
                "no scheme in \"localhost:1381\"".to_string(),
            ),
            (
                "ipc://h:port",
                "bad IPC URL: 'port' is not a port number".to_string(),
            ),
            ("rtps://999", "domain 999 is above 232".to_string()),
            (
                "rtps://0?colour=red",
                "unknown option \"colour\"".to_string(),
            ),
        ] {
            let e = session_url(url).unwrap_err();
            assert!(e.contains(&want), "{url}: {want:?} in {e:?}");
        }
        assert_eq!(kind("IPC://h:1"), Kind::Ipc);
        assert_eq!(kind("rtps://0"), Kind::Dds);
    }
}
