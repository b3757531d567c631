//! Request/reply as ROS 2 does it over DDS: a request topic
//! `rq/<name>Request` and a reply topic `rr/<name>Reply`; a reply names its
//! request in one of two styles ([`RpcStyle`]): as its related sample
//! identity (`PID_RELATED_SAMPLE_IDENTITY`, and Fast DDS's 0x800f; as
//! rmw_fastrtps does), or by a header before the body (as rmw_cyclonedds
//! does). Unless a service or client is given a style, it takes each
//! peer's: a request with a related identity is answered so, a request
//! from a Cyclone DDS participant without one by header; a client asks by
//! header when every service it matched is a Cyclone DDS participant.

use std::time::{Duration, Instant};

use crate::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History, Reliability};
use crate::rtps::participant::{
    Change, ChangeKind, CreateError, EndpointConfig, ReceivedSample, SampleIdentity, WriteError,
};
use crate::rtps::{Guid, GuidPrefix, SequenceNumber};

use super::handles::RequestKey;
use super::request_header::{self, RequestHeader, RpcStyle};
use super::{
    ClientId, Domain, Event, QueryFailure, QueryId, ReaderId, RequestId, Role, ServiceId, WriterId,
};

/// ROS 2's request topic of service `name`.
pub fn request_topic(name: &str) -> String {
    format!("rq/{name}Request")
}

/// ROS 2's reply topic of service `name`.
pub fn reply_topic(name: &str) -> String {
    format!("rr/{name}Reply")
}

/// A service as both its sides see it: name, types and QoS.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ServiceConfig {
    /// The service name (topics `rq/<name>Request`, `rr/<name>Reply`).
    pub name: String,
    /// The request's DDS type name.
    pub request_type: String,
    /// Whether the request type has key fields.
    pub request_keyed: bool,
    /// The reply's DDS type name.
    pub reply_type: String,
    /// Whether the reply type has key fields.
    pub reply_keyed: bool,
    /// QoS of the writers (request writer of a client, reply writer of a service).
    pub writer_qos: EndpointQos,
    /// QoS of the readers.
    pub reader_qos: EndpointQos,
    /// The request/reply style; `None`: each peer's (see the module docs).
    pub style: Option<RpcStyle>,
}

impl ServiceConfig {
    /// A service of these types, reliable, volatile, keep-all both ways.
    pub fn new(name: &str, request_type: &str, reply_type: &str) -> Self {
        let reliable = Reliability::Reliable(RtpsDuration::from_std(Duration::from_millis(100)));
        let mut writer_qos = EndpointQos::writer_default();
        writer_qos.reliability = reliable;
        writer_qos.history = History::KeepAll;
        let mut reader_qos = EndpointQos::reader_default();
        reader_qos.reliability = reliable;
        reader_qos.history = History::KeepAll;
        ServiceConfig {
            name: name.to_string(),
            request_type: request_type.to_string(),
            request_keyed: false,
            reply_type: reply_type.to_string(),
            reply_keyed: false,
            writer_qos,
            reader_qos,
            style: None,
        }
    }

    /// Uses `style` with every peer instead of each peer's own.
    pub fn with_style(mut self, style: RpcStyle) -> Self {
        self.style = Some(style);
        self
    }

    /// Sets whether the request and reply types have keys.
    pub fn keyed(mut self, request: bool, reply: bool) -> Self {
        self.request_keyed = request;
        self.reply_keyed = reply;
        self
    }

    fn request(&self, writer: bool) -> EndpointConfig {
        let t = request_topic(&self.name);
        self.endpoint(writer, &t, &self.request_type, self.request_keyed)
    }

    fn reply(&self, writer: bool) -> EndpointConfig {
        let t = reply_topic(&self.name);
        self.endpoint(writer, &t, &self.reply_type, self.reply_keyed)
    }

    fn endpoint(&self, writer: bool, topic: &str, ty: &str, keyed: bool) -> EndpointConfig {
        let (cfg, qos) = if writer {
            (EndpointConfig::writer(topic, ty), &self.writer_qos)
        } else {
            (EndpointConfig::reader(topic, ty), &self.reader_qos)
        };
        cfg.keyed(keyed).qos(qos.clone())
    }
}

pub(super) struct Service {
    writer: Guid,
    /// `None` once the service stopped taking requests ([`Domain::stop_service`]).
    reader: Option<Guid>,
    style: Option<RpcStyle>,
}

pub(super) struct Client {
    writer: Guid,
    reader: Guid,
    style: Option<RpcStyle>,
    /// Its id in request headers.
    id: u64,
    /// The number of its last request sent with a header.
    seq: i64,
    /// Replies that answered none of its open queries.
    unmatched: u64,
}

/// A client's id in request headers: from its request writer's GUID
/// (rmw_cyclonedds uses the writer's instance handle; any number unique
/// among the service's clients does).
fn header_id(writer: Guid) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&writer.prefix.0[4..12]);
    u64::from_le_bytes(b) ^ u64::from(u32::from_be_bytes(writer.entity.0))
}

pub(super) struct Waiting {
    client: ClientId,
    query: QueryId,
    data: Vec<u8>,
    deadline: Instant,
    timeout: Duration,
}

pub(super) struct Inflight {
    client: ClientId,
    query: QueryId,
    deadline: Instant,
    timeout: Duration,
    /// The client's unmatched replies when it was sent.
    unmatched_before: u64,
}

/// How many cancelled queries' keys are kept, to drop their replies.
const CANCELLED_KEPT: usize = 4096;

impl Domain {
    /// Serves a service: a reader of its request topic and a writer of its
    /// reply topic. Requests come as [`Event::Request`].
    pub fn create_service(
        &mut self,
        config: &ServiceConfig,
        now: Instant,
    ) -> Result<ServiceId, CreateError> {
        let id = ServiceId(self.next_id());
        let (writer, reader) = self.add_pair(
            config.reply(true),
            config.request(false),
            Role::Service(id),
            now,
        )?;
        self.services.insert(
            id,
            Service {
                writer,
                reader: Some(reader),
                style: config.style,
            },
        );
        self.drain(now);
        Ok(id)
    }

    /// Stops taking requests: the request reader is deleted at once, so
    /// that clients see no server (and wait for another, which gets their
    /// next request) while the reply writer still delivers the replies
    /// already given, until [`Domain::delete_service`]. False if there is
    /// no such service or it was stopped already.
    pub fn stop_service(&mut self, service: ServiceId, now: Instant) -> bool {
        let Some(reader) = self
            .services
            .get_mut(&service)
            .and_then(|s| s.reader.take())
        else {
            return false;
        };
        self.remove_reader(reader, now);
        self.drain(now);
        true
    }

    /// Stops serving; false if there is no such service.
    pub fn delete_service(&mut self, service: ServiceId, now: Instant) -> bool {
        let Some(s) = self.services.remove(&service) else {
            return false;
        };
        self.remove_writer(s.writer, now);
        if let Some(reader) = s.reader {
            self.remove_reader(reader, now);
        }
        self.drain(now);
        true
    }

    /// A service's reply writer and request reader (what a ROS 2 node
    /// lists for it in its graph entry); `None` once it stopped taking
    /// requests.
    pub fn service_endpoints(&self, service: ServiceId) -> Option<(WriterId, ReaderId)> {
        self.services
            .get(&service)
            .and_then(|s| Some((WriterId(s.writer), ReaderId(s.reader?))))
    }

    /// A client's request writer and reply reader.
    pub fn client_endpoints(&self, client: ClientId) -> Option<(WriterId, ReaderId)> {
        self.clients
            .get(&client)
            .map(|c| (WriterId(c.writer), ReaderId(c.reader)))
    }

    /// Answers a request with `data` (a serialized reply, padded as
    /// [`Domain::write`] pads).
    pub fn reply(
        &mut self,
        service: ServiceId,
        request: RequestId,
        data: Vec<u8>,
        now: Instant,
    ) -> Result<SequenceNumber, WriteError> {
        let w = self
            .services
            .get(&service)
            .ok_or(WriteError::UnknownWriter)?
            .writer;
        let change = match request.0 {
            RequestKey::Identity(id) => Change::alive_owned(data).with_related_sample_identity(id),
            RequestKey::Header(h) => {
                let mut data = data;
                h.put(&mut data);
                Change::alive_owned(data)
            }
        };
        let r = self.write_guid(w, change, None, now);
        self.drain(now);
        r
    }

    /// A client of a service: a writer of its request topic and a reader
    /// of its reply topic. Several clients of one service, in one domain or
    /// not, each get only the replies to their own queries.
    pub fn create_client(
        &mut self,
        config: &ServiceConfig,
        now: Instant,
    ) -> Result<ClientId, CreateError> {
        let id = ClientId(self.next_id());
        let (writer, reader) = self.add_pair(
            config.request(true),
            config.reply(false),
            Role::Client(id),
            now,
        )?;
        self.clients.insert(
            id,
            Client {
                writer,
                reader,
                style: config.style,
                id: header_id(writer),
                seq: 0,
                unmatched: 0,
            },
        );
        self.drain(now);
        Ok(id)
    }

    /// Deletes a client; its open queries fail
    /// ([`QueryFailure::ClientDeleted`]). False if there is no such client.
    pub fn delete_client(&mut self, client: ClientId, now: Instant) -> bool {
        let Some(c) = self.clients.remove(&client) else {
            return false;
        };
        let mut failed: Vec<QueryId> = Vec::new();
        self.waiting.retain(|q| {
            let mine = q.client == client;
            if mine {
                failed.push(q.query);
            }
            !mine
        });
        self.fail_sent(client, failed, QueryFailure::ClientDeleted);
        self.remove_writer(c.writer, now);
        self.remove_reader(c.reader, now);
        self.drain(now);
        true
    }

    /// Sends a request (serialized, padded as [`Domain::write`] pads) once
    /// the service is matched both ways (a request reader for our writer,
    /// a reply writer for our reader); its reply comes as [`Event::Reply`],
    /// or [`Event::QueryFailed`] after `timeout`.
    pub fn query(
        &mut self,
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
        now: Instant,
    ) -> Result<QueryId, WriteError> {
        if !self.clients.contains_key(&client) {
            return Err(WriteError::UnknownWriter);
        }
        let query = QueryId(self.next_id());
        self.waiting.push(Waiting {
            client,
            query,
            data,
            deadline: crate::time::later(now, timeout),
            timeout,
        });
        self.send_waiting(now);
        self.drain(now);
        Ok(query)
    }

    /// Forgets a query nobody waits for any longer (the application gave
    /// it up before its timeout): no [`Event::Reply`] or
    /// [`Event::QueryFailed`] names it, a reply that still comes is
    /// dropped, and it no longer counts among the deadlines. A request
    /// already sent is not taken back. False if it is not pending.
    pub fn cancel_query(&mut self, query: QueryId) -> bool {
        self.cancel_queries(&std::collections::HashSet::from([query])) == 1
    }

    /// [`cancel_query`](Self::cancel_query) for many at once (one pass);
    /// returns how many were pending.
    pub fn cancel_queries(&mut self, queries: &std::collections::HashSet<QueryId>) -> usize {
        let before = self.waiting.len() + self.inflight.len();
        self.waiting.retain(|q| !queries.contains(&q.query));
        let cancelled = &mut self.cancelled;
        self.inflight.retain(|key, q| {
            let keep = !queries.contains(&q.query);
            if !keep {
                cancelled.push_back(*key);
            }
            keep
        });
        while self.cancelled.len() > CANCELLED_KEPT {
            self.cancelled.pop_front();
        }
        before - (self.waiting.len() + self.inflight.len())
    }

    /// A writer and a reader for one side of a service (neither if
    /// either cannot be made).
    fn add_pair(
        &mut self,
        writer: EndpointConfig,
        reader: EndpointConfig,
        role: Role,
        now: Instant,
    ) -> Result<(Guid, Guid), CreateError> {
        let w = self.add_writer(writer, role, now)?;
        match self.add_reader(reader, role, now) {
            Ok(r) => Ok((w, r)),
            Err(e) => {
                self.remove_writer(w, now);
                Err(e)
            }
        }
    }

    /// Sends the queries whose service is matched both ways.
    pub(super) fn send_waiting(&mut self, now: Instant) {
        let mut i = 0;
        while i < self.waiting.len() {
            let Some(c) = self.clients.get(&self.waiting[i].client) else {
                i += 1;
                continue;
            };
            let (writer, reader) = (c.writer, c.reader);
            let ready = !self.p.matched_readers(writer).is_empty()
                && !self.p.matched_writers(reader).is_empty();
            if !ready {
                i += 1;
                continue;
            }
            let q = self.waiting.swap_remove(i);
            let style = c.style.unwrap_or_else(|| self.style_of_services(writer));
            let (change, header) = match style {
                RpcStyle::SampleIdentity => {
                    // as rmw_fastrtps clients do: the request names the
                    // reader its reply should go to (sequence number unknown)
                    let to = SampleIdentity {
                        writer: reader,
                        sequence_number: SequenceNumber(-1 << 32),
                    };
                    let change = Change::alive_owned(q.data).with_related_sample_identity(to);
                    (change, None)
                }
                RpcStyle::RequestHeader => {
                    let Some(c) = self.clients.get_mut(&q.client) else {
                        continue;
                    };
                    c.seq += 1;
                    let h = RequestHeader {
                        client: c.id,
                        seq: c.seq,
                    };
                    let mut data = q.data;
                    h.put(&mut data);
                    (Change::alive_owned(data), Some(h))
                }
            };
            let unmatched_before = self.clients.get(&q.client).map_or(0, |c| c.unmatched);
            match self.write_guid(writer, change, None, now) {
                Ok(sn) => {
                    let key = match header {
                        Some(h) => RequestKey::Header(h),
                        None => RequestKey::Identity(SampleIdentity {
                            writer,
                            sequence_number: sn,
                        }),
                    };
                    self.inflight.insert(
                        key,
                        Inflight {
                            client: q.client,
                            query: q.query,
                            deadline: q.deadline,
                            timeout: q.timeout,
                            unmatched_before,
                        },
                    );
                }
                Err(e) => self.events.push_back(Event::QueryFailed {
                    client: q.client,
                    query: q.query,
                    reason: QueryFailure::Refused(e),
                }),
            }
        }
    }

    /// A client's request writer or reply reader lost a match: when no
    /// service is left on either side, its queries that went out get no
    /// reply, and fail now rather than at their timeout. (A service that
    /// stops deletes its request reader at once but keeps its reply writer
    /// until its replies are acknowledged: a reply on its way still comes.)
    pub(super) fn client_unmatched(&mut self, client: ClientId) {
        let Some(c) = self.clients.get(&client) else {
            return;
        };
        if !self.p.matched_readers(c.writer).is_empty()
            || !self.p.matched_writers(c.reader).is_empty()
        {
            return;
        }
        self.fail_sent(client, Vec::new(), QueryFailure::ServiceLost);
    }

    /// Fails `failed` and the queries of `client` that went out, in the
    /// order they were made, for `reason`.
    fn fail_sent(&mut self, client: ClientId, mut failed: Vec<QueryId>, reason: QueryFailure) {
        self.inflight.retain(|_, q| {
            let mine = q.client == client;
            if mine {
                failed.push(q.query);
            }
            !mine
        });
        failed.sort();
        for query in failed {
            self.events.push_back(Event::QueryFailed {
                client,
                query,
                reason: reason.clone(),
            });
        }
    }

    /// Queries whose time ran out, waiting or sent.
    pub(super) fn expire_queries(&mut self, now: Instant) {
        let mut late: Vec<(ClientId, QueryId, QueryFailure)> = Vec::new();
        self.waiting.retain(|q| {
            let out = q.deadline <= now;
            if out {
                late.push((q.client, q.query, QueryFailure::NoService(q.timeout)));
            }
            !out
        });
        let clients = &self.clients;
        self.inflight.retain(|_, q| {
            let out = q.deadline <= now;
            if out {
                let unmatched = clients
                    .get(&q.client)
                    .map_or(0, |c| c.unmatched.saturating_sub(q.unmatched_before));
                let reason = if unmatched > 0 {
                    QueryFailure::Unmatched {
                        timeout: q.timeout,
                        replies: unmatched,
                    }
                } else {
                    QueryFailure::Timeout(q.timeout)
                };
                late.push((q.client, q.query, reason));
            }
            !out
        });
        late.sort_by_key(|l| l.1);
        for (client, query, reason) in late {
            self.events.push_back(Event::QueryFailed {
                client,
                query,
                reason,
            });
        }
    }

    pub(super) fn next_query_deadline(&self) -> Option<Instant> {
        let w = self.waiting.iter().map(|q| q.deadline);
        w.chain(self.inflight.values().map(|q| q.deadline)).min()
    }

    /// The style to ask the services matched with request writer
    /// `writer` in: by header when every one is a Cyclone DDS participant.
    fn style_of_services(&self, writer: Guid) -> RpcStyle {
        let readers = self.p.matched_readers(writer);
        let cyclone = |g: &Guid| {
            self.p
                .participant(g.prefix)
                .is_some_and(|d| RpcStyle::of_vendor(d.vendor) == RpcStyle::RequestHeader)
        };
        if !readers.is_empty() && readers.iter().all(cyclone) {
            RpcStyle::RequestHeader
        } else {
            RpcStyle::SampleIdentity
        }
    }

    /// A request for one of our services.
    pub(super) fn on_request(&mut self, service: ServiceId, mut s: ReceivedSample) {
        if s.kind != ChangeKind::Alive {
            return;
        }
        let Some(srv) = self.services.get(&service) else {
            return;
        };
        let style = srv
            .style
            .unwrap_or_else(|| match s.related_sample_identity {
                Some(_) => RpcStyle::SampleIdentity,
                None => self
                    .p
                    .participant(s.writer.prefix)
                    .map_or(RpcStyle::SampleIdentity, |d| RpcStyle::of_vendor(d.vendor)),
            });
        let header = match style {
            RpcStyle::RequestHeader => {
                RequestHeader::peek(s.data()).filter(|_| s.remove_data(4, request_header::LEN))
            }
            RpcStyle::SampleIdentity => None,
        };
        let request = match (header, s.related_sample_identity) {
            (Some(h), _) => RequestKey::Header(h),
            // as rmw_fastrtps: a request that names a reply reader (its
            // related identity's GUID) is answered for that GUID with the
            // request's sequence number; otherwise for the request itself
            (None, Some(r)) if r.writer.prefix != GuidPrefix::UNKNOWN => {
                RequestKey::Identity(SampleIdentity {
                    writer: r.writer,
                    sequence_number: s.sequence_number,
                })
            }
            (None, _) => RequestKey::Identity(s.identity()),
        };
        self.events.push_back(Event::Request {
            service,
            request: RequestId(request),
            sample: s,
        });
    }

    /// A reply to one of our queries (or another client's: ignored).
    pub(super) fn on_reply(&mut self, client: ClientId, mut s: ReceivedSample) {
        let Some(c) = self.clients.get_mut(&client) else {
            return;
        };
        let key = match s.related_sample_identity {
            // a reply names our request writer (Courier, Fast DDS) or our
            // reply reader (rmw_fastrtps) with the request's sequence number
            Some(id) => {
                let id = if id.writer == c.reader {
                    SampleIdentity {
                        writer: c.writer,
                        sequence_number: id.sequence_number,
                    }
                } else {
                    id
                };
                if id.writer != c.writer {
                    return; // another client's
                }
                RequestKey::Identity(id)
            }
            // rmw_cyclonedds: the header names the client
            None => match RequestHeader::peek(s.data()) {
                Some(h) if h.client == c.id => RequestKey::Header(h),
                Some(_) => return, // another client's
                None => {
                    c.unmatched += 1;
                    return;
                }
            },
        };
        let Some(q) = self.inflight.remove(&key) else {
            if let Some(i) = self.cancelled.iter().position(|k| *k == key) {
                // the answer to a query given up: nobody waits for it
                self.cancelled.remove(i);
                return;
            }
            // late, or for a query this client never made
            c.unmatched += 1;
            return;
        };
        if matches!(key, RequestKey::Header(_)) {
            s.remove_data(4, request_header::LEN);
        }
        self.events.push_back(Event::Reply {
            client: q.client,
            query: q.query,
            sample: s,
        });
    }
}
