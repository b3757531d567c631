//! The IPC data-message frame (ipc.md §2): a 28-byte header of seven
//! big-endian `int32`s, then `classTotal` bytes of class data, then
//! `msgTotal` bytes of message data.
//!
//! ```
//! use courier_wire::ipc::frame::{Header, MsgClass};
//! // E1 of ipc.md: module1 publishes message1 (id 116) = 42
//! let bytes = [
//!     0, 0, 0, 0, 0, 0, 0, 12, 0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0x74,
//!     0x22, 0, 0, 0x0f, 0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0x38,
//! ];
//! let h = Header::decode(&bytes).unwrap();
//! assert_eq!(h.msg_total, 12);
//! assert_eq!(h.intent, 116);
//! assert_eq!(h.class_id.class(), MsgClass::Broadcast as u16);
//! assert_eq!(h.encode(), bytes);
//! ```

use super::ByteOrder;

/// Size of the frame header in bytes.
pub const HEADER_SIZE: usize = 28;

/// `intent` of a reply travelling back to the querier (`QUERY_REPLY_INTENT`).
pub const QUERY_REPLY_INTENT: i32 = -4;
/// The "no reference" value of refs and intents.
pub const NO_REF: i32 = -1;

/// Message classes used by IPC 3.9 (`X_IPC_MSG_CLASS_TYPE`, ipc.md §3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum MsgClass {
    /// Formatter messages at connect and replies central generates itself.
    Unknown = 0,
    /// Internal placeholder, never on the wire.
    HandlerReg = 1,
    /// Only its class-data format (`string`) is used.
    ExecHnd = 2,
    /// Queries.
    Query = 3,
    /// TCA goal (asked about at connect only).
    Goal = 4,
    /// TCA command.
    Command = 5,
    /// One-way internal requests to central.
    Inform = 6,
    /// TCA exception.
    Exception = 7,
    /// TCA polling monitor.
    PollingMonitor = 8,
    /// TCA point monitor.
    PointMonitor = 9,
    /// TCA demon monitor.
    DemonMonitor = 10,
    /// Answer to a user query.
    Reply = 11,
    /// "Handler finished" acknowledgement of a Broadcast/Inform.
    Success = 12,
    /// TCA failure.
    Failure = 13,
    /// TCA fire demon.
    FireDemon = 14,
    /// Published messages and central's notifications.
    Broadcast = 15,
    /// TCA multi-query.
    MultiQuery = 16,
}

impl MsgClass {
    /// The class with this number, if IPC defines one.
    pub const fn from_u16(v: u16) -> Option<Self> {
        use MsgClass::*;
        Some(match v {
            0 => Unknown,
            1 => HandlerReg,
            2 => ExecHnd,
            3 => Query,
            4 => Goal,
            5 => Command,
            6 => Inform,
            7 => Exception,
            8 => PollingMonitor,
            9 => PointMonitor,
            10 => DemonMonitor,
            11 => Reply,
            12 => Success,
            13 => Failure,
            14 => FireDemon,
            15 => Broadcast,
            16 => MultiQuery,
            _ => return None,
        })
    }
}

/// The `classId` word: message class, alignment and the byte orders of
/// class data and message data (ipc.md §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ClassId(pub u32);

impl ClassId {
    /// A class id as this machine's C library writes it: both byte orders
    /// native, packed alignment.
    pub const fn native(class: MsgClass) -> Self {
        let n = ByteOrder::NATIVE.nibble() as u32;
        ClassId((n << 28) | (n << 24) | class as u32)
    }

    /// The message class number (low 16 bits).
    pub const fn class(self) -> u16 {
        (self.0 & 0xffff) as u16
    }

    /// The message class, if known.
    pub const fn msg_class(self) -> Option<MsgClass> {
        MsgClass::from_u16(self.class())
    }

    /// The alignment byte; senders write 0 (packed), receivers reject anything else.
    pub const fn alignment(self) -> u8 {
        ((self.0 >> 16) & 0xff) as u8
    }

    /// Byte order of the message data (`None` for PDP or unknown).
    pub const fn data_order(self) -> Option<ByteOrder> {
        ByteOrder::from_nibble(((self.0 >> 24) & 0xf) as u8)
    }

    /// Byte order of the class data (`None` for PDP or unknown).
    pub const fn class_order(self) -> Option<ByteOrder> {
        ByteOrder::from_nibble(((self.0 >> 28) & 0xf) as u8)
    }

    /// This class id with the class number replaced.
    pub const fn with_class(self, class: MsgClass) -> Self {
        ClassId((self.0 & 0xffff_0000) | class as u32)
    }
}

/// The 28-byte header of a data message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Header {
    /// Byte length of the class data.
    pub class_total: i32,
    /// Byte length of the message data.
    pub msg_total: i32,
    /// Ref of the message being handled when this one was sent, else -1.
    pub parent_ref: i32,
    /// Message id, handler id, -4 (reply) or -1.
    pub intent: i32,
    /// Class, alignment and byte orders.
    pub class_id: ClassId,
    /// -1 for a new message; central's dispatch id when answering one.
    pub dispatch_ref: i32,
    /// The sender's message reference number.
    pub msg_ref: i32,
}

/// Why a frame header was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// Fewer than 28 bytes.
    #[error("IPC frame header needs {HEADER_SIZE} bytes, got {0}")]
    Short(usize),
    /// `classTotal` or `msgTotal` is negative.
    #[error("IPC frame has negative length (classTotal {class_total}, msgTotal {msg_total})")]
    NegativeLength {
        /// classTotal.
        class_total: i32,
        /// msgTotal.
        msg_total: i32,
    },
    /// The frame is larger than the configured limit.
    #[error("IPC frame of {size} bytes exceeds the limit of {limit} bytes")]
    TooLarge {
        /// classTotal + msgTotal.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// The alignment byte is not 0 (packed).
    #[error("IPC frame data is not packed (alignment byte {0}); the C library rejects it too")]
    NotPacked(u8),
}

impl Header {
    /// Decodes the header from the first 28 bytes of `b`.
    pub fn decode(b: &[u8]) -> Result<Header, FrameError> {
        if b.len() < HEADER_SIZE {
            return Err(FrameError::Short(b.len()));
        }
        let w = |i: usize| i32::from_be_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        Ok(Header {
            class_total: w(0),
            msg_total: w(1),
            parent_ref: w(2),
            intent: w(3),
            class_id: ClassId(w(4) as u32),
            dispatch_ref: w(5),
            msg_ref: w(6),
        })
    }

    /// Encodes the header (big-endian words).
    pub fn encode(&self) -> [u8; HEADER_SIZE] {
        let mut out = [0u8; HEADER_SIZE];
        let words = [
            self.class_total,
            self.msg_total,
            self.parent_ref,
            self.intent,
            self.class_id.0 as i32,
            self.dispatch_ref,
            self.msg_ref,
        ];
        for (i, v) in words.iter().enumerate() {
            out[4 * i..4 * i + 4].copy_from_slice(&v.to_be_bytes());
        }
        out
    }

    /// Checks the lengths and alignment before anyone allocates the body:
    /// returns `classTotal + msgTotal`.
    pub fn body_len(&self, limit: u64) -> Result<usize, FrameError> {
        if self.class_total < 0 || self.msg_total < 0 {
            return Err(FrameError::NegativeLength {
                class_total: self.class_total,
                msg_total: self.msg_total,
            });
        }
        let size = self.class_total as u64 + self.msg_total as u64;
        if size > limit {
            return Err(FrameError::TooLarge { size, limit });
        }
        if self.class_id.alignment() != 0 {
            return Err(FrameError::NotPacked(self.class_id.alignment()));
        }
        Ok(size as usize)
    }
}

/// Message data of at least this many bytes is handed on rather than
/// copied behind its header ([`Frame::into_parts`]).
pub const SPLIT_AT: usize = 16 * 1024;

/// A whole data message: header, class data, message data.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// The header; its length fields are recomputed by [`Frame::encode`].
    pub header: Header,
    /// Class data (usually empty or a marshalled message name).
    pub class_data: Vec<u8>,
    /// Message data.
    pub data: Vec<u8>,
}

impl Frame {
    /// Splits a complete body (`classTotal + msgTotal` bytes) after its header.
    pub fn from_parts(header: Header, body: &[u8]) -> Result<Frame, FrameError> {
        let n = header.body_len(u64::MAX)?;
        if body.len() < n {
            return Err(FrameError::Short(HEADER_SIZE + body.len()));
        }
        let c = header.class_total as usize;
        Ok(Frame {
            header,
            class_data: body[..c].to_vec(),
            data: body[c..n].to_vec(),
        })
    }

    /// Encodes the frame as [`encode`](Self::encode) does, without copying
    /// a large message: header and class data come in the first buffer and,
    /// when the message data has at least [`SPLIT_AT`] bytes, the data
    /// itself is the second, as it was. Written one after the other (or
    /// with one vectored write) they are the same bytes.
    pub fn into_parts(self) -> (Vec<u8>, Option<Vec<u8>>) {
        if self.data.len() < SPLIT_AT {
            return (self.encode(), None);
        }
        let mut h = self.header;
        h.class_total = self.class_data.len() as i32;
        h.msg_total = self.data.len() as i32;
        let mut head = Vec::with_capacity(HEADER_SIZE + self.class_data.len());
        head.extend_from_slice(&h.encode());
        head.extend_from_slice(&self.class_data);
        (head, Some(self.data))
    }

    /// Encodes header, class data and message data, with the length fields
    /// set from the actual data.
    pub fn encode(&self) -> Vec<u8> {
        let mut h = self.header;
        h.class_total = self.class_data.len() as i32;
        h.msg_total = self.data.len() as i32;
        let mut out = Vec::with_capacity(HEADER_SIZE + self.class_data.len() + self.data.len());
        out.extend_from_slice(&h.encode());
        out.extend_from_slice(&self.class_data);
        out.extend_from_slice(&self.data);
        out
    }
}

/// Splits a byte stream into [`Frame`]s, copying each byte once: from the
/// caller's read buffer into the frame's own `class_data` and `data`.
///
/// A large message is therefore never gathered in a stream buffer first and
/// copied out of it afterwards. Its buffer grows with what has arrived
/// (doubling from 64 KiB up to the size the header announces), so a header
/// announcing a large frame costs nothing until its bytes come.
///
/// ```
/// use courier_wire::ipc::frame::{Deframer, Frame, Header, ClassId, MsgClass};
/// let f = Frame {
///     header: Header {
///         class_total: 0, msg_total: 0, parent_ref: -1, intent: 116,
///         class_id: ClassId::native(MsgClass::Broadcast), dispatch_ref: -1, msg_ref: 56,
///     },
///     class_data: Vec::new(),
///     data: vec![0, 0, 0, 42],
/// };
/// let bytes = f.encode();
/// let mut d = Deframer::new(1 << 20);
/// let (mut first, mut second) = bytes.split_at(10);
/// assert_eq!(d.next(&mut first).unwrap(), None);
/// let got = d.next(&mut second).unwrap().unwrap();
/// assert_eq!(got.data, f.data);
/// assert!(second.is_empty());
/// ```
#[derive(Debug)]
pub struct Deframer {
    limit: u64,
    /// The header being collected.
    head: Vec<u8>,
    /// The frame being filled, once its header is known.
    cur: Option<Partial>,
}

#[derive(Debug)]
struct Partial {
    header: Header,
    class_len: usize,
    data_len: usize,
    class_data: Vec<u8>,
    data: Vec<u8>,
}

/// A body buffer starts at most this large and doubles as bytes arrive.
const FIRST_RESERVE: usize = 64 * 1024;

/// Appends `bytes` to `v`, which will hold `total` bytes in the end:
/// capacity grows by doubling (from [`FIRST_RESERVE`]) but never past
/// `total`, so a frame's buffer ends exactly its size.
fn fill(v: &mut Vec<u8>, total: usize, bytes: &[u8]) {
    let need = v.len() + bytes.len();
    if need > v.capacity() {
        let want = (v.len() * 2).max(need).max(FIRST_RESERVE).min(total);
        v.reserve_exact(want - v.len());
    }
    v.extend_from_slice(bytes);
}

impl Deframer {
    /// Frames larger than `limit` bytes (class and message data) are refused.
    pub fn new(limit: u64) -> Deframer {
        Deframer {
            limit,
            head: Vec::with_capacity(HEADER_SIZE),
            cur: None,
        }
    }

    /// Takes bytes from the front of `input` until a frame is complete (and
    /// returns it) or `input` is used up (`None`: the rest is kept for the
    /// next call). An error leaves the stream unusable.
    pub fn next(&mut self, input: &mut &[u8]) -> Result<Option<Frame>, FrameError> {
        loop {
            let Some(p) = &mut self.cur else {
                let take = (HEADER_SIZE - self.head.len()).min(input.len());
                self.head.extend_from_slice(&input[..take]);
                *input = &input[take..];
                if self.head.len() < HEADER_SIZE {
                    return Ok(None);
                }
                let header = Header::decode(&self.head)?;
                let n = header.body_len(self.limit)?;
                self.head.clear();
                let class_len = header.class_total as usize;
                self.cur = Some(Partial {
                    header,
                    class_len,
                    data_len: n - class_len,
                    class_data: Vec::new(),
                    data: Vec::new(),
                });
                continue;
            };
            let c = (p.class_len - p.class_data.len()).min(input.len());
            fill(&mut p.class_data, p.class_len, &input[..c]);
            *input = &input[c..];
            let d = (p.data_len - p.data.len()).min(input.len());
            fill(&mut p.data, p.data_len, &input[..d]);
            *input = &input[d..];
            if p.class_data.len() < p.class_len || p.data.len() < p.data_len {
                return Ok(None);
            }
            let Some(p) = self.cur.take() else {
                unreachable!("checked above")
            };
            return Ok(Some(Frame {
                header: p.header,
                class_data: p.class_data,
                data: p.data,
            }));
        }
    }

    /// Bytes held for the frame being received (its buffers' capacity).
    pub fn buffered(&self) -> usize {
        self.head.capacity()
            + self
                .cur
                .as_ref()
                .map_or(0, |p| p.class_data.capacity() + p.data.capacity())
    }

    /// Whether a frame is partly received.
    pub fn is_mid_frame(&self) -> bool {
        !self.head.is_empty() || self.cur.is_some()
    }

    /// Forgets any partly received frame.
    pub fn reset(&mut self) {
        self.head.clear();
        self.cur = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame(intent: i32, class_data: Vec<u8>, data: Vec<u8>) -> Frame {
        Frame {
            header: Header {
                class_total: class_data.len() as i32,
                msg_total: data.len() as i32,
                parent_ref: NO_REF,
                intent,
                class_id: ClassId::native(MsgClass::Broadcast),
                dispatch_ref: NO_REF,
                msg_ref: 7,
            },
            class_data,
            data,
        }
    }

    /// Feeds `stream` cut at `cuts` and collects the frames.
    fn deframe(stream: &[u8], cuts: &[usize], limit: u64) -> Result<Vec<Frame>, FrameError> {
        let mut d = Deframer::new(limit);
        let mut out = Vec::new();
        let mut start = 0;
        let mut ends: Vec<usize> = cuts.iter().map(|c| c % (stream.len() + 1)).collect();
        ends.push(stream.len());
        ends.sort();
        for end in ends {
            let mut chunk = &stream[start..end.max(start)];
            start = end.max(start);
            while let Some(f) = d.next(&mut chunk)? {
                out.push(f);
            }
            assert!(chunk.is_empty(), "next returned None with input left");
        }
        assert!(!d.is_mid_frame(), "bytes left over after the last frame");
        Ok(out)
    }

    proptest! {
        /// However the stream is cut, the frames come out whole and equal.
        #[test]
        fn deframer_splits_any_cut_into_the_same_frames(
            frames in proptest::collection::vec(
                (any::<i32>(), proptest::collection::vec(any::<u8>(), 0..40),
                 prop_oneof![
                     proptest::collection::vec(any::<u8>(), 0..100),
                     (0usize..300_000).prop_map(|n| vec![0xa5; n]),
                 ]),
                0..6),
            cuts in proptest::collection::vec(any::<usize>(), 0..12),
        ) {
            let frames: Vec<Frame> = frames.into_iter().map(|(i, c, d)| frame(i, c, d)).collect();
            let stream: Vec<u8> = frames.iter().flat_map(|f| f.encode()).collect();
            let got = deframe(&stream, &cuts, u64::MAX).unwrap();
            prop_assert_eq!(got, frames);
        }
    }

    #[test]
    fn into_parts_is_encode_without_copying_large_data() {
        let small = frame(3, b"ab".to_vec(), vec![4; SPLIT_AT - 1]);
        assert_eq!(small.clone().into_parts(), (small.encode(), None));
        let big = frame(3, b"ab".to_vec(), vec![4; SPLIT_AT]);
        let at = big.data.as_ptr();
        let whole = big.encode();
        let (head, data) = big.into_parts();
        let data = data.unwrap();
        assert_eq!(data.as_ptr(), at, "the data was copied");
        assert_eq!([head, data].concat(), whole);
    }

    #[test]
    fn deframer_buffers_end_exactly_the_frame_size() {
        let f = frame(5, b"abc".to_vec(), vec![1; 1_000_003]);
        let bytes = f.encode();
        let got = deframe(&bytes, &[100, 70_000, 300_000], u64::MAX).unwrap();
        assert_eq!(got[0].data.capacity(), 1_000_003);
        assert_eq!(got[0].class_data.capacity(), 3);
    }

    /// A header announcing a large frame reserves memory only as its bytes
    /// arrive.
    #[test]
    fn deframer_reserves_with_what_arrived_not_with_what_was_announced() {
        let mut h = frame(5, Vec::new(), Vec::new()).header;
        h.msg_total = i32::MAX;
        let mut d = Deframer::new(u64::MAX);
        let head = h.encode();
        assert_eq!(d.next(&mut &head[..]).unwrap(), None);
        assert_eq!(d.next(&mut &[9u8; 10][..]).unwrap(), None);
        let p = d.cur.as_ref().unwrap();
        assert!(p.data.capacity() <= FIRST_RESERVE, "{}", p.data.capacity());
        assert!(d.is_mid_frame());
        d.reset();
        assert!(!d.is_mid_frame());
    }

    #[test]
    fn deframer_refuses_bad_headers() {
        let mut h = frame(5, Vec::new(), vec![0; 100]).header;
        h.msg_total = 100;
        let big = h.encode();
        assert!(matches!(
            Deframer::new(99).next(&mut &big[..]),
            Err(FrameError::TooLarge {
                size: 100,
                limit: 99
            })
        ));
        h.class_total = -1;
        let neg = h.encode();
        assert!(matches!(
            Deframer::new(1000).next(&mut &neg[..]),
            Err(FrameError::NegativeLength { .. })
        ));
    }

    fn hex(s: &str) -> Vec<u8> {
        let s: String = s.chars().filter(|c| c.is_ascii_hexdigit()).collect();
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// ipc.md E2: central delivers message1 to module2's handler 198 (demo-central capture).
    #[test]
    fn e2_delivery_with_class_data() {
        let b = hex("0000000c 0000000c ffffffff 000000c6 2200000f ffffffff 00000001 | 08000000 6d657373 61676531 | 04000000 04000000 2a000000");
        let h = Header::decode(&b).unwrap();
        assert_eq!(h.body_len(1 << 20).unwrap(), 24);
        assert_eq!(h.intent, 198);
        assert_eq!(h.class_id, ClassId::native(MsgClass::Broadcast));
        assert_eq!(h.class_id.data_order(), Some(ByteOrder::Little));
        let f = Frame::from_parts(h, &b[HEADER_SIZE..]).unwrap();
        assert_eq!(f.class_data, hex("08000000 6d657373 61676531"));
        assert_eq!(f.data, hex("04000000 04000000 2a000000"));
        assert_eq!(f.encode(), b);
    }

    /// The Success ack of E2.
    #[test]
    fn success_ack() {
        let b = hex("00000000 00000000 00000001 ffffffff 2200000c 00000001 ffffffff");
        let h = Header::decode(&b).unwrap();
        assert_eq!(h.class_id.msg_class(), Some(MsgClass::Success));
        assert_eq!(
            (h.parent_ref, h.intent, h.dispatch_ref, h.msg_ref),
            (1, NO_REF, 1, NO_REF)
        );
    }

    #[test]
    fn hostile_headers_are_rejected_before_allocation() {
        let mut h = Header::decode(&[0; 28]).unwrap();
        h.msg_total = -5;
        assert!(matches!(
            h.body_len(1 << 20),
            Err(FrameError::NegativeLength { .. })
        ));
        h.msg_total = i32::MAX;
        h.class_total = i32::MAX;
        assert!(matches!(
            h.body_len(1 << 20),
            Err(FrameError::TooLarge { .. })
        ));
        h.msg_total = 0;
        h.class_total = 0;
        h.class_id = ClassId(0x2201_000f);
        assert_eq!(h.body_len(1 << 20), Err(FrameError::NotPacked(1)));
        assert_eq!(Header::decode(&[0; 27]), Err(FrameError::Short(27)));
    }
}
