//! Agent discovery, sans I/O: the GET_INFO eProsima's
//! `uxr_discovery_agents` sends, the INFO an agent answers with, and
//! [`Discovery`], the machine that sends the first to a list of addresses
//! in rounds and collects the agents the second names.
//!
//! What the wire carries (eProsima's client `src/c/profile/discovery`,
//! capture `udp_discovery`):
//! - the request is one message without a session, `80 00 00 00`, holding
//!   GET_INFO of the agent object (`FF FD`) with request id 9 and the
//!   info mask CONFIGURATION | ACTIVITY:
//!   `02 01 08 00 | 00 09 | FF FD | 03 00 00 00`, sent to every address
//!   of the list (the multicast group [`GROUP`]:[`PORT`] by default) from
//!   one fresh socket, `attempts` times, `period` apart;
//! - the answer is INFO with the agent's representation (cookie, XRCE
//!   version, vendor id) and its activity: availability and the
//!   `TransportLocator`s of its XRCE transports, e.g.
//!   `01 7F 00 00 01 00 B8 22` = 127.0.0.1:8888.
//!
//! Where Courier's machine differs from eProsima's loop, on purpose:
//! - eProsima's client reports only agents whose version is exactly 1.0;
//!   Courier accepts any version of major 1 and reports the others as
//!   [`DiscoveryError::Incompatible`].
//! - An INFO without locators (what an agent answers on its XRCE port,
//!   where discovery GET_INFO is just a ping) names the address that
//!   answered; eProsima's client ignores it. A list may therefore hold
//!   agents' XRCE ports as well as their discovery ports.
//! - A locator whose address is unspecified (0.0.0.0) is completed with
//!   the address that answered; `SMALL` locators (serial, CAN) and
//!   `STRING` ones that are not `ip:port` are skipped.
//! - The same agent address is reported once, however many rounds and
//!   paths (unicast, multicast) bring it.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::time::{Duration, Instant};

use super::message::{Message, MessageHeader, SESSION_ID_WITHOUT_CLIENT_KEY};
use super::object::{ActivityInfo, AgentRepresentation, ObjectInfo, ObjectVariant};
use super::submessage::{GetInfo, Info, Payload, Submessage};
use super::types::{
    BaseObjectRequest, ObjectId, RequestId, ResultStatus, StatusCode, StreamId, TransportLocator,
    VERSION,
};
use super::DecodeError;

/// The UDP port agents listen on for discovery (MicroXRCEAgent's `-d`).
pub const PORT: u16 = 7400;
/// The multicast group agents join for discovery.
pub const GROUP: Ipv4Addr = Ipv4Addr::new(239, 255, 0, 2);

/// The discovery request: 16 bytes, as eProsima's client sends them.
pub fn request() -> Message {
    Message::new(
        MessageHeader::new(SESSION_ID_WITHOUT_CLIENT_KEY, StreamId::NONE, 0),
        vec![Submessage::new(Payload::GetInfo(GetInfo {
            request: BaseObjectRequest::new(RequestId::DISCOVERY.0, ObjectId::AGENT),
            info_mask: GetInfo::CONFIGURATION | GetInfo::ACTIVITY,
        }))],
    )
}

/// The discovery request's bytes.
pub fn request_bytes() -> Vec<u8> {
    // a header without key and one fixed-size submessage always encode
    request().to_vec().unwrap_or_default()
}

/// An agent's answer to a discovery request `header`/`get_info`: OK, its
/// representation, availability 1 and the `locators` of its XRCE
/// transports (the reply keeps the request's header, as eProsima's agent
/// does).
pub fn answer(
    header: MessageHeader,
    get_info: &GetInfo,
    agent: AgentRepresentation,
    locators: Vec<TransportLocator>,
) -> Message {
    let info = Info {
        request: get_info.request,
        result: ResultStatus {
            status: StatusCode::OK,
            implementation_status: 0,
        },
        info: ObjectInfo {
            config: Some(ObjectVariant::Agent(agent)),
            activity: Some(ActivityInfo::Agent {
                availability: 1,
                locators,
            }),
        },
    };
    Message::new(header, vec![Submessage::new(Payload::Info(info))])
}

/// A discovery request, if `msg` is one: GET_INFO of the agent object,
/// outside a session, as the first submessage.
pub fn as_request(msg: &Message) -> Option<&GetInfo> {
    if msg.header.session_id & !SESSION_ID_WITHOUT_CLIENT_KEY != 0 {
        return None;
    }
    match msg.submessages.first().map(|s| &s.payload) {
        Some(Payload::GetInfo(g)) if g.request.object_id == ObjectId::AGENT => Some(g),
        _ => None,
    }
}

/// What an agent says of itself in its answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Announcement {
    /// Its representation: cookie, XRCE version, vendor id, properties.
    pub agent: AgentRepresentation,
    /// `availability` (> 0: it serves clients); `None` when the answer had
    /// no activity.
    pub availability: Option<i16>,
    /// The locators of its XRCE transports (may be empty).
    pub locators: Vec<TransportLocator>,
}

/// Why a datagram is not a usable discovery answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DiscoveryError {
    /// Not an XRCE message.
    #[error("not an XRCE message: {0}")]
    Decode(#[from] DecodeError),
    /// An XRCE message, but not INFO answering a discovery request.
    #[error("not an answer to discovery: {0}")]
    NotAnAnswer(&'static str),
    /// The agent refused (status other than OK).
    #[error("the agent answered with status {0}")]
    Refused(StatusCode),
    /// An agent speaking an XRCE version this client does not.
    #[error("the agent speaks XRCE {}.{}, not 1.x", .0[0], .0[1])]
    Incompatible([u8; 2]),
}

/// Reads a discovery answer.
pub fn parse_answer(bytes: &[u8]) -> Result<Announcement, DiscoveryError> {
    let msg = Message::decode(bytes)?;
    let info = match msg.submessages.first().map(|s| &s.payload) {
        Some(Payload::Info(i)) => i,
        Some(_) => return Err(DiscoveryError::NotAnAnswer("not INFO")),
        None => return Err(DiscoveryError::NotAnAnswer("no submessage")),
    };
    if info.request.object_id != ObjectId::AGENT {
        return Err(DiscoveryError::NotAnAnswer("INFO of another object"));
    }
    if info.request.request_id != RequestId::DISCOVERY {
        return Err(DiscoveryError::NotAnAnswer("INFO of another request"));
    }
    if info.result.status != StatusCode::OK {
        return Err(DiscoveryError::Refused(info.result.status));
    }
    let Some(ObjectVariant::Agent(agent)) = &info.info.config else {
        return Err(DiscoveryError::NotAnAnswer(
            "INFO without the agent's configuration",
        ));
    };
    if agent.version[0] != VERSION[0] {
        return Err(DiscoveryError::Incompatible(agent.version));
    }
    let (availability, locators) = match &info.info.activity {
        Some(ActivityInfo::Agent {
            availability,
            locators,
        }) => (Some(*availability), locators.clone()),
        Some(_) => return Err(DiscoveryError::NotAnAnswer("activity of another object")),
        None => (None, Vec::new()),
    };
    Ok(Announcement {
        agent: agent.clone(),
        availability,
        locators,
    })
}

/// The UDP address a locator names, completed with `from`'s address when
/// unspecified; `None` for locators that are not IP addresses.
pub fn locator_address(l: &TransportLocator, from: SocketAddr) -> Option<SocketAddr> {
    let a = match l {
        TransportLocator::Medium { address, port } => {
            SocketAddr::new(IpAddr::V4(Ipv4Addr::from(*address)), *port)
        }
        TransportLocator::Large { address, port } => SocketAddr::new(
            IpAddr::V6(Ipv6Addr::from(*address)),
            u16::try_from(*port).ok()?,
        ),
        TransportLocator::String(s) => s.parse().ok()?,
        TransportLocator::Small { .. } => return None,
    };
    Some(if a.ip().is_unspecified() {
        SocketAddr::new(from.ip(), a.port())
    } else {
        a
    })
}

/// An agent discovery found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FoundAgent {
    /// Where its XRCE UDP transport listens: the address a session connects to.
    pub address: SocketAddr,
    /// The address the answer came from (its discovery port, or `address`).
    pub answered_from: SocketAddr,
    /// Its XRCE version (`[major, minor]`).
    pub version: [u8; 2],
    /// Its vendor id (`[0x01, 0x0F]`: eProsima's, which Courier's agent also sends).
    pub vendor: [u8; 2],
    /// Its availability, when it said.
    pub availability: Option<i16>,
}

/// Rounds and their spacing (`uxr_discovery_agents`' `attempts` and `period`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DiscoveryConfig {
    /// Rounds of requests (at least 1).
    pub attempts: u32,
    /// Time between rounds; after the last one, how long answers are awaited.
    pub period: Duration,
}

impl Default for DiscoveryConfig {
    /// 3 rounds 1 s apart.
    fn default() -> Self {
        DiscoveryConfig {
            attempts: 3,
            period: Duration::from_secs(1),
        }
    }
}

/// Discovery of agents at a list of addresses: every round queues the
/// request once per address ([`Discovery::poll_transmit`]); answers go to
/// [`Discovery::handle_input`]; the discovery is over once the last round's
/// period has passed ([`Discovery::is_finished`]), or earlier if its owner
/// is satisfied with what [`Discovery::found`] holds.
#[derive(Debug)]
pub struct Discovery {
    targets: Vec<SocketAddr>,
    cfg: DiscoveryConfig,
    rounds: u32,
    next: Instant,
    queue: Vec<SocketAddr>,
    found: Vec<FoundAgent>,
    request: Vec<u8>,
}

impl Discovery {
    /// Discovery of the agents at `targets`; the first round is due at `now`.
    pub fn new(targets: Vec<SocketAddr>, cfg: DiscoveryConfig, now: Instant) -> Self {
        let mut d = Discovery {
            targets,
            cfg: DiscoveryConfig {
                attempts: cfg.attempts.max(1),
                period: cfg.period,
            },
            rounds: 0,
            next: now,
            queue: Vec::new(),
            found: Vec::new(),
            request: request_bytes(),
        };
        d.handle_timeout(now);
        d
    }

    /// Starts the rounds that are due at `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        if now >= self.next && self.rounds < self.cfg.attempts {
            self.rounds += 1;
            self.next = crate::time::later(now, self.cfg.period);
            self.queue.extend(self.targets.iter().rev().copied());
        }
    }

    /// When [`Discovery::handle_timeout`] wants to run next: the next round,
    /// or the end of the last one.
    pub fn poll_timeout(&self) -> Instant {
        self.next
    }

    /// The next request to send, and where.
    pub fn poll_transmit(&mut self) -> Option<(SocketAddr, &[u8])> {
        let to = self.queue.pop()?;
        Some((to, &self.request))
    }

    /// True once every round was sent and the last period is over at `now`.
    pub fn is_finished(&self, now: Instant) -> bool {
        self.rounds >= self.cfg.attempts && now >= self.next && self.queue.is_empty()
    }

    /// Takes a datagram from `from`; returns the agents it newly names
    /// (none when they were found already).
    pub fn handle_input(
        &mut self,
        from: SocketAddr,
        bytes: &[u8],
    ) -> Result<Vec<FoundAgent>, DiscoveryError> {
        let a = parse_answer(bytes)?;
        let mut addresses: Vec<SocketAddr> = a
            .locators
            .iter()
            .filter_map(|l| locator_address(l, from))
            .collect();
        if a.locators.is_empty() {
            addresses.push(from);
        }
        let mut new = Vec::new();
        for address in addresses {
            if self.found.iter().any(|f| f.address == address) {
                continue;
            }
            let f = FoundAgent {
                address,
                answered_from: from,
                version: a.agent.version,
                vendor: a.agent.vendor,
                availability: a.availability,
            };
            self.found.push(f.clone());
            new.push(f);
        }
        Ok(new)
    }

    /// Every agent found so far, in the order found.
    pub fn found(&self) -> &[FoundAgent] {
        &self.found
    }

    /// Takes the agents found.
    pub fn into_found(self) -> Vec<FoundAgent> {
        self.found
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// udp_discovery.pcap #1 (eProsima client → agent, unicast and multicast alike).
    const REQUEST: [u8; 16] = [
        0x80, 0x00, 0x00, 0x00, 0x02, 0x01, 0x08, 0x00, 0x00, 0x09, 0xFF, 0xFD, 0x03, 0x00, 0x00,
        0x00,
    ];
    /// udp_discovery.pcap #2 (MicroXRCEAgent v2.3.0 `-d 7400`, XRCE on 8888).
    const ANSWER: [u8; 44] = [
        0x80, 0x00, 0x00, 0x00, 0x06, 0x01, 0x24, 0x00, 0x00, 0x09, 0xFF, 0xFD, 0x00, 0x00, 0x01,
        0x0D, 0x58, 0x52, 0x43, 0x45, 0x01, 0x00, 0x01, 0x0F, 0x00, 0x01, 0x0D, 0x00, 0x01, 0x00,
        0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x7F, 0x00, 0x00, 0x01, 0x00, 0xB8, 0x22,
    ];

    fn at(p: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], p))
    }

    #[test]
    fn the_request_is_eprosimas_bytes() {
        assert_eq!(request_bytes(), REQUEST.to_vec());
        let m = Message::decode(&REQUEST).unwrap();
        assert!(as_request(&m).is_some());
    }

    #[test]
    fn the_answer_of_eprosimas_agent_names_its_xrce_port() {
        let a = parse_answer(&ANSWER).unwrap();
        assert_eq!(a.agent.version, [1, 0]);
        assert_eq!(a.agent.vendor, [0x01, 0x0F]);
        assert_eq!(a.availability, Some(1));
        assert_eq!(
            a.locators,
            vec![TransportLocator::Medium {
                address: [127, 0, 0, 1],
                port: 8888
            }]
        );
    }

    #[test]
    fn answer_encodes_as_eprosimas_agent_does() {
        let req = Message::decode(&REQUEST).unwrap();
        let g = as_request(&req).unwrap();
        let m = answer(
            req.header,
            g,
            AgentRepresentation::default(),
            vec![TransportLocator::Medium {
                address: [127, 0, 0, 1],
                port: 8888,
            }],
        );
        assert_eq!(m.to_vec().unwrap(), ANSWER.to_vec());
    }

    #[test]
    fn rounds_send_to_every_target_then_end() {
        let t0 = Instant::now();
        let cfg = DiscoveryConfig {
            attempts: 2,
            period: Duration::from_millis(100),
        };
        let mut d = Discovery::new(vec![at(1), at(2)], cfg, t0);
        let sent: Vec<_> =
            std::iter::from_fn(|| d.poll_transmit().map(|(a, b)| (a, b.to_vec()))).collect();
        assert_eq!(
            sent,
            vec![(at(1), REQUEST.to_vec()), (at(2), REQUEST.to_vec())]
        );
        assert!(!d.is_finished(t0));
        d.handle_timeout(t0 + Duration::from_millis(50));
        assert!(d.poll_transmit().is_none(), "not yet the second round");
        let t1 = d.poll_timeout();
        assert_eq!(t1, t0 + Duration::from_millis(100));
        d.handle_timeout(t1);
        assert_eq!(d.poll_transmit().map(|(a, _)| a), Some(at(1)));
        assert_eq!(d.poll_transmit().map(|(a, _)| a), Some(at(2)));
        assert!(!d.is_finished(t1));
        let t2 = d.poll_timeout();
        d.handle_timeout(t2);
        assert!(d.poll_transmit().is_none(), "two rounds only");
        assert!(d.is_finished(t2));
    }

    #[test]
    fn answers_are_found_once_and_located() {
        let mut d = Discovery::new(vec![at(7400)], DiscoveryConfig::default(), Instant::now());
        let new = d.handle_input(at(7400), &ANSWER).unwrap();
        assert_eq!(
            new,
            vec![FoundAgent {
                address: at(8888),
                answered_from: at(7400),
                version: [1, 0],
                vendor: [0x01, 0x0F],
                availability: Some(1),
            }]
        );
        // the same agent through multicast: nothing new
        let again = d.handle_input(SocketAddr::from(([127, 0, 0, 1], 7400)), &ANSWER);
        assert_eq!(again.unwrap(), vec![]);
        assert_eq!(d.found().len(), 1);
    }

    #[test]
    fn an_answer_without_locators_names_who_answered() {
        let req = request();
        let g = as_request(&req).unwrap();
        let m = answer(req.header, g, AgentRepresentation::default(), vec![]);
        let mut d = Discovery::new(vec![at(9)], DiscoveryConfig::default(), Instant::now());
        let new = d.handle_input(at(9), &m.to_vec().unwrap()).unwrap();
        assert_eq!(new[0].address, at(9));
    }

    #[test]
    fn unspecified_and_odd_locators() {
        let from = SocketAddr::from(([10, 0, 0, 7], 7400));
        let any = TransportLocator::Medium {
            address: [0; 4],
            port: 8888,
        };
        assert_eq!(
            locator_address(&any, from),
            Some(SocketAddr::from(([10, 0, 0, 7], 8888)))
        );
        let small = TransportLocator::Small {
            address: [1, 2],
            port: 3,
        };
        assert_eq!(locator_address(&small, from), None);
        let big_port = TransportLocator::Large {
            address: [0; 16],
            port: 70_000,
        };
        assert_eq!(locator_address(&big_port, from), None);
        assert_eq!(
            locator_address(&TransportLocator::String("nonsense".into()), from),
            None
        );
        assert_eq!(
            locator_address(&TransportLocator::String("127.0.0.1:5".into()), from),
            Some(at(5))
        );
    }

    #[test]
    fn bad_answers_are_errors() {
        let mut d = Discovery::new(vec![at(1)], DiscoveryConfig::default(), Instant::now());
        // truncated at every length
        let good = ANSWER.to_vec();
        for n in 0..good.len() {
            assert!(d.handle_input(at(1), &good[..n]).is_err(), "{n} bytes");
        }
        // another request id (a ping's answer)
        let mut ping = good.clone();
        ping[9] = 0x0A;
        assert!(matches!(
            d.handle_input(at(1), &ping),
            Err(DiscoveryError::NotAnAnswer(_))
        ));
        // a refusal
        let mut refused = good.clone();
        refused[12] = 0x83;
        assert_eq!(
            d.handle_input(at(1), &refused),
            Err(DiscoveryError::Refused(StatusCode::ERR_DENIED))
        );
        // XRCE 2.0
        let mut v2 = good.clone();
        v2[20] = 2;
        assert_eq!(
            d.handle_input(at(1), &v2),
            Err(DiscoveryError::Incompatible([2, 0]))
        );
        // our own request echoed back
        assert!(matches!(
            d.handle_input(at(1), &REQUEST),
            Err(DiscoveryError::NotAnAnswer("not INFO"))
        ));
        assert!(d.found().is_empty());
    }
}
