//! [`SessionBuilder`], the options it keeps and which backends honour them.

use crate::backend::Backend;
use crate::ipc_backend::{IpcBackend, IpcOptions};
use crate::rtps_backend::{RtpsBackend, RtpsOptions};
use crate::scheme::Resolved;
use crate::session::Session;
use std::sync::Arc;
use std::time::Duration;

/// Why connecting failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// The URL's scheme names no backend this process knows.
    #[error("{}", unknown_scheme(url, scheme.as_deref(), known))]
    UnknownScheme {
        /// The URL.
        url: String,
        /// Its scheme (`None`: the URL has no `scheme://`).
        scheme: Option<String>,
        /// The schemes this process knows.
        known: Vec<String>,
    },
    /// An option was set that the URL's backend cannot honour.
    #[error("{option} is not an option of {scheme}:// sessions ({hint})")]
    Unsupported {
        /// The builder method.
        option: &'static str,
        /// The URL's scheme.
        scheme: String,
        /// Which backends have it.
        hint: &'static str,
    },
    /// A builder option's value is wrong (the URL is fine).
    #[error("bad {option}: {why}")]
    BadOption {
        /// The builder method.
        option: &'static str,
        /// What is wrong.
        why: String,
    },
    /// The URL is not understood.
    #[error("bad session URL {url:?}: {why}")]
    BadUrl {
        /// The URL.
        url: String,
        /// What is wrong.
        why: String,
    },
    /// No central answered.
    #[error("cannot connect to central at {addr} after {attempts} attempt(s)")]
    Unreachable {
        /// Where it tried.
        addr: String,
        /// How often.
        attempts: u32,
        /// The last error (the message does not repeat it).
        #[source]
        source: std::io::Error,
    },
    /// A DDS participant could not join the network (no such interface,
    /// no free participant index, a socket error).
    #[error("cannot join {url}: {why}")]
    Network {
        /// The session URL.
        url: String,
        /// Why.
        why: String,
    },
    /// No DDS-XRCE session with the agent: it did not answer CREATE_CLIENT,
    /// or refused it (the status code named).
    #[error("no DDS-XRCE session with the agent at {url}: {why}")]
    Agent {
        /// The session URL.
        url: String,
        /// Why.
        why: String,
    },
    /// The handshake failed.
    #[error("handshake with central at {addr} failed: {why}")]
    Handshake {
        /// Where.
        addr: String,
        /// Why.
        why: String,
    },
    /// `connect` was called outside a tokio runtime: a session's driver
    /// runs on the runtime it is made in, and is used from there.
    #[error(
        "connect() was called outside a tokio runtime: a Courier session runs on the tokio \
         runtime it is made in (with its I/O and time drivers: #[tokio::main], or a Runtime \
         built with enable_all() and its block_on), and is used from tasks of that runtime"
    )]
    NoRuntime,
}

fn unknown_scheme(url: &str, scheme: Option<&str>, known: &[String]) -> String {
    let what = match scheme {
        Some(s) => format!("unknown URL scheme {s:?} in {url:?}"),
        None => match url.split_once(':') {
            // `ipc:/host`, `rtps:7`: a known scheme without its `//`
            Some((s, rest)) if known.iter().any(|k| k.eq_ignore_ascii_case(s)) => {
                let rest = rest.trim_start_matches('/');
                return format!(
                    "session URL {url:?} lacks \"//\" after \"{s}:\": write {s}://{rest}"
                );
            }
            _ => format!("no scheme in session URL {url:?}"),
        },
    };
    format!("{what}; known schemes: {}", known.join(", "))
}

/// Builds a [`Session`].
#[derive(Debug, Clone)]
#[must_use = "a builder does nothing until `.connect().await`"]
pub struct SessionBuilder {
    pub(crate) url: String,
    pub(crate) name: Option<String>,
    pub(crate) opts: IpcOptions,
    pub(crate) rtps: crate::rtps_backend::RtpsOverrides,
    pub(crate) xrce: Option<Box<crate::xrce_backend::XrceOptions>>,
    /// Builder methods called, by the backends that honour them: one the
    /// URL's backend cannot honour fails `connect`.
    pub(crate) set: Vec<(&'static str, Honoured)>,
}

/// Which backends honour a [`SessionBuilder`] option.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Honoured {
    Ipc,
    Rtps,
    Both,
    Xrce,
}

/// `courier-<pid>` for the process's first session without a name, then
/// `courier-<pid>-2`, `courier-<pid>-3`, …
fn default_name() -> String {
    static UNNAMED: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let pid = std::process::id();
    match UNNAMED.fetch_add(1, std::sync::atomic::Ordering::Relaxed) {
        0 => format!("courier-{pid}"),
        n => format!("courier-{pid}-{}", n + 1),
    }
}

impl SessionBuilder {
    /// The module name (default: `courier-<pid>`, then `courier-<pid>-2`,
    /// `-3`, … for the process's later sessions without a name, as central
    /// refuses a second module of one name; DDS: the participant's entity
    /// name).
    pub fn name(mut self, name: impl Into<String>) -> Self {
        self.name = Some(name.into());
        self
    }

    /// `IPC_connectNoListen`: publishing is not filtered by the list of
    /// subscribed messages.
    pub fn no_listen(mut self) -> Self {
        self.set.push(("no_listen", Honoured::Ipc));
        self.opts.listen = false;
        self
    }

    /// How long to keep trying to reach central (default 5 s, as C's five
    /// one-second retries). IPC only: an RTPS session joins at once, and an
    /// XRCE one takes `attempts=` and `attempt_ms=` in its URL.
    pub fn connect_timeout(mut self, d: Duration) -> Self {
        self.set.push(("connect_timeout", Honoured::Ipc));
        self.opts.connect_timeout = d;
        self
    }

    /// After losing central, keep trying to reach it (first after `backoff`,
    /// doubling up to 5 s), then define and subscribe everything again;
    /// subscribers stay open meanwhile. Operations fail while disconnected
    /// (those issued while the new connection's handshake runs wait for
    /// it). As at start, central knows another module's subscriptions
    /// only once that module has reconnected too: IPC sends no message
    /// nobody subscribes to, so a publish right after a reconnect can reach
    /// nobody ([`Session::num_handlers`](crate::Session::num_handlers) says
    /// who is back).
    /// An embedded central reached through [`SessionBuilder::dial`] that has
    /// stopped is not retried: the session ends as without reconnect.
    pub fn reconnect(mut self, backoff: Duration) -> Self {
        self.set.push(("reconnect", Honoured::Ipc));
        self.opts.reconnect = Some(backoff);
        self
    }

    /// Lower latency for CPU: after every message keep polling for `window`
    /// instead of sleeping until the next one (see [`crate::busy_poll`]).
    /// Off by default; costs a CPU while messages flow. Effective on a
    /// current-thread tokio runtime; what it gains and costs is measured in
    /// the repository's `BENCHMARKS.md`. RTPS: also `busy_poll_us=` in the URL.
    /// At most [`busy_poll::MAX_WINDOW`](crate::busy_poll::MAX_WINDOW) (1 s);
    /// [`connect`](Self::connect) refuses a longer one.
    pub fn busy_poll(mut self, window: Duration) -> Self {
        self.set.push(("busy_poll", Honoured::Both));
        self.opts.busy_poll = Some(window);
        self.rtps.busy_poll = Some(window);
        self
    }

    /// IPC: reach central through `dial` instead of a socket; it is called
    /// for the first connection and for every reconnect. The URL still
    /// names central (error messages, direct mode's listening address).
    /// `courier::central::CentralHandle::session` (feature `central`) uses
    /// it for an in-process link to an embedded central.
    pub fn dial<F, Fut>(mut self, dial: F) -> Self
    where
        F: Fn() -> Fut + Send + Sync + 'static,
        Fut: std::future::Future<Output = std::io::Result<Box<dyn crate::ipc_backend::IpcStream>>>
            + Send
            + 'static,
    {
        self.set.push(("dial", Honoured::Ipc));
        self.opts.dial = Some(crate::ipc_backend::Dial::new(dial));
        self
    }

    /// RTPS: read user data on a receive thread of its own, which also runs
    /// the callbacks of [`SubscriberBuilder::listen`] (see
    /// [`RtpsOptions::receive_thread`]). Also `receive_thread=true` in the
    /// URL. `connect` refuses it on other backends.
    ///
    /// [`SubscriberBuilder::listen`]: crate::SubscriberBuilder::listen
    pub fn receive_thread(mut self, on: bool) -> Self {
        self.set.push(("receive_thread", Honoured::Rtps));
        self.rtps.receive_thread = Some(on);
        self
    }

    /// RTPS: the network interface, by name (`lo`) or IPv4 address
    /// (URL: `interface=`).
    pub fn interface(mut self, interface: impl Into<String>) -> Self {
        self.set.push(("interface", Honoured::Rtps));
        self.rtps.interface = Some(interface.into());
        self
    }

    /// RTPS: unicast discovery peers, `ip` or `ip:port` (URL: `peers=`);
    /// a peer list alone turns multicast off.
    pub fn peers<I: IntoIterator<Item = S>, S: Into<String>>(mut self, peers: I) -> Self {
        self.set.push(("peers", Honoured::Rtps));
        self.rtps.peers = Some(peers.into_iter().map(Into::into).collect());
        self
    }

    /// RTPS: standard SPDP multicast discovery on or off (URL: `multicast=`).
    pub fn multicast(mut self, on: bool) -> Self {
        self.set.push(("multicast", Honoured::Rtps));
        self.rtps.multicast = Some(on);
        self
    }

    /// RTPS: a fixed participant index instead of probing (URL: `index=`).
    pub fn participant_index(mut self, index: u32) -> Self {
        self.set.push(("participant_index", Honoured::Rtps));
        self.rtps.participant_index = Some(index);
        self
    }

    /// The largest message this session sends or takes, in bytes (its
    /// data, as [`ipc::to_vec`](crate::ipc::to_vec) or
    /// [`cdr::to_vec`](crate::cdr::to_vec) gives it).
    ///
    /// - IPC: 256 MiB by default, what Courier's central takes. A larger
    ///   publish, query or reply fails with [`PublishError::TooLarge`]
    ///   (nothing is sent); a larger message from central ends the
    ///   connection (logged; with [`reconnect`](Self::reconnect) the
    ///   session reconnects), as it cannot be skipped on the stream.
    /// - RTPS: 16 MiB by default (URL: `max_sample_size=`). A larger
    ///   sample is given up by the readers (a
    ///   [`SessionEvent::SampleLost`]), and a reliable writer goes on.
    ///
    /// [`PublishError::TooLarge`]: crate::PublishError::TooLarge
    /// [`SessionEvent::SampleLost`]: crate::SessionEvent::SampleLost
    pub fn max_message_bytes(mut self, bytes: usize) -> Self {
        self.set.push(("max_message_bytes", Honoured::Both));
        let room = courier_wire::ipc::module::FRAME_ROOM;
        self.opts.max_frame = (bytes as u64).saturating_add(room);
        self.rtps.max_sample_size = Some(bytes);
        self
    }

    /// RTPS: socket receive and send buffer sizes in bytes (URL:
    /// `recv_buffer=`, `send_buffer=`).
    pub fn socket_buffers(mut self, recv: usize, send: usize) -> Self {
        self.set.push(("socket_buffers", Honoured::Rtps));
        self.rtps.recv_buffer = Some(recv);
        self.rtps.send_buffer = Some(send);
        self
    }

    /// RTPS: the session is ROS 2 node `name` in `namespace` (`/` or
    /// `/a/b`): it publishes the node on `ros_discovery_info` and reads
    /// the other participants' (see [`RtpsOptions::ros2_node`]; URL:
    /// `ros2_node=/namespace/name`). Names that break ROS 2's naming rules
    /// fail `connect`, saying which rule.
    pub fn ros2_node(mut self, namespace: &str, name: &str) -> Self {
        self.set.push(("ros2_node", Honoured::Rtps));
        self.rtps.ros2_node = Some(courier_wire::ros2::names::Node::new(namespace, name));
        self
    }

    /// XRCE: every option of the session at once, typed, instead of the
    /// URL's: the URL is then the scheme alone (`xrce+udp://`; `connect`
    /// refuses one that names an address or options, which would not be
    /// read), and `opts.transport` says where the agent is.
    pub fn xrce(mut self, opts: crate::xrce_backend::XrceOptions) -> Self {
        self.set.push(("xrce", Honoured::Xrce));
        self.xrce = Some(Box::new(opts));
        self
    }

    /// Connects: `ipc://…` reaches a central, `rtps://<domain>?…` joins a
    /// DDS domain, `xrce+udp://host:port?…` (also `xrce+tcp://`,
    /// `xrce+serial:///dev/tty…`) creates a session with a DDS-XRCE agent
    /// (see [`XrceOptions::from_url`](crate::XrceOptions::from_url)), a scheme plugged in with
    /// [`register_scheme`](crate::scheme::register_scheme) its backend.
    ///
    /// Fails at once, naming the option, if an option was set that this
    /// URL's backend cannot honour (say, [`interface`](Self::interface) on
    /// an `ipc://` session), and names the known schemes for an unknown one.
    pub async fn connect(self) -> Result<Session, ConnectError> {
        if tokio::runtime::Handle::try_current().is_err() {
            return Err(ConnectError::NoRuntime);
        }
        let name = self.name.unwrap_or_else(default_name);
        let scheme = self.url.split_once("://").map_or("", |(s, _)| s);
        let refuse = |honoured: &[Honoured]| {
            let bad = self.set.iter().find(|(_, h)| !honoured.contains(h));
            bad.map(|(option, h)| ConnectError::Unsupported {
                option,
                scheme: scheme.to_string(),
                hint: match h {
                    Honoured::Ipc => "it is for ipc:// sessions",
                    Honoured::Rtps => "it is for rtps:// sessions",
                    Honoured::Both => "it is for ipc:// and rtps:// sessions",
                    Honoured::Xrce => {
                        "it is for xrce+udp://, xrce+tcp:// and xrce+serial:// sessions"
                    }
                },
            })
        };
        if let Some(why) = self
            .opts
            .busy_poll
            .and_then(|w| crate::busy_poll::check_window(w).err())
        {
            return Err(ConnectError::BadOption {
                option: "SessionBuilder::busy_poll",
                why,
            });
        }
        if self.rtps.max_sample_size == Some(0) {
            return Err(ConnectError::BadOption {
                option: "SessionBuilder::max_message_bytes",
                why: "0 bytes is no message".into(),
            });
        }
        let backend: Arc<dyn Backend> = match crate::scheme::resolve(&self.url)? {
            Resolved::Rtps => {
                if let Some(e) = refuse(&[Honoured::Rtps, Honoured::Both]) {
                    return Err(e);
                }
                let mut o = RtpsOptions::from_url(&self.url)?;
                self.rtps
                    .apply(&mut o)
                    .map_err(|e| ConnectError::BadOption {
                        option: "SessionBuilder::ros2_node",
                        why: e.to_string(),
                    })?;
                Arc::new(RtpsBackend::start(o, &name).await?)
            }
            Resolved::Xrce => {
                if let Some(e) = refuse(&[Honoured::Xrce]) {
                    return Err(e);
                }
                let o = match self.xrce {
                    // the options say where the agent is: a URL that says
                    // more would be silently ignored
                    Some(_)
                        if !self
                            .url
                            .split_once("://")
                            .is_some_and(|(_, r)| r.is_empty()) =>
                    {
                        return Err(ConnectError::BadUrl {
                            url: self.url.clone(),
                            why: "with .xrce(options), which say where the agent is and how, \
                                  give the scheme alone (xrce+udp://, xrce+tcp://, \
                                  xrce+serial://): the URL's address and options would not be \
                                  read"
                                .into(),
                        });
                    }
                    Some(o) => *o,
                    None => crate::xrce_backend::XrceOptions::from_url(&self.url)?,
                };
                Arc::new(crate::xrce_backend::XrceBackend::connect(o, &name).await?)
            }
            Resolved::Ipc => {
                if let Some(e) = refuse(&[Honoured::Ipc, Honoured::Both]) {
                    return Err(e);
                }
                Arc::new(IpcBackend::connect(&self.url, &name, self.opts).await?)
            }
            Resolved::Plugged(connect) => {
                if let Some(e) = refuse(&[]) {
                    return Err(e);
                }
                connect(crate::scheme::ConnectRequest {
                    url: self.url,
                    name: name.clone(),
                })
                .await?
            }
        };
        Ok(Session::with_backend(backend, name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// From a thread without a tokio runtime, `connect` says so, on every
    /// backend, instead of panicking in tokio (audit 15).
    #[test]
    fn connecting_outside_a_runtime_is_an_error_that_says_so() {
        for url in [
            "ipc://127.0.0.1:1",
            "rtps://7?interface=lo&peers=127.0.0.1",
            "xrce+udp://127.0.0.1:1",
        ] {
            let r = futures::executor::block_on(Session::builder(url).connect());
            match r {
                Err(e @ ConnectError::NoRuntime) => {
                    assert!(e.to_string().contains("outside a tokio runtime"), "{e}")
                }
                other => panic!("{url}: {other:?}"),
            }
        }
    }

    /// `.xrce(options)` with a URL that names an agent or options is
    /// refused: they would not be read (the options say where the agent
    /// is). The scheme alone goes on to connect with the options.
    #[tokio::test]
    async fn xrce_options_take_a_bare_scheme_only() {
        let opts = crate::xrce_backend::XrceOptions::from_url("xrce+udp://127.0.0.1:9").unwrap();
        for url in ["xrce+udp://127.0.0.1:8888", "xrce+udp://?domain=3"] {
            let e = crate::Session::builder(url)
                .xrce(opts.clone())
                .connect()
                .await
                .unwrap_err();
            assert!(
                matches!(&e, ConnectError::BadUrl { why, .. } if why.contains("scheme alone")),
                "{url}: {e}"
            );
        }
        // the scheme alone: the options are used (no agent there: it
        // gives up after its one attempt, not on the URL)
        let opts = crate::xrce_backend::XrceOptions::from_url(
            "xrce+udp://127.0.0.1:9?attempts=1&attempt_ms=50",
        )
        .unwrap();
        let e = crate::Session::builder("xrce+udp://")
            .xrce(opts)
            .connect()
            .await
            .unwrap_err();
        assert!(!matches!(e, ConnectError::BadUrl { .. }), "{e}");
    }
}
