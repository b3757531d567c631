//! What a participant knows of the ROS 2 graph from the
//! [`TOPIC`](super::graph::TOPIC) samples it received: each remote
//! participant's latest [`ParticipantEntitiesInfo`], as rmw_dds_common's
//! `GraphCache` keeps them, until the participant leaves.
//!
//! Entries are keyed by the GUID prefix of the participant that *wrote*
//! the sample (discovery knows it, and loses it with the participant), so a
//! peer cannot fill the cache with made-up participants: a sample whose
//! `gid` names another participant than its writer's is refused, as is one
//! that does not decode. Refusals are errors for the caller to report; the
//! cache keeps what it had.

use std::collections::BTreeMap;

use crate::cdr::DecodeError;
use crate::rtps::{Guid, GuidPrefix};

use super::graph::{Gid, GidSize, NodeEntitiesInfo, ParticipantEntitiesInfo};

/// Why a received graph sample was not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum GraphError {
    /// The bytes are not a `ParticipantEntitiesInfo` of either GID size.
    #[error("a ros_discovery_info sample that does not decode: {0}")]
    Malformed(#[from] DecodeError),
    /// The sample's `gid` is not its writer's participant.
    #[error(
        "a ros_discovery_info sample that speaks for participant {claimed} \
         but was written by participant {writer}"
    )]
    ForeignParticipant {
        /// The `gid` in the sample (hex).
        claimed: String,
        /// The writer's GUID prefix (hex).
        writer: String,
    },
}

/// One remote participant's graph entry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// The participant's GID as it sent it.
    pub gid: Gid,
    /// Its nodes.
    pub nodes: Vec<NodeEntitiesInfo>,
    /// The GID size it writes (its ROS 2 release: see [`GidSize`]).
    pub gid_size: GidSize,
}

/// The remote participants' latest graph samples (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct GraphCache {
    participants: BTreeMap<GuidPrefix, Entry>,
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

impl GraphCache {
    /// An empty cache.
    pub fn new() -> Self {
        GraphCache::default()
    }

    /// Takes a sample (`data`, with its encapsulation header) written by
    /// `writer`: `Ok(Some(entry))` when the writer's participant's graph
    /// changed, `Ok(None)` when it sent what it had sent before.
    pub fn receive(&mut self, writer: Guid, data: &[u8]) -> Result<Option<&Entry>, GraphError> {
        let (info, gid_size) = ParticipantEntitiesInfo::decode(data)?;
        if info.gid.0[..12] != writer.prefix.0 {
            return Err(GraphError::ForeignParticipant {
                claimed: hex(&info.gid.0),
                writer: hex(&writer.prefix.0),
            });
        }
        let entry = Entry {
            gid: info.gid,
            nodes: info.node_entities_info_seq,
            gid_size,
        };
        let changed = self.participants.get(&writer.prefix) != Some(&entry);
        self.participants.insert(writer.prefix, entry);
        Ok(changed.then(|| &self.participants[&writer.prefix]))
    }

    /// Forgets a participant that left; its entry if it had one.
    pub fn remove(&mut self, participant: GuidPrefix) -> Option<Entry> {
        self.participants.remove(&participant)
    }

    /// Every remote participant's entry, by GUID prefix.
    pub fn entries(&self) -> impl Iterator<Item = (GuidPrefix, &Entry)> + '_ {
        self.participants.iter().map(|(p, e)| (*p, e))
    }

    /// How many participants have an entry.
    pub fn len(&self) -> usize {
        self.participants.len()
    }

    /// Whether no participant has an entry.
    pub fn is_empty(&self) -> bool {
        self.participants.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::EntityId;

    fn prefix(b: u8) -> GuidPrefix {
        GuidPrefix([b; 12])
    }

    fn writer(b: u8) -> Guid {
        Guid {
            prefix: prefix(b),
            entity: EntityId([0, 0, 0x12, 0x03]),
        }
    }

    fn info(b: u8, name: &str) -> ParticipantEntitiesInfo {
        let mut gid = [b; 16];
        gid[12..].copy_from_slice(&[0, 0, 1, 0xc1]);
        ParticipantEntitiesInfo {
            gid: Gid(gid),
            node_entities_info_seq: vec![NodeEntitiesInfo {
                node_namespace: "/".into(),
                node_name: name.into(),
                reader_gid_seq: vec![Gid([b; 16])],
                writer_gid_seq: vec![],
            }],
        }
    }

    #[test]
    fn a_participants_latest_sample_replaces_its_last_one_and_leaves_with_it() {
        let mut c = GraphCache::new();
        let a = info(1, "a").encode(GidSize::Sixteen).unwrap();
        let e = c.receive(writer(1), &a).unwrap().expect("new");
        assert_eq!(e.nodes[0].node_name, "a");
        assert_eq!(e.gid_size, GidSize::Sixteen);
        assert_eq!(c.receive(writer(1), &a).unwrap(), None, "unchanged");
        let b = info(1, "b").encode(GidSize::TwentyFour).unwrap();
        let e = c.receive(writer(1), &b).unwrap().expect("changed");
        assert_eq!(
            (e.nodes[0].node_name.as_str(), e.gid_size),
            ("b", GidSize::TwentyFour)
        );
        assert_eq!(c.len(), 1);
        assert!(c.remove(prefix(1)).is_some());
        assert!(c.is_empty());
        assert!(c.remove(prefix(1)).is_none());
    }

    #[test]
    fn refused_samples_leave_the_cache_as_it_was() {
        let mut c = GraphCache::new();
        let a = info(1, "a").encode(GidSize::Sixteen).unwrap();
        c.receive(writer(1), &a).unwrap();
        // participant 2 speaking for participant 1
        let e = c.receive(writer(2), &a).unwrap_err();
        assert!(matches!(e, GraphError::ForeignParticipant { .. }), "{e:?}");
        assert!(e.to_string().contains(&"02".repeat(12)), "{e}");
        // cut short
        let e = c.receive(writer(1), &a[..a.len() - 9]).unwrap_err();
        assert!(matches!(e, GraphError::Malformed(_)), "{e:?}");
        let entries: Vec<_> = c.entries().collect();
        assert_eq!(entries.len(), 1);
        assert_eq!(entries[0].1.nodes[0].node_name, "a");
    }
}
