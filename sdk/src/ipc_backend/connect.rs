//! Connecting to central: the IPC handshake, and the direct-link listener
//! when central runs with `-c`.

use super::direct::UnixListenerFile;
use super::transport::{is_unresolved, open};
use super::*;

/// A dial error that no retry can mend (see [`Dial`]).
pub(super) fn gone_for_good(opts: &IpcOptions, e: &std::io::Error) -> bool {
    opts.dial.is_some() && e.kind() == std::io::ErrorKind::NotConnected
}

/// Opens a connection to central and completes the IPC handshake (with a
/// direct-link listener when central runs with `-c`), both within the
/// connect timeout.
pub(super) async fn handshake(
    host: &str,
    port: u16,
    name: &str,
    opts: &IpcOptions,
) -> Result<(Connection, Box<dyn IpcStream>, Option<DirectListener>), ConnectError> {
    let deadline = crate::deadline::after(opts.connect_timeout);
    let io = dial(host, port, opts, deadline).await?;
    greet(io, host, port, name, opts, deadline).await
}

/// Opens a stream to central, retrying a refused connection every 200 ms
/// until `deadline`.
pub(super) async fn dial(
    host: &str,
    port: u16,
    opts: &IpcOptions,
    deadline: tokio::time::Instant,
) -> Result<Box<dyn IpcStream>, ConnectError> {
    let mut attempts = 0;
    loop {
        attempts += 1;
        let opened = match &opts.dial {
            Some(d) => d.open().await,
            None => open(host, port).await,
        };
        match opened {
            Ok(io) => return Ok(io),
            // a host name that does not resolve will not while we wait:
            // say so now (a reconnect, which waits for the network to come
            // back, still retries it)
            Err(e)
                if gone_for_good(opts, &e)
                    || is_unresolved(&e)
                    || tokio::time::Instant::now() + Duration::from_millis(200) >= deadline =>
            {
                return Err(ConnectError::Unreachable {
                    addr: super::host_port(host, port),
                    attempts,
                    source: e,
                })
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
        }
    }
}

/// The IPC handshake over `io`, a stream [`dial`] opened, within
/// `deadline` (with a direct-link listener when central runs with `-c`).
pub(super) async fn greet(
    mut io: Box<dyn IpcStream>,
    host: &str,
    port: u16,
    name: &str,
    opts: &IpcOptions,
    deadline: tokio::time::Instant,
) -> Result<(Connection, Box<dyn IpcStream>, Option<DirectListener>), ConnectError> {
    let addr = super::host_port(host, port);
    let mut cfg = ModuleConfig::new(name, local_host_name());
    cfg.listen = opts.listen;
    cfg.max_frame = opts.max_frame;
    let mut conn = Connection::new(cfg, Instant::now());
    let mut buf = vec![0u8; 64 * 1024];
    let mut listener: Option<DirectListener> = None;
    let hs = async {
        loop {
            while let Some(b) = conn.poll_transmit() {
                io.write_all(&b).await.map_err(|e| e.to_string())?;
            }
            match conn.poll_event() {
                Some(Event::Connected) => return Ok(()),
                Some(Event::Closed(e)) => {
                    return Err(e.map_or_else(|| closed_during_handshake(name), |e| e.to_string()))
                }
                Some(Event::DirectListenRequested) => {
                    // Like C: the first free port from 8000 (to 9000).
                    let ip = if host == "localhost" || host.starts_with("127.") {
                        "127.0.0.1"
                    } else {
                        "0.0.0.0"
                    };
                    let mut bound = None;
                    for p in 8000..9000u16 {
                        if let Ok(l) = tokio::net::TcpListener::bind((ip, p)).await {
                            bound = Some((l, p));
                            break;
                        }
                    }
                    let (l, p) = bound.ok_or("no free port in 8000..9000 for direct links")?;
                    conn.announce_direct_port(i32::from(p));
                    listener = Some(DirectListener {
                        tcp: l,
                        unix: UnixListenerFile::bind(p),
                    });
                    continue;
                }
                Some(_) => continue,
                None => {}
            }
            while let Some(b) = conn.poll_transmit() {
                io.write_all(&b).await.map_err(|e| e.to_string())?;
            }
            let n = io.read(&mut buf).await.map_err(|e| e.to_string())?;
            if n == 0 {
                return Err(closed_during_handshake(name));
            }
            conn.receive(&buf[..n], Instant::now());
        }
    };
    let res: Result<(), String> = match tokio::time::timeout_at(deadline, hs).await {
        Ok(r) => r,
        Err(_) => Err("no answer within the connect timeout".into()),
    };
    res.map_err(|why| ConnectError::Handshake { addr, why })?;
    Ok((conn, io, listener))
}

/// Why central may have closed a connection before the handshake ended.
/// The module cannot tell which of the two it was: central closes the
/// connection without a word in both cases.
fn closed_during_handshake(name: &str) -> String {
    format!(
        "central closed the connection before the handshake ended: either its access rules \
         (--hosts-allow/--hosts-deny; central logs which rule) refuse this host, or a module \
         named {name:?} is already connected (Courier's central refuses a second module of \
         the same name)"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A host name that glibc refuses without asking a name server (a
    /// label longer than 63 bytes cannot be put in a DNS query), so the
    /// test sends nothing off this machine.
    fn unresolvable() -> String {
        "a".repeat(64)
    }

    #[tokio::test]
    async fn a_host_that_does_not_resolve_is_not_retried() {
        let opts = IpcOptions {
            connect_timeout: Duration::from_secs(5),
            ..IpcOptions::default()
        };
        let started = std::time::Instant::now();
        let Err(e) = handshake(&unresolvable(), 1381, "m", &opts).await else {
            panic!("connected to an unresolvable host")
        };
        let ConnectError::Unreachable {
            attempts, source, ..
        } = &e
        else {
            panic!("{e:?}")
        };
        assert_eq!(*attempts, 1, "{e}");
        assert!(is_unresolved(source), "{source:?}");
        assert!(source.to_string().contains("cannot resolve"), "{source}");
        assert!(
            started.elapsed() < Duration::from_secs(2),
            "{:?}",
            started.elapsed()
        );
    }

    /// Central closing the connection without a word is told with both
    /// reasons it has for doing so.
    #[tokio::test]
    async fn a_connection_closed_before_the_handshake_names_both_causes() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = l.local_addr().unwrap().port();
        // Accepts and closes at once, as central does for a refused host.
        let closer = tokio::spawn(async move {
            let (s, _) = l.accept().await.unwrap();
            drop(s);
        });
        let opts = IpcOptions {
            connect_timeout: Duration::from_secs(20),
            ..IpcOptions::default()
        };
        let Err(e) = handshake("127.0.0.1", port, "robot-7", &opts).await else {
            panic!("a handshake with a closed connection succeeded")
        };
        closer.await.unwrap();
        let ConnectError::Handshake { why, .. } = &e else {
            panic!("{e:?}")
        };
        assert_eq!(*why, closed_during_handshake("robot-7"));
        for part in [
            "access rules",
            "--hosts-allow/--hosts-deny",
            "a module named \"robot-7\" is already connected",
        ] {
            assert!(e.to_string().contains(part), "{part}: {e}");
        }
    }

    #[tokio::test]
    async fn a_refused_connection_is_retried_until_the_timeout() {
        // a port nobody listens on: bind one, note it, close it
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        drop(l);
        let opts = IpcOptions {
            connect_timeout: Duration::from_millis(700),
            ..IpcOptions::default()
        };
        let Err(ConnectError::Unreachable {
            attempts, source, ..
        }) = handshake("127.0.0.1", port, "m", &opts).await
        else {
            panic!("expected Unreachable")
        };
        assert!(attempts > 1, "{attempts}");
        assert!(!is_unresolved(&source), "{source:?}");
    }
}
