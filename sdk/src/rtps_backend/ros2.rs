//! A session in the ROS 2 graph: the `ros_discovery_info` topic
//! (`rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_`) published and
//! read as rmw_cyclonedds and rmw_fastrtps do, so that `ros2 node list`
//! lists a Courier session as a node and the session lists ROS 2 nodes.
//!
//! Opt-in, per session ([`RtpsOptions::ros2_node`], URL
//! `ros2_node=/namespace/name`):
//!
//! - **publishing**: the session is one ROS 2 node. Its participant writes
//!   one `ParticipantEntitiesInfo` (reliable, transient-local, keep last 1,
//!   as both rmws) naming that node, with the GUIDs of every DDS reader and
//!   writer the session has open (publications, subscriptions, and each
//!   service's and client's pair), and writes it again whenever the session
//!   opens or closes one. The graph topic's own reader and writer are not
//!   listed (the rmws list them under no node either).
//! - **reading**: every other participant's latest sample is kept until it
//!   leaves; each change is a [`SessionEvent::Ros2Nodes`] and
//!   [`DdsControl::ros2_nodes`](crate::DdsControl::ros2_nodes) answers with
//!   every node known, its topics resolved through DDS discovery. A sample
//!   that does not decode, or that speaks for another participant than its
//!   writer's, is a [`SessionEvent::Ros2GraphRefused`] and changes nothing.
//!   [`RtpsOptions::ros2_graph`] (URL `ros2_graph=true`) reads without
//!   being a node.
//!
//! GIDs are 16 bytes since ROS 2 Iron and 24 in Humble and older, with both
//! rmws ([`courier_wire::ros2::graph`]); a session writes
//! [`RtpsOptions::ros2_gid`] (default 16, URL `ros2_gid=24` for Humble
//! peers, which cannot read 16-byte GIDs) and reads either.
//!
//! Deviation from the rmws: the participant's USER_DATA carries no
//! `enclave=` entry (the graph tools do not need it).
//!
//! [`RtpsOptions::ros2_node`]: super::RtpsOptions::ros2_node
//! [`RtpsOptions::ros2_graph`]: super::RtpsOptions::ros2_graph
//! [`RtpsOptions::ros2_gid`]: super::RtpsOptions::ros2_gid

use std::fmt;
use std::time::Instant;

use courier_wire::dds::{Domain, ReaderId, WriterId};
use courier_wire::ros2::cache::GraphCache;
use courier_wire::ros2::graph::{
    self, Gid, GidSize, NodeEntitiesInfo, ParticipantEntitiesInfo, TooLong,
};
use courier_wire::ros2::names::{self, Node};
use courier_wire::rtps::participant::{Change, ChangeKind, CreateError, ReceivedSample};
use courier_wire::rtps::{EntityId, Guid, GuidPrefix};
use foldhash::{HashMap, HashMapExt};

use super::Listeners;
use crate::event::{Guid as PublicGuid, SessionEvent};

pub use courier_wire::ros2::names::Kind as Ros2Kind;

/// A ROS 2 node's place in the graph: namespace (`/` or `/a/b`) and name.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[non_exhaustive]
pub struct Ros2NodeName {
    /// The namespace, as the node's participant sent it.
    pub namespace: String,
    /// The name.
    pub name: String,
}

impl fmt::Display for Ros2NodeName {
    /// The fully qualified name (`/ns/name`, `/name` in the root).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ns = self.namespace.trim_end_matches('/');
        write!(f, "{ns}/{}", self.name)
    }
}

/// One of a node's DDS readers or writers, resolved through discovery.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Ros2Endpoint {
    /// Its GUID (the GID the node listed).
    pub guid: PublicGuid,
    /// Its DDS topic and type name; `None` while discovery has not (yet)
    /// announced the endpoint.
    pub dds: Option<(String, String)>,
    /// The ROS 2 name and kind of its topic (`/chatter` for `rt/chatter`,
    /// `/add` and [`Ros2Kind::Request`] for `rq/addRequest`), if the topic
    /// follows ROS 2's naming.
    pub ros_name: Option<(String, Ros2Kind)>,
    /// The ROS 2 type (`std_msgs/msg/String`; a service's request and
    /// reply types give the service type), if the DDS type name follows
    /// ROS 2's convention.
    pub ros_type: Option<String>,
}

/// A ROS 2 node in the graph: from a participant's `ros_discovery_info`
/// sample, or this session's own node.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Ros2Node {
    /// Namespace and name.
    pub name: Ros2NodeName,
    /// The participant it lives in (the GID it sent, as a GUID).
    pub participant: PublicGuid,
    /// True for this session's own node.
    pub local: bool,
    /// The GID size its participant writes (24: ROS 2 Humble or older).
    pub gid_bytes: usize,
    /// Its DDS writers (publishers, service reply writers, client request
    /// writers), in the order listed.
    pub writers: Vec<Ros2Endpoint>,
    /// Its DDS readers.
    pub readers: Vec<Ros2Endpoint>,
}

impl Ros2Node {
    /// The ROS 2 topics it publishes (`rt/` writers), as
    /// `(name, ROS type)`; a type is empty when not known yet.
    pub fn publishes(&self) -> Vec<(String, String)> {
        topics_of(&self.writers)
    }

    /// The ROS 2 topics it subscribes to (`rt/` readers).
    pub fn subscribes(&self) -> Vec<(String, String)> {
        topics_of(&self.readers)
    }
}

fn topics_of(eps: &[Ros2Endpoint]) -> Vec<(String, String)> {
    eps.iter()
        .filter_map(|e| match &e.ros_name {
            Some((n, Ros2Kind::Topic)) => Some((n.clone(), e.ros_type.clone().unwrap_or_default())),
            _ => None,
        })
        .collect()
}

/// The session's side of the graph topic (see the [module docs](self)).
pub(super) struct Ros2Graph {
    /// This session's node, when it publishes one.
    node: Option<Node>,
    gid_size: GidSize,
    participant: Guid,
    writer: Option<WriterId>,
    reader: ReaderId,
    /// The readers and writers last published (sorted).
    published: Option<(Vec<Gid>, Vec<Gid>)>,
    /// Samples written.
    writes: u64,
    cache: GraphCache,
}

impl Ros2Graph {
    /// Creates the graph topic's reader (and its writer, for a node).
    pub(super) fn start(
        d: &mut Domain,
        node: Option<Node>,
        gid_size: GidSize,
        now: Instant,
    ) -> Result<Ros2Graph, CreateError> {
        let writer = match node {
            Some(_) => Some(d.create_writer(graph::writer_config(), now)?),
            None => None,
        };
        let reader = match d.create_reader(graph::reader_config(), now) {
            Ok(r) => r,
            Err(e) => {
                if let Some(w) = writer {
                    d.delete_writer(w, now);
                }
                return Err(e);
            }
        };
        let participant = Guid {
            prefix: d.participant().guid_prefix(),
            entity: EntityId::PARTICIPANT,
        };
        Ok(Ros2Graph {
            node,
            gid_size,
            participant,
            writer,
            reader,
            published: None,
            writes: 0,
            cache: GraphCache::new(),
        })
    }

    /// Whether `r` is the graph topic's reader.
    pub(super) fn is_reader(&self, r: ReaderId) -> bool {
        self.reader == r
    }

    /// The bytes of the sample of `node` with these endpoints (sorted), as
    /// the session writes it.
    fn encode(&self, node: &Node, readers: &[Gid], writers: &[Gid]) -> Result<Vec<u8>, TooLong> {
        ParticipantEntitiesInfo {
            gid: self.participant.into(),
            node_entities_info_seq: vec![NodeEntitiesInfo {
                node_namespace: node.namespace().to_string(),
                node_name: node.name().to_string(),
                reader_gid_seq: readers.to_vec(),
                writer_gid_seq: writers.to_vec(),
            }],
        }
        .encode(self.gid_size)
    }

    /// Publishes the node with the session's readers and writers now,
    /// unless that is what was published last.
    pub(super) fn publish(
        &mut self,
        d: &mut Domain,
        mut readers: Vec<Gid>,
        mut writers: Vec<Gid>,
        now: Instant,
    ) {
        let (Some(node), Some(writer)) = (&self.node, self.writer) else {
            return;
        };
        readers.sort_unstable();
        writers.sort_unstable();
        if self
            .published
            .as_ref()
            .is_some_and(|(r, w)| *r == readers && *w == writers)
        {
            return;
        }
        // a Node's names are checked to be within ROS 2's bounds
        let bytes = match self.encode(node, &readers, &writers) {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!("ros_discovery_info not published: {e}");
                return;
            }
        };
        match d.write(writer, Change::alive_owned(bytes), now) {
            Ok(_) => {
                self.published = Some((readers, writers));
                self.writes += 1;
            }
            // keep last 1: never full; the next change tries again
            Err(e) => tracing::warn!("ros_discovery_info not published: {e}"),
        }
    }

    /// A sample of the graph topic: the cache and the events.
    pub(super) fn receive(&mut self, s: ReceivedSample, events: &Listeners) {
        if s.kind != ChangeKind::Alive || s.writer.prefix == self.participant.prefix {
            return; // a writer that left (the participant's loss says it), or ours
        }
        match self.cache.receive(s.writer, s.data()) {
            Ok(Some(entry)) => events.send(SessionEvent::Ros2Nodes {
                participant: Guid::from(entry.gid).into(),
                nodes: entry.nodes.iter().map(node_name).collect(),
            }),
            Ok(None) => {}
            Err(e) => {
                tracing::warn!("from writer {}: {e}", super::guid_hex(s.writer));
                events.send(SessionEvent::Ros2GraphRefused {
                    writer: s.writer.into(),
                    reason: e.to_string(),
                });
            }
        }
    }

    /// A participant left: its nodes with it.
    pub(super) fn participant_lost(&mut self, prefix: GuidPrefix, events: &Listeners) {
        if let Some(entry) = self.cache.remove(prefix) {
            if !entry.nodes.is_empty() {
                events.send(SessionEvent::Ros2Nodes {
                    participant: Guid::from(entry.gid).into(),
                    nodes: Vec::new(),
                });
            }
        }
    }

    /// Every node known, remote ones' endpoints resolved through discovery
    /// and this session's own (given its readers and writers) through the
    /// domain; ordered by participant, then as their samples list them.
    pub(super) fn nodes(&self, d: &Domain, readers: Vec<Gid>, writers: Vec<Gid>) -> Vec<Ros2Node> {
        let p = d.participant();
        let mut remote: HashMap<Guid, (&str, &str)> = HashMap::new();
        for e in p.publications().chain(p.subscriptions()) {
            remote.insert(e.guid, (e.topic_name.as_str(), e.type_name.as_str()));
        }
        let resolve = |g: &Gid| {
            let guid = Guid::from(*g);
            endpoint(
                guid,
                remote
                    .get(&guid)
                    .copied()
                    .or_else(|| d.local_endpoint(guid)),
            )
        };
        let mut out = Vec::new();
        if let Some(node) = &self.node {
            let mut readers = readers;
            let mut writers = writers;
            readers.sort_unstable();
            writers.sort_unstable();
            out.push(Ros2Node {
                name: Ros2NodeName {
                    namespace: node.namespace().to_string(),
                    name: node.name().to_string(),
                },
                participant: self.participant.into(),
                local: true,
                gid_bytes: self.gid_size.bytes(),
                writers: writers.iter().map(resolve).collect(),
                readers: readers.iter().map(resolve).collect(),
            });
        }
        for (_, entry) in self.cache.entries() {
            for n in &entry.nodes {
                out.push(Ros2Node {
                    name: node_name(n),
                    participant: Guid::from(entry.gid).into(),
                    local: false,
                    gid_bytes: entry.gid_size.bytes(),
                    writers: n.writer_gid_seq.iter().map(resolve).collect(),
                    readers: n.reader_gid_seq.iter().map(resolve).collect(),
                });
            }
        }
        out
    }
}

fn node_name(n: &NodeEntitiesInfo) -> Ros2NodeName {
    Ros2NodeName {
        namespace: n.node_namespace.clone(),
        name: n.node_name.clone(),
    }
}

/// An endpoint with what discovery says of it (`topic`, `type`).
fn endpoint(guid: Guid, dds: Option<(&str, &str)>) -> Ros2Endpoint {
    Ros2Endpoint {
        guid: guid.into(),
        dds: dds.map(|(t, ty)| (t.to_string(), ty.to_string())),
        ros_name: dds.and_then(|(t, _)| names::ros_topic(t)),
        ros_type: dds.and_then(|(_, ty)| names::ros_type(ty)).map(|(t, _)| t),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier_wire::rtps::participant::Config;

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    /// Golden bytes of the sample a session that is node
    /// `/courier_ns/graph_node` writes for one reader and two writers, laid
    /// out as rmw_dds_common's `ParticipantEntitiesInfo` (Gid.msg
    /// `char[16] data`; `char[24]` in Humble), XCDR1 little-endian; the
    /// GIDs are sorted, whatever order the session's maps hold them in.
    #[test]
    fn the_sample_a_session_publishes_golden() {
        let now = Instant::now();
        let prefix = GuidPrefix([1, 15, 0xaa, 0xbb, 1, 2, 3, 4, 5, 6, 7, 8]);
        let mut d = Domain::new(
            Config::new(7, prefix),
            now,
            std::time::SystemTime::UNIX_EPOCH,
        );
        let node = Node::new("/courier_ns", "graph_node").unwrap();
        let mut g = Ros2Graph::start(&mut d, Some(node.clone()), GidSize::Sixteen, now).unwrap();
        let gid = |last: u8| {
            let mut b = [0u8; 16];
            b[..12].copy_from_slice(&prefix.0);
            b[12..].copy_from_slice(&[0, 0, last, 0x03]);
            Gid(b)
        };
        g.publish(&mut d, vec![gid(0x14)], vec![gid(0x16), gid(0x15)], now);
        let (readers, writers) = g.published.clone().expect("published");
        assert_eq!(writers, [gid(0x15), gid(0x16)], "sorted");
        let bytes = g.encode(&node, &readers, &writers).unwrap();
        let p = "010faabb0102030405060708";
        let golden = [
            "00010000", // CDR_LE, options 0
            p,
            "000001c1", // gid: the participant's GUID
            "01000000", // one node
            "0c000000",
            "2f636f75726965725f6e7300", // "/courier_ns"
            "0b000000",
            "67726170685f6e6f646500",
            "00", // "graph_node", pad
            "01000000",
            p,
            "00001403", // readers
            "02000000",
            p,
            "00001503",
            p,
            "00001603", // writers
        ]
        .concat();
        assert_eq!(hex(&bytes), golden);
        assert_eq!(bytes.len(), 112);

        // Humble: each GID zero-padded to 24 bytes
        let mut d = Domain::new(
            Config::new(7, prefix),
            now,
            std::time::SystemTime::UNIX_EPOCH,
        );
        let g = Ros2Graph::start(&mut d, Some(node.clone()), GidSize::TwentyFour, now).unwrap();
        let bytes = g.encode(&node, &[gid(0x14)], &[]).unwrap();
        let z = "0000000000000000";
        let golden = [
            "00010000",
            p,
            "000001c1",
            z,
            "01000000",
            "0c000000",
            "2f636f75726965725f6e7300",
            "0b000000",
            "67726170685f6e6f646500",
            "00",
            "01000000",
            p,
            "00001403",
            z,
            "00000000",
        ]
        .concat();
        assert_eq!(hex(&bytes), golden);
    }

    #[test]
    fn a_node_is_published_again_only_when_its_endpoints_change() {
        let now = Instant::now();
        let prefix = GuidPrefix([9; 12]);
        let mut d = Domain::new(
            Config::new(7, prefix),
            now,
            std::time::SystemTime::UNIX_EPOCH,
        );
        let node = Node::new("/", "n").unwrap();
        let mut g = Ros2Graph::start(&mut d, Some(node), GidSize::Sixteen, now).unwrap();
        let a = Gid([1; 16]);
        let b = Gid([2; 16]);
        g.publish(&mut d, vec![], vec![], now);
        assert_eq!(g.published, Some((vec![], vec![])));
        g.publish(&mut d, vec![b, a], vec![], now);
        assert_eq!(g.published, Some((vec![a, b], vec![])));
        // the same set in another order: nothing to say
        assert_eq!(g.writes, 2);
        g.publish(&mut d, vec![a, b], vec![], now);
        assert_eq!(g.writes, 2);
        g.publish(&mut d, vec![a], vec![b], now);
        assert_eq!(g.published, Some((vec![a], vec![b])));
        assert_eq!(g.writes, 3);
        // a session that only reads the graph publishes nothing
        let mut d = Domain::new(
            Config::new(7, prefix),
            now,
            std::time::SystemTime::UNIX_EPOCH,
        );
        let mut g = Ros2Graph::start(&mut d, None, GidSize::Sixteen, now).unwrap();
        g.publish(&mut d, vec![a], vec![], now);
        assert_eq!(g.published, None);
    }

    #[test]
    fn node_names_print_fully_qualified() {
        let n = |ns: &str, name: &str| Ros2NodeName {
            namespace: ns.into(),
            name: name.into(),
        };
        assert_eq!(n("/", "talker").to_string(), "/talker");
        assert_eq!(n("/robot/arm", "ctl").to_string(), "/robot/arm/ctl");
        assert_eq!(n("", "x").to_string(), "/x");
    }

    #[test]
    fn endpoints_are_named_as_ros_2_names_them_when_they_follow_its_conventions() {
        let g = Guid::from_bytes([7; 16]);
        let e = endpoint(g, Some(("rt/chatter", "std_msgs::msg::dds_::String_")));
        assert_eq!(e.ros_name, Some(("/chatter".into(), Ros2Kind::Topic)));
        assert_eq!(e.ros_type.as_deref(), Some("std_msgs/msg/String"));
        let e = endpoint(g, Some(("plain", "courier::Ping")));
        assert_eq!((e.ros_name, e.ros_type), (None, None));
        assert_eq!(e.dds, Some(("plain".into(), "courier::Ping".into())));
        let e = endpoint(g, None);
        assert_eq!(e.dds, None);
        let node = Ros2Node {
            name: Ros2NodeName {
                namespace: "/".into(),
                name: "n".into(),
            },
            participant: g.into(),
            local: false,
            gid_bytes: 16,
            writers: vec![
                endpoint(g, Some(("rt/a", "std_msgs::msg::dds_::String_"))),
                endpoint(g, Some(("rr/addReply", "x::srv::dds_::Add_Response_"))),
                endpoint(g, None),
            ],
            readers: vec![],
        };
        assert_eq!(
            node.publishes(),
            [("/a".to_string(), "std_msgs/msg/String".to_string())]
        );
        assert!(node.subscribes().is_empty());
    }
}
