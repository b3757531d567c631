//! What a participant reports: the [`Event`]s it queues for the
//! application, the [`Stats`] counters (nothing is dropped silently), and
//! why creating an endpoint or writing a change failed.

use super::ReceivedSample;
use crate::rtps::discovery::{EndpointData, ParticipantData};
use crate::rtps::matching::Incompatible;
use crate::rtps::{Guid, GuidPrefix, SequenceNumber};

/// Why a remote participant is gone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LostReason {
    /// It said so (SPDP dispose).
    Disposed,
    /// Its lease expired.
    LeaseExpired,
    /// The table of participants was full
    /// ([`Config::max_participants`](super::Config::max_participants)) when
    /// another announced itself, and this one, heard from least recently,
    /// had announced no endpoint: the newcomer took its place (it comes
    /// back with its next announcement if there is room then).
    Evicted,
}

/// Something the application may want to know.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Event {
    /// A participant announced itself for the first time.
    ParticipantFound(ParticipantData),
    /// A known participant announced different data.
    ParticipantChanged(ParticipantData),
    /// A participant left or went silent; its endpoints are lost first.
    ParticipantLost {
        /// The participant.
        prefix: GuidPrefix,
        /// Why.
        reason: LostReason,
    },
    /// A remote writer was announced.
    PublicationFound(EndpointData),
    /// A remote writer's announcement changed.
    PublicationChanged(EndpointData),
    /// A remote writer is gone.
    PublicationLost(Guid),
    /// A remote reader was announced.
    SubscriptionFound(EndpointData),
    /// A remote reader's announcement changed.
    SubscriptionChanged(EndpointData),
    /// A remote reader is gone.
    SubscriptionLost(Guid),
    /// A local writer matched a reader (remote or local).
    WriterMatched {
        /// Local writer.
        writer: Guid,
        /// The reader.
        reader: Guid,
    },
    /// A local writer lost a matched reader.
    WriterUnmatched {
        /// Local writer.
        writer: Guid,
        /// The reader.
        reader: Guid,
    },
    /// A local reader matched a writer (remote or local).
    ReaderMatched {
        /// Local reader.
        reader: Guid,
        /// The writer.
        writer: Guid,
    },
    /// A local reader lost a matched writer.
    ReaderUnmatched {
        /// Local reader.
        reader: Guid,
        /// The writer.
        writer: Guid,
    },
    /// A local endpoint and one on the same topic do not match.
    IncompatibleQos {
        /// The local endpoint.
        local: Guid,
        /// The other endpoint.
        remote: Guid,
        /// The first rule that failed.
        reason: Incompatible,
    },
    /// A local reader received a change.
    SampleReceived(ReceivedSample),
    /// A local reader gave up a sample larger than
    /// [`Config::max_sample_size`](super::Config::max_sample_size): it is
    /// skipped (acknowledged as a GAP would be), so a reliable writer goes
    /// on with the next.
    SampleLost {
        /// Local reader.
        reader: Guid,
        /// The writer.
        writer: Guid,
        /// The sample's sequence number.
        sn: SequenceNumber,
        /// Its size, as its fragments announce it.
        size: u32,
        /// The largest this participant takes.
        limit: usize,
    },
    /// Every reader matched with a reliable local writer has acknowledged
    /// every change up to and including `up_to` (for `publish().confirmed()`).
    AckedByAll {
        /// Local writer.
        writer: Guid,
        /// Highest sequence number acknowledged by all.
        up_to: SequenceNumber,
    },
}

/// Counters: nothing is dropped silently.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct Stats {
    /// Datagrams handed to [`Participant::handle_datagram`](super::Participant::handle_datagram).
    pub datagrams_received: u64,
    /// Datagrams that did not parse as RTPS.
    pub datagrams_malformed: u64,
    /// Datagrams ignored: our own (multicast loopback) or after [`Participant::close`](super::Participant::close).
    pub datagrams_ignored: u64,
    /// Submessages skipped because INFO_DST named another participant.
    pub submessages_not_for_us: u64,
    /// SPDP/SEDP data that did not parse or made no sense.
    pub discovery_errors: u64,
    /// Participants or endpoints not tracked because a limit was reached.
    pub discovery_limited: u64,
    /// SPDP data for another domain.
    pub other_domain: u64,
    /// DATA_FRAG submessages rejected by the reassembler.
    pub fragments_rejected: u64,
    /// User DATA from writers no local reader is matched with.
    pub data_unmatched: u64,
    /// Datagrams produced.
    pub datagrams_sent: u64,
    /// Bytes produced.
    pub bytes_sent: u64,
}

/// Why an endpoint could not be created.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CreateError {
    /// Topic and type names must be 1..=256 bytes without NUL.
    #[error("topic and type names must be 1 to 256 bytes without NUL")]
    InvalidName,
    /// All 2^24 - 1 entity keys are used.
    #[error("no entity ids left")]
    TooManyEndpoints,
    /// The participant was closed.
    #[error("the participant is closed")]
    Closed,
}

/// Largest change [`Participant::write`](super::Participant::write) accepts (RTPS sample sizes are 32-bit).
pub const MAX_WRITE_SIZE: usize = u32::MAX as usize - 64;

/// Why a change could not be written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WriteError {
    /// No such local writer.
    #[error("no such writer")]
    UnknownWriter,
    /// Keep-all history full of unacknowledged samples ([`Config::max_history`](super::Config::max_history)
    /// samples or [`Config::max_unacked_bytes`](super::Config::max_unacked_bytes) bytes): wait for
    /// [`Event::AckedByAll`] and try again.
    #[error("history full: {0} samples or max_unacked_bytes of data await acknowledgement")]
    HistoryFull(usize),
    /// The sample is larger than RTPS can describe (4 GiB).
    #[error("sample of {0} bytes is too large")]
    TooLarge(usize),
    /// The participant was closed.
    #[error("the participant is closed")]
    Closed,
}
