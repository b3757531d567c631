//! # courier
//!
//! Typed messages for robots: derive [`IpcMessage`] on a struct and get the
//! CMU IPC format string, IPC marshalling byte-identical to the C library,
//! and DDS CDR (XCDR1 and XCDR2), all generated at compile time.
//!
//! ```
//! use courier::IpcMessage;
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(numeric)]
//! enum Status { Wait, Send, Receive, Listen }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! struct T1 { i1: i32, status: Status, matrix: [[f64; 3]; 2], d1: f64 }
//!
//! assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
//! let t1 = T1 { i1: 666, status: Status::Send, matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]], d1: 3.14 };
//! let bytes = courier::ipc::to_vec(&t1);
//! assert_eq!(bytes.len(), 64);
//! assert_eq!(courier::ipc::from_slice::<T1>(&bytes).unwrap(), t1);
//! let cdr = courier::cdr::to_vec(&t1, courier::cdr::Encoding::Xcdr1Le);
//! assert_eq!(courier::cdr::from_slice::<T1>(&cdr).unwrap(), t1);
//! ```
//!
//! # Quick start
//!
//! One program, no external process: a CMU IPC central embedded on a free
//! port (cargo feature `central`), two modules, a publish/subscribe and a
//! query. The `sensor` module connects over TCP exactly as a C module
//! would; `logger` uses an in-process link to the central it hosts.
//!
//! Courier runs on the application's tokio runtime (either flavour):
//! sessions are made inside one, and their calls are best awaited there.
//! A thread outside any runtime may still await them with another
//! executor (`futures::executor::block_on`, a GUI's): the calls that make
//! tokio timers or tasks (queries, timers, `send_every`, `listen`,
//! `wait_for_handlers`) make them on the session's runtime, which must be
//! running then — a multi-threaded runtime always is, a current-thread
//! runtime only while its `block_on` runs (tokio's rule for
//! `Handle::block_on`). Streams
//! (`Subscriber`, `Requests`, `Timer`, `Events`) are `futures::Stream`s:
//! add `futures` for `StreamExt::next` and the other combinators
//! (`Subscriber::recv` and `Requests::recv` wait for the next item
//! without it).
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier::central::CentralServer;
//! use courier::{IpcMessage, Session};
//! use futures::StreamExt;
//!
//! #[derive(IpcMessage, Debug, Clone, PartialEq)]
//! struct Reading { sensor: String, celsius: f64 }
//!
//! let central = CentralServer::builder().port(0).spawn().await?; // 127.0.0.1, any free port
//! let url = format!("ipc://{}", central.local_addr());
//! let sensor = Session::builder(&url).name("sensor").connect().await?;
//! let logger = central.session("logger").connect().await?;
//!
//! // publish / subscribe
//! let mut readings = logger.subscribe::<Reading>("reading").await?;
//! sensor.num_handlers("reading").await?; // see "Rules" below: central now lists the subscriber
//! sensor.publish("reading", &Reading { sensor: "t1".into(), celsius: 21.5 }).await?;
//! let sample = tokio::time::timeout(Duration::from_secs(5), readings.next())
//!     .await?
//!     .ok_or("subscription ended")??;
//! assert_eq!(sample.value.celsius, 21.5);
//!
//! // query / response: a server task answers, the query waits at most 5 s
//! let mut requests = logger.serve::<String, u32>("length", "").await?;
//! tokio::spawn(async move {
//!     while let Some(req) = requests.next().await {
//!         // a request that does not decode is an error item: skip it
//!         let Ok(req) = req else { continue };
//!         let n = req.value.len() as u32;
//!         if let Err(e) = req.reply(&n).await {
//!             eprintln!("reply failed: {e}");
//!         }
//!     }
//! });
//! let n: u32 = sensor.query("length", &"four".to_string()).timeout(Duration::from_secs(5)).await?;
//! assert_eq!(n, 4);
//!
//! sensor.close().await;
//! logger.close().await;
//! central.shutdown().await;
//! # Ok(()) }
//! ```
//!
//! `cargo run --example demo` in the repository takes one type through IPC,
//! DDS and DDS-XRCE; `cargo run --example pub` / `sub` / `query` / `serve`
//! work on any backend's URL.
//!
//! ## Rules
//!
//! - **Keep the [`Session`] alive.** It stays connected while any clone of
//!   it, or any handle made from it ([`Subscriber`], [`Requests`],
//!   [`Publisher`], …), lives, and disconnects when the last is dropped
//!   (an [`Events`] stream or a [`Timer`] does not keep it: keep the
//!   session beside them);
//!   `close().await` disconnects at once (the handles' streams end, their
//!   calls fail) and waits for the goodbye (DDS: and, for up to a second,
//!   for its readers to acknowledge what its writers still hold). Dropping a handle closes that
//!   handle only.
//! - **How streams end.** A [`Subscriber`] or [`Requests`] stream ends
//!   with `None` after [`Session::close`] (on any clone of the session); a
//!   session that loses its connection (central gone, the XRCE agent
//!   silent) ends them with one `Err(RecvError::Disconnected)` item, then
//!   `None`. Other `Err` items (a sample that does not decode) are not the
//!   end: loop on `next()` and skip or log the errors you expect, or let
//!   `s?` in the loop turn every error, a lost connection included, into
//!   the task's. An [`Events`] stream ends the same way: after
//!   `SessionEvent::Disconnected` when the connection is lost, without it
//!   after `close()`.
//! - **Bound your awaits.** `connect` gives up by itself (IPC: after
//!   [`SessionBuilder::connect_timeout`], 5 s by default; RTPS at once;
//!   XRCE after its attempts), a query after its `.timeout(d)` (10 s by
//!   default) and a confirmed publish after its `.confirmed_within(d)`; a
//!   subscription's `next()` waits for the next sample however long that
//!   takes, so wrap it in `tokio::time::timeout` where silence is an error.
//! - **Cancelling is safe.** Any of these futures may be dropped by a
//!   `timeout`, a `select!` or an aborted task:
//!   - `next()` / `recv()` of a [`Subscriber`], [`Requests`] or [`Events`]
//!     lose nothing: the item stays for the next call;
//!   - an open (`subscribe`, `serve`, `publisher(..).build()`, `listen`,
//!     the first query of a service) leaves nothing open;
//!   - a dropped query is given up (a server may still get it: queries are
//!     not taken back);
//!   - a dropped `publish` is sent if the session had queued it, and not
//!     otherwise, never in part;
//!   - a dropped `close()` still closes the session.
//! - **IPC sends no message nobody subscribes to** (as C): a publish before
//!   central told the module about a subscriber returns `Ok` and sends
//!   nothing. `Session::num_handlers` asks central and makes the answer
//!   count at once; `Session::wait_for_handlers(msg, n, timeout)` waits
//!   for `n` subscribers (DDS: matched readers) first.
//! - **Full queues.** A subscription queues 1000 unread samples by default
//!   ([`QueuePolicy::KeepAll`]); then it stops taking more: on IPC central
//!   holds the rest (back-pressure up to the publisher; central hands a
//!   module its messages one by one, so the session's other subscriptions
//!   and servers wait too, reported as `SessionEvent::SubscriberFull`). With
//!   [`QueuePolicy::KeepLast`] (`subscribe_with`, or `keep_last(n)`) the
//!   oldest of each instance are dropped instead, counted by
//!   `Subscriber::dropped`. Nothing is dropped silently.
//! - **IPC serves one delivery at a time.** Central hands a module its
//!   next message once the last is done, and a request is done when it is
//!   answered (a capacity of 1, as C): a server that takes 200 ms to reply
//!   delays the session's other subscriptions by as much. Give a slow
//!   server a session of its own, or raise the capacity
//!   ([`IpcControl::set_capacity`], through `session.ipc()?`).
//! - **Errors chain.** An error caused by a lower layer (central's
//!   refusal, a socket error, a type IPC cannot carry) says what failed and
//!   keeps the cause as its [`source()`](std::error::Error::source): print
//!   the chain (anyhow's `{:#}`, or walk `source()`) to see both.
//! - **DDS on a shared network:** a participant uses multicast discovery
//!   on the default interface unless told otherwise; pin it (`interface`,
//!   `peers`, `multicast=false`) to keep its traffic where you want it.
//!
//! # One quick start per backend
//!
//! ## IPC through a central
//!
//! The quick start above; against a separate `central` (Courier's or the C
//! one) the URL names it: `Session::builder("ipc://robot:1381")`, or
//! `"ipc://"` for `CENTRALHOST` / localhost:1381 as C does.
//!
//! ## IPC direct links
//!
//! With a central started in direct mode (`central -c`, or
//! `Config::direct`), modules register with central but send each other
//! messages over TCP links of their own; the API does not change.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier::central::{CentralServer, Config};
//! use courier::Session;
//! use futures::StreamExt;
//!
//! let mut config = Config::default();
//! config.direct = true; // as `central -c`
//! let central = CentralServer::builder().port(0).config(config).spawn().await?;
//! let url = format!("ipc://{}", central.local_addr());
//! let a = Session::builder(&url).name("a").connect().await?;
//! let b = Session::builder(&url).name("b").connect().await?;
//! let mut sub = b.subscribe::<i32>("count").await?;
//! a.num_handlers("count").await?;
//! a.publish("count", &7i32).await?; // over a link from a to b, not through central
//! let s = tokio::time::timeout(Duration::from_secs(5), sub.next()).await?.ok_or("ended")??;
//! assert_eq!(s.value, 7);
//! a.close().await;
//! b.close().await;
//! central.shutdown().await;
//! # Ok(()) }
//! ```
//!
//! ## DDS / RTPS
//!
//! `rtps://DOMAIN` joins a DDS domain as a DDSI-RTPS participant that
//! Cyclone DDS, Fast DDS and ROS 2 see as one of theirs. Pinned to `lo`
//! with unicast discovery, nothing leaves the machine. Discovery takes a
//! moment: a volatile sample written before the reader is matched is not
//! delivered to it, so this example makes both ends transient-local.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier::{IpcMessage, Session};
//! use futures::StreamExt;
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(type_name = "HelloWorldData::Msg")] // Cyclone DDS's HelloWorld
//! struct Msg { #[ipc(key)] user_id: i32, message: String }
//!
//! # let domain = courier_tests::domains::lease(1);
//! // `domain`: the DDS domain id (0..=232), here one leased for the test
//! let url = format!("rtps://{domain}?interface=lo&peers=127.0.0.1&multicast=false");
//! let a = Session::builder(&url).name("a").connect().await?;
//! let b = Session::builder(&url).name("b").connect().await?;
//! let writer = a.publisher::<Msg>("HelloWorldData_Msg").transient_local().keep_last(1).build().await?;
//! let mut reader = b.subscriber::<Msg>("HelloWorldData_Msg").transient_local().build().await?;
//! writer.publish(&Msg { user_id: 1, message: "Hello World".into() }).await?;
//! let s = tokio::time::timeout(Duration::from_secs(10), reader.next()).await?.ok_or("ended")??;
//! assert_eq!(s.value.message, "Hello World");
//! drop((writer, reader));
//! a.close().await;
//! b.close().await;
//! # Ok(()) }
//! ```
//!
//! ## DDS-XRCE
//!
//! `xrce+udp://host:port` (or `xrce+tcp://`, `xrce+serial:///dev/ttyX`)
//! is a DDS-XRCE client of an agent: eProsima's MicroXRCEAgent or
//! `courier-broker`'s, embedded here on a free port, its DDS side pinned
//! to `lo`. `domain=` names the DDS domain the agent joins for the client.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier::rtps_backend::RtpsOptions;
//! use courier::Session;
//! use courier_broker::xrce_agent::{Transport, XrceAgent};
//! use futures::StreamExt;
//!
//! # let domain = courier_tests::domains::lease(1);
//! let rtps = RtpsOptions::loopback(domain); // lo, unicast to 127.0.0.1, no multicast
//! let agent = XrceAgent::builder()
//!     .transport(Transport::Udp("127.0.0.1:0".parse()?))
//!     .rtps(rtps)
//!     .spawn()
//!     .await?;
//! let url = format!("xrce+udp://{}?domain={domain}", agent.udp_addrs()[0]);
//! let device = Session::builder(&url).name("device").connect().await?;
//! let mut sub = device.subscribe::<String>("chatter").await?;
//! device.publish("chatter", &"hello".to_string()).await?; // through the agent's DDS participant
//! let s = tokio::time::timeout(Duration::from_secs(10), sub.next()).await?.ok_or("ended")??;
//! assert_eq!(s.value, "hello");
//! drop(sub);
//! device.close().await;
//! agent.shutdown().await;
//! # Ok(()) }
//! ```
//!
//! # Sessions
//!
//! A [`Session`] is one module's connection; over CMU IPC it talks to a
//! `central` (Courier's, see `courier-broker`, or the original C one). This
//! one needs a central already running on localhost:1381, so it is only
//! compiled as a test (the quick starts above run):
//!
//! ```no_run
//! # #[derive(courier::IpcMessage, Debug)] struct T1 { i1: i32 }
//! # #[derive(courier::IpcMessage, Debug)] struct T2 { s: String }
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use courier::Session;
//! use futures::StreamExt;
//! use std::time::Duration;
//!
//! let session = Session::builder("ipc://localhost:1381").name("module1").connect().await?;
//! session.define::<i32>("message1").await?;
//! session.publish("message1", &42i32).await?;
//! let mut sub = session.subscribe::<String>("message2").await?;
//! let r: T2 = session.query("query1", &T1 { i1: 666 }).timeout(Duration::from_secs(2)).await?;
//! while let Some(s) = sub.next().await {
//!     println!("{} on {}", s?.value, "message2");
//! }
//! # Ok(()) }
//! ```
//!
//! With the cargo feature `central`, `courier::central` embeds CMU IPC's central
//! server itself (what `courier-broker`'s `central` binary runs), so that a
//! program can host it and connect its own modules over an in-process link,
//! with no separate process: `courier = { version = "…", features =
//! ["central"] }`.
//!
//! ## The IPC API and its Courier equivalents (manual §4–§8)
//!
//! | IPC | Courier |
//! |---|---|
//! | `IPC_initialize`, `IPC_connect`, `IPC_connectModule` | `Session::builder(url).name(..).connect().await` |
//! | `IPC_connectNoListen`, `IPC_connectModuleNoListen` | `SessionBuilder::no_listen` |
//! | `IPC_disconnect` | `Session::close`, or dropping the last clone |
//! | `IPC_isConnected` | a failed operation returns its error's `Disconnected` variant; `events()` yields `Disconnected` |
//! | `IPC_isModuleConnected` | `Session::is_module_connected` (also `session.ipc()?.is_module_connected`) |
//! | `IPC_defineMsg`, `IPC_isMsgDefined` | `Session::define::<T>` (the format comes from the type); `session.ipc()?.define(msg, format)` with a format string known at run time |
//! | `IPC_defineFormat`, `IPC_checkMsgFormats` | `session.ipc()?.define_formats::<T>()` (automatic in `define`); formats are checked at compile time by the derive |
//! | `IPC_publish`, `IPC_publishData`, `IPC_publishVC`, `IPC_publishFixed` | `Session::publish` (typed) / `publish_raw` (bytes); `Session::publisher::<T>(msg).build()` for a `Publisher` handle |
//! | `IPC_subscribe`, `IPC_subscribeData`, `IPC_unsubscribe` | `Session::subscribe::<T>` / `subscribe_raw`; dropping the `Subscriber` unsubscribes. A handler-style callback: `session.subscriber::<T>(msg).listen(f)` (run on a task of its own on IPC; on RTPS where the datagram is read) |
//! | `IPC_numHandlers` | `Session::num_handlers` |
//! | `IPC_subscribeConnect`, `IPC_subscribeDisconnect`, their `unsubscribe` | `Session::events()` (`ModuleConnected` / `ModuleDisconnected`); drop the stream |
//! | `IPC_subscribeHandlerChange` | `Session::watch_handlers` + `events()` (`HandlersChanged`) |
//! | `IPC_queryResponse`, `IPC_queryResponseData`, `IPC_queryNotify` | `Session::query(..).timeout(d).await` (spawn it for notify-style use) |
//! | `IPC_respond`, `IPC_respondData`, `IPC_delayResponse` | `Session::serve` → `Request::reply`, callable later and from any task |
//! | `IPC_listen`, `IPC_listenClear`, `IPC_listenWait`, `IPC_handleMessage`, `IPC_dispatch` | not needed: driving the `Stream`s (a tokio task reads the socket all the time) |
//! | `IPC_subscribeFD`, `IPC_unsubscribeFD` | not needed: `tokio::select!` over your own I/O and the streams |
//! | `IPC_setCapacity` | `session.ipc()?.set_capacity(n)` ([`Session::ipc`]: the IPC-only controls, [`IpcControl`]) |
//! | `IPC_setMsgPriority` | `session.ipc()?.set_priority(msg, p)` |
//! | `IPC_setMsgQueueLength` | `session.ipc()?.set_queue_length(msg, n)` |
//! | `IPC_setVerbosity`, `IPC_perror` | `tracing`; every error is a typed `Result` |
//! | `IPC_marshall`, `IPC_unmarshall`, `IPC_freeData*`, `IPC_msgFormatter`, `IPC_parseFormat` | `courier::ipc::to_vec` / `from_slice`, `#[derive(IpcMessage)]`; Rust frees memory |
//! | `IPC_getContext`, `IPC_setContext` | several `Session`s (each its own connection) |
//! | `IPC_addTimer`, `IPC_addOneShotTimer`, `IPC_addPeriodicTimer`, `IPC_removeTimer` | `Session::every`, `after`, `times`: `Stream`s of `Tick { scheduled, fired }`; drop to remove; they end when the session is closed |
//! | `IPC_printData`, `IPC_readData` | `courier::ipc::print_value` / `decode_value` (dynamic values) |
//! | `IPC_msgInstanceName`, `IPC_dataLength` | `Sample::msg`, `RawSample::data.len()`; `Sample::source` (the sender) stays `None` on IPC: no IPC frame carries it |
//!
//! ## The Micro XRCE-DDS client API and its Courier equivalents
//!
//! A session over `xrce+udp://`, `xrce+tcp://` or `xrce+serial://` is a
//! DDS-XRCE client of an agent (see [`xrce_backend`]). Every function of
//! eProsima's client library (v2.x):
//!
//! | Micro XRCE-DDS | Courier |
//! |---|---|
//! | `uxr_init_udp_transport`, `uxr_init_tcp_transport`, `uxr_init_serial_transport` | the URL: `xrce+udp://host:port`, `xrce+tcp://host:port` (one write per frame, `TCP_NODELAY`), `xrce+serial:///dev/ttyX?baud=115200` |
//! | `uxr_close_PROTOCOL_transport` | `Session::close`, or dropping the last clone |
//! | `uxr_init_can_transport` | none: no CAN link (CAN FD needs SocketCAN and a frame mapping of its own) |
//! | `uxr_init_custom_transport`, `uxr_set_custom_transport_callbacks` | a backend of your own under a URL scheme of your own ([`scheme::register_scheme`]), driving [`xrce::Client`] over your link |
//! | `uxr_init_session`, `uxr_create_session`, `uxr_create_session_retries` | `Session::builder(url).connect().await` (client key `key=`, session id `session=`, attempts `attempts=`/`attempt_ms=`; [`XrceOptions`]) |
//! | `uxr_delete_session`, `uxr_delete_session_retries` | `Session::close` (what the reliable streams hold is acknowledged first, up to `linger_ms`, as `uxr_run_session_until_confirm_delivery`; then the DELETE is sent, its STATUS awaited briefly) |
//! | `uxr_create_output_best_effort_stream`, `uxr_create_output_reliable_stream`, `uxr_create_input_best_effort_stream`, `uxr_create_input_reliable_stream` | not needed: every session has the built-in best-effort (0x01) and reliable (0x80) streams; a publication's or subscription's [`Reliability`] picks one; window and history: `depth=`, `history=`, `mtu=` |
//! | `uxr_stream_id`, `uxr_stream_id_from_raw`, `uxr_object_id` | not needed: the session allocates object ids and streams; `courier::xrce::{StreamId, ObjectId}` for code that drives the machine itself |
//! | `uxr_buffer_create_participant_{bin,xml,ref}` | automatic: one participant per session, in `domain=`, made with the first entity, by the representation of `representation=binary\|xml\|reference` (`ref.participant=` names its profile) |
//! | `uxr_buffer_create_topic_{bin,xml,ref}` | automatic: each topic once, named and typed by the Rust type's [`TypeInfo`] (`#[ipc(type_name = …)]`, keys) |
//! | `uxr_buffer_create_publisher_{bin,xml}`, `uxr_buffer_create_subscriber_{bin,xml}` | automatic: one publisher and one subscriber per session |
//! | `uxr_buffer_create_datawriter_{bin,xml,ref}` | `Session::publisher::<T>(topic).qos(q).build().await` (or a first `publish`/`define`) |
//! | `uxr_buffer_create_datareader_{bin,xml,ref}` | `Session::subscriber::<T>(topic).qos(q).build().await`, `Session::subscribe` |
//! | `uxr_buffer_create_requester_{bin,xml,ref}` | `Session::query` (one requester per service, made on first use) |
//! | `uxr_buffer_create_replier_{bin,xml,ref}` | `Session::serve::<Req, Resp>(name, "")` |
//! | `uxr_buffer_delete_entity` | dropping the `Publisher`, `Subscriber`, `Requests` |
//! | `uxr_set_status_callback`, `uxr_run_session_until_all_status`, `uxr_run_session_until_one_status` | the `build().await` of each entity resolves once the agent's STATUS came; a refusal is [`OpenError::Refused`] naming the XRCE status code; later ones are [`SessionEvent::EntityError`] |
//! | `uxr_prepare_output_stream`, `uxr_prepare_output_stream_fragmented`, `uxr_buffer_topic` | `Publisher::publish(&value).await` (typed; samples larger than the MTU are fragmented on reliable streams), `Session::publish_raw` (bytes) |
//! | `uxr_run_session_until_confirm_delivery` | `publish(&value).confirmed().await` (bounded: `.confirmed_within(d)`) |
//! | `uxr_buffer_request_data`, `uxr_set_topic_callback`, `uxr_run_session_until_data` | the `Subscriber` stream (a READ_DATA of unlimited samples for as long as it lives), or `subscriber::<T>(topic).listen(f)` for a callback |
//! | `uxr_buffer_cancel_data` | dropping the `Subscriber` |
//! | `uxr_buffer_request`, `uxr_set_reply_callback` | `Session::query(name, &req).timeout(d).await` |
//! | `uxr_set_request_callback`, `uxr_buffer_reply` | the `Requests` stream of `serve`, `Request::reply` (the sample identity travels with the request) |
//! | `uxr_run_session_time`, `uxr_run_session_timeout`, `uxr_run_session_until_timeout`, `uxr_run_session`, `uxr_flash_output_streams` | not needed: a tokio task runs the session all the time and sends what is queued at once |
//! | `uxr_ping_agent`, `uxr_ping_agent_attempts`, `uxr_ping_agent_session` | `session.xrce()?.ping(timeout).await` ([`XrceControl`]); a session also pings by itself after `keepalive_ms=` of silence |
//! | `uxr_sync_session`, `uxr_set_time_callback` | `session.xrce()?.sync_time(timeout).await` → [`TimeSync`] (`offset_ns`, `rtt`) |
//! | `uxr_epoch_millis`, `uxr_epoch_nanos` | `session.xrce()?.agent_time()` (the agent's clock by the last sync) |
//! | `uxr_discovery_agents`, `uxr_discovery_agents_default` | [`xrce_backend::XrceDiscovery`]: `.agent(addr)…` (unicast list) and `.multicast()` (239.255.0.2:7400), then `.all().await` (every agent that answered, with its XRCE version and vendor) or `.first().await`; a session on the first agent found: `xrce+udp://?discover=ip:port,…\|multicast` ([`XrceOptions::discovery`]) |
//! | the ping-and-recreate loop every eProsima application writes | not needed: the session reconnects by itself ([`SessionEvent::AgentLost`], [`SessionEvent::AgentBack`], [`SessionEvent::SessionRecreated`]), keeping its `Subscriber`s and its unacknowledged reliable writes |
//!
//! ## Deviations from CMU IPC
//! - Publishing a message nobody subscribes is silently not sent, as in C
//!   (the module filters by central's `X_IPC_BROADCAST_MSG_VAR`); use
//!   `no_listen()` to send regardless. `publish` still returns `Ok`.
//! - A delivery is acknowledged to central (C's "handler finished") when it
//!   is queued for its `Subscriber` (1000 samples), not when the user reads
//!   it; a full queue holds the acknowledgement, which is back-pressure to
//!   central. A query counts until it is answered.
//! - A query whose handler is being unsubscribed at that moment is lost, as
//!   in C.
//! - Direct mode (`central -c`): the session listens on the first free port
//!   from 8000 (on 127.0.0.1 when central is on loopback, else on all
//!   interfaces, like C) and links to receivers itself; unlike C, a message
//!   is never lost because the receiver list is learned late (it waits for
//!   the links), and a query of a message nobody serves yet waits for its
//!   first handler, within its timeout, as a routed query waits in central
//!   (C drops it: "No handlers for direct message"). As in C (`x_ipcDirectResource`, `x_ipc_connectAt`) the
//!   session also listens at `/tmp/x_ipc/<port>` (removed when it closes;
//!   a leftover file is replaced, one somebody still answers on is left
//!   alone), and reaches a receiver whose host is this machine's name over
//!   that UNIX socket first, TCP otherwise.
#![warn(missing_docs)]
#![deny(unsafe_code)]

pub mod backend;
mod builder;
pub mod busy_poll;
#[cfg(feature = "central")]
#[cfg_attr(docsrs, doc(cfg(feature = "central")))]
pub mod central;
mod deadline;
pub mod derive_guide;
mod direct_link;
#[doc(hidden)]
pub mod driver_timer;
mod error;
pub mod event;
mod format_check;
mod home;
pub mod hub;
mod in_callback;
pub mod ipc_backend;
mod mailbox;
mod open_answer;
mod publisher;
pub mod qos;
mod queue;
mod reply;
mod rpc;
pub mod rtps_backend;
pub mod scheme;
pub mod session;
mod session_end;
mod subscriber;
mod sys;
mod timer;
mod topics;
pub mod xrce_backend;

pub use backend::{
    Backend, Capabilities, ClientId, DdsControl, Handle, IpcControl, PubId, ServiceId, SubId,
    TimeSync, WriteNow, XrceControl, XrceState,
};
/// `#[derive(IpcMessage)]`: its type mapping and every `#[ipc(...)]`
/// attribute are in [`derive_guide`].
pub use courier_derive::IpcMessage;
pub use courier_wire::{
    cdr, format, ipc, key_hash, key_hash_in, rtps, rtps::matching::Incompatible, xrce, IpcMessage,
    LengthError, Matrix, NamedFormats, NdVec, ShapeError,
};
pub use error::{ControlError, Error, OpenError, PublishError};
pub use event::{DurabilityKind, EndpointInfo, Guid, ParticipantInfo, QosSummary};
pub use ipc_backend::{IpcStream, CENTRAL_ANSWER_TIMEOUT};
pub use qos::{DataRepresentation, Durability, History, KeyOf, Reliability};
pub use rtps_backend::{Ros2Node, Ros2NodeName, RtpsOptions, ServiceStyle};
pub use session::{
    ConnectError, Delivery, Encoding, Events, InstanceChange, InstanceState, Ipc, Listener,
    PeriodicPublication, PublicationQos, Publish, PublishFuture, Publisher, PublisherBuilder,
    Query, QueryError, QueuePolicy, RawReply, RawRequest, RawRequests, RawSample, RawSubscriber,
    Received, RecvError, Request, Requests, Responder, Sample, SampleQueue, Samples, Session,
    SessionBuilder, SessionEvent, Subscriber, SubscriberBuilder, SubscriptionQos, Tick, Timer,
    TypeInfo, WithInstances, WriteOptions,
};
pub use xrce_backend::{XrceOptions, XrceRepresentation, XrceTransport};

#[doc(hidden)]
pub use courier_wire as __wire;
