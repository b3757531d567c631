//! Typed handles to what a [`Domain`](super::Domain) holds.

use crate::rtps::participant::SampleIdentity;
use crate::rtps::Guid;

use super::request_header::{RequestHeader, RpcStyle};

/// A writer of this domain ([`Domain::create_writer`](super::Domain::create_writer)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct WriterId(pub(crate) Guid);

/// A reader of this domain: made by
/// [`Domain::create_reader`](super::Domain::create_reader), or by a pattern
/// subscription for each publication it matches ([`Event::PatternMatched`](super::Event::PatternMatched)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ReaderId(pub(crate) Guid);

impl WriterId {
    /// The RTPS writer's GUID (what remote readers see).
    pub fn guid(self) -> Guid {
        self.0
    }
}

impl ReaderId {
    /// The RTPS reader's GUID (what remote writers see).
    pub fn guid(self) -> Guid {
        self.0
    }
}

/// A service: a reader of its request topic and a writer of its reply topic
/// ([`Domain::create_service`](super::Domain::create_service)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ServiceId(pub(crate) u64);

/// A client of a service: a writer of its request topic and a reader of its
/// reply topic ([`Domain::create_client`](super::Domain::create_client)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ClientId(pub(crate) u64);

/// A pattern subscription ([`Domain::create_pattern`](super::Domain::create_pattern)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PatternId(pub(crate) u64);

/// A query made by a client ([`Domain::query`](super::Domain::query)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct QueryId(pub(crate) u64);

/// A request a service received: what its reply must name
/// ([`Domain::reply`](super::Domain::reply)), in the request's
/// [`RpcStyle`]. Related sample identity, as rmw_fastrtps: the reply reader
/// the request named (with the request's sequence number), else the
/// request's own identity. Request header, as rmw_cyclonedds: the client's
/// id and request number from the header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RequestId(pub(crate) RequestKey);

/// A request's identity in either style (also the key of a client's
/// open queries).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) enum RequestKey {
    Identity(SampleIdentity),
    Header(RequestHeader),
}

impl RequestId {
    /// How the reply names the request.
    pub fn style(self) -> RpcStyle {
        match self.0 {
            RequestKey::Identity(_) => RpcStyle::SampleIdentity,
            RequestKey::Header(_) => RpcStyle::RequestHeader,
        }
    }

    /// The identity the reply carries as its related sample identity
    /// ([`RpcStyle::SampleIdentity`]).
    pub fn related_identity(self) -> Option<SampleIdentity> {
        match self.0 {
            RequestKey::Identity(id) => Some(id),
            RequestKey::Header(_) => None,
        }
    }

    /// The header the reply starts with ([`RpcStyle::RequestHeader`]).
    pub fn request_header(self) -> Option<RequestHeader> {
        match self.0 {
            RequestKey::Identity(_) => None,
            RequestKey::Header(h) => Some(h),
        }
    }
}

/// Any local endpoint or group of endpoints, for events about them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Endpoint {
    /// A writer.
    Writer(WriterId),
    /// A reader (plain or of a pattern subscription).
    Reader(ReaderId),
    /// A service's request reader or reply writer.
    Service(ServiceId),
    /// A client's request writer or reply reader.
    Client(ClientId),
}
