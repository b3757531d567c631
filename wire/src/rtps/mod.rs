//! DDSI-RTPS 2.x wire format (sans-I/O): message header, submessages,
//! parameter lists and the basic types, as Cyclone DDS 0.10/11 and Fast DDS
//! 2.9 put them on the wire (`shared/protocols/rtps.md`).
//!
//! ```
//! use courier_wire::rtps::{Message, Submessage};
//! # let bytes = {
//! #     let mut b = b"RTPS\x02\x05\x01\x10".to_vec();
//! #     b.extend_from_slice(&[1; 12]);
//! #     b.extend_from_slice(&[0x0e, 0x01, 12, 0]);
//! #     b.extend_from_slice(&[2; 12]);
//! #     b
//! # };
//! let m = Message::parse(&bytes).unwrap();
//! assert_eq!(m.header.version.minor, 5);
//! assert!(matches!(m.submessages[0], Submessage::InfoDst(p) if p.0 == [2; 12]));
//! assert_eq!(m.to_vec(), bytes);
//! ```
//!
//! Every length (submessage, inline QoS, parameter, locator list, bitmap)
//! is checked against the datagram before use; unknown and vendor-specific
//! submessages are kept as [`Submessage::Unknown`] and skipped by length.

pub mod discovery;
pub mod frag;
pub mod matching;
mod message;
pub mod parameter;
pub mod participant;
pub mod reliability;
mod types;

pub use message::{
    id, AckNack, Data, DataFrag, Gap, Header, Heartbeat, HeartbeatFrag, InfoReply, InfoSrc,
    Message, NackFrag, Submessage, HEADER_SIZE,
};
pub use parameter::{Parameter, ParameterId, ParameterList};
pub use types::{
    EntityId, FragmentNumberSet, Guid, GuidPrefix, Locator, ProtocolVersion, SequenceNumber,
    SequenceNumberSet, Time, VendorId,
};

/// Why an RTPS message could not be parsed. Offsets are from the start of the datagram.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The datagram does not start with `RTPS`.
    #[error("not an RTPS message (magic {0:02x?})")]
    BadMagic([u8; 4]),
    /// Major version other than 2.
    #[error("unsupported RTPS version {}.{}", .0.major, .0.minor)]
    UnsupportedVersion(ProtocolVersion),
    /// A field runs past the end of its submessage or datagram.
    #[error("RTPS data truncated at byte {offset}: {needed} byte(s) needed, {remaining} left")]
    Truncated {
        /// Offset of the field.
        offset: usize,
        /// Bytes needed.
        needed: usize,
        /// Bytes left.
        remaining: usize,
    },
    /// A field holds an impossible value.
    #[error("invalid {what} at byte {offset}: {detail}")]
    Invalid {
        /// Offset.
        offset: usize,
        /// Which field.
        what: &'static str,
        /// What was wrong.
        detail: String,
    },
}
