//! XRCE clients and agents on the shared simulated network
//! ([`crate::sim`], cargo feature `sim`). A [`Net`](crate::sim::Net)
//! holds one node type, so both machines are wrapped in [`Peer`].
//! Input errors are counted, not reported as events.

use std::fmt::Debug;
use std::hash::Hash;
use std::time::Instant;

use super::agent::{Agent, AgentEvent};
use super::client::{Client, Event};
use crate::sim::Node;

/// A client or an agent at an address.
#[derive(Debug, Clone)]
pub enum Peer<A> {
    /// A client that talks to the agent at `agent`.
    Client {
        /// Its own address.
        addr: A,
        /// The agent's.
        agent: A,
        /// The machine.
        client: Box<Client>,
        /// Messages [`Client::handle_input`] refused.
        errors: usize,
    },
    /// An agent.
    Agent {
        /// Its address.
        addr: A,
        /// The machine.
        agent: Box<Agent<A>>,
        /// Messages [`Agent::handle_input`] refused.
        errors: usize,
    },
}

/// What a [`Peer`] reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PeerEvent {
    /// A client's event.
    Client(Event),
    /// An agent's event.
    Agent(AgentEvent),
}

impl<A: Clone + Eq + Hash> Peer<A> {
    /// A client at `addr` for the agent at `agent`.
    pub fn client(addr: A, agent: A, client: Client) -> Self {
        Peer::Client {
            addr,
            agent,
            client: Box::new(client),
            errors: 0,
        }
    }

    /// An agent at `addr`.
    pub fn agent(addr: A, agent: Agent<A>) -> Self {
        Peer::Agent {
            addr,
            agent: Box::new(agent),
            errors: 0,
        }
    }

    /// The client, if this is one.
    pub fn as_client(&mut self) -> Option<&mut Client> {
        match self {
            Peer::Client { client, .. } => Some(client),
            Peer::Agent { .. } => None,
        }
    }

    /// The agent, if this is one.
    pub fn as_agent(&mut self) -> Option<&mut Agent<A>> {
        match self {
            Peer::Agent { agent, .. } => Some(agent),
            Peer::Client { .. } => None,
        }
    }

    /// Input errors so far.
    pub fn errors(&self) -> usize {
        match self {
            Peer::Client { errors, .. } | Peer::Agent { errors, .. } => *errors,
        }
    }
}

impl<A: Clone + Eq + Hash + Debug> Node for Peer<A> {
    type Addr = A;
    type Event = PeerEvent;

    fn owns(&self, to: &A) -> bool {
        match self {
            Peer::Client { addr, .. } | Peer::Agent { addr, .. } => addr == to,
        }
    }

    fn address(&self) -> A {
        match self {
            Peer::Client { addr, .. } | Peer::Agent { addr, .. } => addr.clone(),
        }
    }

    fn handle_datagram(&mut self, from: A, bytes: &[u8], now: Instant) {
        let failed = match self {
            Peer::Client { client, .. } => client.handle_input(bytes, now).is_err(),
            Peer::Agent { agent, .. } => agent.handle_input(from, bytes, now).is_err(),
        };
        if failed {
            match self {
                Peer::Client { errors, .. } | Peer::Agent { errors, .. } => *errors += 1,
            }
        }
    }

    fn handle_timeout(&mut self, now: Instant) {
        match self {
            Peer::Client { client, .. } => client.handle_timeout(now),
            Peer::Agent { agent, .. } => agent.handle_timeout(now),
        }
    }

    fn poll_timeout(&self) -> Option<Instant> {
        match self {
            Peer::Client { client, .. } => client.poll_timeout(),
            Peer::Agent { agent, .. } => agent.poll_timeout(),
        }
    }

    fn poll_transmit(&mut self) -> Option<(A, Vec<u8>)> {
        match self {
            Peer::Client { client, agent, .. } => {
                client.poll_transmit().map(|m| (agent.clone(), m))
            }
            Peer::Agent { agent, .. } => agent.poll_transmit(),
        }
    }

    fn poll_event(&mut self) -> Option<PeerEvent> {
        match self {
            Peer::Client { client, .. } => client.poll_event().map(PeerEvent::Client),
            Peer::Agent { agent, .. } => agent.poll_event().map(PeerEvent::Agent),
        }
    }
}
