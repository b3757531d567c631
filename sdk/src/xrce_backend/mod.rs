//! The DDS-XRCE backend (`xrce+udp://`, `xrce+tcp://`, `xrce+serial://`):
//! a client of a DDS-XRCE agent — eProsima's MicroXRCEAgent or any other —
//! which creates DDS entities on the session's behalf, so that a small
//! device reaches a DDS system through it.
//!
//! ```no_run
//! # #[derive(courier::IpcMessage, Debug)] #[ipc(type_name = "HelloWorld")] struct HelloWorld { index: u32, message: String }
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use courier::Session;
//! use futures::StreamExt;
//! let s = Session::builder("xrce+udp://127.0.0.1:8888").connect().await?;
//! let mut sub = s.subscribe::<HelloWorld>("HelloWorldTopic").await?;
//! let p = s.publisher::<HelloWorld>("HelloWorldTopic").build().await?;
//! p.publish(&HelloWorld { index: 1, message: "hi".into() }).confirmed().await?; // the agent has it
//! let got = sub.next().await.unwrap()?;
//! let rtt = s.xrce()?.ping(std::time::Duration::from_secs(1)).await?;
//! let clock = s.xrce()?.sync_time(std::time::Duration::from_secs(1)).await?;
//! # let _ = (got, rtt, clock); Ok(()) }
//! ```
//!
//! The protocol is [`courier_wire::xrce::Client`], a sans-I/O machine; this
//! module gives it a link ([`XrceTransport`]) and a clock in one driver
//! task, which the [`Backend`] methods send commands to.
//!
//! # How the Session API maps onto XRCE
//! - The session has one participant (in [`XrceOptions::domain`]), one
//!   publisher and one subscriber, created with the first entity that
//!   needs them; each topic is created once.
//! - A publication is a DataWriter. Reliable publications write on the
//!   built-in reliable stream 0x80 (fragmenting samples larger than the
//!   MTU), best-effort ones on 0x01 (a sample larger than the MTU is
//!   refused with [`PublishError::TooLarge`]).
//!   `publish().await` resolves once the sample is queued;
//!   `publish().confirmed()` once the agent has acknowledged every byte of
//!   it — the agent confirms nothing beyond that: whether its DDS write
//!   succeeded it does not say.
//! - A subscription is a DataReader with a READ_DATA of unlimited samples
//!   on the stream its reliability picks. A full keep-all queue of a
//!   reliable subscription stops the reading of the link until the
//!   application takes a sample: the agent's reliable window then holds
//!   the rest (back-pressure); a best-effort one drops and counts. A
//!   best-effort subscription gets only samples that fit one message of
//!   the session's MTU (`mtu=`, 508 bytes by default): only reliable
//!   streams fragment, so the agent drops larger ones before they reach
//!   the session, which cannot count them (Courier's agent logs it once
//!   per reader). Subscribe reliably for samples that may be larger.
//! - Matching is the agent's: XRCE has no message that tells a client its
//!   endpoint does not match another one (another type on the topic,
//!   incompatible QoS), so a session sees no
//!   [`SessionEvent::TypeMismatch`] or
//!   `IncompatibleQos` here; Courier's agent logs each such pair.
//! - `query` is a requester and `serve` a replier, with the request and
//!   reply topics `rq/<name>Request` and `rr/<name>Reply` that Courier's
//!   RTPS backend and ROS 2 use; each request carries its sample identity
//!   to the replier and back.
//! - Samples cross the XRCE link without their 4-byte CDR encapsulation
//!   header (the agent strips and adds it); the backend takes it off and
//!   puts it back, so the bytes a subscriber sees are as on RTPS.
//! - Entities are described by binary representation by default, or as
//!   XML or reference profiles ([`XrceRepresentation`]).
//!
//! # Finding the agent
//! [`XrceDiscovery`] asks a list of addresses (and, if told, the
//! multicast group) which agents are there, as `uxr_discovery_agents`
//! does; `xrce+udp://?discover=ip:port,…` connects to the first that
//! answers.
//!
//! # Reconnection
//! When the agent stops answering for [`XrceOptions::lost_after`] (or
//! answers without knowing the session, or a TCP connection breaks), the
//! session reports [`SessionEvent::AgentLost`] and keeps its `Subscriber`s
//! open. When the agent answers again with the session intact it reports
//! [`SessionEvent::AgentBack`]; when the agent had lost it (restarted), the
//! session is created again with every entity and reading, then
//! [`SessionEvent::SessionRecreated`]. Reliable writes the agent had not
//! acknowledged are sent again in the new session (so a sample may reach
//! the agent twice); publishes, queries and opens made while no session
//! exists wait for one, in order, for [`XrceOptions::agent_wait`], then
//! fail with an error: nothing is dropped silently.

mod cmd;
mod discovery;
mod driver;
mod options;
mod repr;
mod transport;

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use courier_wire::xrce::{Client, ClientConfig, Keepalive, StreamConfig};
use tokio::sync::{mpsc, oneshot};

use crate::backend::{
    Backend, Capabilities, ClientId, Handle, PubId, ServiceId, SubId, TimeSync, XrceControl,
    XrceState,
};
use crate::builder::ConnectError;
use crate::error::{ControlError, OpenError, PublishError, QueryError};
use crate::event::SessionEvent;
use crate::hub::Hub;
use crate::mailbox::{mailbox, Mailbox};
use crate::qos::{PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{Encoding, RawReply, RawRequest, SampleQueue, WriteOptions};
use cmd::Cmd;

pub use discovery::{DiscoverError, FoundAgent, XrceDiscovery};
pub use options::{RefKind, XrceCreation, XrceOptions, XrceRepresentation, XrceTransport};

/// What the backend's callers read without asking the driver.
#[derive(Debug)]
pub(crate) struct Shared {
    sync: Mutex<Option<TimeSync>>,
    state: AtomicU8,
    key: u32,
}

impl Shared {
    fn set_state(&self, s: XrceState) {
        let v = match s {
            XrceState::Connected => 0,
            XrceState::Lost => 1,
            XrceState::Closed => 2,
        };
        self.state.store(v, Ordering::Relaxed);
    }

    fn set_sync(&self, t: TimeSync) {
        *self.sync.lock().unwrap_or_else(|p| p.into_inner()) = Some(t);
    }
}

/// A session's DDS-XRCE client (see the [module docs](self)).
#[derive(Debug)]
pub struct XrceBackend {
    cmd: Mailbox<Cmd>,
    hub: Hub<SessionEvent>,
    shared: Arc<Shared>,
    scheme: &'static str,
    /// Service names of the open clients, for errors.
    clients: Mutex<std::collections::HashMap<ClientId, Arc<str>>>,
}

/// A random client key (never 0): this process, this moment, a random seed.
fn random_key() -> u32 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u128(
        SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .unwrap_or_default()
            .as_nanos(),
    );
    (h.finish() as u32).max(1)
}

fn disconnected<E: crate::error::Failure>() -> E {
    E::disconnected("the XRCE agent (session closed)".into())
}

/// Opens the link; a TCP agent that refuses the connection (not started
/// yet) is tried again as a UDP one is, [`XrceOptions::connect_attempts`]
/// times [`XrceOptions::connect_interval`] apart.
async fn open_link(opts: &XrceOptions, mtu: usize) -> Result<transport::Link, String> {
    use std::io::ErrorKind;
    let mut tries = 1;
    loop {
        match transport::Link::open(&opts.transport, mtu).await {
            Ok(l) => return Ok(l),
            Err(e)
                if matches!(opts.transport, XrceTransport::Tcp(_))
                    && matches!(e.kind(), ErrorKind::ConnectionRefused) =>
            {
                if tries >= opts.connect_attempts {
                    return Err(format!(
                        "{e} ({tries} attempt(s) {:?} apart: is the agent running, on TCP at \
                         that port? attempts= and attempt_ms= set how long to try)",
                        opts.connect_interval
                    ));
                }
                tries += 1;
                tokio::time::sleep(opts.connect_interval).await;
            }
            Err(e) => return Err(e.to_string()),
        }
    }
}

impl XrceBackend {
    /// Opens the link and creates the session with the agent
    /// (CREATE_CLIENT, [`XrceOptions::connect_attempts`] times at most).
    /// With [`XrceOptions::discovery`], the agent is the first that
    /// answers discovery.
    pub async fn connect(mut opts: XrceOptions, name: &str) -> Result<Self, ConnectError> {
        if let Some(d) = &opts.discovery {
            let found = d.first().await.map_err(|e| ConnectError::Agent {
                url: "xrce+udp://?discover=…".into(),
                why: e.to_string(),
            })?;
            tracing::debug!("XRCE: discovered the agent at {}", found.address);
            opts.transport = XrceTransport::Udp(found.address.to_string());
        }
        let url = opts.transport.to_string();
        let scheme = match opts.transport {
            XrceTransport::Udp(_) => "xrce+udp://",
            XrceTransport::Tcp(_) => "xrce+tcp://",
            XrceTransport::Serial { .. } => "xrce+serial://",
        };
        let mtu = usize::from(opts.mtu);
        let link = open_link(&opts, mtu)
            .await
            .map_err(|why| ConnectError::Network {
                url: url.clone(),
                why,
            })?;
        let key = opts.client_key.unwrap_or_else(random_key);
        let mut cfg = ClientConfig::new(key);
        cfg.session_id = opts.session_id;
        cfg.streams = StreamConfig {
            mtu,
            depth: opts.depth,
            max_backlog: usize::from(opts.history).max(1) * mtu,
            max_reassembly: (1 << 20).max(mtu),
            ..StreamConfig::client().delayed_acks()
        };
        cfg.create_attempts = opts.connect_attempts;
        cfg.create_interval = opts.connect_interval;
        // a close (or a cancelled connect) waits for the DELETE's STATUS,
        // so briefly: one DELETE, lost on a lossy link, left the session
        // on the agent until it evicted it
        cfg.delete_attempts = driver::DELETE_ATTEMPTS;
        cfg.delete_interval = driver::DELETE_INTERVAL;
        cfg.keepalive = Some(Keepalive {
            interval: opts.keepalive,
            timeout: opts.lost_after,
        });
        let shared = Arc::new(Shared {
            sync: Mutex::new(None),
            state: AtomicU8::new(1),
            key,
        });
        let hub = Hub::new(crate::hub::DEFAULT_CAPACITY);
        let (tx, rx) = mailbox(crate::mailbox::CAPACITY);
        let (ctx, crx) = oneshot::channel();
        let d = driver::Driver::new(
            opts,
            name.to_string(),
            Client::new(cfg),
            hub.clone(),
            shared.clone(),
            tx.downgrade(),
            ctx,
        );
        tokio::spawn(driver::run(d, rx, Some(link)));
        match crx.await {
            Ok(Ok(())) => Ok(XrceBackend {
                cmd: tx,
                hub,
                shared,
                scheme,
                clients: Mutex::default(),
            }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(ConnectError::Agent {
                url,
                why: "the driver ended".into(),
            }),
        }
    }

    async fn ask<T, E: crate::error::Failure>(
        &self,
        make: impl FnOnce(cmd::Reply<T, E>) -> Cmd,
    ) -> Result<T, E> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(make(tx)).await.map_err(|_| disconnected())?;
        rx.await.map_err(|_| disconnected())?
    }

    /// As `ask`, for a command that opens what `handle` names: if the
    /// caller stops waiting (a `timeout` or `select!` drops the future),
    /// what the driver opened is closed (see [`OpenAnswer`]).
    ///
    /// [`OpenAnswer`]: crate::open_answer::OpenAnswer
    async fn ask_open<T: Copy, E: crate::error::Failure>(
        &self,
        handle: fn(T) -> Handle,
        make: impl FnOnce(cmd::Reply<T, E>) -> Cmd,
    ) -> Result<T, E> {
        crate::open_answer::ask_open(&self.cmd, self, handle, make, disconnected).await
    }
}

#[async_trait::async_trait]
impl Backend for XrceBackend {
    fn capabilities(&self) -> Capabilities {
        let mut c = Capabilities::new(self.scheme, Encoding::Cdr);
        c.confirmed_writes = true;
        c.offers_liveliness = true;
        c
    }

    async fn open_publication(
        &self,
        topic: &str,
        ty: &TypeInfo,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError> {
        crate::error::dds_name(topic)?;
        if ty.is_untyped() {
            return Err(OpenError::Unsupported {
                what: format!(
                    "a publication of {topic} without its type (use Session::define::<T>() or \
                     Session::publisher::<T>())"
                ),
                backend: self.scheme,
            });
        }
        let (topic, ty, qos) = (topic.to_string(), ty.clone(), Box::new(qos.clone()));
        self.ask_open(Handle::Publication, |reply| Cmd::Publication {
            topic,
            ty,
            qos,
            reply,
        })
        .await
    }

    async fn open_subscription(
        &self,
        topic: &str,
        ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError> {
        crate::error::dds_name(topic)?;
        let (topic, ty, qos) = (
            topic.to_string(),
            ty.filter(|t| !t.is_untyped()).cloned(),
            Box::new(qos.clone()),
        );
        self.ask_open(Handle::Subscription, |reply| Cmd::Subscription {
            topic,
            ty,
            qos,
            queue,
            reply,
        })
        .await
    }

    async fn open_service(
        &self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        queue: usize,
    ) -> Result<(ServiceId, mpsc::Receiver<RawRequest>), OpenError> {
        crate::error::dds_name(name)?;
        let (tx, rx) = mpsc::channel(queue.max(1));
        let (name, req, resp) = (name.to_string(), req.clone(), resp.clone());
        let id = self
            .ask_open(Handle::Service, |reply| Cmd::Service {
                name,
                req,
                resp,
                tx,
                reply,
            })
            .await?;
        Ok((id, rx))
    }

    async fn open_client(
        &self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        crate::error::dds_name(name)?;
        let (name, req, resp) = (name.to_string(), req.clone(), resp.clone());
        let n: Arc<str> = Arc::from(name.as_str());
        let id = self
            .ask_open(Handle::Client, |reply| Cmd::Client {
                name,
                req,
                resp,
                reply,
            })
            .await?;
        self.clients
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(id, n);
        Ok(id)
    }

    async fn write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        let confirm = opts.confirm;
        let (tx, rx) = oneshot::channel();
        self.cmd
            .send(Cmd::Write {
                publication,
                data,
                confirm: confirm.is_some(),
                reply: tx,
            })
            .await
            .map_err(|_| disconnected::<PublishError>())?;
        match confirm {
            None => rx.await.map_err(|_| disconnected::<PublishError>())?,
            Some(after) => match tokio::time::timeout(after, rx).await {
                Ok(r) => r.map_err(|_| disconnected::<PublishError>())?,
                Err(_) => Err(PublishError::Timeout {
                    what: "the XRCE agent's acknowledgement".into(),
                    after,
                }),
            },
        }
    }

    async fn query(
        &self,
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        let (tx, rx) = oneshot::channel();
        let name = self
            .clients
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(&client)
            .map_or_else(|| format!("{client:?}"), |n| n.to_string());
        let gone = || QueryError::Disconnected(name.clone());
        let deadline = courier_wire::time::later(Instant::now(), timeout);
        let sent = tokio::time::timeout_at(
            deadline.into(),
            self.cmd.send(Cmd::Query {
                client,
                data,
                reply: tx,
            }),
        )
        .await;
        let timed_out = || {
            let msg = name.clone();
            if self.state() == XrceState::Lost {
                QueryError::AgentLost { msg, timeout }
            } else {
                QueryError::Timeout { msg, timeout }
            }
        };
        match sent {
            Ok(Ok(())) => {}
            Ok(Err(_)) => return Err(gone()),
            Err(_) => return Err(timed_out()),
        }
        match tokio::time::timeout_at(deadline.into(), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(gone()),
            Err(_) => Err(timed_out()),
        }
    }

    fn close_handle(&self, handle: Handle) {
        if let Handle::Client(c) = handle {
            self.clients
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .remove(&c);
        }
        // one per handle
        let _ = self.cmd.post(Cmd::CloseHandle(handle));
    }

    fn events(&self) -> crate::hub::Listener<SessionEvent> {
        self.hub.listen()
    }

    async fn close(&self) {
        self.cmd
            .close_session(Arc::as_ptr(&self.shared) as usize, |reply| Cmd::Close {
                reply,
            })
            .await
    }

    fn xrce(&self) -> Option<&dyn XrceControl> {
        Some(self)
    }
}

#[async_trait::async_trait]
impl XrceControl for XrceBackend {
    async fn ping(&self, timeout: Duration) -> Result<Duration, ControlError> {
        match tokio::time::timeout(timeout, self.ask(|reply| Cmd::Ping { reply })).await {
            Ok(r) => r,
            Err(_) => Err(ControlError::Timeout {
                what: "a ping of the XRCE agent".into(),
                after: timeout,
            }),
        }
    }

    async fn sync_time(&self, timeout: Duration) -> Result<TimeSync, ControlError> {
        match tokio::time::timeout(timeout, self.ask(|reply| Cmd::SyncTime { reply })).await {
            Ok(r) => r,
            Err(_) => Err(ControlError::Timeout {
                what: "a time sync with the XRCE agent".into(),
                after: timeout,
            }),
        }
    }

    fn time_offset(&self) -> Option<TimeSync> {
        *self.shared.sync.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn state(&self) -> XrceState {
        match self.shared.state.load(Ordering::Relaxed) {
            0 => XrceState::Connected,
            1 => XrceState::Lost,
            _ => XrceState::Closed,
        }
    }

    fn client_key(&self) -> u32 {
        self.shared.key
    }
}

impl Drop for XrceBackend {
    fn drop(&mut self) {
        // the driver deletes the session and ends
        let (tx, _rx) = oneshot::channel();
        let _ = self.cmd.post(Cmd::Close { reply: tx });
    }
}

#[cfg(test)]
mod serial_tests {
    //! `xrce+serial://` over a pseudo-terminal pair: an agent machine on
    //! the master side, the session on the slave's path.

    use std::io::{Read, Write};
    use std::time::{Duration, Instant, SystemTime};

    use courier_wire::xrce::serial::{self, SerialDecoder};
    use courier_wire::xrce::{Agent, AgentConfig, AgentEvent, ObjectKind, StatusCode};
    use futures::StreamExt;
    use tokio::io::Interest;

    use crate::session::Session;

    const T: Duration = Duration::from_secs(20);

    /// The agent: answers every CREATE with OK and hands every written
    /// sample to every reading reader (one client, one topic).
    async fn agent(master: std::fs::File) {
        let fd = crate::sys::net::register(master, Interest::READABLE | Interest::WRITABLE)
            .expect("register the pty");
        let mut agent: Agent<u8> =
            Agent::new(AgentConfig::default(), Instant::now(), SystemTime::now());
        let mut dec = SerialDecoder::new();
        let mut reads = Vec::new();
        let mut buf = vec![0u8; 4096];
        loop {
            let wake = agent.poll_timeout();
            tokio::select! {
                g = fd.readable() => {
                    let Ok(mut g) = g else { return };
                    match g.try_io(|f| f.get_ref().read(&mut buf)) {
                        Ok(Ok(n)) if n > 0 => dec.push(&buf[..n]),
                        Ok(_) => tokio::time::sleep(Duration::from_millis(10)).await,
                        Err(_) => {}
                    }
                }
                _ = tokio::time::sleep_until(
                    wake.unwrap_or_else(|| Instant::now() + Duration::from_millis(50)).into()
                ) => agent.handle_timeout(Instant::now()),
            }
            while let Some(Ok(f)) = dec.next_frame() {
                let _ = agent.handle_input(f.src, &f.payload, Instant::now());
            }
            let now = Instant::now();
            while let Some(e) = agent.poll_event() {
                match e {
                    AgentEvent::Create {
                        client,
                        request,
                        reply_stream,
                        ..
                    } => {
                        let _ =
                            agent.reply_status(client, request, StatusCode::OK, reply_stream, now);
                    }
                    AgentEvent::Read { client, read }
                        if read.request.object_id.kind() == Some(ObjectKind::DataReader) =>
                    {
                        reads.push((client, read));
                    }
                    AgentEvent::Write { data, .. } => {
                        for (c, r) in &reads {
                            let _ =
                                agent.send_data(*c, r.request, r.preferred_stream_id, &data, now);
                        }
                    }
                    _ => {}
                }
            }
            while let Some((to, m)) = agent.poll_transmit() {
                let mut frame = Vec::new();
                serial::encode(0, to, &m, &mut frame).unwrap();
                let mut at = 0;
                while at < frame.len() {
                    let Ok(mut g) = fd.writable().await else {
                        return;
                    };
                    if let Ok(Ok(n)) = g.try_io(|f| f.get_ref().write(&frame[at..])) {
                        at += n;
                    }
                }
            }
        }
    }

    #[tokio::test]
    async fn a_session_over_a_pseudo_terminal() {
        let (master, path) = crate::sys::tty::pty_pair().expect("a pty pair");
        let a = tokio::spawn(agent(master));
        let s = tokio::time::timeout(
            T,
            Session::builder(format!("xrce+serial://{path}?baud=115200")).connect(),
        )
        .await
        .unwrap()
        .unwrap();
        let x = s.xrce().unwrap();
        x.ping(T).await.unwrap();
        x.sync_time(T).await.unwrap();
        let mut sub = s.subscribe::<u32>("line").await.unwrap();
        let p = s.publisher::<u32>("line").build().await.unwrap();
        for i in 0..20u32 {
            p.publish(&i).await.unwrap();
        }
        for i in 0..20u32 {
            let got = tokio::time::timeout(T, sub.next())
                .await
                .unwrap()
                .unwrap()
                .unwrap();
            assert_eq!(got.value, i);
        }
        s.close().await;
        a.abort();
    }
}
