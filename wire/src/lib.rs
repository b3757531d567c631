//! # courier-wire
//!
//! Every byte format and protocol state machine of Courier, with no I/O:
//! no sockets, no clocks, no async runtime. Time, where it matters, is an
//! argument.
//!
//! - [`format`](mod@format): the CMU IPC format-string language.
//! - [`ipc`]: IPC marshalling, byte-identical to CMU IPC 3.9.
//! - [`cdr`]: OMG CDR as DDS uses it (XCDR1 and XCDR2).
//! - [`rtps`]: DDSI-RTPS 2.x messages and the participant state machine.
//! - [`dds`]: a sans-I/O DDS domain over the RTPS participant.
//! - [`xrce`]: DDS-XRCE messages, their TCP and serial framings, streams,
//!   and the client and agent session machines.
//! - `sim` (cargo feature `sim`): a deterministic simulated network to
//!   test these machines on.
//! - [`IpcMessage`]: the trait `#[derive(IpcMessage)]` implements, and
//!   [`NdVec`], the multi-dimensional variable arrays (`<T:k1,k2>`) it takes.
//!
//! ```
//! use courier_wire::{ipc, cdr, IpcMessage};
//! assert_eq!(<f64 as IpcMessage>::FORMAT, "double");
//! assert_eq!(ipc::to_vec(&1.5f64), 1.5f64.to_ne_bytes());
//! let bytes = cdr::to_vec(&7u16, cdr::Encoding::Xcdr1Le);
//! assert_eq!(bytes, [0, 1, 0, 0, 7, 0]);
//! assert_eq!(cdr::from_slice::<u16>(&bytes).unwrap(), 7);
//! ```
#![warn(missing_docs)]
#![deny(unsafe_code)] // one audited exception: message::copy_pod_vec

pub mod cdr;
pub mod const_str;
pub mod dds;
pub mod format;
pub mod ipc;
mod message;
pub mod ndvec;
pub mod ros2;
pub mod rtps;
#[cfg(feature = "sim")]
pub mod sim;
pub mod throttle;
pub mod time;
pub mod xrce;

#[doc(hidden)]
pub use message::__private;

pub use message::{IpcMessage, LengthError, NamedFormats};
pub use ndvec::{Matrix, NdVec, ShapeError};

/// The DDS key hash of `value`'s instance (`PID_KEY_HASH`, DDSI-RTPS 2.5
/// §9.6.4.8) in XCDR2 form, the form DDS-XTypes 1.3 §7.6.8 specifies:
/// [`rtps::participant::KeyHash::of`] as bytes, [`key_hash_in`] `(value,`
/// [`cdr::Version::Xcdr2`]`)`.
///
/// A writer sends the hash in the XCDR version of its data (Courier,
/// Cyclone DDS and Fast DDS do), and for keys with an 8-byte member or an
/// array of enums, strings or structs the two versions differ: to compare
/// with the key hash of an instance change from a writer of XCDR1 data
/// (Fast DDS; Courier and Cyclone DDS for final types unless told
/// otherwise), use [`key_hash_in`] with [`cdr::Version::Xcdr1`]. For the
/// key itself see [`cdr::key_from_slice`] and [`cdr::key_from_key_hash_in`].
///
/// ```
/// assert_eq!(courier_wire::key_hash(&7i32)[..4], [0, 0, 0, 7]);
/// ```
pub fn key_hash<T: IpcMessage>(value: &T) -> [u8; 16] {
    rtps::participant::KeyHash::of(value).0
}

/// The DDS key hash of `value`'s instance in XCDR version `version`
/// ([`rtps::participant::KeyHash::of_in`] as bytes): what a writer of data
/// in that version sends as `PID_KEY_HASH`.
///
/// ```
/// use courier_wire::cdr::Version;
/// assert_eq!(courier_wire::key_hash_in(&7i32, Version::Xcdr1)[..4], [0, 0, 0, 7]);
/// ```
pub fn key_hash_in<T: IpcMessage>(value: &T, version: cdr::Version) -> [u8; 16] {
    rtps::participant::KeyHash::of_in(value, version).0
}
