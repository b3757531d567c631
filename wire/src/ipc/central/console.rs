//! The console: the commands typed on central's terminal (`help`,
//! `display`, `status`, `memory`, `close`, `unlock`, and options).

use std::time::SystemTime;

use super::log::{self, Kind};
use super::tables::{Org, Status};
use super::{Central, LogOptions, LogTarget, Output, VERSION};

impl Central {
    /// A console command line (`help`, `display`, `status`, `memory`,
    /// `close <module>`, `unlock <resource>`, or an option such as `-lmsd`).
    pub fn command(&mut self, line: &str, now: SystemTime) {
        self.clock = now;
        let mut words = line.split_whitespace();
        let Some(cmd) = words.next() else {
            return;
        };
        let arg = words.next();
        let say = |c: &mut Central, s: String| {
            c.outputs.push_back(Output::Log {
                target: LogTarget {
                    terminal: true,
                    file: false,
                },
                line: s,
            })
        };
        match (cmd, arg) {
            ("help", _) | ("?", _) => {
                for l in [
                    "The following are central commands:",
                    "  help: print this message",
                    "  display: display the active and pending messages",
                    "  status: display the known modules and their status",
                    "  memory: display total memory usage",
                    "  close <module>: close a connection to a module",
                    "  unlock <resource>: unlock a locked resource",
                    "The following command line options can also be used as commands:",
                    "  -v: display server version information",
                    "  -l<options>: logging onto terminal (m s t d i h r p x)",
                    "  -L<options>: logging into file (as -l, plus F n)",
                    "  -I<msgName>: ignore logging this message",
                    "  -c: use direct connections for messages defined from now on",
                    "  -r: resend non-completed messages when modules crash and reconnect",
                ] {
                    say(self, l.to_string());
                }
            }
            ("display", _) => {
                let mut ids: Vec<i32> = self.dispatches.keys().copied().collect();
                ids.sort_unstable();
                say(self, format!("{} message(s) active or pending:", ids.len()));
                for id in ids {
                    let d = &self.dispatches[&id];
                    let dest = d
                        .hnd
                        .as_ref()
                        .map(|(c, _)| self.module_name(Org::Module(*c)))
                        .unwrap_or_else(|| "(no handler)".into());
                    let st = match d.status {
                        Status::Attending => "Active",
                        Status::Pending => "Pending",
                        Status::Ahead => "Pending (sent ahead)",
                        Status::NoHandler => "Waiting for a handler",
                    };
                    let line = format!(
                        "  {{{id}}} {:<9} {:>15}: {:>10} --> {:<15} {st}",
                        log::class_name(d.class),
                        d.msg,
                        self.module_name(d.org),
                        dest
                    );
                    say(self, line);
                }
            }
            ("status", _) => {
                let lines: Vec<String> = self
                    .modules
                    .iter()
                    .map(|(c, m)| {
                        format!(
                            "  Module {} on {} (sd {}): capacity {}, active {}, pending {}{}",
                            m.name.as_deref().unwrap_or("<connecting>"),
                            if m.host.is_empty() { "?" } else { &m.host },
                            c.0,
                            m.capacity,
                            m.attending,
                            m.pending.len() + m.ahead.len(),
                            if m.port >= 0 {
                                format!(", direct port {}", m.port)
                            } else {
                                String::new()
                            }
                        )
                    })
                    .collect();
                say(self, format!("{} module(s) connected:", lines.len()));
                for l in lines {
                    say(self, l);
                }
            }
            ("memory", _) => {
                let s = self.stats();
                say(self, "Cumulative Memory Usage:".into());
                say(
                    self,
                    format!(
                        "  Messages queued: {} dispatch(es), {} byte(s) pending (peak {})",
                        s.dispatches, s.queued_bytes, s.peak_queued_bytes
                    ),
                );
                say(
                    self,
                    format!(
                        "  Waiting for a handler: {} message(s), {} byte(s), {} dropped",
                        s.waiting_for_handler, s.waiting_bytes, s.dropped_waiting
                    ),
                );
                say(
                    self,
                    format!(
                        "  Modules: {}, messages defined: {}, frames received: {}, dropped by limits: {}",
                        s.modules,
                        self.msgs.len(),
                        s.frames_in,
                        s.dropped
                    ),
                );
            }
            ("close", Some(name)) => {
                let conn = self
                    .modules
                    .iter()
                    .find(|(_, m)| m.name.as_deref() == Some(name))
                    .map(|(c, _)| *c);
                match conn {
                    Some(c) => {
                        self.log_line(Kind::Always, format!("close Module: Closing {name}"));
                        self.outputs.push_back(Output::Close {
                            conn: c,
                            reason: "closed from the console".into(),
                        });
                        self.close_module(c, false, now);
                    }
                    None => say(self, format!("Can not find {name} to close.")),
                }
            }
            ("close", None) => say(self, "usage: close <module>".into()),
            ("unlock", Some(name)) => say(
                self,
                format!("Resource {name} is not locked (IPC modules cannot lock resources)"),
            ),
            ("unlock", None) => say(self, "usage: unlock <resource>".into()),
            ("quit", _) => say(self, "use Ctrl-C (SIGINT) to stop central".into()),
            (opt, _) if opt.starts_with('-') => {
                // A line may hold several options (`-lm -Lx`), as in C.
                for word in line.split_whitespace() {
                    if let Err(e) = self.apply_option(word) {
                        say(self, e);
                    }
                }
            }
            (other, _) => say(self, format!("Unknown command '{other}' (type help)")),
        }
    }

    /// An option given as a console command.
    fn apply_option(&mut self, opt: &str) -> Result<(), String> {
        let (flag, rest) = opt.split_at(opt.len().min(2));
        match flag {
            "-v" => {
                let v = format!(
                    "Task Control Server {}.{}.1 (Courier {})",
                    VERSION.0,
                    VERSION.1,
                    env!("CARGO_PKG_VERSION")
                );
                self.outputs.push_back(Output::Log {
                    target: LogTarget {
                        terminal: true,
                        file: false,
                    },
                    line: v,
                });
            }
            "-l" => {
                self.config.terminal_log =
                    LogOptions::parse(rest, false).map_err(|e| e.to_string())?;
                self.update_log_vars();
            }
            "-L" => {
                self.config.file_log = LogOptions::parse(rest, true).map_err(|e| e.to_string())?;
                self.update_log_vars();
            }
            "-I" if !rest.is_empty() => {
                self.config.ignore.push(rest.to_string());
                self.ignore.insert(rest.to_string());
            }
            "-c" => self.config.direct = true,
            "-r" => self.config.resend_on_reconnect = true,
            "-s" | "-u" | "-p" | "-f" => {
                return Err(format!(
                    "option {flag} can only be given on the command line"
                ))
            }
            _ => return Err(format!("Unknown option '{opt}' (type help)")),
        }
        Ok(())
    }
}
