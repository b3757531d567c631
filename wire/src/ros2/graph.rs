//! The ROS 2 graph topic: each participant publishes which nodes it holds
//! and which readers and writers each node owns on `ros_discovery_info`
//! (type `rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_`), so that
//! `ros2 node list` and friends can name nodes DDS discovery knows nothing
//! of.
//!
//! The GID shrank from 24 bytes (Humble and older) to 16 (Iron and later,
//! rmw_dds_common 2.0, commit "Change Gid.msg to be 16 bytes"): the
//! message's `Gid.msg` is `char[24] data` before and `char[16] data`
//! since. Both rmw_cyclonedds and rmw_fastrtps put the entity's 16-byte
//! DDS GUID (prefix, then entity id, in wire order) first and zeros after
//! it, so the size depends on the peer's ROS 2 release, not on its rmw:
//! [`GidSize`] says which to write; decoding takes either.
//!
//! Both rmws publish on the topic with [`writer_qos`] (reliable,
//! transient-local, keep last 1) and read it with [`reader_qos`] (the same,
//! keep all), in plain CDR (XCDR1): rmw_cyclonedds `rmw_node.cpp`
//! (`rmw_context_impl_s::init`) and rmw_fastrtps
//! `init_rmw_context_impl.cpp` set exactly these.

use crate::cdr::{DecodeError, Encoding, Extensibility, Reader, Writer};
use crate::rtps::discovery::{Durability, EndpointQos, History};
use crate::rtps::participant::EndpointConfig;

/// The topic's name.
pub const TOPIC: &str = "ros_discovery_info";
/// The topic's DDS type name.
pub const TYPE_NAME: &str = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_";
/// The longest node name and namespace (`string<=256`).
pub const MAX_NAME: usize = 256;

/// The QoS the rmws publish [`TOPIC`] with: reliable, transient-local
/// (a late joiner gets each participant's latest sample), keep last 1,
/// XCDR1.
pub fn writer_qos() -> EndpointQos {
    let mut q = EndpointQos::writer_default();
    q.durability = Durability::TransientLocal;
    q.history = History::KeepLast(1);
    q.data_representation = vec![0];
    q
}

/// The QoS the rmws read [`TOPIC`] with: as [`writer_qos`] but keep all
/// (the topic has no key: one sample per participant must not push out
/// another's before it is taken). Accepts XCDR1 only, the representation
/// both rmws write.
pub fn reader_qos() -> EndpointQos {
    let mut q = writer_qos();
    q.history = History::KeepAll;
    q
}

/// The writer of [`TOPIC`] as the rmws create it.
pub fn writer_config() -> EndpointConfig {
    EndpointConfig::writer(TOPIC, TYPE_NAME).qos(writer_qos())
}

/// The reader of [`TOPIC`] as the rmws create it.
pub fn reader_config() -> EndpointConfig {
    EndpointConfig::reader(TOPIC, TYPE_NAME).qos(reader_qos())
}

/// How many bytes a GID takes on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GidSize {
    /// ROS 2 Iron and later (rmw_dds_common 2.x and 3.x).
    #[default]
    Sixteen,
    /// ROS 2 Humble and older (rmw_dds_common 1.x).
    TwentyFour,
}

impl GidSize {
    /// The size in bytes (16 or 24).
    pub fn bytes(self) -> usize {
        self.len()
    }

    /// The size of `bytes` (16 or 24), if it is one.
    pub fn from_bytes(bytes: usize) -> Option<GidSize> {
        match bytes {
            16 => Some(GidSize::Sixteen),
            24 => Some(GidSize::TwentyFour),
            _ => None,
        }
    }

    fn len(self) -> usize {
        match self {
            GidSize::Sixteen => 16,
            GidSize::TwentyFour => 24,
        }
    }
}

/// An entity's GID: its DDS GUID (16 bytes; zero-padded to 24 for Humble).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Gid(pub [u8; 16]);

impl From<crate::rtps::Guid> for Gid {
    fn from(g: crate::rtps::Guid) -> Self {
        Gid(g.to_bytes())
    }
}

impl From<Gid> for crate::rtps::Guid {
    fn from(g: Gid) -> Self {
        crate::rtps::Guid::from_bytes(g.0)
    }
}

/// One node of a participant.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct NodeEntitiesInfo {
    /// Its namespace (`/` or `/a/b`).
    pub node_namespace: String,
    /// Its name.
    pub node_name: String,
    /// Its readers (subscriptions, service request readers, …).
    pub reader_gid_seq: Vec<Gid>,
    /// Its writers.
    pub writer_gid_seq: Vec<Gid>,
}

/// What a participant publishes on [`TOPIC`].
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ParticipantEntitiesInfo {
    /// The participant's GID.
    pub gid: Gid,
    /// Its nodes.
    pub node_entities_info_seq: Vec<NodeEntitiesInfo>,
}

/// Why a graph message was not encoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("node {what} {value:?} is longer than ROS 2's {MAX_NAME} bytes")]
pub struct TooLong {
    /// `name` or `namespace`.
    pub what: &'static str,
    /// The value.
    pub value: String,
}

fn write_gid(w: &mut Writer, g: &Gid, size: GidSize) {
    w.write_bytes(&g.0);
    for _ in 16..size.len() {
        w.write_u8(0);
    }
}

fn write_gids(w: &mut Writer, gids: &[Gid], size: GidSize) {
    w.write_len(gids.len());
    for g in gids {
        write_gid(w, g, size);
    }
}

impl ParticipantEntitiesInfo {
    /// The sample's bytes (XCDR1, little-endian, with its encapsulation
    /// header, as the rmw implementations write it).
    pub fn encode(&self, size: GidSize) -> Result<Vec<u8>, TooLong> {
        let mut w = Writer::with_header(Encoding::Xcdr1Le, Extensibility::Final);
        write_gid(&mut w, &self.gid, size);
        w.write_len(self.node_entities_info_seq.len());
        for n in &self.node_entities_info_seq {
            for (what, v) in [("namespace", &n.node_namespace), ("name", &n.node_name)] {
                if v.len() > MAX_NAME {
                    return Err(TooLong {
                        what,
                        value: v.clone(),
                    });
                }
                w.write_string(v);
            }
            write_gids(&mut w, &n.reader_gid_seq, size);
            write_gids(&mut w, &n.writer_gid_seq, size);
        }
        Ok(w.into_vec())
    }

    /// Decodes a sample of either GID size (with its encapsulation header),
    /// and says which it was.
    pub fn decode(bytes: &[u8]) -> Result<(ParticipantEntitiesInfo, GidSize), DecodeError> {
        match decode_as(bytes, GidSize::Sixteen) {
            Ok(v) => Ok((v, GidSize::Sixteen)),
            Err(first) => decode_as(bytes, GidSize::TwentyFour)
                .map(|v| (v, GidSize::TwentyFour))
                .map_err(|_| first),
        }
    }
}

fn read_gid(r: &mut Reader<'_>, size: GidSize) -> Result<Gid, DecodeError> {
    let b = r.take(size.len())?;
    let mut g = [0; 16];
    g.copy_from_slice(&b[..16]);
    Ok(Gid(g))
}

fn read_gids(r: &mut Reader<'_>, size: GidSize) -> Result<Vec<Gid>, DecodeError> {
    let n = r.read_len(size.len())?;
    (0..n).map(|_| read_gid(r, size)).collect()
}

fn read_name(r: &mut Reader<'_>) -> Result<String, DecodeError> {
    let offset = r.position();
    let s = r.read_str()?;
    if s.len() > MAX_NAME {
        return Err(DecodeError::Malformed {
            offset,
            what: "a node name or namespace longer than 256 bytes",
        });
    }
    Ok(s.to_string())
}

/// Decodes with GIDs of `size`; every byte but the final padding must be
/// used, which is how the two sizes are told apart.
fn decode_as(bytes: &[u8], size: GidSize) -> Result<ParticipantEntitiesInfo, DecodeError> {
    let mut r = Reader::with_header(bytes)?;
    let s = r.begin_struct(Extensibility::Appendable)?;
    let gid = read_gid(&mut r, size)?;
    // each node takes at least 2 string lengths and 2 sequence lengths
    let n = r.read_len(16)?;
    let mut nodes = Vec::with_capacity(n);
    for _ in 0..n {
        r.enter()?;
        let node_namespace = read_name(&mut r)?;
        let node_name = read_name(&mut r)?;
        r.align(4)?;
        let reader_gid_seq = read_gids(&mut r, size)?;
        let writer_gid_seq = read_gids(&mut r, size)?;
        r.leave();
        nodes.push(NodeEntitiesInfo {
            node_namespace,
            node_name,
            reader_gid_seq,
            writer_gid_seq,
        });
    }
    s.end(&mut r)?;
    r.finish_padding()?;
    Ok(ParticipantEntitiesInfo {
        gid,
        node_entities_info_seq: nodes,
    })
}
