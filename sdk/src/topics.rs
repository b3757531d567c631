//! The one type each topic (IPC message) carries within a session.
//!
//! Two Rust types with the same IPC format string and the same DDS type
//! name put the same bytes on the wire, so they may share a topic; any
//! other pair may not: a subscriber would get bytes it cannot decode (IPC)
//! or never match the writer (DDS). The typed API binds a topic to its type
//! on first use and refuses another type afterwards, naming both.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use courier_wire::IpcMessage;

use crate::backend::{ClientId, PubId};
use crate::error::OpenError;
use crate::qos::TypeInfo;

/// A topic's type as bound by its first typed use.
#[derive(Debug, Clone, Copy)]
struct Bound {
    /// The Rust type of the first use, for error messages.
    rust: &'static str,
    format: &'static str,
    type_name: &'static str,
}

impl Bound {
    fn of<T: IpcMessage>() -> Self {
        Bound {
            rust: std::any::type_name::<T>(),
            format: T::FORMAT,
            type_name: T::TYPE_NAME,
        }
    }
}

/// What a session keeps per topic: its type once bound, the session's
/// own publication of it (`Session::define`, `Session::publish`) and its
/// client (`Session::query`), opened on first use and kept open while the
/// session lives. A topic with neither is forgotten, binding and all, when
/// the last of its publishers, subscribers and servers goes ([`TopicUse`]):
/// a node that makes topics by name (one per robot it meets, say) does not
/// keep every name it ever used.
#[derive(Debug, Default, Clone, Copy)]
struct Entry {
    bound: Option<Bound>,
    /// DDS and XRCE: the reply type of the session's client (its reply
    /// reader has that type).
    reply: Option<Bound>,
    /// A typed use succeeded: the binding stays.
    in_use: bool,
    publication: Option<PubId>,
    client: Option<ClientId>,
    /// Live publishers, subscribers and servers of the topic ([`TopicUse`]).
    users: u32,
    /// Typed first uses under way ([`Unsettled`]).
    pending: u32,
}

impl Entry {
    /// Nothing of the session's holds the topic.
    fn unused(&self) -> bool {
        self.users == 0 && self.pending == 0 && self.publication.is_none() && self.client.is_none()
    }
}

/// The lock of a client being opened, with the error of an open that
/// failed (see `Topics::opening`).
pub(crate) type ClientOpening = Arc<tokio::sync::Mutex<Option<OpenError>>>;

/// A session's topic → type bindings and shared handles, shared by the
/// session's clones.
#[derive(Debug, Default)]
pub(crate) struct Topics {
    map: Mutex<HashMap<String, Entry>>,
    /// A lock per service whose client is being opened: tasks that make
    /// the first query of a service at once open one client, not one each
    /// (on XRCE, a thousand requesters created and deleted on the agent).
    /// It holds the error of an open that failed, for those who waited.
    opening: Mutex<HashMap<String, ClientOpening>>,
}

impl Topics {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Entry>> {
        // a panic elsewhere cannot leave the map half-updated: every update
        // is one insert or one field store
        self.map.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The lock to hold while opening the client of `msg` (see
    /// [`Topics::client_open_done`]).
    pub(crate) fn client_opening(&self, msg: &str) -> ClientOpening {
        let mut opening = self.opening.lock().unwrap_or_else(|e| e.into_inner());
        opening.entry(msg.to_string()).or_default().clone()
    }

    /// The open of `msg`'s client ended (either way): its lock goes, and
    /// the next first query opens anew; those already waiting find the
    /// client, or the error left in the lock.
    pub(crate) fn client_open_done(&self, msg: &str) {
        self.opening
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(msg);
    }

    /// DDS and XRCE: binds the replies of the service `msg` to `R`, or
    /// checks that they are bound to a type with the same wire form (the
    /// session's one client of the service reads replies of one type).
    pub(crate) fn bind_reply<R: IpcMessage>(&self, msg: &str) -> Result<(), OpenError> {
        let mut map = self.lock();
        let e = map.entry(msg.to_string()).or_default();
        match e.reply {
            Some(b) if b.format == R::FORMAT && b.type_name == R::TYPE_NAME => Ok(()),
            Some(b) => Err(OpenError::TypeMismatch {
                msg: format!("{msg}'s reply"),
                bound: b.rust,
                given: std::any::type_name::<R>(),
            }),
            None => {
                e.reply = Some(Bound::of::<R>());
                Ok(())
            }
        }
    }

    /// Binds `msg` to `T`, or checks that it is bound to a type with the
    /// same wire form. `Ok(Some(_))`: the session's publication of the
    /// topic, once it has one.
    pub(crate) fn bind<T: IpcMessage>(&self, msg: &str) -> Result<Option<PubId>, OpenError> {
        let mut map = self.lock();
        let e = map.entry(msg.to_string()).or_default();
        match e.bound {
            Some(b) if b.format == T::FORMAT && b.type_name == T::TYPE_NAME => Ok(e.publication),
            Some(b) => Err(OpenError::TypeMismatch {
                msg: msg.to_string(),
                bound: b.rust,
                given: std::any::type_name::<T>(),
            }),
            None => {
                e.bound = Some(Bound::of::<T>());
                Ok(e.publication)
            }
        }
    }

    /// A typed use of `msgs` that bound them has ended: on success the
    /// bindings stay; on failure, a binding no use has confirmed (and
    /// that holds no publication or client) is forgotten, so that a failed
    /// first attempt does not hold the topic to its type.
    pub(crate) fn settle(&self, msgs: &[&str], ok: bool) {
        let mut map = self.lock();
        for m in msgs {
            if let Some(e) = map.get_mut(*m) {
                if ok {
                    e.in_use = true;
                } else if !e.in_use && e.publication.is_none() && e.client.is_none() {
                    e.bound = None;
                    e.reply = None;
                    if e.unused() {
                        map.remove(*m);
                    }
                }
            }
        }
    }

    /// A publisher, subscriber or server of `msg` of type `T` opened:
    /// the topic stays bound to `T` at least while the returned use lives.
    pub(crate) fn hold<T: IpcMessage>(self: &Arc<Self>, msg: &str) -> TopicUse {
        {
            let mut map = self.lock();
            let e = map.entry(msg.to_string()).or_default();
            // bound already, unless it was forgotten in the meantime (the
            // last other use went while this one was being opened)
            e.bound.get_or_insert_with(Bound::of::<T>);
            e.users += 1;
        }
        TopicUse {
            topics: self.clone(),
            msg: msg.to_string(),
        }
    }

    fn release(&self, msg: &str) {
        let mut map = self.lock();
        if let Some(e) = map.get_mut(msg) {
            e.users = e.users.saturating_sub(1);
            if e.unused() {
                map.remove(msg);
            }
        }
    }

    /// Topics the session keeps an entry for (tests).
    #[cfg(test)]
    fn len(&self) -> usize {
        self.lock().len()
    }

    /// The session's publication of `msg`, if it has one.
    pub(crate) fn publication(&self, msg: &str) -> Option<PubId> {
        self.lock().get(msg).and_then(|e| e.publication)
    }

    /// Records `id` as the session's publication of `msg`, unless a
    /// concurrent first use got there first: the one to keep.
    pub(crate) fn set_publication(&self, msg: &str, id: PubId) -> PubId {
        *self
            .lock()
            .entry(msg.to_string())
            .or_default()
            .publication
            .get_or_insert(id)
    }

    /// The session's client of the service `msg`, if it has one.
    pub(crate) fn client(&self, msg: &str) -> Option<ClientId> {
        self.lock().get(msg).and_then(|e| e.client)
    }

    /// As [`Topics::set_publication`], for clients.
    pub(crate) fn set_client(&self, msg: &str, id: ClientId) -> ClientId {
        let kept = *self
            .lock()
            .entry(msg.to_string())
            .or_default()
            .client
            .get_or_insert(id);
        self.client_open_done(msg);
        kept
    }
}

/// A live publisher, subscriber or server of a topic ([`Topics::hold`]):
/// the last one to go lets the topic be forgotten.
#[derive(Debug)]
pub(crate) struct TopicUse {
    topics: Arc<Topics>,
    msg: String,
}

impl Drop for TopicUse {
    fn drop(&mut self) {
        self.topics.release(&self.msg);
    }
}

/// A typed first use under way: its topics are bound, its outcome not yet
/// settled. Dropped, as when its future is cancelled (or a `Publish` is
/// never awaited), it settles as a failure, letting go of the bindings no
/// use has confirmed; left bound, a cancelled first use held the topic to
/// its type for the session's life. After a success has settled them,
/// dropping it changes nothing (a confirmed binding stays).
pub(crate) struct Unsettled<'a> {
    topics: &'a Topics,
    msgs: [&'a str; 2],
    n: usize,
}

impl Topics {
    /// The guard of a first use of `msgs` (one or two topics).
    pub(crate) fn unsettled<'a>(&'a self, msgs: &[&'a str]) -> Unsettled<'a> {
        let mut m = [""; 2];
        let n = msgs.len().min(2);
        m[..n].copy_from_slice(&msgs[..n]);
        {
            let mut map = self.lock();
            for msg in &m[..n] {
                map.entry(msg.to_string()).or_default().pending += 1;
            }
        }
        Unsettled {
            topics: self,
            msgs: m,
            n,
        }
    }
}

impl Drop for Unsettled<'_> {
    fn drop(&mut self) {
        {
            let mut map = self.topics.lock();
            for msg in &self.msgs[..self.n] {
                if let Some(e) = map.get_mut(*msg) {
                    e.pending = e.pending.saturating_sub(1);
                }
            }
        }
        self.topics.settle(&self.msgs[..self.n], false);
    }
}

impl std::fmt::Debug for Unsettled<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("Unsettled")
            .field(&&self.msgs[..self.n])
            .finish()
    }
}

/// What publishing a topic the session has not defined yet needs first:
/// its named formats (IPC) and its type.
#[derive(Debug)]
pub(crate) struct Definition {
    pub(crate) ty: TypeInfo,
    pub(crate) formats: Vec<(&'static str, &'static str)>,
    /// The Rust type, for errors.
    pub(crate) rust: &'static str,
    /// Whether the type's data reads as a format central holds.
    pub(crate) fits: fn(&str) -> Result<(), String>,
}

impl Definition {
    pub(crate) fn of<T: IpcMessage>() -> Definition {
        Definition {
            ty: TypeInfo::of::<T>(),
            formats: courier_wire::NamedFormats::of::<T>().iter().collect(),
            rust: std::any::type_name::<T>(),
            fits: crate::format_check::written_verdict::<T>,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(courier_derive::IpcMessage)]
    #[ipc(type_name = "Point", crate = "::courier_wire")]
    struct Point {
        x: i32,
        y: i32,
    }

    #[derive(courier_derive::IpcMessage)]
    #[ipc(type_name = "Point", crate = "::courier_wire")]
    struct SamePoint {
        a: i32,
        b: i32,
    }

    #[test]
    fn a_topic_keeps_its_first_type() {
        let t = Topics::default();
        assert_eq!(t.bind::<Point>("p").unwrap(), None, "not defined yet");
        assert_eq!(t.bind::<SamePoint>("p").unwrap(), None, "same wire form");
        assert_eq!(t.set_publication("p", PubId(1)), PubId(1));
        assert_eq!(
            t.set_publication("p", PubId(2)),
            PubId(1),
            "the first stays"
        );
        assert_eq!(t.bind::<Point>("p").unwrap(), Some(PubId(1)));
        let e = t.bind::<f64>("p").unwrap_err();
        let text = e.to_string();
        assert!(text.contains("Point") && text.contains("f64"), "{text}");
        assert_eq!(t.bind::<f64>("q").unwrap(), None, "other topics are free");
        assert_eq!(t.publication("q"), None);
        // a failed first use lets the topic go; a successful one keeps it
        t.settle(&["q"], false);
        assert_eq!(t.bind::<Point>("q").unwrap(), None, "q was let go");
        t.settle(&["q"], true);
        t.settle(&["q"], false);
        assert!(
            t.bind::<f64>("q").is_err(),
            "a use succeeded: q keeps Point"
        );
        // a topic with a publication keeps its type whatever fails
        t.settle(&["p"], false);
        assert!(t.bind::<f64>("p").is_err());
    }

    /// A topic held only by publishers, subscribers and servers is
    /// forgotten when the last goes (audit 17: a node that opened and
    /// dropped 9600 topics kept every name, 4 MB); while one lives its type
    /// stays; a topic with the session's publication or client stays.
    #[test]
    fn a_topic_nothing_holds_is_forgotten() {
        let t = Arc::new(Topics::default());
        let open = |msg: &str| {
            t.bind::<Point>(msg).unwrap();
            let first = t.unsettled(&[msg]);
            t.settle(&[msg], true);
            drop(first);
            t.hold::<Point>(msg)
        };
        for i in 0..1000 {
            drop(open(&format!("robot{i}")));
        }
        assert_eq!(t.len(), 0, "every name forgotten");
        let a = open("pose");
        let b = open("pose");
        assert!(t.bind::<f64>("pose").is_err(), "held: its type stays");
        drop(a);
        assert!(t.bind::<f64>("pose").is_err(), "still held by b");
        drop(b);
        assert_eq!(t.bind::<f64>("pose").unwrap(), None, "free again");
        t.settle(&["pose"], false);
        // the session's own publication keeps its topic
        let c = open("cmd");
        t.set_publication("cmd", PubId(3));
        drop(c);
        assert!(t.bind::<f64>("cmd").is_err());
        // a first use under way keeps its binding when another use goes
        let d = open("map");
        t.bind::<Point>("map").unwrap();
        let pending = t.unsettled(&["map"]);
        drop(d);
        assert!(
            t.bind::<f64>("map").is_err(),
            "an open of Point is under way"
        );
        t.settle(&["map"], true);
        drop(pending);
        let e = t.hold::<Point>("map");
        assert!(t.bind::<f64>("map").is_err());
        drop(e);
        assert_eq!(t.len(), 1, "only cmd is left");
    }
}
