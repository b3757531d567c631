//! The embedded central over real sockets on 127.0.0.1 and UNIX sockets,
//! with Courier's IPC module state machine (or raw sockets) as clients.
//! Every wait is bounded: async waits by `tokio::time::timeout`, blocking
//! socket reads by read timeouts.

use std::future::Future;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use courier_broker::access::{AccessControl, Rules};
use courier_broker::{BindError, CentralHandle, CentralServer, Config, LogSink};
use courier_wire::ipc::module::{Event, MsgLength};

mod common;
use common::{read_to_eof, tcp, Client, T};

/// Runs `f` on `rt`, failing the test if it takes longer than [`T`].
fn block<F: Future>(rt: &tokio::runtime::Runtime, f: F) -> F::Output {
    rt.block_on(async { tokio::time::timeout(T, f).await.expect("timed out") })
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

type Logs = Arc<Mutex<Vec<String>>>;

fn capture_logs() -> (LogSink, Logs) {
    let logs = Arc::new(Mutex::new(Vec::new()));
    let l = logs.clone();
    let sink = LogSink::new(move |_, line| l.lock().unwrap().push(line.to_string()));
    (sink, logs)
}

/// Waits until a log line satisfies `f`.
fn wait_log(logs: &Logs, f: impl Fn(&str) -> bool) -> String {
    let deadline = Instant::now() + T;
    loop {
        if let Some(l) = logs.lock().unwrap().iter().find(|l| f(l)) {
            return l.clone();
        }
        assert!(
            Instant::now() < deadline,
            "no such log line in {:?}",
            logs.lock().unwrap()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn local() -> courier_broker::Builder {
    CentralServer::builder()
        .bind("127.0.0.1".parse().unwrap())
        .port(0)
}

fn start(rt: &tokio::runtime::Runtime, b: courier_broker::Builder) -> CentralHandle {
    block(rt, b.spawn()).unwrap()
}

#[test]
fn publish_and_query_over_tcp_then_shutdown_closes_clients() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let central = start(&rt, local().log_sink(sink));
    let addr = central.local_addr();
    assert_eq!(addr.ip().to_string(), "127.0.0.1");
    assert_ne!(addr.port(), 0);
    let mut b = Client::new(tcp(addr), "b");
    for m in ["m", "q", "r"] {
        b.conn
            .define_msg(m, MsgLength::Variable, Some("int"))
            .unwrap();
    }
    b.conn.subscribe("m", "HND-m").unwrap();
    b.conn.subscribe("q", "HND-q").unwrap();
    b.sync();
    let mut a = Client::new(tcp(addr), "a");
    a.conn.publish("m", 5i32.to_le_bytes(), -1).unwrap();
    let q = a.conn.query("q", 6i32.to_le_bytes(), -1).unwrap();
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
                    b.conn.respond(delivery, "r", 7i32.to_le_bytes()).unwrap();
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
    let stats = block(&rt, central.stats()).unwrap();
    assert_eq!(stats.modules, 2);
    block(&rt, central.shutdown());
    // Both clients see EOF after shutdown.
    assert!(read_to_eof(&mut a.sock).is_empty());
    assert!(read_to_eof(&mut b.sock).is_empty());
    let logs = logs.lock().unwrap();
    assert!(
        logs.iter().any(|l| l == " Received a new connection: 5"),
        "{logs:?}"
    );
    assert!(logs.iter().any(|l| l == "   modName : a"), "{logs:?}");
}

/// Start and stop leave no task behind (counted by the runtime) and no
/// socket file.
#[test]
fn start_and_shutdown_leave_no_task_and_no_socket_file() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    assert_eq!(rt.metrics().num_alive_tasks(), 0);
    let central = start(&rt, local().unix_socket(true).log_sink(LogSink::discard()));
    let path = central.unix_path().unwrap().to_path_buf();
    assert_eq!(
        path,
        PathBuf::from(format!("/tmp/x_ipc/{}", central.local_addr().port()))
    );
    assert!(path.exists());
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata("/tmp/x_ipc")
        .unwrap()
        .permissions()
        .mode();
    assert_eq!(mode & 0o777, 0o777, "/tmp/x_ipc is shared by every user");
    // Connections over both transports, with bytes written to each.
    let mut t = tcp(central.local_addr());
    let mut u = UnixStream::connect(&path).unwrap();
    u.set_read_timeout(Some(T)).unwrap();
    let mut first = [0u8; 4];
    // The runtime runs only inside block_on: drive it while reading.
    let reader = std::thread::spawn(move || {
        t.read_exact(&mut first).unwrap();
        u.read_exact(&mut first).unwrap();
        (t, u)
    });
    block(&rt, async {
        while !reader.is_finished() {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    });
    let (mut t, mut u) = reader.join().unwrap();
    // Two accept loops and the task that runs central and reads every
    // connection (a connection has a writer task only while its socket
    // would not take what central has for it).
    assert!(rt.metrics().num_alive_tasks() >= 3);
    block(&rt, central.shutdown());
    assert_eq!(rt.metrics().num_alive_tasks(), 0, "every task ended");
    assert!(!path.exists(), "socket file removed on shutdown");
    assert!(read_to_eof(&mut t).len() < 4096);
    assert!(read_to_eof(&mut u).len() < 4096);
}

#[test]
fn dropping_the_handle_stops_central() {
    let rt = rt();
    let central = start(&rt, local().unix_socket(true).log_sink(LogSink::discard()));
    let addr = central.local_addr();
    let path = central.unix_path().unwrap().to_path_buf();
    let mut c = Client::new(tcp(addr), "dropped");
    c.sync();
    drop(central);
    assert!(!path.exists(), "socket file removed at once");
    read_to_eof(&mut c.sock);
    // The listener is gone too.
    let deadline = Instant::now() + T;
    while TcpStream::connect(addr).is_ok() {
        assert!(Instant::now() < deadline, "still accepting");
        std::thread::sleep(Duration::from_millis(10));
    }
    let deadline = Instant::now() + T;
    while rt.metrics().num_alive_tasks() > 0 {
        assert!(Instant::now() < deadline, "tasks left after drop");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn unix_socket_serves_modules_and_replaces_a_stale_file() {
    let rt = rt();
    // A free port whose socket path we then litter with a dead socket.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let path = courier_broker::unix_path(port);
    std::fs::create_dir_all("/tmp/x_ipc").unwrap();
    let _ = std::fs::remove_file(&path);
    drop(std::os::unix::net::UnixListener::bind(&path).unwrap());
    assert!(path.exists(), "stale socket file in place");
    let central = start(
        &rt,
        local()
            .port(port)
            .unix_socket(true)
            .log_sink(LogSink::discard()),
    );
    assert_eq!(central.unix_path(), Some(path.as_path()));
    // A second server on the same path is refused: someone answers there.
    let second = block(
        &rt,
        CentralServer::builder()
            .bind("127.0.0.2".parse().unwrap())
            .port(port)
            .unix_socket(true)
            .spawn(),
    );
    match second {
        Err(BindError::Unix { path: p, .. }) => assert_eq!(p, path),
        // 127.0.0.2 may not be configured; then TCP fails first.
        Err(BindError::Tcp { .. }) => {}
        other => panic!("second server started: {other:?}"),
    }
    let s = UnixStream::connect(&path).unwrap();
    s.set_read_timeout(Some(T)).unwrap();
    let mut c = Client::new(s, "unix-client");
    c.sync();
    block(&rt, central.shutdown());
    assert!(!path.exists(), "socket file removed on shutdown");
    read_to_eof(&mut c.sock);
}

#[test]
fn denied_peer_gets_eof_before_any_byte_allowed_peer_is_served() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let deny = AccessControl::new(
        Rules::parse("", "hosts.allow").unwrap(),
        Rules::parse("# nobody from here\ncentral : 127.0.0.1\n", "hosts.deny").unwrap(),
    );
    let central = start(&rt, local().access(deny).log_sink(sink));
    let mut s = tcp(central.local_addr());
    let port = s.local_addr().unwrap().port();
    assert_eq!(read_to_eof(&mut s), b"", "closed before any protocol byte");
    let line = wait_log(&logs, |l| l.contains("rejected"));
    assert_eq!(
        line,
        format!("WARNING: connection rejected from 127.0.0.1:{port} (denied by hosts.deny:2)")
    );
    block(&rt, central.shutdown());

    let allow = AccessControl::new(
        Rules::parse("central : 127.0.0.1\n", "hosts.allow").unwrap(),
        Rules::parse("ALL : ALL\n", "hosts.deny").unwrap(),
    );
    let central = start(&rt, local().access(allow).log_sink(LogSink::discard()));
    let mut s = tcp(central.local_addr());
    let mut first = [0u8; 4];
    s.read_exact(&mut first).unwrap();
    assert!(i32::from_be_bytes(first) >= 2, "the msgInfo id comes first");
    // And the connection stays open: a whole module handshake works on it.
    let mut c = Client::new(tcp(central.local_addr()), "allowed");
    c.sync();
    block(&rt, central.shutdown());
}

#[test]
fn unix_socket_peers_are_checked_as_local() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let deny = AccessControl::new(
        Rules::default(),
        Rules::parse("central : localhost\n", "hosts.deny").unwrap(),
    );
    let central = start(&rt, local().unix_socket(true).access(deny).log_sink(sink));
    let mut u = UnixStream::connect(central.unix_path().unwrap()).unwrap();
    u.set_read_timeout(Some(T)).unwrap();
    assert_eq!(read_to_eof(&mut u), b"");
    wait_log(&logs, |l| {
        l == "WARNING: connection rejected from the UNIX socket (denied by hosts.deny:1)"
    });
    block(&rt, central.shutdown());
}

/// Garbage on one connection closes that connection only, with a log line;
/// a module that disconnects in the middle of a frame is cleaned up.
#[test]
fn hostile_input_closes_only_the_offender() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let central = start(&rt, local().log_sink(sink));
    let addr = central.local_addr();
    let mut good = Client::new(tcp(addr), "good");
    good.sync();

    // A header claiming a 2 GiB body.
    let mut bad = tcp(addr);
    let mut hdr = [0u8; 28];
    hdr[0..4].copy_from_slice(&i32::MAX.to_be_bytes());
    hdr[4..8].copy_from_slice(&i32::MAX.to_be_bytes());
    bad.write_all(&hdr).unwrap();
    read_to_eof(&mut bad);
    wait_log(&logs, |l| l.starts_with("ERROR: closing connection"));

    // Half a frame, then gone.
    let mut half = tcp(addr);
    half.write_all(&[0, 0, 0, 0, 0, 0, 0, 4, 0xff]).unwrap();
    drop(half);
    wait_log(&logs, |l| l.contains("in the middle of a frame"));

    // Random bytes.
    let mut noise = tcp(addr);
    let junk: Vec<u8> = (0..10_000u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    let _ = noise.write_all(&junk);
    drop(noise);

    good.sync();
    let deadline = Instant::now() + T;
    while block(&rt, central.stats()).unwrap().modules != 1 {
        assert!(Instant::now() < deadline, "only the good module is left");
        std::thread::sleep(Duration::from_millis(10));
    }
    good.sync();
    block(&rt, central.shutdown());
}

/// Connections that never say their module name are closed after the
/// handshake timeout (C's central kept them for ever: enough of them used
/// up its file descriptors and locked modules out); a module that named
/// itself is left alone however quiet it is.
#[test]
fn silent_connections_are_closed_after_the_handshake_timeout() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let mut config = Config::default();
    config.handshake_timeout = Some(Duration::from_secs(1));
    let central = start(&rt, local().config(config).log_sink(sink));
    let addr = central.local_addr();
    let mut good = Client::new(tcp(addr), "good");
    good.sync();
    let started = Instant::now();
    let mut silent: Vec<TcpStream> = (0..3).map(|_| tcp(addr)).collect();
    for s in &mut silent {
        // Central's greeting, then EOF: central closed it.
        assert!(!read_to_eof(s).is_empty());
    }
    assert!(started.elapsed() >= Duration::from_secs(1));
    let line = wait_log(&logs, |l| l.contains("did not say its module name"));
    assert!(
        line.starts_with("WARNING: closing connection ") && line.ends_with("within 1 s"),
        "{line}"
    );
    // Quiet for longer than the timeout, the named module is still served.
    std::thread::sleep(Duration::from_millis(1200));
    good.sync();
    assert_eq!(block(&rt, central.stats()).unwrap().modules, 1);
    block(&rt, central.shutdown());
}

/// Many modules connecting at once all get central's greeting.
#[test]
fn two_hundred_connections_at_once() {
    let rt = rt();
    let central = start(&rt, local().log_sink(LogSink::discard()));
    let addr = central.local_addr();
    let socks: Vec<TcpStream> = (0..200).map(|_| tcp(addr)).collect();
    for mut s in socks {
        let mut first = [0u8; 4];
        s.read_exact(&mut first).unwrap();
        assert!(i32::from_be_bytes(first) >= 2);
    }
    block(&rt, central.shutdown());
}

#[test]
fn console_commands_reach_the_state_machine() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let central = start(&rt, local().log_sink(sink));
    let mut c = Client::new(tcp(central.local_addr()), "console-test");
    c.sync();
    assert!(central.command("help"));
    wait_log(&logs, |l| l.contains("close <module>"));
    assert!(central.command("close console-test"));
    read_to_eof(&mut c.sock);
    let deadline = Instant::now() + T;
    while block(&rt, central.stats()).unwrap().modules > 0 {
        assert!(Instant::now() < deadline);
        std::thread::sleep(Duration::from_millis(10));
    }
    block(&rt, central.shutdown());
}

/// A publisher floods 100 000 messages of 1 KiB at a subscriber with
/// capacity 1 that is slow to acknowledge: central stops reading the
/// publisher (TCP back-pressure) and its queues stay bounded; nothing is lost.
#[test]
fn slow_subscriber_keeps_central_memory_bounded() {
    flood_a_slow_subscriber(0, 100_000, Inside::Nothing);
}

/// The same with broadcasts sent ahead of their turn
/// (`Config::send_ahead`): everything arrives once, in order, within the
/// same memory bound.
#[test]
fn messages_sent_ahead_arrive_once_in_order_over_tcp() {
    flood_a_slow_subscriber(8, 30_000, Inside::Nothing);
}

/// The publisher floods from inside its handler of a broadcast (a
/// pipeline stage), so it is handling a delivery all along: central holds
/// it back all the same.
#[test]
fn a_publisher_flooding_from_its_handler_keeps_central_memory_bounded() {
    flood_a_slow_subscriber(0, 30_000, Inside::Broadcast);
}

/// The publisher floods while it answers a query from a third module,
/// which waits for the reply all along: central holds it back too.
#[test]
fn a_publisher_flooding_while_it_answers_a_query_keeps_central_memory_bounded() {
    flood_a_slow_subscriber(0, 30_000, Inside::Query);
}

/// Where the flooding publisher is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Inside {
    /// Its main loop.
    Nothing,
    /// Its handler of a broadcast.
    Broadcast,
    /// Its handler of a query, whose asker waits for the reply.
    Query,
}

fn flood_a_slow_subscriber(send_ahead: usize, n: u32, inside: Inside) {
    let in_handler = inside != Inside::Nothing;
    let rt = rt();
    let mut config = Config::default();
    config.max_queued_bytes = 1 << 20;
    if send_ahead > 0 {
        config.send_ahead = [("slow".to_string(), send_ahead)].into();
    }
    let central = start(&rt, local().config(config).log_sink(LogSink::discard()));
    let addr = central.local_addr();
    let mut s = Client::new(tcp(addr), "slow");
    s.conn
        .define_msg("flood", MsgLength::Variable, None)
        .unwrap();
    s.conn.subscribe("flood", "HND-flood").unwrap();
    s.sync();
    let (ready, is_ready) = std::sync::mpsc::channel();
    let publisher = std::thread::spawn(move || {
        let mut p = Client::new(tcp(addr), "flood");
        // In a handler: the delivery of "go" it acknowledges at the end.
        let mut go = None;
        if in_handler {
            p.conn.subscribe("go", "HND-go").unwrap();
            p.sync();
            ready.send(()).unwrap();
            if let Event::Delivery { delivery, .. } =
                p.until(|e| matches!(e, Event::Delivery { .. }))
            {
                go = Some(delivery);
            }
        }
        let body = vec![1u8; 1024];
        for i in 0..n {
            let mut b = body.clone();
            b[..4].copy_from_slice(&i.to_le_bytes());
            p.conn.publish("flood", b.clone(), -1).unwrap();
            if i == 0 {
                // The first publish looks the message up.
                p.until(|e| matches!(e, Event::Published { .. }));
            }
            p.flush();
        }
        if let Some(go) = go {
            if inside == Inside::Query {
                p.conn.respond(go, "went", vec![2u8; 4]).unwrap();
                // The reply's message is looked up first.
                p.settle();
            } else {
                p.conn.ack(go).unwrap();
            }
            p.flush();
        }
        p
    });
    let mut asker = None;
    if in_handler {
        is_ready.recv().unwrap();
        if inside == Inside::Query {
            // It waits for the reply as long as the flood takes.
            asker = Some(std::thread::spawn(move || {
                let mut a = Client::new(tcp(addr), "asker");
                a.conn.define_msg("go", MsgLength::Variable, None).unwrap();
                a.conn
                    .define_msg("went", MsgLength::Variable, None)
                    .unwrap();
                let q = a.conn.query("go", vec![1u8; 4], -1).unwrap();
                let mut buf = vec![0u8; 4096];
                let start = Instant::now();
                loop {
                    a.flush();
                    while let Some(e) = a.conn.poll_event() {
                        if matches!(e, Event::Reply { query, .. } if query == q) {
                            return;
                        }
                    }
                    assert!(start.elapsed() < Duration::from_secs(120), "no reply");
                    match a.sock.read(&mut buf) {
                        Ok(0) => panic!("central closed the connection"),
                        Ok(k) => a.conn.receive(&buf[..k], Instant::now()),
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                        Err(e) => panic!("{e}"),
                    }
                }
            }));
        } else {
            s.conn.define_msg("go", MsgLength::Variable, None).unwrap();
            // The publisher's subscription reaches this module as an update
            // of central's broadcast list, which may still be on its way: a
            // broadcast with no handler in that list is dropped unsent (as
            // the C library does). Counting the handlers settles it.
            let op = s.conn.num_handlers("go").unwrap();
            let counted = s.until(|e| matches!(e, Event::NumHandlers { op: o, .. } if *o == op));
            assert!(
                matches!(counted, Event::NumHandlers { count: 1, .. }),
                "{counted:?}"
            );
            s.conn.publish("go", vec![1u8; 4], -1).unwrap();
            s.flush();
        }
    }
    let mut next = 0u32;
    let start = Instant::now();
    while next < n {
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
    if let Some(a) = asker {
        a.join().unwrap();
    }
    // The last acknowledgement is on its way: every dispatch is finished
    // once central has read it.
    let deadline = Instant::now() + T;
    let stats = loop {
        let stats = block(&rt, central.stats()).unwrap();
        if stats.dispatches == 0 || Instant::now() > deadline {
            break stats;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    println!(
        "real sockets, {n} x 1 KiB, capacity 1, send-ahead {send_ahead}, \
         from inside {inside:?}: peak queued in central {} bytes (limit {})",
        stats.peak_queued_bytes,
        1 << 20
    );
    assert!(stats.peak_queued_bytes <= (1 << 20) + 128 * 1024);
    assert_eq!(stats.dropped, 0);
    assert_eq!(stats.dispatches, 0);
    assert_eq!(stats.queued_bytes, 0);
    block(&rt, central.shutdown());
}

/// Rules that need the peer's host name are decided off the accept path
/// (loopback peers are `localhost` without asking DNS).
#[test]
fn host_name_rules_are_checked_too() {
    let rt = rt();
    let (sink, logs) = capture_logs();
    let deny = AccessControl::new(
        Rules::default(),
        Rules::parse("central : KNOWN\n", "hosts.deny").unwrap(),
    );
    assert!(deny.needs_host_name());
    let central = start(&rt, local().access(deny).log_sink(sink));
    let mut s = tcp(central.local_addr());
    assert_eq!(read_to_eof(&mut s), b"");
    wait_log(&logs, |l| l.ends_with("(denied by hosts.deny:1)"));
    block(&rt, central.shutdown());
}

/// Large queries and replies through a central that forwards them while
/// they arrive (`Config::cut_through`), over real sockets: every byte
/// arrives, in order, several rounds in a row.
#[test]
fn cut_through_relays_large_queries_and_replies_over_tcp() {
    large_queries_and_replies_over_tcp(Some(64 << 10));
}

/// Store-and-forward writes a large message's header and then its data
/// from the buffer it was received into (`Output::TransmitBody`), across
/// as many partial writes as the socket needs.
#[test]
fn large_queries_and_replies_pass_whole_over_tcp_without_cut_through() {
    large_queries_and_replies_over_tcp(None);
}

fn large_queries_and_replies_over_tcp(cut_through: Option<usize>) {
    let rt = rt();
    let mut config = Config::default();
    config.cut_through = cut_through;
    let central = start(&rt, local().config(config).log_sink(LogSink::discard()));
    let addr = central.local_addr();
    let blob = |n: usize, seed: u8| -> Vec<u8> {
        let mut v = (n as i32).to_le_bytes().to_vec();
        v.extend((0..n).map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed)));
        v
    };
    let mut b = Client::new(tcp(addr), "answerer");
    for m in ["ask", "answer"] {
        b.conn
            .define_msg(m, MsgLength::Variable, Some("{int, <ubyte:1>}"))
            .unwrap();
    }
    b.conn.subscribe("ask", "HND-ask").unwrap();
    b.sync();
    const ROUNDS: u8 = 4;
    let server = std::thread::spawn(move || {
        for r in 0..ROUNDS {
            let e = b.until(|e| matches!(e, Event::Delivery { .. }));
            let Event::Delivery { delivery, data, .. } = e else {
                unreachable!()
            };
            assert_eq!(data, blob(1 << 20, r), "query {r}");
            b.conn
                .respond(delivery, "answer", blob(2 << 20, 100 + r))
                .unwrap();
            b.settle();
        }
        b
    });
    let mut a = Client::new(tcp(addr), "asker");
    for r in 0..ROUNDS {
        let q = a.conn.query("ask", blob(1 << 20, r), -1).unwrap();
        a.flush();
        let e = a.until(|e| matches!(e, Event::Reply { .. }));
        let Event::Reply { query, data, .. } = e else {
            unreachable!()
        };
        assert_eq!(query, q);
        assert!(data.ends_with(&blob(2 << 20, 100 + r)[4..]), "reply {r}");
    }
    let _b = server.join().unwrap();
    let stats = block(&rt, central.stats()).unwrap();
    assert_eq!(stats.dispatches, 0);
    block(&rt, central.shutdown());
}
