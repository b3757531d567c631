//! The two ways ROS 2 rmw implementations tie a reply to its request.
//!
//! - **Related sample identity** (rmw_fastrtps, rmw_connextdds, Courier):
//!   the reply carries the request's writer GUID and sequence number as
//!   inline QoS (`PID_RELATED_SAMPLE_IDENTITY`, and Fast DDS's 0x800f).
//! - **Request header** (rmw_cyclonedds, `cdds_request_header_t` in its
//!   `serdata.hpp`): 16 bytes before the body of every request and reply,
//!   in the sample's byte order: the client's id (`uint64`, the instance
//!   handle of its request writer) and the request's number (`int64`, a
//!   counter of the client). A client takes only replies whose id is its
//!   own; a service echoes both fields.

use crate::rtps::VendorId;

/// How a service's requests and replies are correlated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RpcStyle {
    /// Inline `PID_RELATED_SAMPLE_IDENTITY` (rmw_fastrtps, rmw_connextdds).
    SampleIdentity,
    /// A 16-byte header before the body (rmw_cyclonedds).
    RequestHeader,
}

impl RpcStyle {
    /// The style the rmw of a participant from `vendor` uses: ROS 2 over
    /// Eclipse Cyclone DDS means rmw_cyclonedds.
    pub fn of_vendor(vendor: VendorId) -> RpcStyle {
        if vendor == VendorId::CYCLONE {
            RpcStyle::RequestHeader
        } else {
            RpcStyle::SampleIdentity
        }
    }
}

/// Bytes of the header.
pub const LEN: usize = 16;
/// Bytes of the CDR encapsulation header before it.
const ENCAPSULATION: usize = 4;

/// rmw_cyclonedds's request header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RequestHeader {
    /// The client's id.
    pub client: u64,
    /// The request's number within the client.
    pub seq: i64,
}

/// Whether serialized data (encapsulation header first) is little-endian:
/// the low bit of the representation id (CDR_LE 0x0001, PL_CDR_LE 0x0003,
/// the XCDR2 ids alike).
fn little_endian(data: &[u8]) -> bool {
    data.get(1).is_some_and(|b| b & 1 == 1)
}

impl RequestHeader {
    /// Reads the header from serialized data and removes it; `None` (data
    /// unchanged) when the data is too short to hold one.
    pub fn take(data: &mut Vec<u8>) -> Option<RequestHeader> {
        let h = Self::peek(data)?;
        data.drain(ENCAPSULATION..ENCAPSULATION + LEN);
        Some(h)
    }

    /// Reads the header from serialized data.
    pub fn peek(data: &[u8]) -> Option<RequestHeader> {
        let b = data.get(ENCAPSULATION..ENCAPSULATION + LEN)?;
        let (c, s) = b.split_at(8);
        let (c, s): ([u8; 8], [u8; 8]) = (c.try_into().ok()?, s.try_into().ok()?);
        Some(if little_endian(data) {
            RequestHeader {
                client: u64::from_le_bytes(c),
                seq: i64::from_le_bytes(s),
            }
        } else {
            RequestHeader {
                client: u64::from_be_bytes(c),
                seq: i64::from_be_bytes(s),
            }
        })
    }

    /// Puts the header before the body of serialized data, in its byte
    /// order (data without an encapsulation header gets one, CDR_LE).
    pub fn put(&self, data: &mut Vec<u8>) {
        if data.len() < ENCAPSULATION {
            data.clear();
            data.extend_from_slice(&[0, 1, 0, 0]);
        }
        let mut h = [0u8; LEN];
        if little_endian(data) {
            h[..8].copy_from_slice(&self.client.to_le_bytes());
            h[8..].copy_from_slice(&self.seq.to_le_bytes());
        } else {
            h[..8].copy_from_slice(&self.client.to_be_bytes());
            h[8..].copy_from_slice(&self.seq.to_be_bytes());
        }
        data.splice(ENCAPSULATION..ENCAPSULATION, h);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_sits_after_the_encapsulation_in_the_samples_byte_order() {
        let h = RequestHeader {
            client: 0x0102_0304_0506_0708,
            seq: 9,
        };
        let mut le = vec![0x00, 0x01, 0, 0, 0xaa];
        h.put(&mut le);
        assert_eq!(
            le,
            [0, 1, 0, 0, 8, 7, 6, 5, 4, 3, 2, 1, 9, 0, 0, 0, 0, 0, 0, 0, 0xaa]
        );
        assert_eq!(RequestHeader::take(&mut le), Some(h));
        assert_eq!(le, [0, 1, 0, 0, 0xaa]);
        let mut be = vec![0x00, 0x00, 0, 0];
        h.put(&mut be);
        assert_eq!(&be[4..12], &[1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(&be[12..20], &[0, 0, 0, 0, 0, 0, 0, 9]);
        assert_eq!(RequestHeader::peek(&be), Some(h));
        // too short: nothing taken
        let mut short = vec![0, 1, 0, 0, 1, 2, 3];
        assert_eq!(RequestHeader::take(&mut short), None);
        assert_eq!(short, [0, 1, 0, 0, 1, 2, 3]);
    }

    #[test]
    fn cyclone_participants_use_the_header() {
        assert_eq!(
            RpcStyle::of_vendor(VendorId::CYCLONE),
            RpcStyle::RequestHeader
        );
        assert_eq!(
            RpcStyle::of_vendor(VendorId::EPROSIMA),
            RpcStyle::SampleIdentity
        );
        assert_eq!(
            RpcStyle::of_vendor(VendorId::UNKNOWN),
            RpcStyle::SampleIdentity
        );
    }
}
