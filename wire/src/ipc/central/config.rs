//! Central's configuration: the command-line options of the C central
//! (`-c -r -l -L -I -s`) and Courier's own bounds and forwarding options.

use std::collections::BTreeMap;

/// Logging options of `-l` / `-L` (manual §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct LogOptions {
    /// `m`: message traffic.
    pub messages: bool,
    /// `s`: status of IPC (connects, disconnects, registrations).
    pub status: bool,
    /// `t`: the time messages are received by central.
    pub time: bool,
    /// `d`: the data associated with messages.
    pub data: bool,
    /// `i`: ignore logging certain internal messages.
    pub ignore_internal: bool,
    /// `h`: handle time summary of incoming messages.
    pub handle_summary: bool,
    /// `r`: log the reference id as well as the message name.
    pub refs: bool,
    /// `p`: log the reference id of the message's parent.
    pub parent_refs: bool,
    /// `F` (file only): don't flush the file after each line.
    pub no_flush: bool,
    /// `n` (file only): don't prompt the user for comments.
    pub no_prompt: bool,
}

impl LogOptions {
    /// No logging (`-lx`).
    pub const NONE: LogOptions = LogOptions {
        messages: false,
        status: false,
        time: false,
        data: false,
        ignore_internal: false,
        handle_summary: false,
        refs: false,
        parent_refs: false,
        no_flush: false,
        no_prompt: false,
    };

    /// Parses the letters after `-l` (`file == false`) or `-L` (`file ==
    /// true`), as the C central does: no letters = `mstdh`, `x` = none,
    /// otherwise each letter turns one option on (`F` and `n` only for files).
    pub fn parse(letters: &str, file: bool) -> Result<LogOptions, OptionError> {
        let mut o = LogOptions::NONE;
        if letters.is_empty() {
            o.messages = true;
            o.status = true;
            o.time = true;
            o.data = true;
            o.handle_summary = true;
            return Ok(o);
        }
        // Like the C central: letters in either case; an `x` anywhere
        // turns the log off.
        let mut off = false;
        for c in letters.chars() {
            match c.to_ascii_lowercase() {
                'm' => o.messages = true,
                's' => o.status = true,
                't' => o.time = true,
                'd' => o.data = true,
                'i' => o.ignore_internal = true,
                'h' => o.handle_summary = true,
                'r' => o.refs = true,
                'p' => o.parent_refs = true,
                'x' => off = true,
                'f' if file => o.no_flush = true,
                'n' if file => o.no_prompt = true,
                _ => {
                    return Err(OptionError::UnknownLogOption {
                        option: c,
                        flag: if file { 'L' } else { 'l' },
                    })
                }
            }
        }
        if off {
            o = LogOptions::NONE;
        }
        Ok(o)
    }

    /// True if anything at all is logged.
    pub fn any(&self) -> bool {
        self.messages || self.status || self.data || self.time || self.handle_summary
    }
}

/// A bad option given to central (command line or console).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum OptionError {
    /// A letter after `-l`/`-L` that is not a logging option.
    #[error("unknown logging option '{option}' in -{flag} (options: m s t d i h r p x{})", if *flag == 'L' { " F n" } else { "" })]
    UnknownLogOption {
        /// The letter.
        option: char,
        /// `l` or `L`.
        flag: char,
    },
}

/// Most broadcasts [`Config::send_ahead`] writes ahead to one module.
pub const MAX_SEND_AHEAD: usize = 1024;

/// Configuration of a [`Central`](super::Central).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Config {
    /// `-c`: messages go module-to-module; central is only the registry.
    pub direct: bool,
    /// `-r`: resend non-completed messages to a module that crashed and
    /// reconnects. They are kept under the crashed module's name until a
    /// module of that name subscribes their message again; past
    /// [`max_queued_bytes`](Self::max_queued_bytes) of them (counted as
    /// [`Stats::kept_bytes`](super::Stats::kept_bytes)) the oldest are
    /// dropped with a warning.
    pub resend_on_reconnect: bool,
    /// `-l`: terminal logging (default `-lmsi`).
    pub terminal_log: LogOptions,
    /// `-L`: file logging (default `-Lx`, none).
    pub file_log: LogOptions,
    /// `-I`: message names not to log.
    pub ignore: Vec<String>,
    /// `-s`: silent running. The shell prints nothing; modules see it as the
    /// terminal log's `quiet` field of `CENTRAL_TERMINAL_LOG_VAR`.
    pub quiet: bool,
    /// Largest frame body (`classTotal + msgTotal`) accepted from a module;
    /// a larger header closes the connection with a log line.
    pub max_frame: u64,
    /// Bytes of large frames being received, all connections together
    /// (default 512 MiB, two of `max_frame`): a connection that starts a
    /// large frame past it is read no more
    /// ([`Output::PauseRead`](super::Output::PauseRead)) until the frames
    /// in progress complete or go; one frame is always taken, whatever its
    /// size. Without it every connection could hold a frame of up to
    /// `max_frame` half sent (8 of them held 1.6 GB).
    pub max_frames_in_progress: u64,
    /// When the messages queued inside central for delivery exceed this many
    /// bytes (their data plus [`DISPATCH_COST`](super::DISPATCH_COST) each,
    /// so that empty messages count too), the shell is asked to stop reading
    /// from publishers ([`Output::PauseRead`](super::Output::PauseRead))
    /// until the queues drain to half of it: memory stays bounded and nothing
    /// is dropped (TCP back-pressure reaches the publisher). A module is read
    /// on while central waits for something only it can send: the answer to a
    /// query it is handling, or the Success that lets its own queue move; a
    /// module publishing from its handler of a broadcast is held back like
    /// any other, and so is one publishing while it answers a query, unless a
    /// module that waits for an answer has messages queued (its handler may
    /// hold its capacity while it waits, so that queue could wait for the
    /// reply central would not read); queuing a message for such a module
    /// reads answering modules again.
    ///
    /// Queries and informs waiting for a first handler of their message wait
    /// as long as it takes, as in C, and outlive their sender; they are a
    /// pool of their own with the same bound
    /// ([`Stats::waiting_bytes`](super::Stats::waiting_bytes)): past it, the
    /// oldest of a message are dropped with a warning, so that a module
    /// asking a service that is down, again and again, cannot grow central
    /// without bound.
    pub max_queued_bytes: usize,
    /// Cut-through: a message or reply whose body is at least this many
    /// bytes is forwarded while it still arrives, when its receiver can take
    /// it at once (ready, below its capacity, nothing pending). A routed
    /// round trip then moves each large message once instead of twice in a
    /// row, and central holds no copy of it. `None` (the default, as in C):
    /// every frame is stored whole before it is forwarded. Not used with
    /// data logging or `-r` (both need the whole message). The receiver's
    /// stream follows the sender's: while a sender is slow in the middle of
    /// a relayed message, central's other frames for that receiver wait
    /// behind it, and a sender that dies in the middle leaves the receiver
    /// a frame completed with zero bytes (logged). Use it between modules
    /// that are trusted to send whole messages.
    pub cut_through: Option<usize>,
    /// Send-ahead, by module name: while a module named here handles as
    /// many broadcasts as its capacity allows, up to this many of the
    /// broadcasts queued for it are already written to its socket, so that
    /// it finds its next message waiting when it finishes instead of a
    /// round trip later. Empty (the default, as in C): a delivery leaves
    /// central only when a capacity slot is free.
    ///
    /// Meant for modules that only consume, such as loggers and recorders:
    /// a C module handles queued messages while it waits for a reply
    /// (`IPC_queryResponse`, the first `IPC_publish` of a message, which
    /// looks it up, or `IPC_listen` in a handler), so a handler that waits
    /// would be entered again with a message sent ahead, which capacity 1
    /// exists to prevent.
    ///
    /// The module still gets every message once and in central's order,
    /// and central's bookkeeping and log stay C's: a message sent ahead
    /// counts as pending and is logged as sent when its slot frees. Only
    /// broadcasts from modules go ahead, never a message with a queue limit
    /// (it may be dropped) or to a module with a handler of a message with
    /// a priority (a later message may overtake it); a priority or a limit
    /// set later does not call back what is already written. Nothing goes
    /// ahead for a handler the module has not looked up yet (its first
    /// delivery), so the frames are byte for byte C's. A message for a
    /// handler unsubscribed in the meantime reaches the module, which
    /// discards and acknowledges it (the C library warns), where central
    /// would have deleted it. At most [`MAX_SEND_AHEAD`] (more is taken as
    /// that): a module gives up a central that sends more than its
    /// capacity and that before its acknowledgements.
    pub send_ahead: BTreeMap<String, usize>,
    /// How long a new connection may take to say its module name (the
    /// `IPC_connect` query a module sends right after connecting). One
    /// that has not by then is closed with a log line, so that silent
    /// connections (a probe that never closes, a peer that is not an IPC
    /// module) cannot hold central's file descriptors for ever. `None`:
    /// never, as in C. Default 10 s.
    pub handshake_timeout: Option<std::time::Duration>,
    /// How long a large frame being received (16 KiB or more, or one
    /// forwarded as it arrives under [`cut_through`](Self::cut_through))
    /// may go without a byte arriving. Its connection is then closed with
    /// a log line: a peer that stops in the middle of a frame would
    /// otherwise hold its share of
    /// [`max_frames_in_progress`](Self::max_frames_in_progress) (and, cut
    /// through, its receiver's other deliveries) for as long as it keeps
    /// the connection. Time while central itself does not read the
    /// connection does not count. `None`: never, as in C. Default 30 s.
    pub frame_stall_timeout: Option<std::time::Duration>,
    /// Bytes central keeps for what modules define, all together: message
    /// names and formats (also those only subscribed to so far) and named
    /// formats, each with its bookkeeping, about 1 KB a message (default
    /// 64 MiB: some 60 000 messages, tens of times a large system's). Definitions outlive their module, as in C, so
    /// modules defining ever new messages (20 × 10 000 with 4 KB formats
    /// made 979 MB) would grow central without end. Past it a new
    /// definition, subscription to an unknown message or named format is
    /// refused with a warning line; redefining with no more bytes is not.
    pub max_definition_bytes: usize,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            direct: false,
            resend_on_reconnect: false,
            terminal_log: LogOptions {
                messages: true,
                status: true,
                ignore_internal: true,
                ..LogOptions::default()
            },
            file_log: LogOptions::default(),
            ignore: Vec::new(),
            quiet: false,
            max_frame: 256 << 20,
            max_frames_in_progress: 512 << 20,
            max_queued_bytes: 64 << 20,
            cut_through: None,
            send_ahead: BTreeMap::new(),
            handshake_timeout: Some(std::time::Duration::from_secs(10)),
            frame_stall_timeout: Some(std::time::Duration::from_secs(30)),
            max_definition_bytes: 64 << 20,
        }
    }
}
