//! The XRCE agent as a library: XRCE transports (UDP, TCP, serial devices,
//! pseudo-terminals, several at once) in front of one
//! [`Bridge`], whose DDS participant
//! speaks RTPS on the interface and peers of [`RtpsOptions`].
//!
//! One tokio task drives the bridge; each socket has a reader task, each
//! serial line a reader and a writer thread. Everything binds port 0 when
//! asked, and the agent reports what it bound. [`XrceAgent::shutdown`]
//! stops every reader, says goodbye in DDS and waits for the task.
//!
//! Each [`Transport`] binds the address it names (the `xrce-agent`
//! binary binds every interface, as MicroXRCEAgent does). The DDS
//! participant takes [`RtpsOptions::default`] unless given
//! [`XrceAgentBuilder::rtps`]: DDS's standard multicast discovery on the
//! default interface; pin it as below, or with
//! [`RtpsOptions::loopback`], to keep it on 127.0.0.1.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use courier::rtps_backend::RtpsOptions;
//! use courier_broker::xrce_agent::{Transport, XrceAgent};
//!
//! let mut rtps = RtpsOptions::default();
//! # let domain = courier_tests::domains::lease(900);
//! rtps.domain = domain; // a DDS domain id of your choosing
//! rtps.interface = Some("127.0.0.1".into());
//! rtps.peers = vec!["127.0.0.1".into()];
//! rtps.multicast = false;
//! let agent = XrceAgent::builder()
//!     .transport(Transport::Udp("127.0.0.1:0".parse()?))
//!     .rtps(rtps)
//!     .spawn()
//!     .await?;
//! let port = agent.udp_addrs()[0].port();
//! assert_ne!(port, 0);
//! agent.shutdown().await;
//! # Ok(()) }
//! ```

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, Instant, SystemTime};

use courier::driver_timer::DriverTimer;
use courier::rtps_backend::{interface_address, parse_peer, RtpsOptions};
use courier_wire::dds::Domain;
use courier_wire::rtps::participant::{self, Config, PortMapping, SPDP_MULTICAST_ADDRESS};
use courier_wire::rtps::Locator;
use courier_wire::xrce::bridge::{Bridge, BridgeConfig, BridgeEvent, Profiles};
use courier_wire::xrce::discovery;
use courier_wire::xrce::serial::{self, SerialDecoder};
use courier_wire::xrce::tcp::{self, TcpDeframer};
use courier_wire::xrce::{AgentRepresentation, Message, ObjectId, TransportLocator};
use tokio::io::{AsyncReadExt, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, UdpSocket};
use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinSet;

/// An XRCE transport the agent serves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transport {
    /// UDP on this address (port 0: any free port).
    Udp(SocketAddr),
    /// TCP on this address (port 0: any free port).
    Tcp(SocketAddr),
    /// A serial device at a baud rate.
    Serial {
        /// The device (`/dev/ttyUSB0`).
        device: PathBuf,
        /// Baud rate.
        baud: u32,
    },
    /// A new pseudo-terminal; clients open its other end
    /// ([`XrceAgent::serial_paths`]), which `link` (if given) points to.
    Pseudoterminal {
        /// A symbolic link made to the client end.
        link: Option<PathBuf>,
    },
}

/// Why the agent did not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StartError {
    /// A socket could not be bound.
    #[error("cannot bind {what} on {addr}: {source}")]
    Bind {
        /// Which socket.
        what: &'static str,
        /// Where.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// A serial device or pseudo-terminal could not be opened.
    #[error("cannot open serial {device}: {why}")]
    Serial {
        /// The device.
        device: String,
        /// Why.
        why: String,
    },
    /// The DDS side could not start.
    #[error("DDS participant: {0}")]
    Rtps(String),
    /// No transport was given.
    #[error("no transport: give at least one of udp4, tcp4, serial, pseudoterminal")]
    NoTransport,
    /// The state file could not be opened or read.
    #[error("{0}")]
    State(String),
}

/// Builds an [`XrceAgent`].
#[derive(Debug, Clone)]
pub struct XrceAgentBuilder {
    transports: Vec<Transport>,
    rtps: RtpsOptions,
    bridge: BridgeConfig,
    discovery: Option<SocketAddrV4>,
    state: Option<PathBuf>,
    tcp_hello: Duration,
}

/// A running agent. Dropping it without [`shutdown`](Self::shutdown)
/// stops its task and threads without saying goodbye in DDS.
#[derive(Debug)]
pub struct XrceAgent {
    udp: Vec<SocketAddr>,
    tcp: Vec<SocketAddr>,
    serial: Vec<PathBuf>,
    discovery: Option<SocketAddr>,
    rtps: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<()>>,
    threads_stop: Arc<AtomicBool>,
    links: Vec<PathBuf>,
}

impl XrceAgent {
    /// A builder: no transport yet, RTPS options' defaults, no references.
    pub fn builder() -> XrceAgentBuilder {
        XrceAgentBuilder {
            transports: Vec::new(),
            rtps: RtpsOptions::default(),
            bridge: {
                let mut b = BridgeConfig::default();
                b.agent.streams = b.agent.streams.delayed_acks();
                b
            },
            discovery: None,
            state: None,
            tcp_hello: TCP_HELLO_TIMEOUT,
        }
    }

    /// The UDP addresses bound, in the order given.
    pub fn udp_addrs(&self) -> &[SocketAddr] {
        &self.udp
    }

    /// The TCP addresses bound, in the order given.
    pub fn tcp_addrs(&self) -> &[SocketAddr] {
        &self.tcp
    }

    /// The serial devices, and the client ends of pseudo-terminals.
    pub fn serial_paths(&self) -> &[PathBuf] {
        &self.serial
    }

    /// The discovery socket, when on.
    pub fn discovery_addr(&self) -> Option<SocketAddr> {
        self.discovery
    }

    /// The DDS participant's metatraffic unicast address.
    pub fn rtps_addr(&self) -> SocketAddr {
        self.rtps
    }

    /// Stops: readers end, every DDS entity is disposed and the
    /// participant says goodbye, the task ends.
    pub async fn shutdown(mut self) {
        self.stop_all().await;
    }

    async fn stop_all(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
        self.threads_stop.store(true, Ordering::Relaxed);
        for l in self.links.drain(..) {
            let _ = std::fs::remove_file(l);
        }
    }
}

impl Drop for XrceAgent {
    fn drop(&mut self) {
        self.threads_stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.task.take() {
            t.abort();
        }
        for l in self.links.drain(..) {
            let _ = std::fs::remove_file(l);
        }
    }
}

impl XrceAgentBuilder {
    /// Deletes a session whose client has said nothing for `after`, as
    /// DELETE_CLIENT would (default: never; see
    /// [`AgentConfig::client_timeout`](courier_wire::xrce::AgentConfig::client_timeout)).
    /// At the most sessions a new client always takes the place of one
    /// silent for a minute.
    pub fn client_timeout(mut self, after: Option<std::time::Duration>) -> Self {
        self.bridge.agent.client_timeout = after;
        self
    }

    /// Closes a TCP connection that brings no whole XRCE message within
    /// `after` of its opening (default [`TCP_HELLO_TIMEOUT`], 10 s).
    pub fn tcp_hello_timeout(mut self, after: Duration) -> Self {
        self.tcp_hello = after;
        self
    }

    /// Serves one more transport.
    pub fn transport(mut self, t: Transport) -> Self {
        self.transports.push(t);
        self
    }

    /// The DDS participant's options (domain, interface, peers, multicast…).
    pub fn rtps(mut self, o: RtpsOptions) -> Self {
        self.rtps = o;
        self
    }

    /// Profiles for CREATE by reference (MicroXRCEAgent's `-r`).
    pub fn profiles(mut self, p: Profiles) -> Self {
        self.bridge.profiles = p;
        self
    }

    /// Takes participants of any DDS domain id into the agent's domain.
    pub fn any_domain(mut self, yes: bool) -> Self {
        self.bridge.any_domain = yes;
        self
    }

    /// Answers discovery GET_INFO on this address (MicroXRCEAgent's `-d`,
    /// port 7400, multicast group 239.255.0.2 when the interface has
    /// multicast).
    pub fn discovery(mut self, addr: SocketAddrV4) -> Self {
        self.discovery = Some(addr);
        self
    }

    /// Keeps every client's session, objects and READ_DATA in this file
    /// (created if need be) and serves the clients it holds at start, so
    /// that a restart (even after `kill -9`) is invisible to clients that
    /// go on with their sessions. Transports must be given in the same
    /// order as before: a UDP client is known by the index of its
    /// transport and its address.
    ///
    /// The file also keeps, per reliable stream of each client, the last
    /// message whose samples DDS took, committed durably before the
    /// ACKNACK that acknowledges that message goes (one commit per turn
    /// of the agent's loop for every client that moved). A sample the
    /// client sends again after the restart because its acknowledgement
    /// never came is then recognised and not written twice. The
    /// guarantees, for reliable streams:
    /// - nothing the agent acknowledged is ever lost, however it stops;
    /// - after a graceful stop ([`XrceAgent::shutdown`], SIGTERM or
    ///   Ctrl-C for the binary) nothing is written twice;
    /// - after `kill -9` or power loss, a sample DDS took (and the agent
    ///   may have sent on) before the commit of its position completed is
    ///   written again when the client resends it: **at least once** for
    ///   the last samples of each client stream before the crash (those of
    ///   one commit, a few milliseconds), exactly once for every other.
    ///
    /// Samples on their way to the agent's own XRCE readers (reliable
    /// output not yet acknowledged by those clients) are not kept: they
    /// are gone with the old process.
    pub fn state(mut self, path: impl Into<PathBuf>) -> Self {
        self.state = Some(path.into());
        self
    }

    /// Binds everything and starts the agent.
    pub async fn spawn(self) -> Result<XrceAgent, StartError> {
        if self.transports.is_empty() {
            return Err(StartError::NoTransport);
        }
        let (tx, rx) = mpsc::channel::<Input>(1024);
        let mut readers = JoinSet::new();
        let threads_stop = Arc::new(AtomicBool::new(false));
        let mut udp = Vec::new();
        let mut udp_addrs = Vec::new();
        let mut tcp_addrs = Vec::new();
        let mut serial_paths = Vec::new();
        let mut serial_out = Vec::new();
        let mut links = Vec::new();
        for t in &self.transports {
            match t {
                Transport::Udp(a) => {
                    let s = UdpSocket::bind(a)
                        .await
                        .map_err(|source| StartError::Bind {
                            what: "XRCE UDP",
                            addr: *a,
                            source,
                        })?;
                    udp_addrs.push(s.local_addr().unwrap_or(*a));
                    // Read by the driver itself (`Driver::poll_udp`).
                    udp.push(Arc::new(s));
                }
                Transport::Tcp(a) => {
                    let l = TcpListener::bind(a)
                        .await
                        .map_err(|source| StartError::Bind {
                            what: "XRCE TCP",
                            addr: *a,
                            source,
                        })?;
                    tcp_addrs.push(l.local_addr().unwrap_or(*a));
                    readers.spawn(tcp_acceptor(l, tx.clone(), self.tcp_hello));
                }
                Transport::Serial { device, baud } => {
                    let port = serialport::new(device.to_string_lossy(), *baud)
                        .timeout(Duration::from_millis(100))
                        .open_native()
                        .map_err(|e| StartError::Serial {
                            device: device.display().to_string(),
                            why: e.to_string(),
                        })?;
                    let idx = serial_out.len() as u8;
                    let line = SerialLine {
                        port,
                        keep: None,
                        reopen: Some((device.clone(), *baud)),
                    };
                    serial_out.push(serial_threads(line, idx, tx.clone(), &threads_stop)?);
                    serial_paths.push(device.clone());
                }
                Transport::Pseudoterminal { link } => {
                    let fail = |e: serialport::Error| StartError::Serial {
                        device: "pseudo-terminal".into(),
                        why: e.to_string(),
                    };
                    let (mut master, slave) = serialport::TTYPort::pair().map_err(fail)?;
                    let _ = serialport::SerialPort::set_timeout(
                        &mut master,
                        Duration::from_millis(100),
                    );
                    let path = serialport::SerialPort::name(&slave)
                        .map(PathBuf::from)
                        .unwrap_or_default();
                    if let Some(l) = link {
                        let _ = std::fs::remove_file(l);
                        std::os::unix::fs::symlink(&path, l).map_err(|e| StartError::Serial {
                            device: l.display().to_string(),
                            why: e.to_string(),
                        })?;
                        links.push(l.clone());
                    }
                    let idx = serial_out.len() as u8;
                    let line = SerialLine {
                        port: master,
                        keep: Some(slave),
                        reopen: None,
                    };
                    serial_out.push(serial_threads(line, idx, tx.clone(), &threads_stop)?);
                    serial_paths.push(path);
                }
            }
        }
        let (domain, rtps_addr) = open_rtps(&self.rtps, &mut readers, &tx).await?;
        let discovery = match self.discovery {
            Some(a) => {
                let (s, bound) = discovery_socket(a, &self.rtps)?;
                let s = Arc::new(s);
                readers.spawn(discovery_reader(
                    s,
                    udp_addrs.clone(),
                    interface_address(&self.rtps).unwrap_or(Ipv4Addr::LOCALHOST),
                ));
                Some(bound)
            }
            None => None,
        };
        let mut bridge_cfg = self.bridge.clone();
        bridge_cfg.domain_id = self.rtps.domain;
        let now = Instant::now();
        let mut bridge = Bridge::new(bridge_cfg, domain.domain, now, SystemTime::now());
        let store = match &self.state {
            None => None,
            Some(path) => {
                let (store, states) = crate::xrce_state::open(path).map_err(StartError::State)?;
                // acknowledge only what the file says DDS took
                bridge.hold_acks_until_saved();
                for st in states {
                    let client = u32::from(st.client);
                    let n = st.objects.len();
                    for (object, why) in bridge.restore(st, now) {
                        tracing::warn!(
                            "restoring client 0x{client:08X}: object {:#06x}: {why}",
                            object.0
                        );
                    }
                    tracing::info!("restored client 0x{client:08X} with {n} object(s)");
                }
                Some(store)
            }
        };
        let (stop_tx, stop_rx) = oneshot::channel();
        let driver = Driver {
            bridge,
            udp,
            tcp: HashMap::new(),
            serial: serial_out,
            rtps_send: domain.send,
            readers,
            store,
        };
        let task = tokio::spawn(driver.run(rx, stop_rx));
        Ok(XrceAgent {
            udp: udp_addrs,
            tcp: tcp_addrs,
            serial: serial_paths,
            discovery,
            rtps: rtps_addr,
            stop: Some(stop_tx),
            task: Some(task),
            threads_stop,
            links,
        })
    }
}

/// Where an XRCE client is: the transport and its address there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Peer {
    Udp(u8, SocketAddr),
    Tcp(u64),
    Serial(u8, u8),
}

enum Input {
    Xrce(Peer, Vec<u8>),
    Rtps(Locator, Vec<u8>),
    TcpOpen(u64, mpsc::Sender<Vec<u8>>),
    TcpClosed(u64),
}

/// A TCP connection that brings no whole XRCE message in this long is
/// closed (a client's first, CREATE_CLIENT or GET_INFO, comes at once):
/// connections that never said anything were held for ever, 1100 of them
/// taking every descriptor the agent had.
pub const TCP_HELLO_TIMEOUT: Duration = Duration::from_secs(10);

async fn tcp_acceptor(l: TcpListener, tx: mpsc::Sender<Input>, hello: Duration) {
    let mut next = 1u64;
    let mut warned: Option<std::time::Instant> = None;
    loop {
        let (stream, from) = match l.accept().await {
            Ok(c) => c,
            Err(e) => {
                // out of descriptors (EMFILE), say: the connection waits in
                // the backlog and accept fails again at once; a pause, not
                // a spin, and one line a minute
                if warned.is_none_or(|t| t.elapsed() >= Duration::from_secs(60)) {
                    tracing::warn!("XRCE TCP accept failed: {e} (retrying every 50 ms)");
                    warned = Some(std::time::Instant::now());
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let id = next;
        next += 1;
        let _ = stream.set_nodelay(true);
        // a board that lost power leaves its connection half open: probed
        // after 30 s of silence, closed about 30 s later
        let probe = socket2::TcpKeepalive::new()
            .with_time(Duration::from_secs(30))
            .with_interval(Duration::from_secs(10))
            .with_retries(3);
        let _ = socket2::SockRef::from(&stream).set_tcp_keepalive(&probe);
        tracing::info!("XRCE TCP connection {id} from {from}");
        let (mut rd, mut wr) = stream.into_split();
        let (out_tx, mut out_rx) = mpsc::channel::<Vec<u8>>(256);
        if tx.send(Input::TcpOpen(id, out_tx)).await.is_err() {
            return;
        }
        tokio::spawn(async move {
            while let Some(m) = out_rx.recv().await {
                let mut framed = Vec::with_capacity(m.len() + 2);
                if tcp::encode(&m, &mut framed).is_err() || wr.write_all(&framed).await.is_err() {
                    break;
                }
            }
        });
        let tx = tx.clone();
        tokio::spawn(async move {
            let mut d = TcpDeframer::new();
            // XRCE messages are small (a client's MTU): reads of larger
            // frames take a few turns, and 1024 idle connections hold 8 MiB
            let mut buf = vec![0u8; 8192];
            let hello_by = tokio::time::Instant::now() + hello;
            let mut said_hello = false;
            loop {
                let read = rd.read(&mut buf);
                let n = if said_hello {
                    read.await
                } else {
                    match tokio::time::timeout_at(hello_by, read).await {
                        Ok(r) => r,
                        Err(_) => {
                            tracing::warn!(
                                "XRCE TCP connection {id} from {from}: closed, no XRCE message \
                                 within {hello:?}"
                            );
                            break;
                        }
                    }
                };
                let n = match n {
                    Ok(0) | Err(_) => break,
                    Ok(n) => n,
                };
                d.push(&buf[..n]);
                while let Some(f) = d.next_frame() {
                    match f {
                        Ok(m) => {
                            said_hello = true;
                            if tx.send(Input::Xrce(Peer::Tcp(id), m)).await.is_err() {
                                return;
                            }
                        }
                        Err(e) => tracing::warn!("XRCE TCP connection {id}: {e}"),
                    }
                }
            }
            let _ = tx.send(Input::TcpClosed(id)).await;
        });
    }
}

/// The agent's own serial address (MicroXRCEAgent's is fixed at 0).
const SERIAL_ADDRESS: u8 = 0;

/// A serial line the agent serves.
struct SerialLine {
    port: serialport::TTYPort,
    /// The other end of the agent's own pseudo-terminal, held open.
    keep: Option<serialport::TTYPort>,
    /// A device (path, baud) to open again when the line goes away (a
    /// USB adapter unplugged, the other end of a pty pair gone).
    reopen: Option<(PathBuf, u32)>,
}

/// Opens `device` again once it is back (every half second until `stop`).
fn reopen_serial(
    device: &std::path::Path,
    baud: u32,
    stop: &AtomicBool,
) -> Option<serialport::TTYPort> {
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(500));
        let opened = serialport::new(device.to_string_lossy(), baud)
            .timeout(Duration::from_millis(100))
            .open_native();
        if let Ok(p) = opened {
            tracing::info!("serial line {} is back", device.display());
            return Some(p);
        }
    }
    None
}

/// Reader and writer threads of a serial line; the sender feeds the writer.
fn serial_threads(
    line: SerialLine,
    idx: u8,
    tx: mpsc::Sender<Input>,
    stop: &Arc<AtomicBool>,
) -> Result<std::sync::mpsc::Sender<(u8, Vec<u8>)>, StartError> {
    let SerialLine { port, keep, reopen } = line;
    let clone = |p: &serialport::TTYPort| {
        p.try_clone_native().map_err(|e| StartError::Serial {
            device: "serial".into(),
            why: e.to_string(),
        })
    };
    // the writer's port, replaced when the line is opened again
    let wport = Arc::new(std::sync::Mutex::new(Some(clone(&port)?)));
    let wport_r = wport.clone();
    let (out_tx, out_rx) = std::sync::mpsc::channel::<(u8, Vec<u8>)>();
    let stop_r = stop.clone();
    let mut rport = port;
    std::thread::Builder::new()
        .name("xrce-serial-rx".into())
        .spawn(move || {
            let _keep = keep;
            let mut d = SerialDecoder::new();
            let mut buf = [0u8; 4096];
            while !stop_r.load(Ordering::Relaxed) {
                let gone = match rport.read(&mut buf) {
                    Ok(0) => Some("hung up".to_string()),
                    Ok(n) => {
                        d.push(&buf[..n]);
                        while let Some(f) = d.next_frame() {
                            match f {
                                Ok(f) if f.dst == SERIAL_ADDRESS => {
                                    let m = Input::Xrce(Peer::Serial(idx, f.src), f.payload);
                                    if tx.blocking_send(m).is_err() {
                                        return;
                                    }
                                }
                                Ok(_) => {}
                                Err(e) => tracing::debug!("XRCE serial frame: {e}"),
                            }
                        }
                        None
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => None,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => None,
                    Err(e) => Some(e.to_string()),
                };
                let Some(why) = gone else { continue };
                let Some((device, baud)) = &reopen else {
                    // the agent's own pseudo-terminal, whose other end
                    // nobody holds now: someone may open it again
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                };
                tracing::warn!(
                    "serial line {} went away ({why}): opening it again when it is back",
                    device.display()
                );
                *wport_r.lock().unwrap_or_else(|e| e.into_inner()) = None;
                let Some(p) = reopen_serial(device, *baud, &stop_r) else {
                    return;
                };
                let Ok(w) = p.try_clone_native() else {
                    continue;
                };
                *wport_r.lock().unwrap_or_else(|e| e.into_inner()) = Some(w);
                rport = p;
                // a frame cut by the break is garbage
                d = SerialDecoder::new();
            }
        })
        .map_err(|e| StartError::Serial {
            device: "serial".into(),
            why: e.to_string(),
        })?;
    std::thread::Builder::new()
        .name("xrce-serial-tx".into())
        .spawn(move || {
            let mut framed = Vec::new();
            while let Ok((dst, m)) = out_rx.recv() {
                framed.clear();
                if serial::encode(SERIAL_ADDRESS, dst, &m, &mut framed).is_ok() {
                    // (while the line is away, dropped: reliable streams
                    // repeat what matters)
                    if let Some(w) = wport.lock().unwrap_or_else(|e| e.into_inner()).as_mut() {
                        let _ = w.write_all(&framed);
                        let _ = w.flush();
                    }
                }
            }
        })
        .map_err(|e| StartError::Serial {
            device: "serial".into(),
            why: e.to_string(),
        })?;
    Ok(out_tx)
}

struct Rtps {
    domain: Domain,
    send: Arc<UdpSocket>,
}

fn udp_socket(bind: SocketAddrV4, reuse: bool) -> std::io::Result<std::net::UdpSocket> {
    use socket2::{Domain as D, Protocol, Socket, Type};
    let s = Socket::new(D::IPV4, Type::DGRAM, Some(Protocol::UDP))?;
    if reuse {
        s.set_reuse_address(true)?;
        s.set_reuse_port(true)?;
    }
    let _ = s.set_recv_buffer_size(1 << 20);
    s.set_nonblocking(true)?;
    s.bind(&SocketAddr::V4(bind).into())?;
    Ok(s.into())
}

async fn rtps_reader(s: Arc<UdpSocket>, tx: mpsc::Sender<Input>) {
    let mut buf = vec![0u8; 65_536];
    loop {
        if let Ok((n, from)) = s.recv_from(&mut buf).await {
            let ip = match from.ip() {
                IpAddr::V4(a) => a.octets(),
                IpAddr::V6(_) => continue,
            };
            let l = Locator::udpv4(ip, from.port());
            if tx.send(Input::Rtps(l, buf[..n].to_vec())).await.is_err() {
                return;
            }
        }
    }
}

/// The DDS participant's sockets (unicast pair at the first free
/// participant index, multicast when asked) and its Domain.
async fn open_rtps(
    o: &RtpsOptions,
    readers: &mut JoinSet<()>,
    tx: &mpsc::Sender<Input>,
) -> Result<(Rtps, SocketAddr), StartError> {
    let address = interface_address(o).map_err(StartError::Rtps)?;
    let m = PortMapping::STANDARD;
    let mut found = None;
    let mut last = String::from("no participant index to try");
    let indices: Vec<u32> = match o.participant_index {
        Some(i) => vec![i],
        None => (0..=o.max_participant_index).collect(),
    };
    for i in indices {
        let (Some(mp), Some(up)) = (
            m.metatraffic_unicast(o.domain, i),
            m.user_unicast(o.domain, i),
        ) else {
            last = format!("no ports for participant index {i} in domain {}", o.domain);
            break;
        };
        let meta = match udp_socket(SocketAddrV4::new(address, mp), false) {
            Ok(s) => s,
            Err(e) => {
                last = format!("{address}:{mp}: {e}");
                continue;
            }
        };
        match udp_socket(SocketAddrV4::new(address, up), false) {
            Ok(user) => {
                found = Some((i, meta, user));
                break;
            }
            Err(e) => last = format!("{address}:{up}: {e}"),
        }
    }
    let (index, meta, user) = found.ok_or_else(|| {
        StartError::Rtps(format!(
            "no free participant index in domain {} on {address} ({last})",
            o.domain
        ))
    })?;
    let meta_addr = meta
        .local_addr()
        .map_err(|e| StartError::Rtps(e.to_string()))?;
    let tok = |s: std::net::UdpSocket| {
        UdpSocket::from_std(s).map_err(|e| StartError::Rtps(e.to_string()))
    };
    let meta = Arc::new(tok(meta)?);
    let user = Arc::new(tok(user)?);
    readers.spawn(rtps_reader(meta, tx.clone()));
    readers.spawn(rtps_reader(user.clone(), tx.clone()));
    let mut peers = Vec::new();
    let mut peer_hosts = Vec::new();
    for p in &o.peers {
        let (ip, port) = parse_peer(p).map_err(StartError::Rtps)?;
        match port {
            Some(port) => peers.push(Locator::udpv4(ip.octets(), port)),
            None => peer_hosts.push(ip.octets()),
        }
    }
    if o.peers.is_empty() && !o.multicast {
        peer_hosts.push(address.octets());
    }
    let prefix = participant::guid_prefix(entropy());
    let mut cfg = Config::udpv4(o.domain, index, prefix, address.octets())
        .ok_or_else(|| StartError::Rtps(format!("no ports for participant index {index}")))?
        .with_unicast_peers(&peer_hosts, o.max_participant_index);
    for l in peers {
        if !cfg.spdp_destinations.contains(&l) {
            cfg.spdp_destinations.push(l);
        }
    }
    if o.multicast {
        cfg = cfg.with_multicast();
        let group = Ipv4Addr::from(SPDP_MULTICAST_ADDRESS);
        for port in [m.spdp_multicast(o.domain), m.user_multicast(o.domain)]
            .into_iter()
            .flatten()
        {
            let s = udp_socket(SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, port), true)
                .and_then(|s| {
                    s.join_multicast_v4(&group, &address)?;
                    s.set_multicast_loop_v4(true)?;
                    Ok(s)
                })
                .map_err(|e| StartError::Rtps(format!("multicast {group}:{port}: {e}")))?;
            readers.spawn(rtps_reader(Arc::new(tok(s)?), tx.clone()));
        }
        let _ = socket2::SockRef::from(&*user).set_multicast_if_v4(&address);
    }
    cfg.lease_duration = o.lease;
    cfg.max_message_size = o.max_message_size_on(address);
    cfg.entity_name = Some("xrce-agent".into());
    let domain = Domain::new(cfg, Instant::now(), SystemTime::now());
    Ok((Rtps { domain, send: user }, meta_addr))
}

/// Ten random bytes for the GUID prefix (std's randomly keyed hasher,
/// fed the time and the process id).
fn entropy() -> [u8; 10] {
    use std::hash::{BuildHasher, Hasher};
    let t = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap_or_default()
        .as_nanos();
    let mut b = [0u8; 10];
    for (i, chunk) in b.chunks_mut(5).enumerate() {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u128(t);
        h.write_u32(std::process::id());
        h.write_usize(i);
        chunk.copy_from_slice(&h.finish().to_le_bytes()[..5]);
    }
    b
}

fn discovery_socket(
    a: SocketAddrV4,
    o: &RtpsOptions,
) -> Result<(UdpSocket, SocketAddr), StartError> {
    let s = udp_socket(a, true).map_err(|source| StartError::Bind {
        what: "XRCE discovery",
        addr: SocketAddr::V4(a),
        source,
    })?;
    // as MicroXRCEAgent: the group is joined whatever the DDS side does
    let iface = interface_address(o).unwrap_or(Ipv4Addr::LOCALHOST);
    let group = Ipv4Addr::new(239, 255, 0, 2);
    if let Err(e) = s.join_multicast_v4(&group, &iface) {
        tracing::warn!("XRCE discovery: cannot join {group} on {iface}: {e}");
    }
    let bound = s.local_addr().unwrap_or(SocketAddr::V4(a));
    let s = UdpSocket::from_std(s).map_err(|e| StartError::Rtps(e.to_string()))?;
    Ok((s, bound))
}

/// Answers discovery GET_INFO with the agent's UDP addresses.
async fn discovery_reader(s: Arc<UdpSocket>, udp: Vec<SocketAddr>, iface: Ipv4Addr) {
    let locators: Vec<TransportLocator> = udp
        .iter()
        .filter_map(|a| match a {
            SocketAddr::V4(v) => {
                let ip = if v.ip().is_unspecified() {
                    iface
                } else {
                    *v.ip()
                };
                Some(TransportLocator::Medium {
                    address: ip.octets(),
                    port: v.port(),
                })
            }
            SocketAddr::V6(_) => None,
        })
        .collect();
    let mut buf = vec![0u8; 2048];
    loop {
        let Ok((n, from)) = s.recv_from(&mut buf).await else {
            continue;
        };
        let Ok(m) = Message::decode(&buf[..n]) else {
            continue;
        };
        let Some(g) = discovery::as_request(&m) else {
            continue;
        };
        let reply = discovery::answer(
            m.header,
            g,
            AgentRepresentation::default(),
            locators.clone(),
        );
        if let Ok(reply) = reply.to_vec() {
            let _ = s.send_to(&reply, from).await;
        }
    }
}

/// Datagrams [`Driver::poll_udp`] takes in before the bridge's output is
/// sent.
const UDP_BATCH: usize = 64;

/// An XRCE message from `peer`, into the bridge; one it refuses is logged
/// (debug) and dropped.
fn xrce_input(bridge: &mut Bridge<Peer>, peer: Peer, bytes: &[u8]) {
    if let Err(e) = bridge.handle_input(peer, bytes, Instant::now()) {
        tracing::debug!("XRCE from {peer:?}: {e}");
    }
}

struct Driver {
    bridge: Bridge<Peer>,
    udp: Vec<Arc<UdpSocket>>,
    tcp: HashMap<u64, mpsc::Sender<Vec<u8>>>,
    serial: Vec<std::sync::mpsc::Sender<(u8, Vec<u8>)>>,
    rtps_send: Arc<UdpSocket>,
    readers: JoinSet<()>,
    store: Option<crate::xrce_state::Store>,
}

impl Driver {
    async fn run(mut self, mut rx: mpsc::Receiver<Input>, mut stop: oneshot::Receiver<()>) {
        // One timer for the whole loop, moved when the bridge's next
        // deadline moves.
        let mut timer = DriverTimer::quiet();
        let mut buf = vec![0u8; 65_536];
        loop {
            timer.set_next(self.bridge.poll_timeout());
            tokio::select! {
                biased;
                _ = &mut stop => break,
                _ = std::future::poll_fn(|cx| self.poll_udp(cx, &mut buf)) => {
                    // the other inputs get their turn however busy UDP is
                    for _ in 0..UDP_BATCH {
                        let Ok(m) = rx.try_recv() else { break };
                        self.input(m);
                    }
                }
                m = rx.recv() => match m {
                    Some(m) => {
                        self.input(m);
                        // take what else is there before sending
                        while let Ok(m) = rx.try_recv() {
                            self.input(m);
                        }
                    }
                    None => break,
                },
                () = std::future::poll_fn(|cx| timer.poll_fired(cx)) => {
                    self.bridge.handle_timeout(Instant::now());
                }
            }
            self.flush().await;
        }
        self.readers.abort_all();
        self.bridge.close(Instant::now());
        self.flush().await;
    }

    /// Takes what the XRCE UDP sockets hold (up to [`UDP_BATCH`]
    /// datagrams) straight into the bridge, with no task or channel
    /// between the socket and the state machine. Pending (every socket's
    /// readiness registered) when none had anything.
    fn poll_udp(&mut self, cx: &mut Context<'_>, buf: &mut [u8]) -> Poll<usize> {
        let mut taken = 0;
        for (idx, s) in self.udp.iter().enumerate() {
            while taken < UDP_BATCH {
                let mut rb = ReadBuf::new(buf);
                match s.poll_recv_from(cx, &mut rb) {
                    Poll::Ready(Ok(from)) => {
                        taken += 1;
                        let peer = Peer::Udp(idx as u8, from);
                        xrce_input(&mut self.bridge, peer, rb.filled());
                    }
                    // ICMP port unreachable from a client that went away
                    Poll::Ready(Err(e)) => {
                        tracing::debug!("XRCE UDP receive: {e}");
                        taken += 1;
                    }
                    Poll::Pending => break,
                }
            }
        }
        if taken > 0 {
            Poll::Ready(taken)
        } else {
            Poll::Pending
        }
    }

    fn input(&mut self, m: Input) {
        let now = Instant::now();
        match m {
            Input::Xrce(peer, bytes) => xrce_input(&mut self.bridge, peer, &bytes),
            Input::Rtps(from, bytes) => self.bridge.handle_datagram(from, &bytes, now),
            Input::TcpOpen(id, tx) => {
                self.tcp.insert(id, tx);
            }
            Input::TcpClosed(id) => {
                self.tcp.remove(&id);
            }
        }
    }

    /// Sends what the bridge has to send. With a state file, a client's
    /// ACKNACK waits for the input positions that allow it to be saved:
    /// what DDS took goes out first (RTPS datagrams, and XRCE messages to
    /// this agent's own readers), then the positions are committed, then
    /// the ACKNACKs go. Killed in between, the agent writes those samples
    /// again after its restart (at least once); killed later or stopped,
    /// it writes nothing twice.
    async fn flush(&mut self) {
        loop {
            while let Some(d) = self.bridge.poll_datagram() {
                if let Some(a) = d.destination.socket_addr() {
                    let _ = self.rtps_send.send_to(&d.payload, a).await;
                }
            }
            self.send_xrce().await;
            self.resave_if_reopened();
            while let Some(e) = self.bridge.poll_event() {
                log(&e);
                if let Some(store) = &mut self.store {
                    // (a failure is said once by the store, which then
                    // saves nothing until it can write again)
                    let _ = match &e {
                        BridgeEvent::ClientChanged { client } => {
                            match self.bridge.client_state(*client) {
                                Some(st) => store.save(&st),
                                None => Ok(()),
                            }
                        }
                        BridgeEvent::ClientDeleted { client } => store.remove(*client),
                        _ => Ok(()),
                    };
                }
            }
            if !self.save_positions() {
                break;
            }
        }
    }

    /// A state file that could not be written and now can: every session
    /// is saved anew, and those it holds that ended meanwhile forgotten.
    fn resave_if_reopened(&mut self) {
        let Some(store) = &mut self.store else {
            return;
        };
        if !store.reopened(Instant::now()) {
            return;
        }
        let live: Vec<courier_wire::xrce::ClientKey> = self.bridge.agent().clients().collect();
        for k in store.saved_clients() {
            if !live.contains(&k) && store.remove(k).is_err() {
                return;
            }
        }
        for k in live {
            if let Some(st) = self.bridge.client_state(k) {
                if store.save(&st).is_err() {
                    return;
                }
            }
        }
    }

    /// Commits the input positions that moved and lets the ACKNACKs they
    /// allow go; whether there were any.
    fn save_positions(&mut self) -> bool {
        let Some(store) = &mut self.store else {
            return false;
        };
        let moved = self.bridge.take_moved_positions();
        if moved.is_empty() {
            return false;
        }
        // A failure (said once by the store): holding the acknowledgements
        // would stall the clients for good; a restart after this may write
        // their last samples again (never lose one)
        let _ = store.save_positions(&moved);
        for (client, p) in &moved {
            self.bridge.positions_saved(*client, p);
        }
        true
    }

    async fn send_xrce(&mut self) {
        while let Some((to, m)) = self.bridge.poll_transmit() {
            match to {
                Peer::Udp(i, addr) => {
                    if let Some(s) = self.udp.get(usize::from(i)) {
                        let _ = s.send_to(&m, addr).await;
                    }
                }
                Peer::Tcp(id) => {
                    if let Some(t) = self.tcp.get(&id) {
                        // a connection that cannot keep up loses messages;
                        // reliable streams repair them
                        let _ = t.try_send(m);
                    }
                }
                Peer::Serial(i, dst) => {
                    if let Some(t) = self.serial.get(usize::from(i)) {
                        let _ = t.send((dst, m));
                    }
                }
            }
        }
    }
}

fn kind(o: ObjectId) -> String {
    o.kind().map_or_else(
        || format!("object kind {:#x}", o.kind_bits()),
        |k| format!("{k:?}").to_lowercase(),
    )
}

fn log(e: &BridgeEvent) {
    match e {
        BridgeEvent::ClientCreated {
            client,
            session_id,
            kept,
        } => tracing::info!(
            "session created: client 0x{:08X}, session {session_id:#04x}{}",
            u32::from(*client),
            if *kept { " (objects kept)" } else { "" }
        ),
        BridgeEvent::ClientDeleted { client } => {
            tracing::info!("session deleted: client 0x{:08X}", u32::from(*client))
        }
        BridgeEvent::ClientExpired {
            client,
            silent,
            for_client,
        } => match for_client {
            Some(new) => tracing::warn!(
                "session of client 0x{:08X} deleted to make room for client 0x{:08X}: it had \
                 said nothing for {} s (the agent holds its most sessions)",
                u32::from(*client),
                u32::from(*new),
                silent.as_secs()
            ),
            None => tracing::warn!(
                "session of client 0x{:08X} deleted: it said nothing for {} s (--client-timeout)",
                u32::from(*client),
                silent.as_secs()
            ),
        },
        BridgeEvent::ClientRefused { client, status } => tracing::warn!(
            "refused client 0x{:08X}: {}{}",
            u32::from(*client),
            status.name(),
            if *status == courier_wire::xrce::StatusCode::ERR_RESOURCES {
                " (the agent holds its most sessions, and none has been silent long enough to \
                 make room)"
            } else {
                ""
            }
        ),
        BridgeEvent::Created {
            client,
            object,
            status,
            reason,
        } => match reason {
            None => tracing::info!(
                "created {} {:#06x} of client 0x{:08X}: {}",
                kind(*object),
                object.0,
                u32::from(*client),
                status.name()
            ),
            Some(r) => tracing::warn!(
                "create {} {:#06x} of client 0x{:08X}: {}: {r}",
                kind(*object),
                object.0,
                u32::from(*client),
                status.name()
            ),
        },
        BridgeEvent::Deleted {
            client,
            object,
            status,
        } => tracing::info!(
            "deleted {:#06x} of client 0x{:08X}: {}",
            object.0,
            u32::from(*client),
            status.name()
        ),
        BridgeEvent::Unmatched {
            client,
            object,
            why,
        } => tracing::warn!(
            "{} {:#06x} of client 0x{:08X} does not match: {why}",
            kind(*object),
            object.0,
            u32::from(*client)
        ),
        BridgeEvent::WriteRefused {
            client,
            object,
            reason,
        } => tracing::warn!(
            "DDS refused a sample of {:#06x} of client 0x{:08X}: {reason}",
            object.0,
            u32::from(*client)
        ),
        BridgeEvent::SampleTooLarge {
            client,
            object,
            len,
            max,
        } => tracing::warn!(
            "{} {:#06x} of client 0x{:08X} reads best effort, and a sample of {len} bytes does \
             not fit its best-effort stream ({max} at most: the client's MTU): dropped, and so \
             will be every such sample (only reliable streams fragment: read reliably, or give \
             the client a larger MTU)",
            kind(*object),
            object.0,
            u32::from(*client)
        ),
        _ => {}
    }
}
