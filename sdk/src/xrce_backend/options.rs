//! `xrce+udp://`, `xrce+tcp://` and `xrce+serial://` URLs and the
//! [`XrceOptions`] they carry.

use std::collections::BTreeMap;
use std::time::Duration;

use super::discovery::XrceDiscovery;
use crate::session::ConnectError;

/// How the session reaches its agent.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum XrceTransport {
    /// One XRCE message per datagram, from a connected socket (`host:port`).
    Udp(String),
    /// A TCP connection (`host:port`): each message behind its 2-byte
    /// little-endian length, written in one call, with `TCP_NODELAY`.
    Tcp(String),
    /// A serial line (a tty path) in raw mode at `baud`, with the HDLC-like
    /// framing and CRC-16/ARC of eProsima's stream framing; this client is
    /// address 1, the agent 0.
    Serial {
        /// The tty (`/dev/ttyUSB0`, a pseudo-terminal).
        path: String,
        /// Line speed (one of the POSIX speeds, 50 to 4 000 000).
        baud: u32,
    },
}

impl std::fmt::Display for XrceTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            XrceTransport::Udp(a) => write!(f, "xrce+udp://{a}"),
            XrceTransport::Tcp(a) => write!(f, "xrce+tcp://{a}"),
            XrceTransport::Serial { path, baud } => write!(f, "xrce+serial://{path}?baud={baud}"),
        }
    }
}

/// How CREATE describes the session's entities to the agent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum XrceRepresentation {
    /// `IN_BINARY` (the default): the type name, topic name and QoS in
    /// eProsima's binary layout, generated from the Rust type. A keyed
    /// type's *topic* goes as XML all the same: the binary topic has no
    /// key kind, and an agent makes binary topics unkeyed.
    #[default]
    Binary,
    /// `AS_XML_STRING`: Fast DDS XML snippets generated from the type and
    /// the QoS.
    Xml,
    /// `BY_REFERENCE`: profile names of the agent's reference file (its
    /// `-r` option), by [`XrceOptions::reference`].
    Reference,
}

/// CREATE's creation mode (flags `REUSE` and `REPLACE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum XrceCreation {
    /// Replace what exists under the same object id (the eProsima
    /// examples' choice).
    #[default]
    Replace,
    /// Keep what exists if it matches, replace it otherwise.
    ReuseOrReplace,
    /// Neither: an existing object is an error (`ERR_ALREADY_EXISTS`).
    Create,
}

/// The kinds of entity a reference profile names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[non_exhaustive]
pub enum RefKind {
    /// The participant (one per session).
    Participant,
    /// A topic.
    Topic,
    /// A data writer.
    DataWriter,
    /// A data reader.
    DataReader,
    /// A requester (a query's client).
    Requester,
    /// A replier (a service).
    Replier,
}

impl RefKind {
    /// The name used in URLs and default profile names: `participant`,
    /// `topic`, `data_writer`, `data_reader`, `requester`, `replier`.
    pub fn name(self) -> &'static str {
        match self {
            RefKind::Participant => "participant",
            RefKind::Topic => "topic",
            RefKind::DataWriter => "data_writer",
            RefKind::DataReader => "data_reader",
            RefKind::Requester => "requester",
            RefKind::Replier => "replier",
        }
    }

    fn parse(s: &str) -> Option<Self> {
        [
            RefKind::Participant,
            RefKind::Topic,
            RefKind::DataWriter,
            RefKind::DataReader,
            RefKind::Requester,
            RefKind::Replier,
        ]
        .into_iter()
        .find(|k| k.name() == s)
    }
}

/// Options of the XRCE backend. From a URL with [`XrceOptions::from_url`]
/// (every field has a query key, listed with it), or built in code and
/// given to [`SessionBuilder::xrce`](crate::SessionBuilder::xrce).
///
/// ```
/// use courier::xrce_backend::{XrceOptions, XrceRepresentation, XrceTransport};
/// let o = XrceOptions::from_url(
///     "xrce+udp://127.0.0.1:8888?key=0xAABBCCDD&mtu=1024&representation=xml",
/// ).unwrap();
/// assert_eq!(o.transport, XrceTransport::Udp("127.0.0.1:8888".into()));
/// assert_eq!((o.client_key, o.mtu), (Some(0xAABB_CCDD), 1024));
/// assert_eq!(o.representation, XrceRepresentation::Xml);
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct XrceOptions {
    /// Where the agent is.
    pub transport: XrceTransport,
    /// The client key (`key=`, decimal or `0x` hex; never 0); `None`: a
    /// random one per session.
    ///
    /// A key names one client at a time: an agent takes a second session
    /// with a live session's key as that client reconnecting (the XRCE
    /// rule), so two sessions sharing a key take the agent's session from
    /// each other, over and over (`AgentLost` / `SessionRecreated` events),
    /// and lose what was in flight. Give each a key of its own, or none.
    pub client_key: Option<u32>,
    /// The session id (`session=`): 0x81 as eProsima's library uses;
    /// below 0x80 every message carries the client key.
    pub session_id: u8,
    /// The largest message (`mtu=`): 508 by default, what eProsima's
    /// client advertises over its 512-byte transports. Larger samples are
    /// fragmented on reliable streams and refused on best-effort ones.
    pub mtu: u16,
    /// The reliable window in messages (`depth=`, default 16: the agent's).
    pub depth: u16,
    /// Reliable messages queued beyond the window (`history=`, default
    /// 2048); a publish that finds it full waits.
    pub history: u16,
    /// CREATE's creation mode (`creation=replace|reuse|create`).
    pub creation: XrceCreation,
    /// How entities are described (`representation=binary|xml|reference`).
    pub representation: XrceRepresentation,
    /// The DDS domain of the session's participant (`domain=`).
    pub domain: i16,
    /// Ping the agent after this much silence (`keepalive_ms=`, 1000).
    pub keepalive: Duration,
    /// The agent is lost after this much silence (`lost_ms=`, 3000).
    pub lost_after: Duration,
    /// CREATE_CLIENT attempts when connecting (`attempts=`, 10, 1 s apart
    /// as in eProsima's library).
    pub connect_attempts: u32,
    /// Time between CREATE_CLIENT attempts (`attempt_ms=`, 1000).
    pub connect_interval: Duration,
    /// How long a publish or open waits for a lost agent to come back
    /// before it fails (`wait_ms=`, 10 000).
    pub agent_wait: Duration,
    /// How long [`Session::close`](crate::Session::close) waits for the
    /// agent to acknowledge what the reliable streams still hold before it
    /// deletes the session (`linger_ms=`, 3000; less if the agent is lost
    /// meanwhile). Writes it gives up on are logged as a warning; 0 deletes
    /// at once, as eProsima's `uxr_delete_session` does.
    pub linger: Duration,
    /// Reference profile names (`ref.<kind>.<name>=<profile>`, kind one of
    /// [`RefKind::name`]; `ref.participant=<profile>` for the participant).
    /// Without one, an entity's profile is `<name>_<kind>`
    /// (`chatter_data_writer`) and the participant's
    /// `default_xrce_participant`.
    pub references: BTreeMap<(RefKind, String), String>,
    /// Find the agent by discovery before connecting (`xrce+udp://` with
    /// no address and `discover=<addr>,<addr>,…`, where an address is an
    /// agent's discovery or XRCE port, `ip:port`, or `multicast` for
    /// 239.255.0.2:7400; `discover_attempts=`, `discover_ms=`). The
    /// session connects over UDP to the first agent that answers, and
    /// stays with it: a lost agent is waited for, not rediscovered.
    /// [`XrceOptions::transport`] is then `Udp("")` until connected.
    pub discovery: Option<XrceDiscovery>,
}

impl XrceOptions {
    /// Defaults for `transport`.
    pub fn new(transport: XrceTransport) -> Self {
        XrceOptions {
            transport,
            client_key: None,
            session_id: 0x81,
            mtu: 508,
            depth: 16,
            history: 2048,
            creation: XrceCreation::Replace,
            representation: XrceRepresentation::Binary,
            domain: 0,
            keepalive: Duration::from_secs(1),
            lost_after: Duration::from_secs(3),
            connect_attempts: 10,
            connect_interval: Duration::from_secs(1),
            agent_wait: Duration::from_secs(10),
            linger: Duration::from_secs(3),
            references: BTreeMap::new(),
            discovery: None,
        }
    }

    /// Defaults, connecting over UDP to the first agent `discovery` finds.
    pub fn discovered(discovery: XrceDiscovery) -> Self {
        XrceOptions {
            discovery: Some(discovery),
            ..XrceOptions::new(XrceTransport::Udp(String::new()))
        }
    }

    /// Names the reference profile of an entity (see
    /// [`XrceOptions::references`]); `name` is the topic or service, ignored
    /// for the participant.
    pub fn reference(mut self, kind: RefKind, name: &str, profile: &str) -> Self {
        let name = if kind == RefKind::Participant {
            ""
        } else {
            name
        };
        self.references
            .insert((kind, name.to_string()), profile.to_string());
        self
    }

    /// The reference profile of an entity.
    pub fn profile(&self, kind: RefKind, name: &str) -> String {
        let name = if kind == RefKind::Participant {
            ""
        } else {
            name
        };
        if let Some(p) = self.references.get(&(kind, name.to_string())) {
            return p.clone();
        }
        match kind {
            RefKind::Participant => "default_xrce_participant".into(),
            k => format!("{name}_{}", k.name()),
        }
    }

    /// Parses `xrce+udp://host:port?…`, `xrce+tcp://host:port?…` or
    /// `xrce+serial:///dev/tty…?baud=115200&…`.
    pub fn from_url(url: &str) -> Result<Self, ConnectError> {
        let bad = |why: String| ConnectError::BadUrl {
            url: url.to_string(),
            why,
        };
        let (scheme, rest) = url
            .split_once("://")
            .ok_or_else(|| bad("no scheme".into()))?;
        if let Some((_, frag)) = rest.split_once('#') {
            return Err(bad(format!(
                "#{frag}: an XRCE URL has no #fragment (options go after ?)"
            )));
        }
        let (addr, query) = rest.split_once('?').unwrap_or((rest, ""));
        let mut pairs = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair
                .split_once('=')
                .ok_or_else(|| bad(format!("option {pair:?} has no value (key=value)")))?;
            // a second value would silently replace the first
            if pairs.iter().any(|(seen, _)| *seen == k) {
                return Err(bad(format!("option {k:?} is given twice")));
            }
            pairs.push((k, v));
        }
        let host_port = |default_port: u16| -> Result<String, ConnectError> {
            if addr.is_empty() {
                return Err(bad("no agent address (host:port)".into()));
            }
            if addr.contains('/') {
                return Err(bad(format!("{addr:?} is not host:port")));
            }
            // [v6]:port, [v6], host:port, host
            let (host, port) = match addr.strip_prefix('[') {
                Some(v6) => match v6.split_once(']') {
                    Some((h, "")) => (h, None),
                    Some((h, p)) => match p.strip_prefix(':') {
                        Some(p) => (h, Some(p)),
                        None => return Err(bad(format!("{addr:?} is not [address]:port"))),
                    },
                    None => return Err(bad(format!("{addr:?} lacks its closing ]"))),
                },
                None if addr.matches(':').count() > 1 => {
                    return Err(bad(format!(
                        "{addr:?}: an IPv6 address goes in brackets ([::1]:8888)"
                    )))
                }
                None => match addr.split_once(':') {
                    Some((h, p)) => (h, Some(p)),
                    None => (addr, None),
                },
            };
            if host.is_empty() {
                return Err(bad(format!("{addr:?} names no host")));
            }
            let port = match port {
                None => default_port,
                Some(p) => match p.parse::<u32>() {
                    Ok(n) if (1..=65535).contains(&n) => n as u16,
                    Ok(_) => return Err(bad(format!("port {p} is out of range (1 to 65535)"))),
                    Err(_) => return Err(bad(format!("{p:?} is not a port number"))),
                },
            };
            Ok(if addr.starts_with('[') {
                format!("[{host}]:{port}")
            } else {
                format!("{host}:{port}")
            })
        };
        let discover = pairs.iter().any(|(k, _)| *k == "discover");
        let transport = match scheme.to_ascii_lowercase().as_str() {
            "xrce+udp" if discover => {
                if !addr.is_empty() {
                    return Err(bad(format!(
                        "{addr:?} and discover=: name the agent or discover it, not both"
                    )));
                }
                XrceTransport::Udp(String::new())
            }
            _ if discover => {
                return Err(bad(
                    "discover= finds agents over UDP only (xrce+udp://)".into()
                ))
            }
            "xrce+udp" => XrceTransport::Udp(host_port(8888)?),
            "xrce+tcp" => XrceTransport::Tcp(host_port(8888)?),
            "xrce+serial" => {
                if !addr.starts_with('/') {
                    return Err(bad(format!(
                        "{addr:?} is not a tty path (xrce+serial:///dev/ttyX)"
                    )));
                }
                let baud = match pairs.iter().find(|(k, _)| *k == "baud") {
                    Some((_, v)) => v
                        .parse()
                        .map_err(|_| bad(format!("baud={v} is not a number")))?,
                    None => 115_200,
                };
                if crate::sys::tty::speed(baud).is_none() {
                    return Err(bad(format!("baud={baud} is not a POSIX line speed")));
                }
                XrceTransport::Serial {
                    path: addr.to_string(),
                    baud,
                }
            }
            other => return Err(bad(format!("{other}:// is not an XRCE scheme"))),
        };
        let mut o = XrceOptions::new(transport);
        for (k, v) in pairs {
            let num = |v: &str| -> Result<u64, ConnectError> {
                let parsed = match v.strip_prefix("0x").or_else(|| v.strip_prefix("0X")) {
                    Some(h) => u64::from_str_radix(h, 16),
                    None => v.parse(),
                };
                parsed.map_err(|_| bad(format!("{k}={v} is not a number")))
            };
            let fit = |n: u64, max: u64| -> Result<u64, ConnectError> {
                if n > max {
                    Err(bad(format!("{k}={v} is out of range (at most {max})")))
                } else {
                    Ok(n)
                }
            };
            let at_least_1 = |n: u64| -> Result<u64, ConnectError> {
                match n {
                    0 => Err(bad(format!("{k}=0: give 1 or more"))),
                    n => Ok(n),
                }
            };
            // a period of 0 ms would mean "all the time"
            let ms = |v: &str| -> Result<Duration, ConnectError> {
                match num(v)? {
                    0 => Err(bad(format!("{k}=0: a period of 0 ms; give 1 or more"))),
                    n => Ok(Duration::from_millis(n)),
                }
            };
            match k {
                "baud" if matches!(o.transport, XrceTransport::Serial { .. }) => {}
                "key" => {
                    let n = fit(num(v)?, u64::from(u32::MAX))? as u32;
                    if n == 0 {
                        return Err(bad("key=0 is refused by agents".into()));
                    }
                    o.client_key = Some(n);
                }
                "session" => {
                    let n = fit(num(v)?, 0xFF)? as u8;
                    if n == 0 || n == 0x80 {
                        return Err(bad(format!(
                            "session={v}: 0x00 and 0x80 mean \"no session\""
                        )));
                    }
                    o.session_id = n;
                }
                "mtu" => {
                    let n = fit(num(v)?, u64::from(u16::MAX))? as u16;
                    if n < 64 {
                        return Err(bad(format!("mtu={v} is below 64")));
                    }
                    o.mtu = n;
                }
                "depth" => {
                    o.depth = fit(at_least_1(num(v)?)?, 0x4000)? as u16;
                }
                "history" => o.history = fit(at_least_1(num(v)?)?, u64::from(u16::MAX))? as u16,
                "domain" => {
                    let n = fit(num(v)?, 0x7FFF)?;
                    o.domain = n as i16;
                }
                "keepalive_ms" => o.keepalive = ms(v)?,
                "lost_ms" => o.lost_after = ms(v)?,
                "attempts" => {
                    o.connect_attempts = fit(at_least_1(num(v)?)?, u64::from(u32::MAX))? as u32
                }
                "attempt_ms" => o.connect_interval = ms(v)?,
                // 0: fail at once while the agent is lost
                "wait_ms" => o.agent_wait = Duration::from_millis(num(v)?),
                // 0: delete the session at once
                "linger_ms" => o.linger = Duration::from_millis(num(v)?),
                "creation" => {
                    o.creation = match v {
                        "replace" => XrceCreation::Replace,
                        "reuse" => XrceCreation::ReuseOrReplace,
                        "create" => XrceCreation::Create,
                        _ => {
                            return Err(bad(format!("creation={v}: one of replace, reuse, create")))
                        }
                    }
                }
                "representation" => {
                    o.representation = match v {
                        "binary" => XrceRepresentation::Binary,
                        "xml" => XrceRepresentation::Xml,
                        "reference" | "ref" => XrceRepresentation::Reference,
                        _ => {
                            return Err(bad(format!(
                                "representation={v}: one of binary, xml, reference"
                            )))
                        }
                    }
                }
                "discover" => {
                    let mut d = o.discovery.take().unwrap_or_default();
                    for a in v.split(',').filter(|a| !a.is_empty()) {
                        d = if a == "multicast" {
                            d.multicast()
                        } else {
                            d.agent(a.parse().map_err(|_| {
                                bad(format!("discover={v}: {a:?} is not ip:port or multicast"))
                            })?)
                        };
                    }
                    if d.targets.is_empty() {
                        return Err(bad("discover= lists no address".into()));
                    }
                    o.discovery = Some(d);
                }
                "discover_attempts" => {
                    let n = fit(num(v)?, 1000)? as u32;
                    let d = o.discovery.take().unwrap_or_default();
                    o.discovery = Some(d.attempts(n));
                }
                "discover_ms" => {
                    let d = o.discovery.take().unwrap_or_default();
                    o.discovery = Some(d.period(ms(v)?.max(Duration::from_millis(1))));
                }
                _ if k.starts_with("ref.") => {
                    let rest = &k[4..];
                    let (kind, name) = rest.split_once('.').unwrap_or((rest, ""));
                    let kind = RefKind::parse(kind)
                        .ok_or_else(|| bad(format!("{k}: unknown entity kind {kind:?}")))?;
                    if name.is_empty() && kind != RefKind::Participant {
                        return Err(bad(format!("{k}: ref.{}.<name>=<profile>", kind.name())));
                    }
                    o = o.reference(kind, name, v);
                }
                _ => return Err(bad(format!("unknown XRCE option {k:?}"))),
            }
        }
        if o.discovery.as_ref().is_some_and(|d| d.targets.is_empty()) {
            return Err(bad(
                "discover_attempts= and discover_ms= go with discover=<addresses>".into(),
            ));
        }
        if o.lost_after < o.keepalive {
            return Err(bad(format!(
                "lost_ms ({:?}) is shorter than keepalive_ms ({:?})",
                o.lost_after, o.keepalive
            )));
        }
        Ok(o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_of_each_transport() {
        let o = XrceOptions::from_url("xrce+tcp://localhost").unwrap();
        assert_eq!(o.transport, XrceTransport::Tcp("localhost:8888".into()));
        let o = XrceOptions::from_url("xrce+udp://[::1]:9999?session=0x01&depth=8").unwrap();
        assert_eq!(o.transport, XrceTransport::Udp("[::1]:9999".into()));
        let v6 = XrceOptions::from_url("xrce+tcp://[::1]").unwrap();
        assert_eq!(v6.transport, XrceTransport::Tcp("[::1]:8888".into()));
        assert_eq!((o.session_id, o.depth), (1, 8));
        let o = XrceOptions::from_url("xrce+serial:///dev/pts/3?baud=9600&mtu=256").unwrap();
        assert_eq!(
            o.transport,
            XrceTransport::Serial {
                path: "/dev/pts/3".into(),
                baud: 9600
            }
        );
        assert_eq!(o.mtu, 256);
        assert_eq!(o.linger, Duration::from_secs(3));
        let z = XrceOptions::from_url("xrce+udp://h:1?linger_ms=0").unwrap();
        assert_eq!(z.linger, Duration::ZERO);
        assert_eq!(
            o.to_owned().transport.to_string(),
            "xrce+serial:///dev/pts/3?baud=9600"
        );
    }

    #[test]
    fn discovery_urls() {
        let o = XrceOptions::from_url(
            "xrce+udp://?discover=127.0.0.1:7400,multicast,[::1]:8888&discover_attempts=5&discover_ms=200",
        )
        .unwrap();
        let d = o.discovery.unwrap();
        assert_eq!(
            d.targets,
            vec![
                "127.0.0.1:7400".parse().unwrap(),
                "239.255.0.2:7400".parse().unwrap(),
                "[::1]:8888".parse().unwrap()
            ]
        );
        assert_eq!((d.attempts, d.period), (5, Duration::from_millis(200)));
        assert_eq!(o.transport, XrceTransport::Udp(String::new()));
        assert!(XrceOptions::from_url("xrce+udp://h:1")
            .unwrap()
            .discovery
            .is_none());
    }

    #[test]
    fn references_by_kind_and_name() {
        let o = XrceOptions::from_url(
            "xrce+udp://h:1?representation=reference&ref.data_writer.Square=shapetype_data_writer&ref.participant=p",
        )
        .unwrap();
        assert_eq!(o.representation, XrceRepresentation::Reference);
        assert_eq!(
            o.profile(RefKind::DataWriter, "Square"),
            "shapetype_data_writer"
        );
        assert_eq!(
            o.profile(RefKind::DataReader, "Square"),
            "Square_data_reader"
        );
        assert_eq!(o.profile(RefKind::Participant, "x"), "p");
    }

    #[test]
    fn bad_urls_say_what_is_wrong() {
        for (url, says) in [
            ("xrce+udp://h:1?key=0", "key=0"),
            ("xrce+udp://h:1?mtu=10", "below 64"),
            ("xrce+udp://h:1?session=0x80", "no session"),
            ("xrce+udp://h:1?nope=1", "unknown XRCE option"),
            ("xrce+udp://h:1?creation=x", "one of replace"),
            ("xrce+serial://dev/tty", "tty path"),
            ("xrce+serial:///dev/tty?baud=12345", "POSIX line speed"),
            ("xrce+udp://", "no agent address"),
            ("xrce+udp://h:1?ref.thing.x=y", "unknown entity kind"),
            ("xrce+udp://h:1?keepalive_ms=5000", "shorter than"),
            (
                "xrce+udp://h:1?keepalive_ms=0",
                "keepalive_ms=0: a period of 0 ms",
            ),
            ("xrce+udp://h:1?lost_ms=0", "lost_ms=0: a period of 0 ms"),
            ("xrce+udp://h:1?discover=127.0.0.1:7400", "not both"),
            ("xrce+tcp://?discover=127.0.0.1:7400", "UDP only"),
            ("xrce+udp://?discover=here", "not ip:port"),
            ("xrce+udp://?discover=", "no address"),
            ("xrce+udp://h:1?discover_ms=5", "go with discover="),
            (
                "xrce+udp://h:1?key=1&key=2",
                "option \"key\" is given twice",
            ),
            // the port was taken for part of the host, and :8888 added
            (
                "xrce+udp://127.0.0.1:99999",
                "port 99999 is out of range (1 to 65535)",
            ),
            ("xrce+udp://127.0.0.1:0", "port 0 is out of range"),
            ("xrce+udp://127.0.0.1:x", "\"x\" is not a port number"),
            (
                "xrce+udp://127.0.0.1:21901#frag",
                "#frag: an XRCE URL has no #fragment",
            ),
            ("xrce+udp://::1:8888", "an IPv6 address goes in brackets"),
            ("xrce+udp://[::1", "lacks its closing ]"),
            ("xrce+udp://:8888", "names no host"),
            ("xrce+udp://h:1?attempts=0", "attempts=0: give 1 or more"),
            ("xrce+udp://h:1?depth=0", "depth=0: give 1 or more"),
            ("xrce+udp://h:1?history=0", "history=0: give 1 or more"),
        ] {
            let e = XrceOptions::from_url(url).unwrap_err().to_string();
            assert!(e.contains(says), "{url}: {e}");
        }
    }
}
