//! The `xrce-agent` library and binary on loopback: Courier's XRCE client
//! machine over UDP, TCP and a pseudo-terminal ⇄ the agent ⇄ Cyclone DDS
//! 0.10 (Debian's, through `courier_tests::peers`, pinned to `lo` with
//! unicast discovery) in both directions; two XRCE clients of one agent;
//! the command line's errors, word for word.
//!
//! Every DDS participant (the agent's, Cyclone's) is on `lo`, unicast to
//! 127.0.0.1, multicast off, in a domain leased machine-wide
//! (`courier_tests::domains`). Every XRCE socket binds 127.0.0.1 port 0.

use std::net::SocketAddr;
use std::process::Command;
use std::time::Instant;

use courier_broker::xrce_agent::{Transport, XrceAgent};
use courier_tests::peers::{cyclone_peer, payload, PeerProcess};
use courier_wire::xrce::{DeliveryControl, Event, ObjectKind};

mod xrce_client;
use xrce_client::{msg, oid, reader, rtps, runtime, unmsg, writer, XClient, R, T};

fn agent(rt: &tokio::runtime::Runtime, domain: u32, transports: Vec<Transport>) -> XrceAgent {
    let mut b = XrceAgent::builder().rtps(rtps(domain));
    for t in transports {
        b = b.transport(t);
    }
    rt.block_on(b.spawn()).unwrap()
}

fn cyclone(args: &[&str]) -> PeerProcess {
    let exe = cyclone_peer().unwrap_or_else(|e| panic!("cannot build the Cyclone DDS peer: {e}"));
    PeerProcess::spawn(exe, args).unwrap_or_else(|e| panic!("{e}"))
}

/// The agent's DDS participant on `lo` only, unicast to 127.0.0.1.
const LOOPBACK: [&str; 6] = [
    "--interface",
    "lo",
    "--peers",
    "127.0.0.1",
    "--multicast",
    "off",
];

fn local(port: u16) -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], port))
}

#[test]
fn xrce_client_over_udp_writes_to_cyclone() {
    let d = courier_tests::domains::lease(1);
    let rt = runtime();
    let a = agent(&rt, d, vec![Transport::Udp(local(0))]);
    let ds = d.to_string();
    let mut sub = cyclone(&[
        "--domain",
        &ds,
        "--topic",
        "xrce_up",
        "--type",
        "msg",
        "--sub",
        "--reliable",
        "--transient-local",
        "--keep-all",
        "--count",
        "5",
        "--timeout-s",
        "60",
    ]);
    sub.expect_line("ready", T).unwrap();
    let mut c = XClient::udp(0x1111_0001, a.udp_addrs()[0]);
    c.create(writer(d, "xrce_up"));
    sub.expect_line("matched 1", T).unwrap();
    for seq in 1..=5u32 {
        let body = msg(seq, "xrce", &payload(seq, 40));
        c.c.write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
            .unwrap();
    }
    // every write acknowledged: DDS has taken them all
    assert!(c.until(T, |e| e
        .iter()
        .filter(|e| matches!(e, Event::WriteAcked(_)))
        .count()
        == 5));
    for seq in 1..=5u32 {
        let line = sub.expect_line("sample", T).unwrap();
        assert_eq!(
            line,
            courier_tests::peers::msg_sample_line(seq, "xrce", 40),
            "{}",
            sub.stderr()
        );
    }
    sub.expect_line("done", T).unwrap();
    rt.block_on(a.shutdown());
}

#[test]
fn cyclone_writes_to_an_xrce_client_over_tcp() {
    let d = courier_tests::domains::lease(2);
    let rt = runtime();
    let a = agent(&rt, d, vec![Transport::Tcp(local(0))]);
    let mut c = XClient::tcp(0x1111_0002, a.tcp_addrs()[0]);
    c.create(reader(d, "xrce_down"));
    let unlimited = Some(DeliveryControl {
        max_samples: u16::MAX,
        ..DeliveryControl::default()
    });
    c.c.read(oid(ObjectKind::DataReader), R, R, unlimited, Instant::now())
        .unwrap();
    let ds = d.to_string();
    let mut publ = cyclone(&[
        "--domain",
        &ds,
        "--topic",
        "xrce_down",
        "--type",
        "msg",
        "--pub",
        "--reliable",
        "--count",
        "5",
        "--size",
        "1500",
        "--wait-match",
        "1",
        "--text",
        "cyc",
        "--linger-ms",
        "3000",
        "--timeout-s",
        "60",
    ]);
    assert!(c.until(T, |e| e
        .iter()
        .filter(|e| matches!(e, Event::Data { .. }))
        .count()
        >= 5));
    let got: Vec<(u32, String, Vec<u8>)> = c.data().iter().map(|b| unmsg(b)).collect();
    for (i, (seq, text, p)) in got.iter().enumerate() {
        let want = i as u32 + 1;
        assert_eq!(*seq, want);
        assert!(text.starts_with("cyc"), "{text}");
        assert_eq!(*p, payload(want, 1500));
    }
    publ.kill();
    rt.block_on(a.shutdown());
}

/// A TCP connection that says nothing is closed after the hello timeout
/// (audit 20: 1100 silent connections were held for ever and took every
/// descriptor); one whose first XRCE message comes in time stays.
#[test]
fn a_silent_tcp_connection_is_closed_and_a_client_is_not() {
    use std::io::{Read, Write};
    let rt = runtime();
    let d = courier_tests::domains::lease(12);
    let a = rt
        .block_on(
            XrceAgent::builder()
                .rtps(rtps(d))
                .transport(Transport::Tcp(local(0)))
                .tcp_hello_timeout(std::time::Duration::from_millis(300))
                .spawn(),
        )
        .unwrap();
    let addr = a.tcp_addrs()[0];
    let mut silent = std::net::TcpStream::connect(addr).unwrap();
    silent.set_read_timeout(Some(T)).unwrap();
    // a client: a GET_INFO of the agent (eProsima's ping) in a TCP frame
    let mut talker = std::net::TcpStream::connect(addr).unwrap();
    talker.set_read_timeout(Some(T)).unwrap();
    let ping = courier_wire::xrce::discovery::request_bytes();
    let mut framed = (ping.len() as u16).to_le_bytes().to_vec();
    framed.extend_from_slice(&ping);
    talker.write_all(&framed).unwrap();
    let mut b = [0u8; 64];
    // bounded by the read timeout: a connection kept open fails the unwrap
    assert_eq!(silent.read(&mut b).unwrap(), 0, "the silent one was closed");
    // the talker is still served: another ping after the silent one went
    std::thread::sleep(std::time::Duration::from_millis(400));
    talker.write_all(&framed).unwrap();
    talker
        .set_read_timeout(Some(std::time::Duration::from_millis(200)))
        .unwrap();
    let mut open = true;
    let mut got = 0;
    while let Ok(n) = talker.read(&mut b) {
        if n == 0 {
            open = false;
            break;
        }
        got += n;
    }
    assert!(open, "the client's connection stays open");
    assert!(got > 0, "the client's pings were answered");
    rt.block_on(a.shutdown());
}

#[test]
fn two_xrce_clients_through_a_pseudoterminal_and_udp() {
    let d = courier_tests::domains::lease(3);
    let rt = runtime();
    let a = agent(
        &rt,
        d,
        vec![
            Transport::Pseudoterminal { link: None },
            Transport::Udp(local(0)),
        ],
    );
    let pty = a.serial_paths()[0].clone();
    assert!(pty.exists(), "{}", pty.display());
    let mut w = XClient::serial(0x2222_0001, &pty);
    let mut r = XClient::udp(0x2222_0002, a.udp_addrs()[0]);
    r.create(reader(d, "serial_topic"));
    let unlimited = Some(DeliveryControl {
        max_samples: u16::MAX,
        ..DeliveryControl::default()
    });
    r.c.read(oid(ObjectKind::DataReader), R, R, unlimited, Instant::now())
        .unwrap();
    w.create(writer(d, "serial_topic"));
    for seq in 0..10u32 {
        let body = msg(seq, "pty", &payload(seq, 600));
        w.c.write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
            .unwrap();
    }
    let end = Instant::now() + T;
    while r.data().len() < 10 && Instant::now() < end {
        w.turn();
        r.turn();
    }
    let got: Vec<_> = r.data().iter().map(|b| unmsg(b)).collect();
    let want: Vec<_> = (0..10u32)
        .map(|s| (s, "pty".to_string(), payload(s, 600)))
        .collect();
    assert_eq!(got, want);
    rt.block_on(a.shutdown());
}

fn agent_cli(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_xrce-agent"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn command_line_errors() {
    let dir = std::env::temp_dir().join(format!("xrce-agent-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.refs");
    std::fs::write(
        &bad,
        "<profiles>\n  <topic profile_name=\"t\">\n</profiles>\n",
    )
    .unwrap();
    let incomplete = dir.join("incomplete.refs");
    std::fs::write(
        &incomplete,
        "<profiles>\n  <topic profile_name=\"ok\"><name>y</name><dataType>T</dataType></topic>\n  <topic profile_name=\"t\"><name>x</name></topic>\n</profiles>",
    )
    .unwrap();
    // cut short, as a full disk or an unfinished copy leaves it
    let cut = dir.join("cut.refs");
    std::fs::write(
        &cut,
        "<profiles>\n  <topic profile_name=\"ok\"><name>y</name><dataType>T</dataType></topic>\n  <topic profile_",
    )
    .unwrap();
    let missing = dir.join("missing.refs");
    let missing_dir = dir.join("no-such-dir");
    let state_in_missing = missing_dir.join("agent.redb");
    let link_in_missing = missing_dir.join("tty");
    // a port somebody else has
    let busy = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let busy_port = busy.local_addr().unwrap().port();
    let cases: Vec<(Vec<String>, i32, String)> = vec![
        (
            vec!["udp4".into()],
            2,
            "error: the following required arguments were not provided:\n  --port <PORT>".into(),
        ),
        (
            // the transport forgotten (it comes first)
            vec!["-p".into(), "8888".into()],
            2,
            "error: -p comes after a transport: name the transport first (one of udp4, tcp4, \
             serial, pseudoterminal), e.g. xrce-agent udp4 -p 8888"
                .into(),
        ),
        (
            vec!["udp6".into(), "-p".into(), "8888".into()],
            2,
            "error: the udp6 transport is not supported (these are: udp4, tcp4, serial, pseudoterminal)".into(),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-v".into(), "9".into()],
            2,
            "error: invalid value '9' for '--verbose <VERBOSE>': 9 is not in 0..=6".into(),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-m".into(), "ced".into()],
            2,
            "xrce-agent: middleware \"ced\" is not supported: this agent always bridges into DDS (-m dds)".into(),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-r".into(), bad.display().to_string()],
            2,
            format!(
                "xrce-agent: references file {}: XML at line 3, column 1: expected 'topic' tag, not 'profiles'",
                bad.display()
            ),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-r".into(), incomplete.display().to_string()],
            2,
            format!(
                "xrce-agent: references file {}: line 3: <topic profile_name=\"t\">: <topic> has no <dataType>",
                incomplete.display()
            ),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-r".into(), cut.display().to_string()],
            2,
            format!(
                "xrce-agent: references file {}: XML at line 3, column 18: the text ends before the root element is closed (is it cut short?)",
                cut.display()
            ),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "-r".into(), missing.display().to_string()],
            2,
            format!(
                "xrce-agent: references file {}: No such file or directory (os error 2)",
                missing.display()
            ),
        ),
        (
            vec!["tcp4".into(), "-p".into(), "0".into(), "--multicast".into(), "maybe".into()],
            2,
            "error: invalid value 'maybe' for '--multicast <MULTICAST>': \"maybe\": expected on or off".into(),
        ),
        // a file, directory or device the command line names that is not
        // there: a usage error, as a missing references file (exit 2)
        (
            vec!["serial".into(), "--dev".into(), "/nonexistent/tty".into(), "--bind".into(), "127.0.0.1".into()],
            2,
            "xrce-agent: cannot open serial /nonexistent/tty: No such file or directory (os error 2)".into(),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "--bind".into(), "127.0.0.1".into(), "--state".into(), state_in_missing.display().to_string()],
            2,
            format!(
                "xrce-agent: state file {}: directory {}: No such file or directory (os error 2)",
                state_in_missing.display(),
                missing_dir.display()
            ),
        ),
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "--bind".into(), "127.0.0.1".into(), "--state".into(), dir.display().to_string()],
            2,
            format!(
                "xrce-agent: state file {}: it is a directory (--state names the file to keep clients' sessions in)",
                dir.display()
            ),
        ),
        // a directory that cannot be written (procfs: not even root may
        // make a file there): said before anything starts, not as the
        // database's failure (audit 16: exit 1, where --help says 2)
        (
            vec!["udp4".into(), "-p".into(), "0".into(), "--bind".into(), "127.0.0.1".into(), "--state".into(), "/proc/self/agent.db".into()],
            2,
            "xrce-agent: state file /proc/self/agent.db: its directory cannot be written (".into(),
        ),
        (
            vec!["pseudoterminal".into(), "--dev".into(), link_in_missing.display().to_string(), "--bind".into(), "127.0.0.1".into()],
            2,
            format!(
                "xrce-agent: cannot make the link {} to the pseudo-terminal: directory {}: No such file or directory (os error 2)",
                link_in_missing.display(),
                missing_dir.display()
            ),
        ),
        // what is there but cannot be had is a failure to start (exit 1)
        (
            vec!["udp4".into(), "-p".into(), busy_port.to_string(), "--bind".into(), "127.0.0.1".into()],
            1,
            format!("xrce-agent: cannot bind XRCE UDP on 127.0.0.1:{busy_port}: "),
        ),
    ];
    for (args, code, want) in cases {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let (got_code, stderr) = agent_cli(&a);
        assert_eq!(got_code, code, "{args:?}: {stderr}");
        assert!(
            stderr.starts_with(&want),
            "{args:?}:\n got: {stderr}\nwant: {want}"
        );
    }
    drop(busy);
    assert!(
        !missing_dir.exists(),
        "nothing was made in the missing directory"
    );
    // --help says which is which
    let help = Command::new(env!("CARGO_BIN_EXE_xrce-agent"))
        .arg("--help")
        .output()
        .unwrap();
    assert_eq!(help.status.code(), Some(0));
    let version = Command::new(env!("CARGO_BIN_EXE_xrce-agent"))
        .arg("--version")
        .output()
        .unwrap();
    assert_eq!(version.status.code(), Some(0));
    assert_eq!(
        String::from_utf8_lossy(&version.stdout),
        format!("xrce-agent {}\n", env!("CARGO_PKG_VERSION"))
    );
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains(
            "Exit status: 0 stopped by Ctrl-C, SIGTERM or SIGHUP; 2 the command line is wrong"
        ) && help.contains("--state's directory; serial --dev;")
            && help.contains("1 the agent could not start for another reason (a port in use"),
        "{help}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// `xrce-agent` with `--state`, on 127.0.0.1 at `port` (0: any); its UDP address.
/// Waits for an agent process to exit, at most `T`; one that does not is
/// killed and the test fails (an unbounded wait hung a test run for good).
fn wait_exit(agent: &mut std::process::Child, what: &str) {
    let end = Instant::now() + T;
    while Instant::now() < end {
        if agent.try_wait().unwrap().is_some() {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let _ = agent.kill();
    let _ = agent.wait();
    panic!("{what}: the agent did not exit within {T:?}");
}

/// An agent process, killed and reaped when dropped: a test that fails
/// half-way leaves no agent running (two did, after an assertion).
struct AgentProc(std::process::Child);

impl Drop for AgentProc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl std::ops::Deref for AgentProc {
    type Target = std::process::Child;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl std::ops::DerefMut for AgentProc {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

/// A directory of this test process named `name`, and a state file path
/// in it that holds nothing yet.
fn fresh_state(name: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let state = dir.join("agent.redb");
    let _ = std::fs::remove_file(&state);
    (dir, state)
}

fn agent_with_state(domain: u32, state: &std::path::Path, port: u16) -> (AgentProc, SocketAddr) {
    start_agent(
        Command::new(env!("CARGO_BIN_EXE_xrce-agent")),
        domain,
        state,
        port,
    )
}

/// [`agent_with_state`] run by `cmd` (the agent's binary, or `nohup` to
/// run it).
fn start_agent(
    mut cmd: Command,
    domain: u32,
    state: &std::path::Path,
    port: u16,
) -> (AgentProc, SocketAddr) {
    use std::io::BufRead;
    let mut child = AgentProc(
        cmd.args(["udp4", "-p", &port.to_string(), "--bind", "127.0.0.1"])
            .args(LOOPBACK)
            .args(["--domain", &domain.to_string(), "-v", "2", "--state"])
            .arg(state)
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let out = child.stdout.take().unwrap();
    let mut addr = None;
    for line in std::io::BufReader::new(out).lines() {
        let line = line.unwrap();
        if let Some(a) = line.strip_prefix("udp4 ") {
            addr = Some(a.parse().unwrap());
        }
        if line == "ready" {
            break;
        }
    }
    (child, addr.expect("the agent printed its address"))
}

#[test]
fn a_restart_with_state_after_kill_9_is_invisible_to_clients() {
    let d = courier_tests::domains::lease(4);
    let (dir, state) = fresh_state("xrce-agent-state");
    let (mut agent, addr) = agent_with_state(d, &state, 0);
    let mut w = XClient::udp(0x4444_0001, addr);
    let mut r = XClient::udp(0x4444_0002, addr);
    r.create(reader(d, "restart"));
    let unlimited = Some(DeliveryControl {
        max_samples: u16::MAX,
        ..DeliveryControl::default()
    });
    r.c.read(oid(ObjectKind::DataReader), R, R, unlimited, Instant::now())
        .unwrap();
    w.create(writer(d, "restart"));
    let mut next = 0u32;
    let mut exchange = |w: &mut XClient, r: &mut XClient, n: u32| {
        let end = Instant::now() + T;
        while r.data().len() < n as usize && Instant::now() < end {
            while next < n {
                let body = msg(next, "restart", &[next as u8; 32]);
                match w
                    .c
                    .write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
                {
                    Ok(_) => next += 1,
                    Err(_) => break,
                }
            }
            w.turn();
            r.turn();
        }
    };
    exchange(&mut w, &mut r, 10);
    assert_eq!(r.data().len(), 10);
    // kill -9, and the same agent again on the same port with the same state
    agent.kill().unwrap();
    wait_exit(&mut agent, "stopped");
    let (mut again, addr2) = agent_with_state(d, &state, addr.port());
    assert_eq!(addr2, addr);
    // the clients know nothing of it and go on with their sessions
    exchange(&mut w, &mut r, 20);
    let got: Vec<u32> = r.data().iter().map(|b| unmsg(b).0).collect();
    assert_eq!(
        got,
        (0..20).collect::<Vec<_>>(),
        "complete and in order across the restart"
    );
    assert!(w.until(T, |e| e
        .iter()
        .filter(|e| matches!(e, Event::WriteAcked(_)))
        .count()
        == 20));
    again.kill().unwrap();
    wait_exit(&mut again, "killed");
    let _ = std::fs::remove_dir_all(dir);
}

/// A graceful stop (SIGTERM) with `--state`, under traffic to a remote DDS
/// reader, loses nothing the client wrote meanwhile. The fault this guards
/// (a restored agent writing the client's resent samples with its new DDS
/// participant before the remote reader had found it again, so a volatile
/// reader never got them) is a race this client's slower resending does
/// not always hit: the bridge now holds writes for `REDISCOVERY` after a
/// restore, which the Courier session client's reproduction (20 of 120
/// samples lost before, none after) showed.
#[test]
fn a_restart_with_state_after_sigterm_loses_nothing_for_a_remote_reader() {
    use futures::StreamExt;
    use xrce_client::Msg;
    let d = courier_tests::domains::lease(5);
    let (dir, state) = fresh_state("xrce-agent-term");
    let rt = runtime();
    let s = rt
        .block_on(
            courier::Session::builder(format!("rtps://{d}?interface=lo&peers=127.0.0.1")).connect(),
        )
        .unwrap();
    let mut sub = rt.block_on(s.subscribe::<Msg>("term")).unwrap();
    let (mut agent, addr) = agent_with_state(d, &state, 0);
    let mut w = XClient::udp(0x5555_0001, addr);
    w.create(xrce_client::writer_with(
        d,
        "term",
        courier_wire::xrce::qos_flags::RELIABLE,
    ));
    let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let g = got.clone();
    rt.spawn(async move {
        while let Some(Ok(m)) = sub.next().await {
            g.lock().unwrap().push(m.value.seq);
        }
    });
    let mut next = 0u32;
    // write until the reader has one (it matches the agent's writer)
    let end = Instant::now() + T;
    while got.lock().unwrap().is_empty() && Instant::now() < end {
        let body = msg(next, "term", &[1; 8]);
        if w.c
            .write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
            .is_ok()
        {
            next += 1;
        }
        w.turn();
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let first = got.lock().unwrap()[0];
    let write = |w: &mut XClient, upto: u32, next: &mut u32| {
        while *next < upto {
            let body = msg(*next, "term", &[1; 8]);
            match w
                .c
                .write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
            {
                Ok(_) => *next += 1,
                Err(_) => break,
            }
        }
        w.turn();
    };
    write(&mut w, next + 5, &mut next);
    // SIGTERM: the agent stops cleanly (its participant says goodbye)
    let pid = i32::try_from(agent.id()).unwrap();
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
    wait_exit(&mut agent, "stopped");
    // the client goes on writing while the agent is down
    let down_until = next + 8;
    for _ in 0..20 {
        write(&mut w, down_until, &mut next);
        std::thread::sleep(std::time::Duration::from_millis(25));
    }
    let (mut again, addr2) = agent_with_state(d, &state, addr.port());
    assert_eq!(addr2, addr);
    let last = next + 10;
    let end = Instant::now() + T;
    while Instant::now() < end && got.lock().unwrap().last() != Some(&(last - 1)) {
        write(&mut w, last, &mut next);
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let got = got.lock().unwrap().clone();
    assert_eq!(
        got,
        (first..last).collect::<Vec<_>>(),
        "complete and in order across the restart"
    );
    again.kill().unwrap();
    wait_exit(&mut again, "killed");
    rt.block_on(s.close());
    let _ = std::fs::remove_dir_all(dir);
}

/// SIGHUP (a closed terminal, a dropped ssh session) stops the agent as
/// SIGTERM does: exit status 0, its state saved as a graceful stop saves
/// it (audit 16: it died of the signal, status 129, a crash for --state).
#[test]
fn sighup_stops_the_agent_cleanly() {
    let d = courier_tests::domains::lease(7);
    let (dir, state) = fresh_state("xrce-agent-hup");
    let (mut agent, _addr) = agent_with_state(d, &state, 0);
    let pid = i32::try_from(agent.id()).unwrap();
    // SAFETY: a signal to the child this test started and still holds
    assert_eq!(unsafe { libc::kill(pid, libc::SIGHUP) }, 0);
    wait_exit(&mut agent, "hung up");
    let status = agent.0.wait().unwrap();
    assert_eq!(status.code(), Some(0), "{status:?}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Under `nohup` a hang-up goes on being ignored (the agent must not undo
/// what `nohup` asked for); SIGTERM still stops it.
#[test]
fn under_nohup_sighup_is_ignored() {
    let d = courier_tests::domains::lease(8);
    let (dir, state) = fresh_state("xrce-agent-nohup");
    let mut nohup = Command::new("nohup");
    nohup.arg(env!("CARGO_BIN_EXE_xrce-agent"));
    let (mut agent, _addr) = start_agent(nohup, d, &state, 0);
    let pid = i32::try_from(agent.id()).unwrap();
    // SAFETY: signals to the child this test started and still holds
    assert_eq!(unsafe { libc::kill(pid, libc::SIGHUP) }, 0);
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(
        agent.0.try_wait().unwrap().is_none(),
        "a hang-up stopped it"
    );
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
    wait_exit(&mut agent, "terminated");
    assert_eq!(agent.0.wait().unwrap().code(), Some(0));
    let _ = std::fs::remove_dir_all(dir);
}

/// An agent on UDP 127.0.0.1 port 0, its DDS participant on `lo` in
/// domain `d`, with `extra` arguments and `env`: the first line it writes
/// on stderr (within `T`; the agent is killed after).
fn first_stderr_line(d: u32, extra: &[&str], env: &[(&str, &str)]) -> String {
    use std::io::BufRead;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_xrce-agent"));
    cmd.args(["udp4", "-p", "0", "--bind", "127.0.0.1"])
        .args(LOOPBACK)
        .args(["--domain", &d.to_string()])
        .args(extra)
        .envs(env.iter().copied())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped());
    let mut agent = AgentProc(cmd.spawn().unwrap());
    let err = agent.0.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    // (the reader thread ends when the agent, killed on drop, is gone)
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(err).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    rx.recv_timeout(T).expect("a line on stderr")
}

/// The agent reads `RUST_LOG` as central does (audit 16: it ignored it):
/// one that does not parse is said on stderr.
#[test]
fn the_agent_reads_rust_log() {
    let d = courier_tests::domains::lease(9);
    let line = first_stderr_line(d, &[], &[("RUST_LOG", "=bad=")]);
    assert!(line.contains("RUST_LOG=\"=bad=\" ignored"), "{line}");
}

/// A references file that parses but defines no profile (other XML, or
/// every element name mistyped) is said at start: every CREATE by
/// reference would be refused (audit 16: it started silently).
#[test]
fn a_references_file_without_profiles_is_said_at_start() {
    let d = courier_tests::domains::lease(10);
    let refs = std::env::temp_dir().join(format!("xrce-agent-noprof-{}.xml", std::process::id()));
    std::fs::write(&refs, "<foo><bar/></foo>").unwrap();
    let line = first_stderr_line(d, &["-r", refs.to_str().unwrap()], &[]);
    let _ = std::fs::remove_file(&refs);
    assert!(line.contains("defines no profiles"), "{line}");
}

/// A client participant of another domain than the agent's is refused
/// with `STATUS_ERR_INCOMPATIBLE`, which says nothing by itself; the error
/// names the likely cause and the option that changes it.
#[test]
fn a_participant_of_another_domain_is_refused_naming_the_domains() {
    use courier::IpcMessage;
    #[derive(IpcMessage, Debug, Clone, PartialEq)]
    struct Reading {
        value: f64,
    }
    let d = courier_tests::domains::lease(6);
    let rt = runtime();
    let a = agent(&rt, d, vec![Transport::Udp(local(0))]);
    let other = if d == 1 { 2 } else { d - 1 };
    let url = format!("xrce+udp://{}?domain={other}", a.udp_addrs()[0]);
    let s = rt
        .block_on(courier::Session::builder(url).name("lost").connect())
        .unwrap();
    let e = rt
        .block_on(s.publisher::<Reading>("r").build())
        .unwrap_err();
    assert!(
        matches!(
            &e,
            courier::OpenError::Refused {
                entity: "participant",
                ..
            }
        ),
        "{e:?}"
    );
    let text = e.to_string();
    assert!(
        text.contains("STATUS_ERR_INCOMPATIBLE") && text.contains("--any-domain"),
        "{text}"
    );
    rt.block_on(s.close());
    rt.block_on(a.shutdown());
}

/// A board's publication through XRCE offering MANUAL_BY_TOPIC liveliness
/// (Courier's XRCE client, `representation=xml`: the binary form has no
/// field for it): the agent's DDS writer offers it, so an RTPS subscriber
/// requesting it sees the board alive while it publishes and not alive a
/// lease after it stops — though the agent, and its participant, live on.
#[test]
fn an_xrce_publication_offers_manual_liveliness_to_dds() {
    use courier::qos::LivelinessKind;
    use courier::{Session, SessionEvent};
    use futures::{FutureExt, StreamExt};
    use std::time::Duration;
    let d = courier_tests::domains::lease(11);
    let rt = runtime();
    let ag = agent(&rt, d, vec![Transport::Udp(local(0))]);
    let addr = ag.udp_addrs()[0];
    rt.block_on(async {
        let dds = Session::builder(format!("rtps://{d}?interface=lo&peers=127.0.0.1"))
            .connect()
            .await
            .unwrap();
        let mut ev = dds.events();
        let _sub = dds
            .subscriber::<i32>("board_alive")
            .liveliness(LivelinessKind::ManualByTopic, Duration::from_secs(1))
            .build()
            .await
            .unwrap();
        let board = Session::builder(format!("xrce+udp://{addr}?representation=xml&domain={d}"))
            .connect()
            .await
            .unwrap();
        let p = board
            .publisher::<i32>("board_alive")
            .liveliness(LivelinessKind::ManualByTopic, Duration::from_secs(1))
            .build()
            .await
            .unwrap();
        let liveliness = |e: SessionEvent| match e {
            SessionEvent::LivelinessChanged {
                alive,
                alive_count,
                not_alive_count,
                ..
            } => Some((alive, alive_count, not_alive_count)),
            _ => None,
        };
        // the next liveliness change, within T
        async fn next_change(
            ev: &mut courier::Events,
            liveliness: impl Fn(SessionEvent) -> Option<(bool, u32, u32)>,
        ) -> Option<(bool, u32, u32)> {
            tokio::time::timeout(T, async {
                loop {
                    if let Some(l) = liveliness(ev.next().await?) {
                        return Some(l);
                    }
                }
            })
            .await
            .ok()
            .flatten()
        }
        let first = next_change(&mut ev, liveliness)
            .await
            .expect("the RTPS subscriber never matched the board's writer");
        assert_eq!(first, (true, 1, 0));
        // three leases of publishing, 300 ms apart: never not alive
        for i in 0..10 {
            p.publish(&i).await.unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            while let Some(Some(e)) = ev.next().now_or_never() {
                assert_eq!(liveliness(e).map(|l| l.0), None, "lapsed while publishing");
            }
        }
        let lapsed = next_change(&mut ev, liveliness)
            .await
            .expect("no lapse after the board stopped publishing");
        assert_eq!(lapsed, (false, 0, 1));
        drop(p);
        board.close().await;
        dds.close().await;
    });
    rt.block_on(ag.shutdown());
}
