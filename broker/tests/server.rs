//! The embedded central and the `central` binary over real sockets on
//! 127.0.0.1 (and UNIX sockets), with Courier's IPC module state machine as
//! the client. Every wait is bounded.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use courier_broker::access::{AccessControl, Rules};
use courier_broker::{CentralServer, Config, LogTarget};
use courier_wire::ipc::module::{Connection, Event, ModuleConfig, MsgLength};

const T: Duration = Duration::from_secs(20);

/// A blocking module client on its own socket.
struct Client<S: Read + Write> {
    conn: Connection,
    sock: S,
    buf: Vec<u8>,
}

impl<S: Read + Write> Client<S> {
    fn new(sock: S, name: &str) -> Self {
        let mut c = Client {
            conn: Connection::new(ModuleConfig::new(name, "localhost"), Instant::now()),
            sock,
            buf: vec![0; 1 << 16],
        };
        c.until(|e| matches!(e, Event::Connected));
        c
    }

    fn flush(&mut self) {
        while let Some(b) = self.conn.poll_transmit() {
            self.sock.write_all(&b).unwrap();
        }
    }

    /// Runs until an event satisfies `f` (returns it).
    fn until(&mut self, mut f: impl FnMut(&Event) -> bool) -> Event {
        let deadline = Instant::now() + T;
        loop {
            assert!(Instant::now() < deadline, "timed out");
            let e = self.conn.poll_event();
            self.flush();
            if let Some(e) = e {
                if std::env::var_os("TEST_DEBUG").is_some() {
                    eprintln!("event {e:?}");
                }
                if f(&e) {
                    return e;
                }
                if let Event::Closed(err) = &e {
                    panic!("connection closed: {err:?}");
                }
                continue;
            }
            let n = self.sock.read(&mut self.buf).unwrap();
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
        }
    }

    /// Reads until no operation waits for central (e.g. a respond that
    /// first looks its reply message up).
    fn settle(&mut self) {
        self.flush();
        while self.conn.is_waiting() {
            let n = self.sock.read(&mut self.buf).unwrap();
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
            while self.conn.poll_event().is_some() {}
            self.flush();
        }
    }

    fn sync(&mut self) {
        let op = self.conn.is_module_connected("x").unwrap();
        self.until(|e| matches!(e, Event::ModuleConnected { op: o, .. } if *o == op));
    }
}

fn tcp(addr: SocketAddr) -> TcpStream {
    let s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(T)).unwrap();
    s.set_nodelay(true).unwrap();
    s
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

fn capture_logs() -> (courier_broker::LogSink, Arc<Mutex<Vec<String>>>) {
    let logs = Arc::new(Mutex::new(Vec::new()));
    let l = logs.clone();
    let sink: courier_broker::LogSink =
        Arc::new(move |_: LogTarget, line: &str| l.lock().unwrap().push(line.to_string()));
    (sink, logs)
}

#[test]
fn publish_and_query_over_tcp_then_clean_shutdown() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .log_sink(sink)
                .spawn(),
        )
        .unwrap();
    let addr = central.local_addr();
    let mut b = Client::new(tcp(addr), "b");
    b.conn
        .define_msg("m", MsgLength::Variable, Some("int"))
        .unwrap();
    b.conn
        .define_msg("q", MsgLength::Variable, Some("int"))
        .unwrap();
    b.conn
        .define_msg("r", MsgLength::Variable, Some("int"))
        .unwrap();
    b.conn.subscribe("m", "HND-m").unwrap();
    b.conn.subscribe("q", "HND-q").unwrap();
    b.sync();
    let mut a = Client::new(tcp(addr), "a");
    a.conn.publish("m", &5i32.to_le_bytes(), -1).unwrap();
    let q = a.conn.query("q", &6i32.to_le_bytes(), -1).unwrap();
    a.flush();
    let server = std::thread::spawn(move || {
        for _ in 0..2 {
            let e = b.until(|e| matches!(e, Event::Delivery { .. }));
            if let Event::Delivery {
                delivery,
                msg,
                data,
                ..
            } = e
            {
                if msg == "m" {
                    assert_eq!(data, 5i32.to_le_bytes());
                    b.conn.ack(delivery).unwrap();
                } else {
                    b.conn.respond(delivery, "r", &7i32.to_le_bytes()).unwrap();
                }
                b.settle();
            }
        }
        b
    });
    let e = a.until(|e| matches!(e, Event::Reply { .. }));
    assert!(
        matches!(e, Event::Reply { query, data, .. } if query == q && data == 7i32.to_le_bytes())
    );
    let mut b = server.join().unwrap();
    rt.block_on(async { tokio::time::timeout(T, central.shutdown()).await.unwrap() });
    // Both clients see EOF after shutdown.
    let mut one = [0u8; 1];
    assert_eq!(a.sock.read(&mut one).unwrap(), 0);
    assert_eq!(b.sock.read(&mut one).unwrap(), 0);
    assert!(logs
        .lock()
        .unwrap()
        .iter()
        .any(|l| l == " Received a new connection: 6"));
}

#[test]
fn unix_socket_is_served_and_removed() {
    let rt = rt();
    // A port of our own so /tmp/x_ipc/<port> is ours.
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .unix_socket(false)
                .spawn(),
        )
        .unwrap();
    let port = central.local_addr().port();
    rt.block_on(central.shutdown());
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(port)
                .unix_socket(true)
                .spawn(),
        )
        .unwrap();
    let path = central.unix_path().unwrap().to_path_buf();
    assert_eq!(path, std::path::PathBuf::from(format!("/tmp/x_ipc/{port}")));
    let s = std::os::unix::net::UnixStream::connect(&path).unwrap();
    s.set_read_timeout(Some(T)).unwrap();
    let mut c = Client::new(s, "unix-client");
    c.sync();
    rt.block_on(central.shutdown());
    assert!(!path.exists(), "socket file removed on shutdown");
}

#[test]
fn denied_peer_gets_nothing_allowed_peer_gets_the_handshake() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let deny = AccessControl::new(
        Rules::parse("", "hosts.allow").unwrap(),
        Rules::parse("central : 127.0.0.1\n", "hosts.deny").unwrap(),
    );
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .access(deny)
                .log_sink(sink)
                .spawn(),
        )
        .unwrap();
    let mut s = tcp(central.local_addr());
    let mut buf = [0u8; 64];
    assert_eq!(
        s.read(&mut buf).unwrap(),
        0,
        "closed before any protocol byte"
    );
    assert!(logs.lock().unwrap().iter().any(|l| l
        .starts_with("Access denied: connection from 127.0.0.1:")
        && l.ends_with("refused by hosts.deny:1")));
    rt.block_on(central.shutdown());

    let allow = AccessControl::new(
        Rules::parse("central : 127.0.0.1\n", "hosts.allow").unwrap(),
        Rules::parse("ALL : ALL\n", "hosts.deny").unwrap(),
    );
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .access(allow)
                .spawn(),
        )
        .unwrap();
    let mut s = tcp(central.local_addr());
    let mut first = [0u8; 4];
    s.read_exact(&mut first).unwrap();
    assert!(i32::from_be_bytes(first) >= 2, "the msgInfo id comes first");
    rt.block_on(central.shutdown());
}

/// A publisher floods 100 000 messages of 1 KiB at a subscriber with
/// capacity 1 that is slow to acknowledge: central stops reading the
/// publisher (TCP back-pressure) and its queues stay bounded; nothing is lost.
#[test]
fn slow_subscriber_keeps_central_memory_bounded() {
    let rt = rt();
    let mut config = Config::default();
    config.max_queued_bytes = 1 << 20;
    let central = rt
        .block_on(
            CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .config(config)
                .spawn(),
        )
        .unwrap();
    let addr = central.local_addr();
    let mut s = Client::new(tcp(addr), "slow");
    s.conn
        .define_msg("flood", MsgLength::Variable, None)
        .unwrap();
    s.conn.subscribe("flood", "HND-flood").unwrap();
    s.sync();
    const N: u32 = 100_000;
    let publisher = std::thread::spawn(move || {
        let mut p = Client::new(tcp(addr), "flood");
        let body = vec![1u8; 1024];
        for i in 0..N {
            let mut b = body.clone();
            b[..4].copy_from_slice(&i.to_le_bytes());
            p.conn.publish("flood", &b, -1).unwrap();
            if i == 0 {
                // The first publish looks the message up.
                p.until(|e| matches!(e, Event::Published { .. }));
            }
            p.flush();
        }
        p
    });
    let mut next = 0u32;
    let start = Instant::now();
    while next < N {
        let e = s.until(|e| matches!(e, Event::Delivery { .. }));
        if let Event::Delivery { delivery, data, .. } = e {
            assert_eq!(u32::from_le_bytes(data[..4].try_into().unwrap()), next);
            next += 1;
            if next % 20_000 == 0 {
                std::thread::sleep(Duration::from_millis(50));
            }
            s.conn.ack(delivery).unwrap();
            s.flush();
        }
        assert!(start.elapsed() < Duration::from_secs(120));
    }
    let _p = publisher.join().unwrap();
    let stats = central.stats();
    println!(
        "real sockets, 100 000 x 1 KiB, capacity 1: peak queued in central {} bytes (limit {})",
        stats.peak_queued_bytes,
        1 << 20
    );
    assert!(stats.peak_queued_bytes <= (1 << 20) + 64 * 1024);
    assert_eq!(stats.dropped, 0);
    rt.block_on(central.shutdown());
}

#[test]
fn central_binary_options_and_signals() {
    let bin = env!("CARGO_BIN_EXE_central");
    for (args, want) in [
        (vec!["-pabc"], "option -p: 'abc' is not a port number"),
        (vec!["-lq"], "unknown logging option 'q' in -l"),
        (vec!["-z"], "unknown option '-z'"),
        (
            vec!["--bind", "bogus"],
            "option --bind: 'bogus' is not an IP address",
        ),
    ] {
        let out = Command::new(bin).args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(want), "{args:?}: {err}");
    }
    let out = Command::new(bin)
        .arg("-v")
        .arg("-p1")
        .arg("-s")
        .arg("-u")
        .arg("--bind")
        .arg("256.0.0.1")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));

    // A free port, then the real binary on it.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut child = Command::new(bin)
        .args([
            format!("-p{port}"),
            "--bind".into(),
            "127.0.0.1".into(),
            "--no-unix-socket".into(),
            "-u".into(),
            "--hosts-allow".into(),
            "/nonexistent/allow".into(),
            "--hosts-deny".into(),
            "/nonexistent/deny".into(),
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + T;
    let sock = loop {
        match TcpStream::connect(("127.0.0.1", port)) {
            Ok(s) => break s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("central did not start: {e}"),
        }
    };
    sock.set_read_timeout(Some(T)).unwrap();
    let mut c = Client::new(sock, "cli-test");
    c.sync();
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let deadline = Instant::now() + T;
    let code = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline, "central did not stop on SIGTERM");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(code.success(), "{code:?}");
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    assert!(
        out.contains(&format!("Expecting 1 on port {port}")),
        "{out}"
    );
    assert!(out.contains(" Received a new connection: 5"), "{out}");
    assert!(out.contains("   modName : cli-test"), "{out}");
}
