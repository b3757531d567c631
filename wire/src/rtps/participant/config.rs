//! Who a participant is and how it is set up: Courier's vendor id and
//! protocol version, GUID prefixes and the entity ids of user endpoints,
//! the participant's [`Config`] (locators, SPDP destinations, timing,
//! limits) and a local endpoint's [`EndpointConfig`].

use std::time::Duration;

use super::ports::{PortMapping, SPDP_MULTICAST_ADDRESS};
use crate::rtps::discovery::EndpointQos;
use crate::rtps::{EntityId, GuidPrefix, Locator, ProtocolVersion, VendorId};

/// Courier's RTPS vendor id, `01.c0`: unregistered, see the module docs.
pub const VENDOR_ID: VendorId = VendorId([0x01, 0xc0]);

/// The protocol version Courier writes in headers and discovery data.
pub const PROTOCOL_VERSION: ProtocolVersion = ProtocolVersion::V2_4;

/// `PID_BUILTIN_ENDPOINT_SET` bits (§8.5.4.3, §9.3.2).
pub mod builtin_endpoints {
    /// SPDP writer.
    pub const PARTICIPANT_ANNOUNCER: u32 = 1 << 0;
    /// SPDP reader.
    pub const PARTICIPANT_DETECTOR: u32 = 1 << 1;
    /// SEDP publications writer.
    pub const PUBLICATIONS_ANNOUNCER: u32 = 1 << 2;
    /// SEDP publications reader.
    pub const PUBLICATIONS_DETECTOR: u32 = 1 << 3;
    /// SEDP subscriptions writer.
    pub const SUBSCRIPTIONS_ANNOUNCER: u32 = 1 << 4;
    /// SEDP subscriptions reader.
    pub const SUBSCRIPTIONS_DETECTOR: u32 = 1 << 5;
    /// Participant-message (liveliness) writer.
    pub const PARTICIPANT_MESSAGE_WRITER: u32 = 1 << 10;
    /// Participant-message (liveliness) reader.
    pub const PARTICIPANT_MESSAGE_READER: u32 = 1 << 11;
    /// SPDP and SEDP, the standard four discovery endpoints and SPDP's pair (0x3f).
    pub const DISCOVERY: u32 = 0x3f;
    /// What Courier implements and announces: SPDP, SEDP and the
    /// participant-message (writer liveliness) pair (0xc3f).
    pub const COURIER: u32 = DISCOVERY | PARTICIPANT_MESSAGE_WRITER | PARTICIPANT_MESSAGE_READER;
}

/// A GUID prefix for a Courier participant: the vendor id, then 10 bytes
/// the caller makes unique (random bytes, the process id, a counter), as
/// Cyclone DDS does with its `0110` + 10 pseudo-random bytes.
pub fn guid_prefix(entropy: [u8; 10]) -> GuidPrefix {
    let mut p = [0; 12];
    p[..2].copy_from_slice(&VENDOR_ID.0);
    p[2..].copy_from_slice(&entropy);
    GuidPrefix(p)
}

/// Writer or reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EndpointKind {
    /// A data writer.
    Writer,
    /// A data reader.
    Reader,
}

/// The entity id of a user endpoint (§9.3.1.2): a 3-byte key (1..=0xffffff)
/// and the kind octet — writer with key 0x02, writer without key 0x03,
/// reader without key 0x04, reader with key 0x07. `None` if the key does not
/// fit. Courier numbers its endpoints 1, 2, 3, … in creation order, as Fast
/// DDS does (its first reader is `00000104`).
pub fn entity_id(key: u32, kind: EndpointKind, keyed: bool) -> Option<EntityId> {
    if key == 0 || key > 0x00ff_ffff {
        return None;
    }
    let k = key.to_be_bytes();
    let kind = match (kind, keyed) {
        (EndpointKind::Writer, true) => 0x02,
        (EndpointKind::Writer, false) => 0x03,
        (EndpointKind::Reader, false) => 0x04,
        (EndpointKind::Reader, true) => 0x07,
    };
    Some(EntityId([k[1], k[2], k[3], kind]))
}

/// Everything a participant needs to know about itself.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Config {
    /// DDS domain id; SPDP data announcing another domain is ignored.
    pub domain_id: u32,
    /// This participant's GUID prefix (see [`guid_prefix`]).
    pub guid_prefix: GuidPrefix,
    /// Where this participant receives SPDP/SEDP traffic (announced).
    pub metatraffic_unicast: Vec<Locator>,
    /// Multicast locators for discovery traffic (announced; the I/O layer joins them).
    pub metatraffic_multicast: Vec<Locator>,
    /// Where this participant receives user data (announced).
    pub default_unicast: Vec<Locator>,
    /// Multicast locators for user data (announced).
    pub default_multicast: Vec<Locator>,
    /// Where SPDP announcements go besides the known participants: the
    /// unicast peer list and/or the SPDP multicast locator.
    pub spdp_destinations: Vec<Locator>,
    /// Lease announced: peers drop this participant after this much silence.
    pub lease_duration: Duration,
    /// Period of SPDP announcements after start-up (at most a third of
    /// [`lease_duration`](Self::lease_duration)).
    pub announce_period: Duration,
    /// Number of quick announcements after the first one (Fast DDS: 5).
    pub initial_announcements: u32,
    /// Period of the quick start-up announcements (Fast DDS: 100 ms).
    pub initial_announce_period: Duration,
    /// Heartbeat period of reliable writers while something is unacknowledged.
    pub heartbeat_period: Duration,
    /// Largest datagram sent; samples that do not fit in one DATA are
    /// fragmented. Default 14720, Cyclone's `MaxMessageSize`.
    pub max_message_size: usize,
    /// Fragment size for large samples. Default 1344, Cyclone's `FragmentSize`.
    pub fragment_size: u16,
    /// Largest sample accepted for reassembly.
    pub max_sample_size: usize,
    /// Bytes of incomplete fragmented samples held at most.
    pub reassembly_limit: usize,
    /// Bytes of received-sample buffers kept for reuse once the application
    /// hands them back ([`Participant::recycle`](super::Participant::recycle)). Default 2 MiB: the
    /// unacknowledged bytes a Courier writer lets out plus as much again.
    pub spare_buffer_bytes: usize,
    /// Samples a writer holds at most (keep-all history, keyed keep-last:
    /// all instances together). A reliable writer full of samples some
    /// reader has not acknowledged refuses writes
    /// ([`WriteError::HistoryFull`](super::WriteError::HistoryFull)) rather
    /// than drop one; a transient-local one drops its oldest acknowledged
    /// sample for a new one, so late joiners get the newest `max_history`.
    pub max_history: usize,
    /// Unacknowledged payload bytes a reliable keep-all writer holds at
    /// most before [`Participant::write`](super::Participant::write) answers
    /// [`WriteError::HistoryFull`](super::WriteError::HistoryFull) (a high-water mark, like Cyclone's
    /// `WhcHigh`, 500 kB): a writer must not overrun its readers' socket
    /// buffers when they share a CPU. Default 1 MiB: the most
    /// that one core's reader with Courier's 1 MiB `SO_RCVBUF` took without kernel
    /// drops in `rtps_bench` (2 MiB overran it; 512 KiB was 10–25 % slower).
    pub max_unacked_bytes: usize,
    /// Out-of-order samples a reliable reader buffers per writer.
    pub max_out_of_order: usize,
    /// Payload bytes a reliable reader buffers out of order, all its
    /// writers together (default 64 MiB): beyond it a sample that does not
    /// come next is dropped and asked for again later. Without it writers
    /// that never send their first sample held 1024 samples each of up to
    /// `max_sample_size`.
    pub max_out_of_order_bytes: usize,
    /// Remote participants tracked at most.
    pub max_participants: usize,
    /// Remote writers plus readers tracked at most.
    pub max_remote_endpoints: usize,
    /// Bytes the remote writers and readers tracked may hold, all
    /// together (default 128 MiB; what each takes: its names, locators,
    /// partitions and type information). A peer announcing endpoints with
    /// 60 KB of type information each would otherwise take about 4 GiB
    /// within [`max_remote_endpoints`](Self::max_remote_endpoints).
    /// Beyond it a new endpoint is not tracked
    /// ([`Stats::discovery_limited`](super::Stats::discovery_limited)).
    pub max_remote_endpoint_bytes: usize,
    /// `PID_ENTITY_NAME` to announce, if any.
    pub entity_name: Option<String>,
}

/// [`Config::max_message_size`] by default: Cyclone's `MaxMessageSize`.
pub const DEFAULT_MAX_MESSAGE_SIZE: usize = 14_720;

impl Config {
    /// A configuration with no locators and the default timing and limits.
    pub fn new(domain_id: u32, guid_prefix: GuidPrefix) -> Self {
        Config {
            domain_id,
            guid_prefix,
            metatraffic_unicast: Vec::new(),
            metatraffic_multicast: Vec::new(),
            default_unicast: Vec::new(),
            default_multicast: Vec::new(),
            spdp_destinations: Vec::new(),
            lease_duration: Duration::from_secs(10),
            announce_period: Duration::from_secs(3),
            initial_announcements: 5,
            initial_announce_period: Duration::from_millis(100),
            heartbeat_period: Duration::from_millis(100),
            max_message_size: DEFAULT_MAX_MESSAGE_SIZE,
            fragment_size: 1344,
            max_sample_size: 16 << 20,
            reassembly_limit: 64 << 20,
            spare_buffer_bytes: 2 << 20,
            max_history: 4096,
            max_unacked_bytes: 1 << 20,
            max_out_of_order: 1024,
            max_out_of_order_bytes: 64 << 20,
            max_participants: 1024,
            max_remote_endpoints: 65_536,
            max_remote_endpoint_bytes: 128 << 20,
            entity_name: None,
        }
    }

    /// A configuration for UDPv4 at `address` with participant index
    /// `participant_index`: metatraffic unicast on 7410 + 2i, user data on
    /// 7411 + 2i (domain 0; [`PortMapping::STANDARD`]). `None` if the ports
    /// do not exist for that domain and index.
    pub fn udpv4(
        domain_id: u32,
        participant_index: u32,
        guid_prefix: GuidPrefix,
        address: [u8; 4],
    ) -> Option<Self> {
        let m = PortMapping::STANDARD;
        let meta = m.metatraffic_unicast(domain_id, participant_index)?;
        let user = m.user_unicast(domain_id, participant_index)?;
        let mut c = Config::new(domain_id, guid_prefix);
        c.metatraffic_unicast = vec![Locator::udpv4(address, meta)];
        c.default_unicast = vec![Locator::udpv4(address, user)];
        Some(c)
    }

    /// Adds unicast SPDP peers: the metatraffic port of participant indices
    /// `0..=max_index` at each address (Cyclone's `Peers` expansion; rtps.md
    /// §7 rule 7 asks for at least 20). This participant's own locator is left out.
    pub fn with_unicast_peers(mut self, addresses: &[[u8; 4]], max_index: u32) -> Self {
        for a in addresses {
            for l in PortMapping::STANDARD.unicast_peers(*a, self.domain_id, max_index) {
                if !self.metatraffic_unicast.contains(&l) && !self.spdp_destinations.contains(&l) {
                    self.spdp_destinations.push(l);
                }
            }
        }
        self
    }

    /// Adds standard multicast discovery: SPDP to 239.255.0.1:7400 + 250·domain,
    /// and that locator (and the user multicast port) announced as this
    /// participant's multicast locators.
    pub fn with_multicast(mut self) -> Self {
        let m = PortMapping::STANDARD;
        if let Some(l) = m.spdp_multicast_locator(self.domain_id) {
            if !self.spdp_destinations.contains(&l) {
                self.spdp_destinations.push(l);
            }
            self.metatraffic_multicast = vec![l];
        }
        if let Some(p) = m.user_multicast(self.domain_id) {
            self.default_multicast = vec![Locator::udpv4(SPDP_MULTICAST_ADDRESS, p)];
        }
        self
    }
}

/// What a local writer or reader is: topic, type, whether the type has a
/// key, and its QoS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EndpointConfig {
    /// Topic name.
    pub topic_name: String,
    /// DDS type name (matched exactly).
    pub type_name: String,
    /// The type has key fields (entity kind "with key").
    pub keyed: bool,
    /// QoS. An empty `data_representation` means XCDR1.
    pub qos: EndpointQos,
}

impl EndpointConfig {
    /// A writer with the DDS default writer QoS (reliable, volatile, keep last 1).
    pub fn writer(topic_name: &str, type_name: &str) -> Self {
        EndpointConfig {
            topic_name: topic_name.into(),
            type_name: type_name.into(),
            keyed: false,
            qos: EndpointQos::writer_default(),
        }
    }

    /// A reader with the DDS default reader QoS (best effort, volatile, keep last 1).
    pub fn reader(topic_name: &str, type_name: &str) -> Self {
        EndpointConfig {
            qos: EndpointQos::reader_default(),
            ..Self::writer(topic_name, type_name)
        }
    }

    /// Sets whether the type is keyed.
    pub fn keyed(mut self, keyed: bool) -> Self {
        self.keyed = keyed;
        self
    }

    /// Sets the QoS.
    pub fn qos(mut self, qos: EndpointQos) -> Self {
        self.qos = qos;
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entity_ids_follow_the_spec_kinds() {
        assert_eq!(
            entity_id(1, EndpointKind::Reader, false),
            Some(EntityId([0, 0, 1, 4]))
        );
        assert_eq!(
            entity_id(1, EndpointKind::Writer, false),
            Some(EntityId([0, 0, 1, 3]))
        );
        assert_eq!(
            entity_id(0x123456, EndpointKind::Writer, true),
            Some(EntityId([0x12, 0x34, 0x56, 2]))
        );
        assert_eq!(
            entity_id(2, EndpointKind::Reader, true),
            Some(EntityId([0, 0, 2, 7]))
        );
        assert_eq!(entity_id(0, EndpointKind::Reader, true), None);
        assert_eq!(entity_id(1 << 24, EndpointKind::Reader, true), None);
        for k in [EndpointKind::Writer, EndpointKind::Reader] {
            for keyed in [false, true] {
                let e = entity_id(5, k, keyed).unwrap();
                assert!(!e.is_builtin());
                assert_eq!(e.is_writer(), k == EndpointKind::Writer);
                assert_eq!(e.is_reader(), k == EndpointKind::Reader);
            }
        }
        assert_eq!(guid_prefix([7; 10]).0[..2], VENDOR_ID.0);
    }
}
