//! The CMU IPC `central` server as a sans-I/O state machine (ipc.md §1–§8, §11).
//!
//! [`Central`] owns every routing decision — the message and handler
//! tables, named formats, pending queues, capacity, priorities, queue
//! limits, global variables, direct-mode bookkeeping — and no sockets,
//! threads or clocks. A shell (the `central` binary in `courier-broker`)
//! feeds it what happens on connections and carries out what it asks for:
//!
//! ```text
//!   accept      -> central.connect(conn, peer, now)
//!   bytes read  -> central.receive(conn, &bytes, now)
//!   EOF / error -> central.disconnect(conn, now)
//!   stdin line  -> central.command(line, now)
//!   loop { match central.poll_output() { Transmit / Close / Log / PauseRead / ResumeRead } }
//! ```
//!
//! Framing is done here too: `receive` takes raw stream bytes in any
//! split, so tests can replay captured byte streams exactly.

use std::time::SystemTime;

/// Identifies one accepted connection (chosen by the shell, never reused
/// while the connection is open).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ConnId(pub u64);

/// Where a connection came from, for logs and `status`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Peer {
    /// A TCP peer: its address as text, e.g. `127.0.0.1:53122`.
    Tcp(String),
    /// A UNIX-domain socket peer.
    Unix,
    /// Anything else (tests).
    Other(String),
}

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
        for c in letters.chars() {
            match c {
                'm' => o.messages = true,
                's' => o.status = true,
                't' => o.time = true,
                'd' => o.data = true,
                'i' => o.ignore_internal = true,
                'h' => o.handle_summary = true,
                'r' => o.refs = true,
                'p' => o.parent_refs = true,
                'x' => o = LogOptions::NONE,
                'F' if file => o.no_flush = true,
                'n' if file => o.no_prompt = true,
                _ => {
                    return Err(OptionError::UnknownLogOption {
                        option: c,
                        flag: if file { 'L' } else { 'l' },
                    })
                }
            }
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

/// Configuration of a [`Central`].
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Config {
    /// `-c`: messages go module-to-module; central is only the registry.
    pub direct: bool,
    /// `-r`: resend non-completed messages to a module that crashed and reconnects.
    pub resend_on_reconnect: bool,
    /// `-l`: terminal logging (default `-lmsi`).
    pub terminal_log: LogOptions,
    /// `-L`: file logging (default `-Lx`, none).
    pub file_log: LogOptions,
    /// `-I`: message names not to log.
    pub ignore: Vec<String>,
    /// Largest frame body (`classTotal + msgTotal`) accepted from a module;
    /// a larger header closes the connection with a log line.
    pub max_frame: u64,
    /// When the messages queued inside central for delivery exceed this many
    /// bytes, the shell is asked to stop reading from publishers
    /// ([`Output::PauseRead`]) until the queues drain: memory stays bounded
    /// and nothing is dropped (TCP back-pressure reaches the publisher).
    pub max_queued_bytes: usize,
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
            max_frame: 256 << 20,
            max_queued_bytes: 64 << 20,
        }
    }
}

/// Where a log line goes (the shell writes it to the terminal and/or the log file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogTarget {
    /// Print on the terminal (`-l`; suppressed by `-s` in the shell).
    pub terminal: bool,
    /// Append to the log file (`-L`).
    pub file: bool,
}

/// What the state machine asks the shell to do.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Output {
    /// Write these bytes to the connection, in order.
    Transmit {
        /// The connection.
        conn: ConnId,
        /// Bytes to write.
        bytes: Vec<u8>,
    },
    /// Close the connection (after writing what was queued before).
    Close {
        /// The connection.
        conn: ConnId,
        /// Why, for the shell's log.
        reason: String,
    },
    /// A line for the log, already formatted as the C central prints it
    /// (no trailing newline).
    Log {
        /// Where it goes.
        target: LogTarget,
        /// The text.
        line: String,
    },
    /// Stop reading from this connection until [`Output::ResumeRead`].
    PauseRead {
        /// The connection.
        conn: ConnId,
    },
    /// Resume reading from this connection.
    ResumeRead {
        /// The connection.
        conn: ConnId,
    },
}

/// The IPC central server's state.
#[derive(Debug)]
pub struct Central {
    config: Config,
    outputs: std::collections::VecDeque<Output>,
}

impl Central {
    /// A central with no modules.
    pub fn new(config: Config) -> Self {
        Central {
            config,
            outputs: std::collections::VecDeque::new(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// A module connected: queues the 4-byte msgInfo id and the two
    /// formatter frames central speaks first (ipc.md §4).
    pub fn connect(&mut self, conn: ConnId, peer: Peer, now: SystemTime) {
        let _ = (conn, peer, now);
    }

    /// Bytes arrived on a connection (any split of the stream).
    pub fn receive(&mut self, conn: ConnId, bytes: &[u8], now: SystemTime) {
        let _ = (conn, bytes, now);
    }

    /// The connection ended (EOF, error, or after [`Output::Close`]).
    pub fn disconnect(&mut self, conn: ConnId, now: SystemTime) {
        let _ = (conn, now);
    }

    /// A console command line (`help`, `display`, `status`, `memory`,
    /// `close <module>`, `unlock <resource>`, or an option such as `-lmsd`).
    pub fn command(&mut self, line: &str, now: SystemTime) {
        let _ = (line, now);
    }

    /// The next thing the shell must do, if any.
    pub fn poll_output(&mut self) -> Option<Output> {
        self.outputs.pop_front()
    }
}
