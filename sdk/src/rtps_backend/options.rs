//! `rtps://` URLs and the options they carry.

use std::net::{Ipv4Addr, SocketAddrV4};
use std::time::Duration;

use courier_wire::ros2::graph::GidSize;
use courier_wire::ros2::names::{NameError, Node};

use crate::session::ConnectError;

/// Largest datagram a participant on the loopback interface sends by
/// default: Fast DDS's default `maxMessageSize` (it accepts no more), below
/// both the 65 507-byte UDP limit and the 64 KiB MTU of `lo`, so nothing is
/// fragmented by IP. A 64 KiB sample then takes 2 datagrams instead of 5,
/// and each datagram costs a system call and a wake-up on each side
/// (BENCHMARKS.md: 64 KiB throughput about doubles). Other interfaces keep
/// Cyclone's 14720, which stays within IP reassembly's comfort on real links.
pub const LOOPBACK_MAX_MESSAGE_SIZE: usize = 65_500;

/// Options of the RTPS backend. The defaults follow the DDS standard
/// (multicast discovery on the default interface); tests and loopback-only
/// machines pass `interface=lo&peers=127.0.0.1`.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct RtpsOptions {
    /// DDS domain id (0..=232 with the standard port mapping).
    pub domain: u32,
    /// Network interface by name (`lo`) or IPv4 address; `None`: the first
    /// up, multicast-capable, non-loopback IPv4 interface, else loopback.
    pub interface: Option<String>,
    /// Unicast discovery peers: `ip` (every participant index
    /// 0..=[`RtpsOptions::max_participant_index`] there) or `ip:port`.
    pub peers: Vec<String>,
    /// Standard SPDP multicast discovery (239.255.0.1). Default on. The URL
    /// parser and [`SessionBuilder::peers`](crate::SessionBuilder::peers)
    /// turn it off when peers are given; a program that fills this struct
    /// itself sets it too (or starts from [`RtpsOptions::loopback`]).
    pub multicast: bool,
    /// A fixed participant index; `None` probes 0, 1, 2, … for free ports.
    pub participant_index: Option<u32>,
    /// Highest participant index probed and expanded for peers (default 20).
    pub max_participant_index: u32,
    /// `SO_RCVBUF` in bytes (default 1 MiB, as Cyclone DDS; capped by the
    /// kernel at `net.core.rmem_max`).
    pub recv_buffer: Option<usize>,
    /// `SO_SNDBUF` in bytes (default: the system's).
    pub send_buffer: Option<usize>,
    /// Lease announced to peers (default 10 s).
    pub lease: Duration,
    /// Keep polling for this long after each datagram or command instead of
    /// sleeping ([`crate::busy_poll`]); `None` (the default) never spins.
    pub busy_poll: Option<Duration>,
    /// Largest datagram sent (Cyclone's `MaxMessageSize`, Fast DDS's
    /// `maxMessageSize`); `None`: [`LOOPBACK_MAX_MESSAGE_SIZE`] on the
    /// loopback interface, else Cyclone's 14720.
    pub max_message_size: Option<usize>,
    /// Fragment size of large samples (Cyclone's `FragmentSize`); `None`:
    /// 1344. A size that does not fit in one datagram with its headers is
    /// lowered to the largest that does.
    pub fragment_size: Option<u16>,
    /// Largest sample this participant's readers take (URL option
    /// `max_sample_size`; also [`SessionBuilder::max_message_bytes`](crate::SessionBuilder::max_message_bytes));
    /// `None`: 16 MiB. A larger sample is given up: its readers skip it
    /// and say so ([`SessionEvent::SampleLost`](crate::SessionEvent::SampleLost)),
    /// and a reliable writer goes on with the next.
    pub max_sample_size: Option<usize>,
    /// Read user data on a thread of its own that blocks in `recvmmsg` and
    /// runs immediate subscriptions' callbacks
    /// ([`SubscriberBuilder::listen`](crate::SubscriberBuilder::listen))
    /// as each datagram arrives, as ORTE and Cyclone DDS do; default off:
    /// the driver task reads it. It saves a tokio wake-up per datagram
    /// (BENCHMARKS.md: round trips); `Subscriber` streams are fed from it too.
    pub receive_thread: bool,
    /// How `query` and `serve` tie replies to requests (URL option
    /// `services=auto|fastrtps|cyclonedds`).
    pub services: ServiceStyle,
    /// ROS 2: the node this session is in the ROS 2 graph (URL option
    /// `ros2_node=/namespace/name`, or [`RtpsOptions::with_ros2_node`]):
    /// the session publishes it on `ros_discovery_info` with its readers
    /// and writers, and reads the other participants' nodes (see
    /// [`super::ros2`]). `None` (the default): neither.
    pub ros2_node: Option<Node>,
    /// ROS 2: read the other participants' nodes without being one (URL
    /// option `ros2_graph=true`); implied by [`RtpsOptions::ros2_node`].
    pub ros2_graph: bool,
    /// ROS 2: the size of the GIDs written (URL option `ros2_gid=16|24`):
    /// 16 bytes for ROS 2 Iron and later (the default), 24 for Humble and
    /// older, whose rmws read no other. Either size is read.
    pub ros2_gid: GidSize,
}

/// The two ways ROS 2's DDS-based rmw implementations tie a reply to its
/// request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum ServiceStyle {
    /// Each peer's own (the default): a request that carries its related
    /// sample identity is answered so, a request from a Cyclone DDS
    /// participant without one by header; a query goes by header when
    /// every service it matched is a Cyclone DDS participant.
    #[default]
    Auto,
    /// rmw_fastrtps's (and rmw_connextdds's): the reply carries the
    /// request's identity as inline QoS.
    FastRtps,
    /// rmw_cyclonedds's: a 16-byte header (client id, request number)
    /// before the body of each request and reply.
    CycloneDds,
}

impl ServiceStyle {
    pub(crate) fn wire(self) -> Option<courier_wire::dds::RpcStyle> {
        match self {
            ServiceStyle::Auto => None,
            ServiceStyle::FastRtps => Some(courier_wire::dds::RpcStyle::SampleIdentity),
            ServiceStyle::CycloneDds => Some(courier_wire::dds::RpcStyle::RequestHeader),
        }
    }
}

impl RtpsOptions {
    /// Loopback only on `domain`: interface `lo`, unicast discovery of
    /// 127.0.0.1, no multicast. Nothing leaves the machine.
    ///
    /// ```
    /// let o = courier::rtps_backend::RtpsOptions::loopback(7);
    /// assert_eq!((o.domain, o.multicast, o.peers.len()), (7, false, 1));
    /// ```
    pub fn loopback(domain: u32) -> Self {
        RtpsOptions {
            domain,
            interface: Some("lo".into()),
            peers: vec!["127.0.0.1".into()],
            multicast: false,
            ..RtpsOptions::default()
        }
    }
}

impl Default for RtpsOptions {
    fn default() -> Self {
        RtpsOptions {
            domain: 0,
            interface: None,
            peers: Vec::new(),
            multicast: true,
            participant_index: None,
            max_participant_index: 20,
            recv_buffer: None,
            send_buffer: None,
            lease: Duration::from_secs(10),
            busy_poll: None,
            max_message_size: None,
            fragment_size: None,
            max_sample_size: None,
            receive_thread: false,
            services: ServiceStyle::Auto,
            ros2_node: None,
            ros2_graph: false,
            ros2_gid: GidSize::Sixteen,
        }
    }
}

fn bad(url: &str, why: impl Into<String>) -> ConnectError {
    ConnectError::BadUrl {
        url: url.to_string(),
        why: why.into(),
    }
}

fn parse_bool(url: &str, key: &str, v: &str) -> Result<bool, ConnectError> {
    match v {
        "1" | "true" | "on" | "yes" => Ok(true),
        "0" | "false" | "off" | "no" => Ok(false),
        _ => Err(bad(url, format!("{key}={v:?}: expected true or false"))),
    }
}

fn parse_num<T: std::str::FromStr>(url: &str, key: &str, v: &str) -> Result<T, ConnectError> {
    v.parse()
        .map_err(|_| bad(url, format!("{key}={v:?}: expected a number")))
}

/// A node's fully qualified name (`/ns/name`, `/name`) as its namespace
/// and name.
pub(crate) fn parse_node(full: &str) -> Result<Node, NameError> {
    let (ns, name) = full.rsplit_once('/').unwrap_or(("", full));
    if !full.starts_with('/') {
        // Node::new says why a relative namespace is refused
        return Node::new(full, "node");
    }
    Node::new(ns, name)
}

impl RtpsOptions {
    /// These options with the session as ROS 2 node `name` in `namespace`
    /// (see [`RtpsOptions::ros2_node`]); an error names the ROS 2 naming
    /// rule the names break.
    ///
    /// ```
    /// use courier::rtps_backend::RtpsOptions;
    /// let o = RtpsOptions::default().with_ros2_node("/robot", "driver").unwrap();
    /// assert_eq!(o.ros2_node.unwrap().to_string(), "/robot/driver");
    /// assert!(RtpsOptions::default().with_ros2_node("/", "2d").is_err());
    /// ```
    pub fn with_ros2_node(mut self, namespace: &str, name: &str) -> Result<Self, NameError> {
        self.ros2_node = Some(Node::new(namespace, name)?);
        Ok(self)
    }

    /// Whether the session reads the ROS 2 graph (a node, or `ros2_graph`).
    pub fn reads_ros2_graph(&self) -> bool {
        self.ros2_graph || self.ros2_node.is_some()
    }

    /// Parses `rtps://<domain>?key=value&…` (or `rtps://?domain=N&…`, as
    /// `xrce+udp://` URLs name theirs; not both). Keys: `interface`, `peers`
    /// (comma-separated `ip` or `ip:port`), `multicast` (true/false),
    /// `index` (participant index), `max_index`, `recv_buffer`,
    /// `send_buffer` (bytes), `lease_ms`, `busy_poll_us`, `max_message_size`,
    /// `fragment_size` (bytes), `receive_thread` (true/false), `services`
    /// (auto/fastrtps/cyclonedds), `ros2_node` (`/namespace/name`),
    /// `ros2_graph` (true/false), `ros2_gid` (16/24), `max_sample_size`
    /// (bytes). `peers` without `multicast` turns multicast off; an empty
    /// `peers=` is an error (never multicast by accident). `lease_ms` is at
    /// least 100. Anything else is an error naming the key.
    ///
    /// ```
    /// use courier::rtps_backend::RtpsOptions;
    /// let o = RtpsOptions::from_url("rtps://7?interface=lo&peers=127.0.0.1").unwrap();
    /// assert_eq!((o.domain, o.multicast), (7, false));
    /// assert!(RtpsOptions::from_url("rtps://0?colour=blue").is_err());
    /// ```
    pub fn from_url(url: &str) -> Result<Self, ConnectError> {
        let rest = url
            .strip_prefix("rtps://")
            .or_else(|| url.strip_prefix("rtps:"))
            .ok_or_else(|| bad(url, "an RTPS URL starts with rtps://"))?;
        let (domain, query) = rest.split_once('?').unwrap_or((rest, ""));
        let domain = domain.trim_end_matches('/');
        let mut o = RtpsOptions::default();
        let in_path = !domain.is_empty();
        if in_path {
            o.domain = domain
                .parse()
                .map_err(|_| bad(url, format!("domain {domain:?} is not a number")))?;
        }
        let mut multicast_set = false;
        let mut seen: Vec<&str> = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair
                .split_once('=')
                .ok_or_else(|| bad(url, format!("option {pair:?} has no value")))?;
            // a second value would silently replace the first
            if seen.contains(&k) {
                return Err(bad(
                    url,
                    format!("option {k:?} is given twice (peers take a comma-separated list)"),
                ));
            }
            seen.push(k);
            match k {
                // `rtps://?domain=N`, as xrce+udp:// URLs name theirs
                "domain" if in_path => {
                    return Err(bad(
                        url,
                        format!("the domain is given twice: rtps://{domain} and domain={v}"),
                    ));
                }
                "domain" => {
                    o.domain = v
                        .parse()
                        .map_err(|_| bad(url, format!("domain {v:?} is not a number")))?;
                }
                "interface" => o.interface = Some(v.to_string()),
                "peers" => {
                    o.peers = v
                        .split(',')
                        .filter(|p| !p.is_empty())
                        .map(str::to_string)
                        .collect();
                    // `peers=$UNSET_VAR` must not fall back to multicast
                    if o.peers.is_empty() {
                        return Err(bad(
                            url,
                            format!(
                                "peers={v:?} names no peer: give host[,host…], or leave \
                                 the option out for multicast discovery"
                            ),
                        ));
                    }
                }
                "multicast" => {
                    o.multicast = parse_bool(url, k, v)?;
                    multicast_set = true;
                }
                "index" => o.participant_index = Some(parse_num(url, k, v)?),
                "max_index" => o.max_participant_index = parse_num(url, k, v)?,
                "recv_buffer" => o.recv_buffer = Some(parse_num(url, k, v)?),
                "send_buffer" => o.send_buffer = Some(parse_num(url, k, v)?),
                "lease_ms" => {
                    let ms: u64 = parse_num(url, k, v)?;
                    // peers drop a participant silent for its lease: below
                    // this, one late datagram does
                    if ms < 100 {
                        return Err(bad(
                            url,
                            format!("{k}={ms}: a lease under 100 ms expires between announcements"),
                        ));
                    }
                    o.lease = Duration::from_millis(ms);
                }
                "max_message_size" => {
                    let n: usize = parse_num(url, k, v)?;
                    if !(512..=65_507).contains(&n) {
                        return Err(bad(
                            url,
                            format!("{k}={n}: a UDP datagram carries 512 to 65507 bytes here"),
                        ));
                    }
                    o.max_message_size = Some(n);
                }
                "fragment_size" => {
                    let n: u16 = parse_num(url, k, v)?;
                    if !(64..=65_000).contains(&n) {
                        return Err(bad(url, format!("{k}={n}: expected 64 to 65000 bytes")));
                    }
                    o.fragment_size = Some(n);
                }
                "max_sample_size" => {
                    let n: usize = parse_num(url, k, v)?;
                    if n == 0 {
                        return Err(bad(url, format!("{k}=0: a sample of 0 bytes is no sample")));
                    }
                    o.max_sample_size = Some(n);
                }
                "receive_thread" => o.receive_thread = parse_bool(url, k, v)?,
                "services" => {
                    o.services = match v {
                        "auto" => ServiceStyle::Auto,
                        "fastrtps" => ServiceStyle::FastRtps,
                        "cyclonedds" => ServiceStyle::CycloneDds,
                        _ => {
                            return Err(bad(
                                url,
                                format!("{k}={v}: expected auto, fastrtps or cyclonedds"),
                            ))
                        }
                    }
                }
                "ros2_node" => {
                    o.ros2_node = Some(parse_node(v).map_err(|e| bad(url, e.to_string()))?)
                }
                "ros2_graph" => o.ros2_graph = parse_bool(url, k, v)?,
                "ros2_gid" => {
                    o.ros2_gid = parse_num::<usize>(url, k, v)
                        .ok()
                        .and_then(GidSize::from_bytes)
                        .ok_or_else(|| {
                            bad(
                                url,
                                format!(
                                    "{k}={v}: expected 16 (ROS 2 Iron and later) or 24 (Humble)"
                                ),
                            )
                        })?
                }
                "busy_poll_us" => {
                    let w = Duration::from_micros(parse_num(url, k, v)?);
                    crate::busy_poll::check_window(w)
                        .map_err(|why| bad(url, format!("{k}={v}: {why}")))?;
                    o.busy_poll = Some(w).filter(|d| !d.is_zero())
                }
                _ => {
                    return Err(bad(
                        url,
                        format!(
                        "unknown option {k:?} (known: domain, interface, peers, multicast, index, \
                             max_index, recv_buffer, send_buffer, lease_ms, busy_poll_us, \
                             max_message_size, fragment_size, max_sample_size, receive_thread, \
                             services, ros2_node, ros2_graph, ros2_gid)"
                    ),
                    ))
                }
            }
        }
        if o.domain > 232 {
            return Err(bad(
                url,
                format!(
                    "domain {} is above 232, the highest the standard port mapping allows",
                    o.domain
                ),
            ));
        }
        if !o.peers.is_empty() && !multicast_set {
            o.multicast = false;
        }
        for p in &o.peers {
            parse_peer(p).map_err(|e| bad(url, e))?;
        }
        Ok(o)
    }

    /// The largest datagram sent on the interface with `address`
    /// ([`RtpsOptions::max_message_size`] or its default there).
    pub fn max_message_size_on(&self, address: Ipv4Addr) -> usize {
        match self.max_message_size {
            Some(n) => n,
            None if address.is_loopback() => LOOPBACK_MAX_MESSAGE_SIZE,
            None => courier_wire::rtps::participant::DEFAULT_MAX_MESSAGE_SIZE,
        }
    }
}

/// A peer of [`RtpsOptions::peers`]: its address and, if given, its port.
pub fn parse_peer(p: &str) -> Result<(Ipv4Addr, Option<u16>), String> {
    let p = p.trim();
    if let Ok(a) = p.parse::<SocketAddrV4>() {
        return Ok((*a.ip(), Some(a.port())));
    }
    if let Ok(a) = p.parse::<Ipv4Addr>() {
        return Ok((a, None));
    }
    if p == "localhost" {
        return Ok((Ipv4Addr::LOCALHOST, None));
    }
    if let Some(port) = p.strip_prefix("localhost:") {
        if let Ok(port) = port.parse::<u16>() {
            return Ok((Ipv4Addr::LOCALHOST, Some(port)));
        }
    }
    Err(format!(
        "peer {p:?} is not an IPv4 address or address:port (or localhost[:port])"
    ))
}

/// Builder-level overrides, applied over the URL's options.
#[derive(Debug, Clone, Default)]
pub(crate) struct RtpsOverrides {
    pub(crate) interface: Option<String>,
    pub(crate) peers: Option<Vec<String>>,
    pub(crate) multicast: Option<bool>,
    pub(crate) participant_index: Option<u32>,
    pub(crate) recv_buffer: Option<usize>,
    pub(crate) send_buffer: Option<usize>,
    pub(crate) busy_poll: Option<Duration>,
    pub(crate) receive_thread: Option<bool>,
    pub(crate) max_sample_size: Option<usize>,
    pub(crate) ros2_node: Option<Result<Node, NameError>>,
}

impl RtpsOverrides {
    /// Applies the overrides; a ROS 2 node name that breaks the rules is
    /// the error.
    pub(crate) fn apply(&self, o: &mut RtpsOptions) -> Result<(), NameError> {
        if let Some(i) = &self.interface {
            o.interface = Some(i.clone());
        }
        if let Some(p) = &self.peers {
            o.peers = p.clone();
            if self.multicast.is_none() && !p.is_empty() {
                o.multicast = false;
            }
        }
        if let Some(m) = self.multicast {
            o.multicast = m;
        }
        if let Some(i) = self.participant_index {
            o.participant_index = Some(i);
        }
        if let Some(n) = self.recv_buffer {
            o.recv_buffer = Some(n);
        }
        if let Some(n) = self.send_buffer {
            o.send_buffer = Some(n);
        }
        if let Some(d) = self.busy_poll {
            o.busy_poll = Some(d);
        }
        if let Some(on) = self.receive_thread {
            o.receive_thread = on;
        }
        if let Some(n) = self.max_sample_size {
            o.max_sample_size = Some(n);
        }
        if let Some(n) = &self.ros2_node {
            o.ros2_node = Some(n.clone()?);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        let o =
            RtpsOptions::from_url("rtps://0?interface=lo&peers=127.0.0.1&multicast=false").unwrap();
        assert_eq!(o.interface.as_deref(), Some("lo"));
        assert_eq!(o.peers, ["127.0.0.1"]);
        assert!(!o.multicast);
        let o = RtpsOptions::from_url("rtps://3").unwrap();
        assert_eq!(o.domain, 3);
        assert!(o.multicast, "the standard default");
        let o = RtpsOptions::from_url("rtps://?domain=192&interface=lo&peers=127.0.0.1").unwrap();
        assert_eq!((o.domain, o.multicast), (192, false));
        let o = RtpsOptions::from_url("rtps://1?peers=127.0.0.1:7410,127.0.0.2&multicast=true")
            .unwrap();
        assert!(o.multicast);
        assert_eq!(o.peers.len(), 2);
        let o = RtpsOptions::from_url(
            "rtps://0?index=4&max_index=9&recv_buffer=1000000&send_buffer=2000&lease_ms=500&busy_poll_us=50",
        )
        .unwrap();
        assert_eq!(o.participant_index, Some(4));
        assert_eq!(o.max_participant_index, 9);
        assert_eq!(o.recv_buffer, Some(1_000_000));
        assert_eq!(o.send_buffer, Some(2000));
        assert_eq!(o.lease, Duration::from_millis(500));
        assert_eq!(o.busy_poll, Some(Duration::from_micros(50)));
        assert!(!o.receive_thread);
        assert_eq!(o.max_sample_size, None);
        let o = RtpsOptions::from_url("rtps://0?peers=localhost:7410,localhost").unwrap();
        assert_eq!(o.peers, ["localhost:7410", "localhost"]);
        assert_eq!(
            parse_peer("localhost:7410"),
            Ok((Ipv4Addr::LOCALHOST, Some(7410)))
        );
        let e = RtpsOptions::from_url("rtps://0?interface=lo&peers=127.0.0.1&interface=eth0")
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("option \"interface\" is given twice"),
            "{e}"
        );
        let o = RtpsOptions::from_url("rtps://0?max_sample_size=67108864").unwrap();
        assert_eq!(o.max_sample_size, Some(64 << 20));
        let e = RtpsOptions::from_url("rtps://0?max_sample_size=0").unwrap_err();
        assert!(e.to_string().contains("max_sample_size=0"), "{e}");
        assert!(
            RtpsOptions::from_url("rtps://0?receive_thread=true")
                .unwrap()
                .receive_thread
        );
        let o = RtpsOptions::from_url("rtps://0?max_message_size=9000&fragment_size=1400").unwrap();
        assert_eq!(
            (o.max_message_size, o.fragment_size),
            (Some(9000), Some(1400))
        );
        for (u, needle) in [
            ("rtps://0?max_message_size=70000", "65507"),
            ("rtps://0?max_message_size=100", "512"),
            ("rtps://0?fragment_size=70000", "fragment_size"),
            ("rtps://0?fragment_size=10", "64 to 65000"),
            ("rtps://x", "domain"),
            ("rtps://233", "232"),
            ("rtps://0?colour=blue", "colour"),
            ("rtps://0?multicast=maybe", "multicast"),
            ("rtps://0?receive_thread=2", "receive_thread"),
            ("rtps://0?peers=not-an-ip", "not-an-ip"),
            // an empty list (an unset shell variable) is not multicast
            ("rtps://0?interface=lo&peers=", "names no peer"),
            ("rtps://0?peers=,", "names no peer"),
            ("rtps://0?lease_ms=0", "under 100 ms"),
            ("rtps://0?lease_ms=99", "under 100 ms"),
            // a window that would hold a CPU for nothing
            (
                "rtps://0?busy_poll_us=1000001",
                "busy_poll_us=1000001: a window of 1.000001s is longer than 1s",
            ),
            ("rtps://0?index", "index"),
            ("ipc://x", "rtps://"),
            (
                "rtps://3?domain=4",
                "the domain is given twice: rtps://3 and domain=4",
            ),
            ("rtps://?domain=233", "232"),
            ("rtps://?domain=x", "domain \"x\" is not a number"),
        ] {
            let e = RtpsOptions::from_url(u).unwrap_err().to_string();
            assert!(e.contains(needle), "{u}: {e}");
        }
    }

    #[test]
    fn ros2_options() {
        let o = RtpsOptions::from_url("rtps://0?ros2_node=/robot/arm/ctl&ros2_gid=24").unwrap();
        let n = o.ros2_node.clone().unwrap();
        assert_eq!((n.namespace(), n.name()), ("/robot/arm", "ctl"));
        assert_eq!(o.ros2_gid, GidSize::TwentyFour);
        assert!(o.reads_ros2_graph());
        let o = RtpsOptions::from_url("rtps://0?ros2_node=/talker").unwrap();
        let n = o.ros2_node.unwrap();
        assert_eq!((n.namespace(), n.name()), ("/", "talker"));
        let o = RtpsOptions::from_url("rtps://0?ros2_graph=true").unwrap();
        assert!(o.ros2_node.is_none() && o.reads_ros2_graph());
        assert!(!RtpsOptions::default().reads_ros2_graph());
        assert_eq!(RtpsOptions::default().ros2_gid, GidSize::Sixteen);
        for (u, needle) in [
            ("rtps://0?ros2_node=talker", "start with `/`"),
            ("rtps://0?ros2_node=/ns/", "empty"),
            ("rtps://0?ros2_node=/2fast", "digit"),
            ("rtps://0?ros2_gid=20", "16 (ROS 2 Iron"),
            ("rtps://0?ros2_graph=perhaps", "ros2_graph"),
        ] {
            let e = RtpsOptions::from_url(u).unwrap_err().to_string();
            assert!(e.contains(needle), "{u}: {e}");
        }
    }

    #[test]
    fn loopback_participants_send_datagrams_as_large_as_fast_dds_takes() {
        let lo = Ipv4Addr::LOCALHOST;
        let eth = Ipv4Addr::new(192, 168, 1, 20);
        let o = RtpsOptions::default();
        assert_eq!(o.max_message_size_on(lo), 65_500);
        assert_eq!(o.max_message_size_on(eth), 14_720, "Cyclone's default");
        let o = RtpsOptions::from_url("rtps://0?max_message_size=1400").unwrap();
        assert_eq!(
            (o.max_message_size_on(lo), o.max_message_size_on(eth)),
            (1400, 1400)
        );
    }
}
