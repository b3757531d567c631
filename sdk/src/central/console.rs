//! The console's commands, read as the C central reads them, and the text
//! it answers with ([`command`]).
//!
//! The text is the shell's, not the state machine's: this module uses
//! nothing but central's public console API ([`Central::dispatches`],
//! [`Central::modules`], [`Central::stats`],
//! [`Central::close_module_named`], [`Central::reconfigure`],
//! [`Central::print`]).

use std::time::SystemTime;

use courier_wire::ipc::central::{
    Central, DispatchInfo, DispatchState, LogOptions, ModuleInfo, Stats, VERSION,
};

/// The line the console's `-v` prints.
fn banner() -> String {
    format!(
        "Task Control Server {}.{}.1 (Courier {})",
        VERSION.0,
        VERSION.1,
        env!("CARGO_PKG_VERSION")
    )
}

/// `help`, in the C central's words (`displayHelp`), listing the options
/// that work as console commands here.
const HELP: &[&str] = &[
    "",
    "The following command are available:",
    "help: print this message.",
    "display : Display active and pending messages.",
    "status : Display the known modules and their status.",
    "memory : Display total memory usage.",
    "close <module>: Close a connection to a module.",
    "unlock <resource>: Unlock a locked resouce.",
    "The following command line options can also be used as commands",
    " -v: display server version info.",
    " -l: logging onto terminal.",
    "     options are: m (message traffic)",
    "                  s (status of IPC)",
    "                  t (time messages are handled)",
    "                  d (data associated with message)",
    "                  i (ignore logging registration and deregistration messages)",
    "                  h (incoming message handle time summary)",
    "                  r (log the reference Id as well as the msg name)",
    "                  p (log the reference Id of the message's parent)",
    "                  x (no logging)",
    "     -l is equivalent to -lmstdh; the default is -lmsi",
    " -L: logging into file.",
    "     options are the same as above with the addition of F.",
    "                  F (don't flush file after each line)",
    "                  n (do not prompt the user for comments)",
    "     the default is -Lx",
    " -c: Use direct (not via central) conntections where possible.",
    " -I<msgName>: Ignore logging this message.",
    " -r: try resending non-completed messages when modules crash",
];

/// Runs a console command line (`help`, `display`, `status`, `memory`,
/// `close <module>`, `unlock <resource>`, or an option such as `-lmsd`):
/// its answer goes out as terminal lines ([`Central::print`]), its action
/// (closing a module, an option) is carried out. `quit` is the shell's: it
/// is only told how to stop.
pub(crate) fn command(central: &mut Central, line: &str, now: SystemTime) {
    let mut words = line.split_whitespace();
    let Some(cmd) = words.next() else {
        return;
    };
    let arg = words.next();
    match (cmd, arg) {
        ("help", _) | ("?", _) => {
            for l in HELP {
                central.print(l.to_string());
            }
        }
        ("display", _) => {
            central.print("Active and Pending Messages:".into());
            for d in &central.dispatches() {
                central.print(dispatch_line(d));
            }
        }
        ("status", _) => {
            central.print("Resource status".into());
            let mut ms = central.modules();
            // C walks its resource table in hash order; by name here.
            ms.sort_by(|a, b| a.name.cmp(&b.name));
            for m in &ms {
                if let Some(line) = module_line(m) {
                    central.print(line);
                }
            }
        }
        ("memory", _) => {
            for l in memory_report(&central.stats()) {
                central.print(l);
            }
        }
        ("close", Some(name)) => {
            if !central.close_module_named(name, now) {
                central.print(format!("Can not find {name} to close."));
            }
        }
        ("close", None) => central.print("usage: close <module>".into()),
        ("unlock", Some(name)) => central.print(format!(
            "Resource {name} is not locked (IPC modules cannot lock resources)"
        )),
        ("unlock", None) => central.print("usage: unlock <resource>".into()),
        ("quit", _) => central.print("use Ctrl-C (SIGINT) to stop central".into()),
        (opt, _) if opt.starts_with('-') => {
            // A line may hold several options (`-lm -Lx`), as in C.
            for word in line.split_whitespace() {
                if let Err(e) = option(central, word) {
                    central.print(e);
                }
            }
        }
        (other, _) => central.print(format!("Unknown command '{other}' (type help)")),
    }
}

/// An option given as a console command.
fn option(central: &mut Central, opt: &str) -> Result<(), String> {
    let (flag, rest) = opt.split_at(opt.len().min(2));
    match flag {
        "-v" => central.print(banner()),
        "-l" => {
            let o = LogOptions::parse(rest, false).map_err(|e| e.to_string())?;
            central.reconfigure(|c| c.terminal_log = o);
        }
        "-L" => {
            let o = LogOptions::parse(rest, true).map_err(|e| e.to_string())?;
            central.reconfigure(|c| c.file_log = o);
        }
        "-I" if !rest.is_empty() => central.reconfigure(|c| c.ignore.push(rest.to_string())),
        "-c" => central.reconfigure(|c| c.direct = true),
        "-r" => central.reconfigure(|c| c.resend_on_reconnect = true),
        "-s" | "-u" | "-p" | "-f" => {
            return Err(format!(
                "option {flag} can only be given on the command line"
            ))
        }
        _ => return Err(format!("Unknown option '{opt}' (type help)")),
    }
    Ok(())
}

/// `display`: one message alive, as C's `displayMessages` prints it
/// (`  <message> {<id>}: <status>`, with C's status names).
fn dispatch_line(d: &DispatchInfo) -> String {
    let st = match d.state {
        DispatchState::Active => "Active",
        DispatchState::Pending | DispatchState::SentAhead => "Pending",
        // C keeps a query without a handler as an inactive dispatch.
        DispatchState::WaitingForHandler => "Inactive",
        _ => "Allocated",
    };
    format!("  {} {{{}}}: {st}", d.msg, d.id)
}

/// `status`: one module, as C's `showResourceStatus` prints its resource
/// (a module not named yet has none).
fn module_line(m: &ModuleInfo) -> Option<String> {
    let name = m.name.as_deref()?;
    Some(format!(
        " Resource {name}  Attending: {}  Pending: {} Resource Status: Active",
        m.active, m.pending
    ))
}

/// What `memory` prints, and what central prints on standard error when a
/// signal stops it (C's `x_ipcStats`): C's heading, then Courier's own
/// counters (C counts its `malloc` calls, which Courier does not have).
/// The line on what `-r` keeps comes only once something was kept.
pub fn memory_report(s: &Stats) -> Vec<String> {
    let mut lines = vec![
        "Cumulative Memory Usage:".into(),
        format!(
            "  Messages queued: {} dispatch(es), {} byte(s) pending (peak {})",
            s.dispatches, s.queued_bytes, s.peak_queued_bytes
        ),
        format!(
            "  Waiting for a handler: {} message(s), {} byte(s), {} dropped",
            s.waiting_for_handler, s.waiting_bytes, s.dropped_waiting
        ),
    ];
    if s.kept_for_resend > 0 || s.dropped_kept > 0 {
        lines.push(format!(
            "  Kept to resend (-r): {} message(s), {} byte(s), {} dropped",
            s.kept_for_resend, s.kept_bytes, s.dropped_kept
        ));
    }
    lines.push(format!(
        "  Modules: {}, messages defined: {} ({} bytes of definitions), frames received: {}, \
         dropped by limits: {}",
        s.modules, s.messages, s.definition_bytes, s.frames_in, s.dropped
    ));
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier_wire::ipc::central::{Config, ConnId, Output, Peer};

    fn answer(central: &mut Central, line: &str) -> Vec<String> {
        command(central, line, SystemTime::UNIX_EPOCH);
        std::iter::from_fn(|| central.poll_output())
            .filter_map(|o| match o {
                Output::Log { target, line } => {
                    assert!(target.terminal && !target.file, "{line}");
                    Some(line)
                }
                _ => None,
            })
            .collect()
    }

    #[test]
    fn bad_options_and_commands_are_answered() {
        let mut c = Central::new(Config::default());
        assert_eq!(
            answer(&mut c, "-p1381 -lq"),
            [
                "option -p can only be given on the command line".to_string(),
                LogOptions::parse("q", false).unwrap_err().to_string(),
            ]
        );
        assert_eq!(
            answer(&mut c, "frob"),
            ["Unknown command 'frob' (type help)"]
        );
        assert_eq!(
            answer(&mut c, "close nobody"),
            ["Can not find nobody to close."]
        );
        assert_eq!(answer(&mut c, "close"), ["usage: close <module>"]);
        assert_eq!(answer(&mut c, "-v"), [banner()]);
        assert_eq!(answer(&mut c, "help").len(), HELP.len());
        assert!(answer(&mut c, "   ").is_empty());
    }

    #[test]
    fn status_display_and_memory() {
        let mut c = Central::new(Config::default());
        c.connect(ConnId(5), Peer::Other("t".into()), SystemTime::UNIX_EPOCH);
        while c.poll_output().is_some() {}
        // A module not named yet has no resource.
        assert_eq!(answer(&mut c, "status"), ["Resource status"]);
        assert_eq!(answer(&mut c, "display"), ["Active and Pending Messages:"]);
        let memory = answer(&mut c, "memory");
        assert_eq!(memory[0], "Cumulative Memory Usage:");
        assert!(
            memory[3].starts_with("  Modules: 1, messages defined: "),
            "{memory:?}"
        );
    }

    #[test]
    fn a_console_line_with_several_options() {
        let mut c = Central::new(Config::default());
        command(&mut c, "-lmd -Lx -Ifoo", SystemTime::now());
        assert!(c.config().terminal_log.data && c.config().terminal_log.messages);
        assert!(!c.config().file_log.any());
        assert!(c.config().ignore.contains(&"foo".to_string()));
        while c.poll_output().is_some() {}
    }
}
