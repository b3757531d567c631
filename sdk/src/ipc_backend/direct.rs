//! Direct mode's links between modules: the listener other modules
//! connect to, and connecting to theirs.

use super::*;

/// Where this module takes direct links: the TCP port it announced and,
/// as C's `x_ipcDirectResource` does, the UNIX socket `/tmp/x_ipc/<port>`.
pub(super) struct DirectListener {
    pub(super) tcp: tokio::net::TcpListener,
    pub(super) unix: Option<UnixListenerFile>,
}

/// A listening UNIX socket whose file is removed when it is dropped.
pub(super) struct UnixListenerFile {
    pub(super) listener: tokio::net::UnixListener,
    pub(super) path: std::path::PathBuf,
}

impl UnixListenerFile {
    /// Listens at `/tmp/x_ipc/<port>`. Like C (`x_ipc_listenAtSocket`) the
    /// directory is created world-writable and a leftover file is replaced;
    /// unlike C a file somebody still answers on is left alone (then only
    /// TCP is offered). `None` (with a warning) when that is not possible:
    /// peers then use TCP, as C ones do when the socket is missing.
    pub(super) fn bind(port: u16) -> Option<Self> {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::path::Path::new(UNIX_SOCKET_DIR);
        if std::fs::create_dir(dir).is_ok() {
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777));
        }
        let path = dir.join(port.to_string());
        if std::os::unix::net::UnixStream::connect(&path).is_ok() {
            tracing::warn!(
                "{} is in use by another process: direct links over TCP only",
                path.display()
            );
            return None;
        }
        let _ = std::fs::remove_file(&path); // stale, from a process that died
        match tokio::net::UnixListener::bind(&path) {
            Ok(listener) => Some(UnixListenerFile { listener, path }),
            Err(e) => {
                tracing::warn!(
                    "cannot listen at {}: {e}; direct links over TCP only",
                    path.display()
                );
                None
            }
        }
    }
}

impl Drop for UnixListenerFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Directory of C IPC's UNIX sockets (`UNIX_DIR_NAME`).
pub(super) const UNIX_SOCKET_DIR: &str = "/tmp/x_ipc";

/// Accepts direct links on both sockets until the session's driver is gone
/// (which drops the listeners and removes the UNIX socket's file).
pub(super) fn spawn_accept(l: DirectListener, tx: Mailbox<Cmd>) {
    tokio::spawn(async move {
        let DirectListener { tcp, unix } = l;
        loop {
            let accepted: Box<dyn IpcStream> = tokio::select! {
                _ = tx.closed() => break,
                r = tcp.accept() => match r {
                    Ok((s, _)) => match Tcp::new(s) {
                        Ok(s) => Box::new(s),
                        Err(_) => continue,
                    },
                    Err(_) => break,
                },
                r = async {
                    match &unix {
                        Some(u) => u.listener.accept().await,
                        None => std::future::pending().await,
                    }
                } => match r {
                    Ok((s, _)) => match Unix::new(s) {
                        Ok(s) => Box::new(s),
                        Err(_) => continue,
                    },
                    Err(_) => break,
                },
            };
            if tx.send(Cmd::LinkAccepted(accepted)).await.is_err() {
                break;
            }
        }
        drop(unix);
    });
}

/// Connects to a direct-link receiver as C's `x_ipc_connectAt` does: its
/// UNIX socket first when the host is this machine, else (or when that
/// fails) TCP.
pub(super) async fn connect_direct(host: &str, port: u16) -> Option<Box<dyn IpcStream>> {
    let local = host == "localhost" || is_local_name(host, &local_host_name());
    if local {
        if let Ok(s) = tokio::net::UnixStream::connect(format!("{UNIX_SOCKET_DIR}/{port}")).await {
            if let Ok(s) = Unix::new(s) {
                return Some(Box::new(s));
            }
        }
    }
    let host = if local { "127.0.0.1" } else { host };
    let s = tokio::net::TcpStream::connect((host, port)).await.ok()?;
    Some(Box::new(Tcp::new(s).ok()?))
}
