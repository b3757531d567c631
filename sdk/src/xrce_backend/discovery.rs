//! Finding agents before connecting: eProsima's `uxr_discovery_agents`
//! (a unicast list) and `uxr_discovery_agents_default` (the multicast
//! group 239.255.0.2:7400), over [`courier_wire::xrce::discovery`].
//!
//! The addresses may be agents' discovery ports (MicroXRCEAgent's `-d`,
//! whose answer names the agent's XRCE port) or their XRCE ports (which
//! answer as to a ping, naming no port: the address that answered is the
//! agent's). Multicast reaches agents on the local network: any address
//! outside loopback is a real network, so tests multicast only inside a
//! private network namespace.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::time::{Duration, Instant};

use courier_wire::xrce::discovery::{self, Discovery, DiscoveryConfig};
use tokio::net::UdpSocket;

pub use courier_wire::xrce::discovery::FoundAgent;

/// What to look for, and how long ([`XrceDiscovery::all`],
/// [`XrceDiscovery::first`]); in a URL, `xrce+udp://?discover=…` (see
/// [`XrceOptions::discovery`](super::XrceOptions::discovery)).
///
/// The addresses may be agents' discovery ports (MicroXRCEAgent's `-d`,
/// whose answer names the agent's XRCE port) or their XRCE ports (which
/// answer as to a ping, naming no port: the address that answered is the
/// agent's). Multicast reaches every agent on the local network.
///
/// ```no_run
/// # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
/// use courier::xrce_backend::XrceDiscovery;
/// let found = XrceDiscovery::new()
///     .agent("127.0.0.1:7400".parse()?)
///     .agent("127.0.0.1:8888".parse()?)
///     .all()
///     .await?;
/// for a in &found {
///     println!("agent at {} (XRCE {}.{})", a.address, a.version[0], a.version[1]);
/// }
/// // or straight into a session on the first agent that answers:
/// let s = courier::Session::builder("xrce+udp://?discover=127.0.0.1:7400,127.0.0.1:8888")
///     .connect()
///     .await?;
/// # let _ = s; Ok(()) }
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct XrceDiscovery {
    /// Where the requests go (unicast addresses and multicast groups).
    pub targets: Vec<SocketAddr>,
    /// Rounds of requests (`discover_attempts=`, default 3).
    pub attempts: u32,
    /// Time between rounds, and how long answers are awaited after the
    /// last (`discover_ms=`, default 1000).
    pub period: Duration,
    /// The interface address multicast requests leave from (`None`: the
    /// system's choice by its routes).
    pub multicast_interface: Option<Ipv4Addr>,
}

impl Default for XrceDiscovery {
    fn default() -> Self {
        Self::new()
    }
}

/// Why discovery found nothing, or could not look.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiscoverError {
    /// No address to ask.
    #[error("XRCE agent discovery has no address to ask")]
    NoTargets,
    /// The discovery socket could not be opened or used.
    #[error("XRCE agent discovery: {0}")]
    Socket(#[from] std::io::Error),
    /// Every round went unanswered.
    #[error(
        "no XRCE agent answered discovery at {} ({attempts} round(s), {period:?} apart)",
        list(.tried)
    )]
    NotFound {
        /// The addresses asked.
        tried: Vec<SocketAddr>,
        /// Rounds sent.
        attempts: u32,
        /// Their spacing.
        period: Duration,
    },
}

fn list(a: &[SocketAddr]) -> String {
    a.iter()
        .map(|a| a.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

impl XrceDiscovery {
    /// No address yet; 3 rounds 1 s apart.
    pub fn new() -> Self {
        let d = DiscoveryConfig::default();
        XrceDiscovery {
            targets: Vec::new(),
            attempts: d.attempts,
            period: d.period,
            multicast_interface: None,
        }
    }

    /// Also asks `addr` (an agent's discovery or XRCE port).
    pub fn agent(mut self, addr: SocketAddr) -> Self {
        if !self.targets.contains(&addr) {
            self.targets.push(addr);
        }
        self
    }

    /// Also asks the agents' multicast group, 239.255.0.2:7400, as
    /// `uxr_discovery_agents_default` does. This leaves the machine unless
    /// multicast is routed to `lo` alone.
    pub fn multicast(self) -> Self {
        self.agent(SocketAddr::V4(SocketAddrV4::new(
            discovery::GROUP,
            discovery::PORT,
        )))
    }

    /// Sends multicast requests from the interface with this address.
    pub fn multicast_interface(mut self, addr: Ipv4Addr) -> Self {
        self.multicast_interface = Some(addr);
        self
    }

    /// Rounds of requests (at least 1).
    pub fn attempts(mut self, n: u32) -> Self {
        self.attempts = n.max(1);
        self
    }

    /// Time between rounds.
    pub fn period(mut self, d: Duration) -> Self {
        self.period = d;
        self
    }

    /// Every agent that answers within the rounds (at most
    /// `attempts × period`), in the order they answered; empty if none did.
    pub async fn all(&self) -> Result<Vec<FoundAgent>, DiscoverError> {
        self.run(false).await
    }

    /// The first agent that answers; [`DiscoverError::NotFound`] when none
    /// does within `attempts × period`.
    pub async fn first(&self) -> Result<FoundAgent, DiscoverError> {
        self.run(true)
            .await?
            .into_iter()
            .next()
            .ok_or_else(|| DiscoverError::NotFound {
                tried: self.targets.clone(),
                attempts: self.attempts,
                period: self.period,
            })
    }

    async fn socket(&self, v6: bool) -> Result<UdpSocket, DiscoverError> {
        let any: SocketAddr = if v6 {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        } else {
            (Ipv4Addr::UNSPECIFIED, 0).into()
        };
        let s = UdpSocket::bind(any).await?;
        if let (false, Some(i)) = (v6, self.multicast_interface) {
            socket2::SockRef::from(&s).set_multicast_if_v4(&i)?;
        }
        Ok(s)
    }

    async fn run(&self, first_only: bool) -> Result<Vec<FoundAgent>, DiscoverError> {
        if self.targets.is_empty() {
            return Err(DiscoverError::NoTargets);
        }
        let cfg = DiscoveryConfig {
            attempts: self.attempts,
            period: self.period,
        };
        // one socket per address family asked
        let v4 = match self.targets.iter().any(|a| a.is_ipv4()) {
            true => Some(self.socket(false).await?),
            false => None,
        };
        let v6 = match self.targets.iter().any(|a| a.is_ipv6()) {
            true => Some(self.socket(true).await?),
            false => None,
        };
        let mut d = Discovery::new(self.targets.clone(), cfg, Instant::now());
        let (mut b4, mut b6) = (vec![0u8; 2048], vec![0u8; 2048]);
        loop {
            while let Some((to, bytes)) = d.poll_transmit() {
                let s = if to.is_ipv4() { &v4 } else { &v6 };
                if let Some(s) = s {
                    if let Err(e) = s.send_to(bytes, to).await {
                        tracing::debug!("XRCE discovery: cannot send to {to}: {e}");
                    }
                }
            }
            if (first_only && !d.found().is_empty()) || d.is_finished(Instant::now()) {
                return Ok(d.into_found());
            }
            let got = tokio::select! {
                r = recv(&v4, &mut b4) => r.map(|(n, from)| (from, &b4[..n])),
                r = recv(&v6, &mut b6) => r.map(|(n, from)| (from, &b6[..n])),
                _ = tokio::time::sleep_until(d.poll_timeout().into()) => {
                    d.handle_timeout(Instant::now());
                    continue;
                }
            };
            match got {
                Ok((from, bytes)) => match d.handle_input(from, bytes) {
                    Ok(new) => {
                        for a in new {
                            tracing::debug!("XRCE discovery: agent at {} (from {from})", a.address);
                        }
                    }
                    Err(e) => tracing::debug!("XRCE discovery: {from}: {e}"),
                },
                Err(e) => {
                    // nothing to read until the next round
                    tracing::debug!("XRCE discovery: {e}");
                    tokio::time::sleep_until(d.poll_timeout().into()).await;
                    d.handle_timeout(Instant::now());
                }
            }
        }
    }
}

async fn recv(s: &Option<UdpSocket>, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr)> {
    match s {
        Some(s) => s.recv_from(buf).await,
        None => std::future::pending().await,
    }
}
