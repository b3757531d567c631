//! The floor under central's idle memory: a program with central's runtime
//! (a tokio current-thread runtime with every driver on, built the same
//! way as `central` builds it) that listens on 127.0.0.1 over TCP and on a
//! UNIX socket, accepts connections and holds them, and does nothing else:
//! no IPC, no logging, no signals, no console. `central-memory` starts it
//! as it starts a central and reports its resident size next to theirs;
//! what central uses above it is central's own.
//!
//! ```text
//! tokio-listen-floor -p<port> --unix <path>
//! ```
//! An accepted connection is kept, registered with the runtime's reactor
//! as central keeps an idle module's socket, and never read (central reads
//! an idle module's socket only when it becomes readable). It runs until
//! killed; the UNIX socket's file is left for the caller to remove.

use std::path::PathBuf;
use std::process::ExitCode;

use tokio::net::{TcpListener, UnixListener};

fn main() -> ExitCode {
    let mut port: Option<u16> = None;
    let mut unix: Option<PathBuf> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if let Some(p) = a.strip_prefix("-p") {
            port = p.parse().ok();
            if port.is_none() {
                eprintln!("tokio-listen-floor: bad port {a:?}");
                return ExitCode::from(2);
            }
        } else if a == "--unix" {
            unix = args.next().map(PathBuf::from);
        } else {
            eprintln!("usage: tokio-listen-floor -p<port> --unix <path>");
            return ExitCode::from(2);
        }
    }
    let (Some(port), Some(unix)) = (port, unix) else {
        eprintln!("usage: tokio-listen-floor -p<port> --unix <path>");
        return ExitCode::from(2);
    };
    // As central builds its runtime (broker/src/bin/central.rs).
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("tokio-listen-floor: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let r: std::io::Result<()> = rt.block_on(async move {
        let tcp = TcpListener::bind(("127.0.0.1", port)).await?;
        let _ = std::fs::remove_file(&unix);
        let uds = UnixListener::bind(&unix)?;
        let mut tcp_held = Vec::new();
        let mut uds_held = Vec::new();
        loop {
            tokio::select! {
                r = tcp.accept() => tcp_held.push(r?.0),
                r = uds.accept() => uds_held.push(r?.0),
            }
        }
    });
    if let Err(e) = r {
        eprintln!("tokio-listen-floor: {e}");
    }
    ExitCode::FAILURE
}
