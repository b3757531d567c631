//! Parameter lists (§9.4.2.11): the encoding of inline QoS and of
//! SPDP/SEDP discovery data.

use super::types::Cursor;
use super::{Error, VendorId};

/// `PID_PAD`.
pub const PID_PAD: u16 = 0x0000;
/// `PID_SENTINEL`: ends a list.
pub const PID_SENTINEL: u16 = 0x0001;
/// Bit of a PID that marks it vendor-specific (interpreted per vendor id).
pub const PID_VENDOR_SPECIFIC: u16 = 0x8000;
/// Bit of a PID that says "must understand: ignore the whole message if unknown".
pub const PID_MUST_UNDERSTAND: u16 = 0x4000;

/// The identity of a parameter: standard PIDs stand alone, vendor-specific
/// ones (bit 0x8000) only mean something together with the sender's vendor id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParameterId {
    /// A standard PID (without the must-understand bit).
    Standard(u16),
    /// A vendor-specific PID (without the must-understand bit) of a vendor.
    Vendor(VendorId, u16),
}

/// One parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Parameter<'a> {
    /// The raw 16-bit PID as on the wire.
    pub pid: u16,
    /// The value bytes (padded to a multiple of 4 by the sender).
    pub value: &'a [u8],
}

impl Parameter<'_> {
    /// The PID without the must-understand bit, keyed by vendor when vendor-specific.
    pub fn id(&self, vendor: VendorId) -> ParameterId {
        let p = self.pid & !PID_MUST_UNDERSTAND;
        if p & PID_VENDOR_SPECIFIC != 0 {
            ParameterId::Vendor(vendor, p)
        } else {
            ParameterId::Standard(p)
        }
    }

    /// True if the sender requires the receiver to understand it.
    pub fn must_understand(&self) -> bool {
        self.pid & PID_MUST_UNDERSTAND != 0
    }
}

/// A parsed parameter list, borrowing its bytes.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ParameterList<'a> {
    /// The parameters in order (PAD and the sentinel removed).
    pub params: Vec<Parameter<'a>>,
    /// Byte order of the values.
    pub little: bool,
}

impl<'a> ParameterList<'a> {
    /// Parses a list that ends with `PID_SENTINEL`; returns it and the bytes consumed.
    pub fn parse(b: &'a [u8], little: bool) -> Result<(ParameterList<'a>, usize), Error> {
        let mut c = Cursor::new(b, little, 0);
        let mut params = Vec::new();
        loop {
            let offset = c.pos;
            let pid = c.u16()?;
            let len = c.u16()? as usize;
            if pid == PID_SENTINEL {
                break;
            }
            let value = c.take(len).map_err(|_| Error::Invalid {
                offset,
                what: "parameter",
                detail: format!("PID 0x{pid:04x} length {len} exceeds the list"),
            })?;
            if pid != PID_PAD {
                params.push(Parameter { pid, value });
            }
        }
        Ok((ParameterList { params, little }, c.pos))
    }

    /// The first parameter with this id.
    pub fn get(&self, id: ParameterId, vendor: VendorId) -> Option<&Parameter<'a>> {
        self.params.iter().find(|p| p.id(vendor) == id)
    }

    /// Appends a list: each value padded to 4 bytes, then the sentinel.
    pub fn write(params: &[(u16, &[u8])], little: bool, out: &mut Vec<u8>) {
        let put = |v: u16, out: &mut Vec<u8>| {
            out.extend_from_slice(&if little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            })
        };
        for (pid, value) in params {
            let padded = value.len().div_ceil(4) * 4;
            put(*pid, out);
            put(u16::try_from(padded).unwrap_or(u16::MAX), out);
            out.extend_from_slice(value);
            out.resize(out.len() + (padded - value.len()), 0);
        }
        put(PID_SENTINEL, out);
        put(0, out);
    }
}
