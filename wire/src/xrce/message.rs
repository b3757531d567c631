//! The XRCE message: header (4 bytes, or 8 with the client key) and
//! submessages, each header 4-aligned from the start of the message
//! (`protocols/xrce.md` §2, §3).

use super::submessage::{Submessage, SUBMESSAGE_HEADER_SIZE};
use super::types::{ClientKey, StreamId};
use super::{DecodeError, EncodeError};

/// Session ids below this carry the client key in every message header.
pub const SESSION_ID_WITHOUT_CLIENT_KEY: u8 = 0x80;

/// The message header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MessageHeader {
    /// `session_id`: below 0x80 the header carries the client key.
    pub session_id: u8,
    /// `stream_id`.
    pub stream_id: StreamId,
    /// `sequence_nr`, always little-endian on the wire. Messages on stream
    /// 0 (NONE) carry 0.
    pub sequence_nr: u16,
    /// The client key: present exactly when `session_id < 0x80`.
    pub client_key: Option<ClientKey>,
}

impl MessageHeader {
    /// A header for session `session_id` (0x80 or above: no key).
    pub fn new(session_id: u8, stream_id: StreamId, sequence_nr: u16) -> Self {
        MessageHeader {
            session_id,
            stream_id,
            sequence_nr,
            client_key: None,
        }
    }

    /// A header that carries `key` (session id below 0x80).
    pub fn with_key(session_id: u8, key: ClientKey, stream_id: StreamId, sequence_nr: u16) -> Self {
        MessageHeader {
            client_key: Some(key),
            ..Self::new(session_id, stream_id, sequence_nr)
        }
    }

    /// The header of the CREATE_CLIENT message of session `session_id`:
    /// `session_id & 0x80`, stream 0, sequence 0, with the key when the
    /// session id is below 0x80 (§2).
    pub fn create_client(session_id: u8, key: ClientKey) -> Self {
        let id = session_id & SESSION_ID_WITHOUT_CLIENT_KEY;
        if id < SESSION_ID_WITHOUT_CLIENT_KEY {
            Self::with_key(id, key, StreamId::NONE, 0)
        } else {
            Self::new(id, StreamId::NONE, 0)
        }
    }

    /// 4, or 8 with the client key.
    pub fn encoded_len(&self) -> usize {
        if self.session_id < SESSION_ID_WITHOUT_CLIENT_KEY {
            8
        } else {
            4
        }
    }

    /// Decodes the header at the start of `buf`; returns it and its length.
    pub fn decode(buf: &[u8]) -> Result<(MessageHeader, usize), DecodeError> {
        let truncated = |needed| DecodeError::Truncated {
            offset: 0,
            what: "message header",
            needed,
            remaining: buf.len(),
        };
        let &[session_id, stream_id, s0, s1, ..] = buf else {
            return Err(truncated(4));
        };
        let mut h = MessageHeader::new(
            session_id,
            StreamId(stream_id),
            u16::from_le_bytes([s0, s1]),
        );
        if session_id < SESSION_ID_WITHOUT_CLIENT_KEY {
            let Some(&[k0, k1, k2, k3]) = buf.get(4..8) else {
                return Err(truncated(8));
            };
            h.client_key = Some(ClientKey([k0, k1, k2, k3]));
        }
        Ok((h, h.encoded_len()))
    }

    /// Appends the header to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        out.extend_from_slice(&[self.session_id, self.stream_id.0]);
        out.extend_from_slice(&self.sequence_nr.to_le_bytes());
        match (
            self.session_id < SESSION_ID_WITHOUT_CLIENT_KEY,
            self.client_key,
        ) {
            (true, Some(k)) => out.extend_from_slice(&k.0),
            (false, None) => {}
            (true, None) => return Err(EncodeError::MissingClientKey(self.session_id)),
            (false, Some(_)) => return Err(EncodeError::UnexpectedClientKey(self.session_id)),
        }
        Ok(())
    }
}

/// An XRCE message: one UDP datagram, TCP record or serial frame.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Message {
    /// The header.
    pub header: MessageHeader,
    /// The submessages, in order.
    pub submessages: Vec<Submessage>,
    /// Bytes after the last submessage too few to hold another header:
    /// the eProsima client pads its last submessage to 4 with whatever its
    /// buffer held; the agent sends none. Written back as they are.
    pub trailing: Vec<u8>,
}

fn align4(n: usize) -> usize {
    (n + 3) & !3
}

impl Message {
    /// A message with these submessages and no trailing bytes.
    pub fn new(header: MessageHeader, submessages: Vec<Submessage>) -> Self {
        Message {
            header,
            submessages,
            trailing: Vec::new(),
        }
    }

    /// Decodes a whole message. Submessages are walked as the peers walk
    /// them: decode one by its type, align to 4, and stop when fewer than
    /// 4 bytes are left.
    pub fn decode(buf: &[u8]) -> Result<Message, DecodeError> {
        let (header, mut pos) = MessageHeader::decode(buf)?;
        let mut submessages: Vec<Submessage> = Vec::new();
        loop {
            let next = align4(pos);
            if next + SUBMESSAGE_HEADER_SIZE > buf.len() {
                break;
            }
            if let Some(prev) = submessages.last_mut() {
                prev.padding.extend_from_slice(&buf[pos..next]);
                prev.trim_padding();
            }
            let (s, end) = Submessage::decode_untrimmed(buf, next)?;
            submessages.push(s);
            pos = end;
        }
        if let Some(last) = submessages.last_mut() {
            last.trim_padding();
        }
        Ok(Message {
            header,
            submessages,
            trailing: buf[pos..].to_vec(),
        })
    }

    /// Decodes a submessage rebuilt from FRAGMENT bodies as the agent does:
    /// behind the header of the message that carried the first fragment.
    pub fn reassembled(header: &MessageHeader, body: &[u8]) -> Result<Message, DecodeError> {
        let mut buf = Vec::with_capacity(header.encoded_len() + body.len());
        header.encode(&mut buf).map_err(|_| DecodeError::Invalid {
            offset: 0,
            what: "session id for this client key",
            value: header.session_id.into(),
        })?;
        buf.extend_from_slice(body);
        Message::decode(&buf)
    }

    /// Appends the encoded message to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let origin = out.len();
        let res = self.encode_inner(out, origin);
        if res.is_err() {
            out.truncate(origin);
        }
        res
    }

    fn encode_inner(&self, out: &mut Vec<u8>, origin: usize) -> Result<(), EncodeError> {
        self.header.encode(out)?;
        let mut gap: &[u8] = &[];
        for s in &self.submessages {
            let pad = align4(out.len() - origin) - (out.len() - origin);
            out.extend((0..pad).map(|i| gap.get(i).copied().unwrap_or(0)));
            let used = s.encode_counting(out, origin)?;
            gap = s.padding.get(used..).unwrap_or(&[]);
        }
        out.extend_from_slice(&self.trailing);
        Ok(())
    }

    /// The encoded message.
    pub fn to_vec(&self) -> Result<Vec<u8>, EncodeError> {
        let mut v = Vec::new();
        self.encode(&mut v)?;
        Ok(v)
    }
}
