//! Connecting to central: the IPC handshake, and the direct-link listener
//! when central runs with `-c`.

use super::direct::UnixListenerFile;
use super::transport::open;
use super::*;

/// A dial error that no retry can mend (see [`Dial`]).
pub(super) fn gone_for_good(opts: &IpcOptions, e: &std::io::Error) -> bool {
    opts.dial.is_some() && e.kind() == std::io::ErrorKind::NotConnected
}

/// Opens a connection to central and completes the IPC handshake (with a
/// direct-link listener when central runs with `-c`).
pub(super) async fn handshake(
    host: &str,
    port: u16,
    name: &str,
    opts: &IpcOptions,
) -> Result<(Connection, Box<dyn IpcStream>, Option<DirectListener>), ConnectError> {
    {
        let host = host.to_string();
        let addr = format!("{host}:{port}");
        let deadline = tokio::time::Instant::now() + opts.connect_timeout;
        let mut attempts = 0;
        let mut io = loop {
            attempts += 1;
            let opened = match &opts.dial {
                Some(d) => d.open().await,
                None => open(&host, port).await,
            };
            match opened {
                Ok(io) => break io,
                Err(e)
                    if gone_for_good(opts, &e)
                        || tokio::time::Instant::now() + Duration::from_millis(200) >= deadline =>
                {
                    return Err(ConnectError::Unreachable {
                        addr,
                        attempts,
                        source: e,
                    })
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        };
        let mut cfg = ModuleConfig::new(name, local_host_name());
        cfg.listen = opts.listen;
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
                        return Err(
                            e.map_or("central closed the connection".into(), |e| e.to_string())
                        )
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
                    return Err("central closed the connection".into());
                }
                conn.receive(&buf[..n], Instant::now());
            }
        };
        let res: Result<(), String> = match tokio::time::timeout_at(deadline, hs).await {
            Ok(r) => r,
            Err(_) => Err("no answer within the connect timeout".into()),
        };
        res.map_err(|why| ConnectError::Handshake {
            addr: addr.clone(),
            why,
        })?;
        Ok((conn, io, listener))
    }
}
