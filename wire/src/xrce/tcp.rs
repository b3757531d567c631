//! TCP framing (`protocols/xrce.md` §12): every message is preceded by its
//! length as a 2-byte little-endian number; a length of 0 is skipped.
//!
//! ```
//! use courier_wire::xrce::tcp::{self, TcpDeframer};
//! let mut wire = Vec::new();
//! tcp::encode(&[0x81, 0, 0, 0], &mut wire).unwrap();
//! assert_eq!(wire, [4, 0, 0x81, 0, 0, 0]);
//! let mut d = TcpDeframer::new();
//! d.push(&wire[..1]); // any split is fine
//! assert!(d.next_frame().is_none());
//! d.push(&wire[1..]);
//! assert_eq!(d.next_frame(), Some(Ok(vec![0x81, 0, 0, 0])));
//! ```

use super::EncodeError;

/// Size of the length prefix.
pub const PREFIX_SIZE: usize = 2;

/// Why the byte stream did not give a message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TcpError {
    /// The length prefix is above the deframer's limit; the record is skipped.
    #[error("XRCE TCP record at stream byte {offset} announces {len} bytes, more than the {max} allowed")]
    Oversize {
        /// Stream offset of the length prefix.
        offset: u64,
        /// Announced length.
        len: usize,
        /// The limit.
        max: usize,
    },
}

/// Appends the length prefix and `message` to `out`. The message must hold
/// 1 to 65535 bytes. Send the result in one write (and set `TCP_NODELAY`):
/// the eProsima peers' two writes meet Nagle's algorithm.
pub fn encode(message: &[u8], out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let len = u16::try_from(message.len())
        .ok()
        .filter(|&l| l > 0)
        .ok_or(EncodeError::TooLong {
            what: "TCP record (1 to 65535 bytes)",
            len: message.len(),
            max: usize::from(u16::MAX),
        })?;
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(message);
    Ok(())
}

/// Splits a TCP byte stream into messages, whatever the reads' boundaries.
#[derive(Debug, Clone)]
pub struct TcpDeframer {
    buf: Vec<u8>,
    start: usize,
    /// Stream offset of `buf[start]`.
    offset: u64,
    /// Bytes of an oversize record still to drop.
    skip: usize,
    max_len: usize,
}

impl Default for TcpDeframer {
    fn default() -> Self {
        Self::new()
    }
}

impl TcpDeframer {
    /// A deframer that accepts any length (up to 65535).
    pub fn new() -> Self {
        Self::with_max_len(usize::from(u16::MAX))
    }

    /// A deframer that rejects (and skips) records longer than `max_len`.
    pub fn with_max_len(max_len: usize) -> Self {
        TcpDeframer {
            buf: Vec::new(),
            start: 0,
            offset: 0,
            skip: 0,
            max_len,
        }
    }

    /// Adds bytes read from the socket.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start > 0 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes pushed but not yet returned or skipped.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// Whether a record is part way: bytes wait for the rest of theirs, or
    /// an oversize one is being skipped. A peer that then goes quiet may
    /// be talking out of step (one bad length prefix swallows what follows).
    pub fn mid_record(&self) -> bool {
        self.skip > 0 || self.buffered() > 0
    }

    fn advance(&mut self, n: usize) {
        self.start += n;
        self.offset += n as u64;
    }

    /// The next complete message, an error for a record that was skipped,
    /// or `None` until more bytes are pushed.
    pub fn next_frame(&mut self) -> Option<Result<Vec<u8>, TcpError>> {
        loop {
            if self.skip > 0 {
                let n = self.skip.min(self.buffered());
                self.advance(n);
                self.skip -= n;
                if self.skip > 0 {
                    return None;
                }
            }
            let &[l0, l1, ..] = &self.buf[self.start..] else {
                return None;
            };
            let len = usize::from(u16::from_le_bytes([l0, l1]));
            if len == 0 {
                self.advance(PREFIX_SIZE);
                continue;
            }
            if len > self.max_len {
                let offset = self.offset;
                self.advance(PREFIX_SIZE);
                self.skip = len;
                return Some(Err(TcpError::Oversize {
                    offset,
                    len,
                    max: self.max_len,
                }));
            }
            if self.buffered() < PREFIX_SIZE + len {
                return None;
            }
            let body = self.start + PREFIX_SIZE;
            let frame = self.buf[body..body + len].to_vec();
            self.advance(PREFIX_SIZE + len);
            return Some(Ok(frame));
        }
    }
}
