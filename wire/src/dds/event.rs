//! What a [`Domain`](super::Domain) tells its shell.

use std::time::Duration;

use crate::rtps::matching::Incompatible;
use crate::rtps::participant::{self, KeyHash, ReceivedSample, WriteError};
use crate::rtps::{Guid, SequenceNumber};

use super::{ClientId, Endpoint, PatternId, QueryId, ReaderId, RequestId, ServiceId, WriterId};

/// Why a reader-side filter dropped a sample (counted by the shell).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum DropReason {
    /// Older than its writer's lifespan, by source timestamp.
    Lifespan,
    /// Closer than the reader's minimum separation to the last sample of
    /// its instance (time-based filter).
    MinimumSeparation,
}

/// Why a confirmed write was not confirmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ConfirmFailure {
    /// Not every matched reliable reader acknowledged it in time.
    Timeout(Duration),
    /// The writer was deleted first.
    WriterDeleted,
}

/// Why a query got no reply.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum QueryFailure {
    /// The request went out (the service was matched both ways) and no
    /// reply came within its timeout.
    Timeout(Duration),
    /// No service was matched within the timeout: the request was never
    /// sent.
    NoService(Duration),
    /// The request went out, no reply to it came within its timeout, but
    /// `replies` replies came meanwhile that answered no open query of this
    /// client (late replies to queries that had timed out, or a service of
    /// another request/reply style).
    Unmatched {
        /// The timeout.
        timeout: Duration,
        /// Replies that matched nothing.
        replies: u64,
    },
    /// Every service the request went to left (its request reader and its
    /// reply writer unmatched) before a reply came: none will.
    ServiceLost,
    /// The request could not be written.
    Refused(WriteError),
    /// The client was deleted first.
    ClientDeleted,
}

/// Something the shell acts on, from [`Domain::poll_event`](super::Domain::poll_event).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Event {
    /// A sample (or dispose/unregister) for a reader, past its filters.
    ///
    /// An [`Unregistered`](participant::ChangeKind::Unregistered) change
    /// of a keyed reader says that its instance has no live writer left
    /// (DDS's NOT_ALIVE_NO_WRITERS): sent by its last writer, or made by
    /// the reader when that writer left without a word for the instance
    /// (deleted, its participant lost, its liveliness lapsed) — then with
    /// no data, no source timestamp, [`SequenceNumber::UNKNOWN`], and its
    /// key hash as the instance's last change carried it.
    Sample {
        /// The reader.
        reader: ReaderId,
        /// The change.
        sample: ReceivedSample,
    },
    /// A reader-side filter dropped a sample.
    SampleDropped {
        /// The reader.
        reader: ReaderId,
        /// Which filter.
        reason: DropReason,
    },
    /// A reader gave up a sample larger than the participant takes
    /// ([`Config::max_sample_size`](crate::rtps::participant::Config::max_sample_size));
    /// a reliable writer goes on with the next.
    SampleLost {
        /// The reader.
        reader: ReaderId,
        /// The writer.
        writer: Guid,
        /// The sample's size.
        size: u32,
        /// The largest taken.
        limit: usize,
    },
    /// An instance of a reader with a deadline had no sample for a period
    /// (again every period until one comes).
    DeadlineMissed {
        /// The reader.
        reader: ReaderId,
        /// The instance (all zero for a topic without key), by its key
        /// hash as the reader names it: in the XCDR version of its
        /// writers' data; when they write both versions, in the one the
        /// reader chose ([`InstanceKeys`](super::InstanceKeys)).
        instance: KeyHash,
        /// Misses of this reader so far.
        total: u64,
    },
    /// A writer offering a deadline wrote no sample of a live instance
    /// (written, not disposed or unregistered) for a period (again every
    /// period until it writes one): DDS's OFFERED_DEADLINE_MISSED.
    OfferedDeadlineMissed {
        /// The writer.
        writer: WriterId,
        /// The instance (all zero for a topic without key).
        instance: KeyHash,
        /// Misses of this writer so far.
        total: u64,
    },
    /// A writer matched with a reader that requests a finite liveliness
    /// lease changed liveliness (DDS's LIVELINESS_CHANGED): `alive` when it
    /// matched or asserted itself again after a lapse; not alive when its
    /// lease lapsed, or when it left (deleted, unmatched, its participant
    /// lost: then it is in neither count any more).
    LivelinessChanged {
        /// The reader.
        reader: ReaderId,
        /// The writer.
        writer: Guid,
        /// Whether it is alive now.
        alive: bool,
        /// The reader's matched writers that are alive.
        alive_count: u32,
        /// The reader's matched writers whose lease lapsed.
        not_alive_count: u32,
    },
    /// A writer with a MANUAL liveliness kind and a finite lease asserted
    /// nothing (no write, no [`Domain::assert_liveliness`](super::Domain::assert_liveliness))
    /// within its lease: DDS's LIVELINESS_LOST, once per lapse.
    LivelinessLost {
        /// The writer.
        writer: WriterId,
        /// Lapses of this writer so far.
        total: u64,
    },
    /// A pattern subscription made a reader for a publication it matches;
    /// that reader's samples come as [`Event::Sample`].
    PatternMatched {
        /// The pattern subscription.
        pattern: PatternId,
        /// Its new reader.
        reader: ReaderId,
        /// The publication's topic.
        topic: String,
        /// The publication's type name.
        type_name: String,
        /// The reader of the same topic and type it replaces (deleted):
        /// one that asked more reliability or durability than a
        /// publication found since offers.
        replaces: Option<ReaderId>,
    },
    /// A pattern subscription's reader was deleted: every publication it
    /// was made for is gone (deleted, or lost with its participant). One
    /// is made again ([`Event::PatternMatched`]) if another publication of
    /// its topic and type comes.
    PatternUnmatched {
        /// The pattern subscription.
        pattern: PatternId,
        /// The deleted reader.
        reader: ReaderId,
        /// Its topic.
        topic: String,
        /// Its type name.
        type_name: String,
    },
    /// A request for a service.
    Request {
        /// The service.
        service: ServiceId,
        /// What the reply names.
        request: RequestId,
        /// The request sample.
        sample: ReceivedSample,
    },
    /// The reply to a query.
    Reply {
        /// The client.
        client: ClientId,
        /// The query answered.
        query: QueryId,
        /// The reply sample.
        sample: ReceivedSample,
    },
    /// A query that will get no reply.
    QueryFailed {
        /// The client.
        client: ClientId,
        /// The query.
        query: QueryId,
        /// Why.
        reason: QueryFailure,
    },
    /// A confirmed write was acknowledged by every matched reliable reader.
    WriteConfirmed {
        /// The writer.
        writer: WriterId,
        /// The write.
        sequence_number: SequenceNumber,
    },
    /// A confirmed write will not be confirmed.
    ConfirmFailed {
        /// The writer.
        writer: WriterId,
        /// The write.
        sequence_number: SequenceNumber,
        /// Why.
        reason: ConfirmFailure,
    },
    /// A writer whose keep-all history was full (a refused
    /// [`Domain::write`](super::Domain::write), or
    /// [`Domain::has_room`](super::Domain::has_room) answering false) has
    /// room again.
    Writable {
        /// The writer.
        writer: WriterId,
    },
    /// A writer matched a reader (remote or local).
    WriterMatched {
        /// The writer.
        writer: WriterId,
        /// The reader.
        reader: Guid,
    },
    /// A writer lost a matched reader.
    WriterUnmatched {
        /// The writer.
        writer: WriterId,
        /// The reader.
        reader: Guid,
    },
    /// A reader matched a writer (remote or local).
    ReaderMatched {
        /// The reader.
        reader: ReaderId,
        /// The writer.
        writer: Guid,
    },
    /// A reader lost a matched writer.
    ReaderUnmatched {
        /// The reader.
        reader: ReaderId,
        /// The writer.
        writer: Guid,
    },
    /// A remote endpoint on a topic a local endpoint uses has another type
    /// name: they will not match.
    TypeMismatch {
        /// The local endpoint.
        local: Endpoint,
        /// The remote endpoint.
        remote: Guid,
        /// The topic.
        topic: String,
        /// Our type name.
        local_type: String,
        /// Theirs.
        remote_type: String,
    },
    /// A local endpoint and one on the same topic do not match.
    IncompatibleQos {
        /// The local endpoint.
        local: Endpoint,
        /// Its topic.
        topic: String,
        /// The other endpoint.
        remote: Guid,
        /// The first rule that failed.
        reason: Incompatible,
    },
    /// Discovery, as the participant reports it: only
    /// `ParticipantFound`/`Changed`/`Lost`, `PublicationFound`/`Changed`/`Lost`
    /// and `SubscriptionFound`/`Changed`/`Lost` come this way.
    Discovery(participant::Event),
}
