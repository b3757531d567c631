//! A minimal DDS-XRCE agent for the tests: `courier_wire::xrce::Agent` on
//! UDP or TCP on 127.0.0.1, whose host relays what writers write to every
//! reader of the same topic (by name), requests to every replier of the
//! same service, and replies back to the requester that asked, as a DDS
//! domain behind a real agent would.
//!
//! Entities are understood in all three representations: binary (decoded),
//! XML (the `<name>` element, or `service_name`), reference (the profile
//! name is the topic). A topic whose name starts with `refused` is refused
//! with `STATUS_ERR_DDS_ERROR`, to test how errors reach the session (so
//! is a requester of a service whose name does).
//! Samples written while a topic has no reader are held (up to 1000 per
//! topic) for the first reader that comes, as a transient-local writer
//! would keep them: after a restart the writers' and readers' sessions
//! come back in any order.

#![allow(dead_code)]

use std::collections::{HashMap, VecDeque};
use std::hash::Hash;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Instant, SystemTime};

use courier::xrce::{
    Agent, AgentCommandError, AgentConfig, AgentEvent, BaseObjectRequest, BinaryRepresentation,
    ClientKey, ObjectId, ObjectKind, ObjectVariant, QueueError, ReadData, Representation,
    SampleIdentity, StatusCode, StreamError, StreamId,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, UdpSocket};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

#[derive(Debug, Clone)]
enum Obj {
    Topic(String),
    Writer(ObjectId),
    Reader(ObjectId),
    Requester(String),
    Replier(String),
    Other,
}

fn xml_value(xml: &str, open: &str, close: &str) -> Option<String> {
    let a = xml.find(open)? + open.len();
    let b = xml[a..].find(close)? + a;
    Some(xml[a..b].to_string())
}

/// What a representation names: the topic (topics) or service.
fn named(rep: &Representation, kind: ObjectKind) -> String {
    match rep {
        Representation::Reference(r) => r.clone(),
        Representation::Xml(x) => match kind {
            ObjectKind::Requester | ObjectKind::Replier => {
                xml_value(x, "service_name=\"", "\"").unwrap_or_default()
            }
            _ => xml_value(x, "<name>", "</name>").unwrap_or_default(),
        },
        Representation::Binary(b) => match BinaryRepresentation::decode(kind, b) {
            Ok(BinaryRepresentation::Topic(t)) => t.topic_name,
            Ok(BinaryRepresentation::Requester(s)) | Ok(BinaryRepresentation::Replier(s)) => {
                s.service_name
            }
            _ => String::new(),
        },
    }
}

/// The topic object a writer or reader refers to (binary: its topic id;
/// XML and reference: the topic named, looked up among the client's).
fn endpoint_topic(rep: &Representation, kind: ObjectKind) -> Result<ObjectId, String> {
    match rep {
        Representation::Binary(b) => match BinaryRepresentation::decode(kind, b) {
            Ok(BinaryRepresentation::DataWriter(w)) => Ok(w.topic_id),
            Ok(BinaryRepresentation::DataReader(r)) => Ok(r.topic_id),
            _ => Err(String::new()),
        },
        Representation::Xml(x) => Err(xml_value(x, "<name>", "</name>").unwrap_or_default()),
        Representation::Reference(r) => Err(r.clone()),
    }
}

/// The agent's host: entities and readings of every client.
#[derive(Default)]
struct Host {
    objects: HashMap<(ClientKey, ObjectId), Obj>,
    /// Endpoints created by name (XML, reference): the topic name.
    by_name: HashMap<(ClientKey, ObjectId), String>,
    reads: Vec<(ClientKey, ReadData)>,
    held: HashMap<String, Vec<Vec<u8>>>,
    out: VecDeque<(ClientKey, BaseObjectRequest, StreamId, Vec<u8>)>,
    /// What the [`TestAgent`] reads of it.
    counts: Arc<Counts>,
}

/// What a test reads of a running agent.
#[derive(Default)]
struct Counts {
    /// Requesters created so far.
    requesters: std::sync::atomic::AtomicUsize,
    /// Client sessions the agent has now.
    sessions: std::sync::atomic::AtomicUsize,
}

impl Host {
    fn topic_of(&self, client: ClientKey, endpoint: ObjectId) -> Option<String> {
        if let Some(n) = self.by_name.get(&(client, endpoint)) {
            return Some(n.clone());
        }
        let t = match self.objects.get(&(client, endpoint))? {
            Obj::Writer(t) | Obj::Reader(t) => *t,
            _ => return None,
        };
        match self.objects.get(&(client, t))? {
            Obj::Topic(n) => Some(n.clone()),
            _ => None,
        }
    }

    fn serve<A: Clone + Eq + Hash>(&mut self, a: &mut Agent<A>, now: Instant) {
        self.counts
            .sessions
            .store(a.clients().count(), Ordering::SeqCst);
        while let Some(e) = a.poll_event() {
            match e {
                AgentEvent::Create {
                    client,
                    request,
                    object,
                    reply_stream,
                    ..
                } => {
                    let id = request.object_id;
                    let mut status = StatusCode::OK;
                    let obj = match &object {
                        ObjectVariant::Topic { representation, .. } => {
                            let n = named(representation, ObjectKind::Topic);
                            if n.starts_with("refused") {
                                status = StatusCode::ERR_DDS_ERROR;
                            }
                            Obj::Topic(n)
                        }
                        ObjectVariant::DataWriter { representation, .. }
                        | ObjectVariant::DataReader { representation, .. } => {
                            let kind = object.kind();
                            let t = endpoint_topic(representation, kind);
                            let t = match t {
                                Ok(t) => t,
                                Err(name) => {
                                    self.by_name.insert((client, id), name);
                                    ObjectId::INVALID
                                }
                            };
                            if kind == ObjectKind::DataWriter {
                                Obj::Writer(t)
                            } else {
                                Obj::Reader(t)
                            }
                        }
                        ObjectVariant::Requester { representation, .. } => {
                            self.counts.requesters.fetch_add(1, Ordering::SeqCst);
                            let n = named(representation, ObjectKind::Requester);
                            if n.starts_with("refused") {
                                status = StatusCode::ERR_DDS_ERROR;
                            }
                            Obj::Requester(n)
                        }
                        ObjectVariant::Replier { representation, .. } => {
                            Obj::Replier(named(representation, ObjectKind::Replier))
                        }
                        _ => Obj::Other,
                    };
                    if status.is_ok() {
                        self.objects.insert((client, id), obj);
                    }
                    let _ = a.reply_status(client, request, status, reply_stream, now);
                }
                AgentEvent::Delete {
                    client,
                    request,
                    reply_stream,
                } => {
                    self.objects.remove(&(client, request.object_id));
                    self.by_name.remove(&(client, request.object_id));
                    self.reads
                        .retain(|(c, r)| (*c, r.request.object_id) != (client, request.object_id));
                    let _ = a.reply_status(client, request, StatusCode::OK, reply_stream, now);
                }
                AgentEvent::Read { client, read } => {
                    let id = read.request.object_id;
                    self.reads
                        .retain(|(c, r)| (*c, r.request.object_id) != (client, id));
                    let cancel = read
                        .delivery_control
                        .is_some_and(|d| d == Default::default());
                    if !cancel {
                        if id.kind() == Some(ObjectKind::DataReader) {
                            let held = self
                                .topic_of(client, id)
                                .and_then(|t| self.held.remove(&t))
                                .unwrap_or_default();
                            for d in held {
                                self.out.push_back((
                                    client,
                                    read.request,
                                    read.preferred_stream_id,
                                    d,
                                ));
                            }
                        }
                        self.reads.push((client, read));
                    }
                }
                // the test agent does not confirm writes (host_confirms_writes
                // off): the ticket needs no answer
                AgentEvent::Write {
                    client,
                    request,
                    data,
                    ..
                } => self.write(client, request, data),
                AgentEvent::ClientDeleted { client } => {
                    self.objects.retain(|(c, _), _| *c != client);
                    self.by_name.retain(|(c, _), _| *c != client);
                    self.reads.retain(|(c, _)| *c != client);
                }
                _ => {}
            }
        }
        while let Some((c, req, stream, d)) = self.out.pop_front() {
            match a.send_data(c, req, stream, &d, now) {
                Ok(()) => {}
                Err(AgentCommandError::Queue(QueueError::Stream(StreamError::Backlog {
                    ..
                }))) => {
                    self.out.push_front((c, req, stream, d));
                    break;
                }
                Err(_) => {}
            }
        }
    }

    fn write(&mut self, client: ClientKey, request: BaseObjectRequest, data: Vec<u8>) {
        let object = request.object_id;
        match self.objects.get(&(client, object)).cloned() {
            Some(Obj::Writer(_)) => {
                let Some(topic) = self.topic_of(client, object) else {
                    return;
                };
                let mut readers = 0;
                for (c, r) in &self.reads {
                    let is_reader = r.request.object_id.kind() == Some(ObjectKind::DataReader);
                    if is_reader && self.topic_of(*c, r.request.object_id).as_ref() == Some(&topic)
                    {
                        readers += 1;
                        self.out
                            .push_back((*c, r.request, r.preferred_stream_id, data.clone()));
                    }
                }
                if readers == 0 {
                    let held = self.held.entry(topic).or_default();
                    if held.len() < 1000 {
                        held.push(data);
                    }
                }
            }
            Some(Obj::Requester(service)) => {
                // the request's identity: who asked, with which request id
                let mut guid = [0u8; 16];
                guid[..4].copy_from_slice(&client.0);
                guid[4..6].copy_from_slice(&object.to_bytes());
                let identity = SampleIdentity {
                    writer_guid: guid,
                    sequence_high: 0,
                    sequence_low: u32::from(request.request_id.0),
                };
                for (c, r) in &self.reads {
                    if let Some(Obj::Replier(s)) = self.objects.get(&(*c, r.request.object_id)) {
                        if *s == service {
                            let mut body = identity.to_bytes().to_vec();
                            body.extend_from_slice(&data);
                            self.out
                                .push_back((*c, r.request, r.preferred_stream_id, body));
                        }
                    }
                }
            }
            Some(Obj::Replier(_)) => {
                let Some(id) = SampleIdentity::from_bytes(&data) else {
                    return;
                };
                let asker = ClientKey(id.writer_guid[..4].try_into().unwrap());
                let requester =
                    ObjectId(u16::from_be_bytes([id.writer_guid[4], id.writer_guid[5]]));
                let Some((c, r)) = self
                    .reads
                    .iter()
                    .find(|(c, r)| *c == asker && r.request.object_id == requester)
                else {
                    return;
                };
                let mut body = (id.sequence_low as u16).to_be_bytes().to_vec();
                body.extend_from_slice(&requester.to_bytes());
                body.extend_from_slice(&data[SampleIdentity::LEN..]);
                self.out
                    .push_back((*c, r.request, r.preferred_stream_id, body));
            }
            _ => {}
        }
    }
}

fn config() -> AgentConfig {
    let mut c = AgentConfig::default();
    c.streams.max_backlog = 4 << 20;
    // takes samples larger than a client session rebuilds (1 MiB)
    c.streams.max_reassembly = 4 << 20;
    c
}

/// A running test agent; dropping it stops it (the process "dies": its
/// sessions are gone).
pub struct TestAgent {
    pub addr: SocketAddr,
    task: JoinHandle<()>,
    muted: Arc<AtomicBool>,
    counts: Arc<Counts>,
}

impl TestAgent {
    /// Stops answering (and reading) without losing any state, or starts
    /// again.
    pub fn mute(&self, on: bool) {
        self.muted.store(on, Ordering::SeqCst);
    }

    /// How many client sessions it has now.
    pub fn sessions(&self) -> usize {
        self.counts.sessions.load(Ordering::SeqCst)
    }

    /// How many requesters (query clients) its clients created so far.
    pub fn requesters_created(&self) -> usize {
        self.counts.requesters.load(Ordering::SeqCst)
    }

    /// Stops it and waits until it has let its port go.
    pub async fn stop(self) {
        self.task.abort();
        let _ = (&mut { self }.task).await;
    }
}

impl Drop for TestAgent {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// An agent on UDP 127.0.0.1:`port` (0: any free port).
pub async fn udp(port: u16) -> TestAgent {
    udp_dropping(port, None).await
}

/// An agent on UDP that loses every `every`-th datagram it receives (a
/// lossy link; the kernel has no netem), or none.
pub async fn udp_dropping(port: u16, every: Option<u32>) -> TestAgent {
    let sock = UdpSocket::bind(("127.0.0.1", port)).await.unwrap();
    let addr = sock.local_addr().unwrap();
    let muted = Arc::new(AtomicBool::new(false));
    let counts = Arc::new(Counts::default());
    let c = counts.clone();
    let m = muted.clone();
    let task = tokio::spawn(async move {
        let mut agent: Agent<SocketAddr> = Agent::new(config(), Instant::now(), SystemTime::now());
        let mut host = Host {
            counts: c.clone(),
            ..Host::default()
        };
        let mut buf = vec![0u8; 65_536];
        let mut received = 0u32;
        loop {
            let wake = agent.poll_timeout();
            tokio::select! {
                r = sock.recv_from(&mut buf) => {
                    let Ok((n, from)) = r else { continue };
                    if m.load(Ordering::SeqCst) { continue; }
                    received = received.wrapping_add(1);
                    if every.is_some_and(|k| received % k == 0) { continue; }
                    let _ = agent.handle_input(from, &buf[..n], Instant::now());
                }
                _ = async {
                    match wake {
                        Some(t) => tokio::time::sleep_until(t.into()).await,
                        None => std::future::pending().await,
                    }
                } => agent.handle_timeout(Instant::now()),
                _ = tokio::time::sleep(std::time::Duration::from_millis(20)) => {}
            }
            if m.load(Ordering::SeqCst) {
                continue;
            }
            host.serve(&mut agent, Instant::now());
            while let Some((to, msg)) = agent.poll_transmit() {
                let _ = sock.send_to(&msg, to).await;
            }
        }
    });
    TestAgent {
        addr,
        task,
        muted,
        counts,
    }
}

/// An agent on TCP 127.0.0.1:`port` (0: any free port); each connection
/// is an address of its own.
pub async fn tcp(port: u16) -> TestAgent {
    let s = TcpSocket::new_v4().unwrap();
    s.set_reuseaddr(true).unwrap();
    s.bind(SocketAddr::from(([127, 0, 0, 1], port))).unwrap();
    let listener = s.listen(16).unwrap();
    let addr = listener.local_addr().unwrap();
    let muted = Arc::new(AtomicBool::new(false));
    let counts = Arc::new(Counts::default());
    let c = counts.clone();
    let m = muted.clone();
    let task = tokio::spawn(async move {
        let mut agent: Agent<u64> = Agent::new(config(), Instant::now(), SystemTime::now());
        let mut host = Host {
            counts: c.clone(),
            ..Host::default()
        };
        let (in_tx, mut in_rx) = mpsc::channel::<(u64, Vec<u8>)>(1024);
        let mut writers = HashMap::new();
        let mut readers = Vec::new();
        let mut next_conn = 1u64;
        loop {
            let wake = agent.poll_timeout();
            tokio::select! {
                c = listener.accept() => {
                    let Ok((stream, _)) = c else { continue };
                    stream.set_nodelay(true).unwrap();
                    let (mut r, w) = stream.into_split();
                    let id = next_conn;
                    next_conn += 1;
                    writers.insert(id, w);
                    let tx = in_tx.clone();
                    // aborted with the agent: the connection closes
                    readers.push(AbortOnDrop(tokio::spawn(async move {
                        let mut d = courier::xrce::tcp::TcpDeframer::new();
                        let mut buf = vec![0u8; 65_536];
                        loop {
                            match r.read(&mut buf).await {
                                Ok(0) | Err(_) => return,
                                Ok(n) => d.push(&buf[..n]),
                            }
                            while let Some(Ok(f)) = d.next_frame() {
                                if tx.send((id, f)).await.is_err() {
                                    return;
                                }
                            }
                        }
                    })));
                }
                Some((from, msg)) = in_rx.recv() => {
                    if !m.load(Ordering::SeqCst) {
                        let _ = agent.handle_input(from, &msg, Instant::now());
                    }
                }
                _ = async {
                    match wake {
                        Some(t) => tokio::time::sleep_until(t.into()).await,
                        None => std::future::pending().await,
                    }
                } => agent.handle_timeout(Instant::now()),
                _ = tokio::time::sleep(std::time::Duration::from_millis(20)) => {}
            }
            if m.load(Ordering::SeqCst) {
                continue;
            }
            host.serve(&mut agent, Instant::now());
            while let Some((to, msg)) = agent.poll_transmit() {
                if let Some(w) = writers.get_mut(&to) {
                    let mut frame = Vec::with_capacity(msg.len() + 2);
                    courier::xrce::tcp::encode(&msg, &mut frame).unwrap();
                    if w.write_all(&frame).await.is_err() {
                        writers.remove(&to);
                    }
                }
            }
        }
    });
    TestAgent {
        addr,
        task,
        muted,
        counts,
    }
}

struct AbortOnDrop(JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}
