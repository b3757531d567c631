//! The types the CLI knows by name, and how samples print.

use courier::IpcMessage;

use crate::text::hex;

/// The sample `courier ping` sends (DDS type `courier::Ping`).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::Ping")]
pub struct Ping {
    pub seq: u32,
    /// Nanoseconds since the Unix epoch when sent.
    pub stamp_ns: u64,
    pub text: String,
}

/// A sample's bytes for `spy`: decoded when the type is known
/// (`courier::Ping`), else the first 64 bytes in hex (`…` when there are
/// more), `-` when there are none.
pub fn sample_text(type_name: &str, data: &[u8]) -> String {
    if type_name == Ping::TYPE_NAME {
        if let Ok(p) = courier::cdr::from_slice::<Ping>(data) {
            return format!(
                "courier::Ping {{ seq: {}, stamp_ns: {}, text: {:?} }}",
                p.seq, p.stamp_ns, p.text
            );
        }
    }
    hex(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_print_decoded_or_as_bounded_hex() {
        let p = Ping {
            seq: 7,
            stamp_ns: 9,
            text: "hi".into(),
        };
        let data = courier::cdr::to_vec(&p, courier::cdr::Encoding::Xcdr1Le);
        assert_eq!(
            sample_text("courier::Ping", &data),
            "courier::Ping { seq: 7, stamp_ns: 9, text: \"hi\" }"
        );
        // an unknown type (or one that does not decode): hex, 64 bytes at most
        assert_eq!(sample_text("x::Y", &[0xab, 0x01]), "ab01");
        assert_eq!(sample_text("courier::Ping", &[0xab]), "ab");
        assert_eq!(sample_text("x::Y", &[]), "-");
    }
}
