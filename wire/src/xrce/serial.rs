//! Serial framing, eProsima's HDLC-like "stream framing" (`protocols/xrce.md` §12):
//!
//! `7E | src | dst | len_lo | len_hi | payload … | crc_lo | crc_hi`
//!
//! Every byte after the flag that equals 0x7E or 0x7D is sent as `7D`,
//! `byte ^ 0x20`. The CRC is CRC-16/ARC over the unescaped payload only,
//! little-endian. A 0x7E inside a frame starts a new frame.
//!
//! ```
//! use courier_wire::xrce::serial::{self, SerialDecoder, SerialFrame};
//! let ping = [0x80, 0, 0, 0, 2, 1, 8, 0, 0, 0x0A, 0xFF, 0xFD, 2, 0, 0, 0];
//! let mut wire = vec![0x55]; // line noise before the frame
//! serial::encode(1, 0, &ping, &mut wire).unwrap();
//! assert_eq!(wire[1..6], [0x7E, 1, 0, 16, 0]);
//! assert_eq!(wire[wire.len() - 2..], [0xCF, 0x12]);
//! let mut d = SerialDecoder::new();
//! d.push(&wire);
//! let frame = d.next_frame().unwrap().unwrap();
//! assert_eq!(frame, SerialFrame { src: 1, dst: 0, payload: ping.to_vec() });
//! assert_eq!(d.skipped(), 1);
//! ```

use super::EncodeError;

/// The frame start flag.
pub const FLAG: u8 = 0x7E;
/// The escape byte.
pub const ESCAPE: u8 = 0x7D;
/// What an escaped byte is XORed with.
pub const ESCAPE_XOR: u8 = 0x20;
/// Default largest payload [`SerialDecoder::new`] accepts: the peers' 512-byte MTU, with room to spare.
pub const DEFAULT_MAX_PAYLOAD: usize = 4096;

const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_ARC);

/// CRC-16/ARC of `data`, as the frame trailer carries it.
pub fn crc16(data: &[u8]) -> u16 {
    CRC16.checksum(data)
}

/// One decoded frame.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct SerialFrame {
    /// Sender's address (the eProsima examples: client 1, agent 0).
    pub src: u8,
    /// Receiver's address; receivers drop frames not addressed to them.
    pub dst: u8,
    /// The XRCE message.
    pub payload: Vec<u8>,
}

/// Why bytes of the serial stream did not give a frame. Offsets count
/// bytes pushed into the decoder since it was made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SerialError {
    /// The CRC in the trailer does not match the payload.
    #[error("XRCE serial frame at stream byte {offset}: CRC {received:#06x} received, {computed:#06x} computed")]
    BadCrc {
        /// Offset of the frame's start flag.
        offset: u64,
        /// CRC in the frame.
        received: u16,
        /// CRC of the payload received.
        computed: u16,
    },
    /// An escape byte followed by a byte that does not unescape to 0x7E or 0x7D.
    #[error("XRCE serial frame: bad escape 7D {byte:02X} at stream byte {offset}")]
    BadEscape {
        /// Offset of the byte after the escape.
        offset: u64,
        /// That byte.
        byte: u8,
    },
    /// The length field is above the decoder's limit.
    #[error("XRCE serial frame at stream byte {offset} announces {len} payload bytes, more than the {max} allowed")]
    Oversize {
        /// Offset of the frame's start flag.
        offset: u64,
        /// Announced length.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// A start flag arrived before the frame was complete; decoding goes on
    /// with the new frame.
    #[error(
        "XRCE serial frame at stream byte {offset} cut short by a new frame at byte {restart}"
    )]
    Interrupted {
        /// Offset of the incomplete frame's start flag.
        offset: u64,
        /// Offset of the flag that interrupted it.
        restart: u64,
    },
}

/// Appends a frame carrying `payload` (at most 65535 bytes) from `src` to `dst`.
pub fn encode(src: u8, dst: u8, payload: &[u8], out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let len = u16::try_from(payload.len()).map_err(|_| EncodeError::TooLong {
        what: "serial frame payload",
        len: payload.len(),
        max: usize::from(u16::MAX),
    })?;
    let [l0, l1] = len.to_le_bytes();
    let [c0, c1] = crc16(payload).to_le_bytes();
    out.push(FLAG);
    for &b in [src, dst, l0, l1].iter().chain(payload).chain(&[c0, c1]) {
        if b == FLAG || b == ESCAPE {
            out.extend_from_slice(&[ESCAPE, b ^ ESCAPE_XOR]);
        } else {
            out.push(b);
        }
    }
    Ok(())
}

/// A frame being read: `got` unescaped bytes so far.
#[derive(Debug, Clone)]
struct Partial {
    /// Stream offset of the start flag.
    start: u64,
    escaped: bool,
    got: usize,
    src: u8,
    dst: u8,
    len: usize,
    payload: Vec<u8>,
    crc: [u8; 2],
}

/// Streaming frame decoder: push bytes as they arrive, pull frames. It
/// skips bytes outside frames and resynchronises on the next start flag
/// after any error.
#[derive(Debug, Clone)]
pub struct SerialDecoder {
    input: Vec<u8>,
    pos: usize,
    /// Stream offset of `input[0]`.
    base: u64,
    frame: Option<Partial>,
    max_payload: usize,
    skipped: u64,
}

impl Default for SerialDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl SerialDecoder {
    /// A decoder accepting payloads up to [`DEFAULT_MAX_PAYLOAD`].
    pub fn new() -> Self {
        Self::with_max_payload(DEFAULT_MAX_PAYLOAD)
    }

    /// A decoder rejecting payloads longer than `max_payload`.
    pub fn with_max_payload(max_payload: usize) -> Self {
        SerialDecoder {
            input: Vec::new(),
            pos: 0,
            base: 0,
            frame: None,
            max_payload,
            skipped: 0,
        }
    }

    /// Adds bytes read from the line.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 {
            self.input.drain(..self.pos);
            self.base += self.pos as u64;
            self.pos = 0;
        }
        self.input.extend_from_slice(bytes);
    }

    /// Bytes seen outside any frame (line noise) so far.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// The next complete frame, an error for bytes that did not make one,
    /// or `None` until more bytes are pushed.
    pub fn next_frame(&mut self) -> Option<Result<SerialFrame, SerialError>> {
        while self.pos < self.input.len() {
            let b = self.input[self.pos];
            let at = self.base + self.pos as u64;
            self.pos += 1;
            if b == FLAG {
                let new = Partial {
                    start: at,
                    escaped: false,
                    got: 0,
                    src: 0,
                    dst: 0,
                    len: 0,
                    payload: Vec::new(),
                    crc: [0; 2],
                };
                if let Some(old) = self.frame.replace(new) {
                    return Some(Err(SerialError::Interrupted {
                        offset: old.start,
                        restart: at,
                    }));
                }
                continue;
            }
            let Some(f) = self.frame.as_mut() else {
                self.skipped += 1;
                continue;
            };
            let v = if f.escaped {
                f.escaped = false;
                let v = b ^ ESCAPE_XOR;
                if v != FLAG && v != ESCAPE {
                    self.frame = None;
                    return Some(Err(SerialError::BadEscape {
                        offset: at,
                        byte: b,
                    }));
                }
                v
            } else if b == ESCAPE {
                f.escaped = true;
                continue;
            } else {
                b
            };
            if let Some(done) = self.feed(v) {
                self.frame = None;
                return Some(done);
            }
        }
        None
    }

    /// Takes one unescaped byte of the current frame; returns the frame or
    /// an error once it is complete or hopeless.
    fn feed(&mut self, v: u8) -> Option<Result<SerialFrame, SerialError>> {
        let max = self.max_payload;
        let f = self.frame.as_mut()?;
        let i = f.got;
        f.got += 1;
        match i {
            0 => f.src = v,
            1 => f.dst = v,
            2 => f.len = usize::from(v),
            3 => {
                f.len |= usize::from(v) << 8;
                if f.len > max {
                    return Some(Err(SerialError::Oversize {
                        offset: f.start,
                        len: f.len,
                        max,
                    }));
                }
            }
            _ if i - 4 < f.len => f.payload.push(v),
            _ => {
                f.crc[i - 4 - f.len] = v;
                if i - 4 - f.len == 1 {
                    let received = u16::from_le_bytes(f.crc);
                    let computed = crc16(&f.payload);
                    return Some(if received == computed {
                        Ok(SerialFrame {
                            src: f.src,
                            dst: f.dst,
                            payload: std::mem::take(&mut f.payload),
                        })
                    } else {
                        Err(SerialError::BadCrc {
                            offset: f.start,
                            received,
                            computed,
                        })
                    });
                }
            }
        }
        None
    }
}
