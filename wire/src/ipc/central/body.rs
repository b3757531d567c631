//! Message data as central holds it: shared between its queues and the
//! frames that carry it out, so a large message is never copied inside
//! central.

use std::fmt;
use std::ops::{Deref, Range};
use std::sync::Arc;

/// The data of one message (or reply), immutable and cheap to clone.
///
/// A small message is copied out of the receive buffer into a buffer of
/// its own. A large one keeps the buffer its frame was received into
/// (header and class data included) and points at its data, so it goes
/// from the receive buffer to every handler's socket without a copy (see
/// [`Output::TransmitBody`](super::Output::TransmitBody)).
#[derive(Clone)]
pub struct Body(Repr);

#[derive(Clone)]
enum Repr {
    Own(Arc<[u8]>),
    InFrame {
        buf: Arc<Vec<u8>>,
        start: usize,
        end: usize,
    },
}

impl Body {
    /// The bytes `range` of a received frame, without copying them.
    ///
    /// # Panics
    /// If `range` is not within `frame`.
    pub(crate) fn in_frame(frame: Vec<u8>, range: Range<usize>) -> Body {
        assert!(range.start <= range.end && range.end <= frame.len());
        Body(Repr::InFrame {
            buf: Arc::new(frame),
            start: range.start,
            end: range.end,
        })
    }

    /// No data.
    pub fn empty() -> Body {
        Body::from(&[][..])
    }
}

impl Deref for Body {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match &self.0 {
            Repr::Own(b) => b,
            Repr::InFrame { buf, start, end } => &buf[*start..*end],
        }
    }
}

impl AsRef<[u8]> for Body {
    fn as_ref(&self) -> &[u8] {
        self
    }
}

impl From<&[u8]> for Body {
    fn from(b: &[u8]) -> Body {
        Body(Repr::Own(Arc::from(b)))
    }
}

impl From<Vec<u8>> for Body {
    fn from(b: Vec<u8>) -> Body {
        Body(Repr::Own(Arc::from(b)))
    }
}

impl PartialEq for Body {
    fn eq(&self, other: &Body) -> bool {
        **self == **other
    }
}

impl Eq for Body {}

impl fmt::Debug for Body {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Body({} bytes)", self.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_body_in_its_frame_is_the_range_and_shares_the_buffer() {
        let frame: Vec<u8> = (0..100).collect();
        let at = frame.as_ptr();
        let b = Body::in_frame(frame, 28..90);
        assert_eq!(&b[..], &(28..90).collect::<Vec<u8>>()[..]);
        // Not copied: the data is where the frame was received.
        assert_eq!(b.as_ptr(), at.wrapping_add(28));
        let c = b.clone();
        assert_eq!(c.as_ptr(), b.as_ptr());
        assert_eq!(b, Body::from(&(28..90).collect::<Vec<u8>>()[..]));
        assert_eq!(format!("{b:?}"), "Body(62 bytes)");
    }

    #[test]
    fn an_owned_body_is_its_bytes() {
        assert_eq!(&Body::from(vec![1, 2, 3])[..], &[1, 2, 3]);
        assert!(Body::empty().is_empty());
        assert_ne!(Body::from(&[1u8][..]), Body::from(&[2u8][..]));
    }
}
