//! READ_DATA delivery control (`protocols/xrce.md` §9): how many samples,
//! for how long, how fast, how far apart.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use super::super::submessage::{DeliveryControl, ReadData};
use super::super::types::{BaseObjectRequest, StreamId};

/// A READ_DATA being served.
#[derive(Debug, Clone)]
pub(super) struct Delivery {
    /// The READ_DATA's request id and object: every DATA carries it.
    pub request: BaseObjectRequest,
    /// Where the DATA goes.
    pub stream: StreamId,
    /// Samples still to send; `None`: unlimited.
    remaining: Option<u32>,
    /// When delivery ends; `None`: never.
    until: Option<Instant>,
    /// Bytes per second; `None`: unlimited.
    rate: Option<u32>,
    tokens: f64,
    refilled: Instant,
    /// At least this long between two samples.
    pace: Duration,
    next_at: Instant,
}

/// Whether a sample may go now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Gate {
    /// Yes.
    Open,
    /// Not before then.
    Wait(Instant),
    /// The delivery is over.
    Ended,
}

impl Delivery {
    /// The delivery a READ_DATA asks for, from `now`; `None` for a cancel
    /// (max_samples 0). Without delivery control: one sample, as eProsima's
    /// agent does.
    pub fn start(read: &ReadData, now: Instant) -> Option<Self> {
        let dc = read.delivery_control.unwrap_or(DeliveryControl {
            max_samples: 1,
            ..DeliveryControl::default()
        });
        if dc.max_samples == 0 {
            return None;
        }
        Some(Delivery {
            request: read.request,
            stream: read.preferred_stream_id,
            remaining: (dc.max_samples != u16::MAX).then_some(u32::from(dc.max_samples)),
            until: (dc.max_elapsed_time != 0)
                .then(|| now + Duration::from_secs(u64::from(dc.max_elapsed_time))),
            rate: (dc.max_bytes_per_second != 0).then_some(u32::from(dc.max_bytes_per_second)),
            tokens: f64::from(dc.max_bytes_per_second),
            refilled: now,
            pace: Duration::from_millis(u64::from(dc.min_pace_period)),
            next_at: now,
        })
    }

    /// Whether it has run out of time at `now`.
    pub fn expired(&self, now: Instant) -> bool {
        self.until.is_some_and(|u| now >= u)
    }

    /// Whether a sample of `len` bytes may go at `now`.
    pub fn gate(&mut self, len: usize, now: Instant) -> Gate {
        if self.expired(now) || self.remaining == Some(0) {
            return Gate::Ended;
        }
        if now < self.next_at {
            return Gate::Wait(self.next_at);
        }
        if let Some(rate) = self.rate {
            let rate = f64::from(rate);
            let dt = now.saturating_duration_since(self.refilled).as_secs_f64();
            // the bucket holds a second's worth, or one sample if larger
            let cap = rate.max(len as f64);
            self.tokens = (self.tokens + dt * rate).min(cap);
            self.refilled = now;
            if self.tokens < len as f64 {
                let wait = (len as f64 - self.tokens) / rate;
                return Gate::Wait(now + Duration::from_secs_f64(wait.min(3600.0)));
            }
        }
        Gate::Open
    }

    /// A sample of `len` bytes went at `now`; whether the delivery is over.
    pub fn sent(&mut self, len: usize, now: Instant) -> bool {
        if self.rate.is_some() {
            self.tokens -= len as f64;
        }
        self.next_at = now + self.pace;
        if let Some(r) = self.remaining.as_mut() {
            *r = r.saturating_sub(1);
        }
        self.remaining == Some(0)
    }

    /// The next moment something may change without input.
    pub fn deadline(&self) -> Option<Instant> {
        self.until
    }
}

/// What a reader-like object (data reader, requester, replier) holds for
/// its client: samples taken from DDS, and the READ_DATA serving them.
#[derive(Debug, Clone)]
pub(super) struct Inbox {
    /// Samples as the client gets them (body, with any prefix).
    pub queue: VecDeque<Vec<u8>>,
    /// Samples kept at most; the oldest goes first.
    pub cap: usize,
    /// The bytes of `queue`.
    bytes: usize,
    /// Bytes kept at most (the newest sample always is): a reader whose
    /// client never reads (it died without DELETE) holds no more.
    byte_cap: usize,
    /// The READ_DATA being served.
    pub delivery: Option<Delivery>,
    /// The READ_DATA that started it (kept for restoring).
    pub read: Option<ReadData>,
    /// When the gate next opens (rate, pace).
    pub wake: Option<Instant>,
    /// A reliable keep-all reader: at `cap` it holds the bridge's own
    /// writers back instead of dropping ([`Inbox::is_full`]); only samples
    /// from elsewhere (remote DDS writers) can take it beyond, up to
    /// [`HOLD_SLACK`] × `cap`, where the oldest go after all.
    pub hold: bool,
    /// A sample too large for the best-effort stream was dropped and
    /// reported ([`BridgeEvent::SampleTooLarge`](super::BridgeEvent::SampleTooLarge));
    /// later ones are only counted.
    pub too_large_reported: bool,
}

/// How far beyond its `cap` a holding inbox takes samples that nothing
/// could hold back (from remote DDS writers) before it drops the oldest.
pub const HOLD_SLACK: usize = 4;

/// The bytes a reader keeps, newest first, for a client that has answered
/// nothing for a while ([`StreamConfig::silent_after`](crate::xrce::stream::StreamConfig::silent_after)):
/// a dead client's readers (1024 clients, each reader up to 16 MiB) cost
/// little, and one whose link comes back still finds the latest samples.
pub const SILENT_BYTES: usize = 1 << 20;

impl Inbox {
    pub fn new(cap: usize, byte_cap: usize) -> Self {
        Inbox {
            queue: VecDeque::new(),
            cap: cap.max(1),
            bytes: 0,
            byte_cap,
            delivery: None,
            read: None,
            wake: None,
            hold: false,
            too_large_reported: false,
        }
    }

    /// A reliable keep-all reader's inbox (see [`Inbox::hold`]).
    pub fn holding(cap: usize, byte_cap: usize) -> Self {
        Inbox {
            hold: true,
            ..Inbox::new(cap, byte_cap)
        }
    }

    /// A holding inbox at its cap (of samples, or a [`HOLD_SLACK`]th of
    /// its bytes): the bridge's writers matched with it wait.
    pub fn is_full(&self) -> bool {
        self.hold && (self.queue.len() >= self.cap || self.bytes >= self.byte_cap / HOLD_SLACK)
    }

    /// What a holding inbox takes before [`is_full`](Self::is_full):
    /// samples, and bytes (a writer may overshoot by its last sample).
    pub fn room(&self) -> (usize, usize) {
        (
            self.cap.saturating_sub(self.queue.len()),
            (self.byte_cap / HOLD_SLACK).saturating_sub(self.bytes),
        )
    }

    /// A holding inbox that drained to half of that: the writers it held go on.
    pub fn has_room(&self) -> bool {
        self.queue.len() <= self.cap / 2 && self.bytes <= self.byte_cap / HOLD_SLACK / 2
    }

    /// Keeps a sample; whether an older one was dropped for it.
    pub fn push(&mut self, sample: Vec<u8>) -> bool {
        self.bytes += sample.len();
        self.queue.push_back(sample);
        let limit = if self.hold {
            self.cap.saturating_mul(HOLD_SLACK)
        } else {
            self.cap
        };
        let mut dropped = false;
        while self.queue.len() > 1 && (self.queue.len() > limit || self.bytes > self.byte_cap) {
            self.pop();
            dropped = true;
        }
        dropped
    }

    /// Drops the oldest samples down to what a reader keeps for a client
    /// that answers nothing ([`SILENT_BYTES`], and `cap` samples): how many.
    pub fn trim_for_silence(&mut self) -> usize {
        let mut dropped = 0;
        while self.queue.len() > 1
            && (self.queue.len() > self.cap || self.bytes > SILENT_BYTES.min(self.byte_cap))
        {
            self.pop();
            dropped += 1;
        }
        dropped
    }

    /// Takes the oldest sample out.
    pub fn pop(&mut self) -> Option<Vec<u8>> {
        let s = self.queue.pop_front()?;
        self.bytes -= s.len();
        Some(s)
    }

    /// The bytes of the samples kept.
    #[cfg(test)]
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// When this inbox needs the clock.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let d = self.delivery.as_ref()?;
        let wake = if self.queue.is_empty() {
            None
        } else {
            self.wake
        };
        [wake, d.deadline()].into_iter().flatten().min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reader whose client never reads keeps at most its bytes (the
    /// newest sample always), however many samples its cap allows.
    #[test]
    fn an_inbox_keeps_at_most_its_bytes() {
        let mut i = Inbox::new(1024, 1000);
        for n in 0..50u8 {
            i.push(vec![n; 100]);
        }
        assert_eq!((i.queue.len(), i.bytes()), (10, 1000));
        assert_eq!(i.queue.front().map(|s| s[0]), Some(40));
        // one sample above the bound is kept alone
        assert!(i.push(vec![0; 5000]));
        assert_eq!((i.queue.len(), i.bytes()), (1, 5000));
        assert_eq!(i.pop().map(|s| s.len()), Some(5000));
        assert_eq!(i.bytes(), 0);
        // a holding one holds its writers back at a quarter of its bytes
        let mut h = Inbox::holding(1024, 1000);
        h.push(vec![0; 200]);
        assert!(!h.is_full());
        h.push(vec![0; 100]);
        assert!(h.is_full() && !h.has_room());
        h.pop();
        assert!(h.has_room());
    }
    use crate::xrce::{ObjectId, ObjectKind, RequestId};

    fn read(dc: Option<DeliveryControl>) -> ReadData {
        ReadData {
            request: BaseObjectRequest {
                request_id: RequestId(14),
                object_id: ObjectId::new(1, ObjectKind::DataReader),
            },
            preferred_stream_id: StreamId::RELIABLE,
            data_format: 0,
            content_filter: None,
            delivery_control: dc,
        }
    }

    #[test]
    fn no_delivery_control_is_one_sample_and_zero_samples_cancel() {
        let now = Instant::now();
        let mut d = Delivery::start(&read(None), now).unwrap();
        assert_eq!(d.gate(10, now), Gate::Open);
        assert!(d.sent(10, now));
        assert_eq!(d.gate(10, now), Gate::Ended);
        assert!(Delivery::start(&read(Some(DeliveryControl::default())), now).is_none());
    }

    #[test]
    fn rate_pace_and_elapsed_time() {
        let now = Instant::now();
        let dc = DeliveryControl {
            max_samples: u16::MAX,
            max_elapsed_time: 2,
            max_bytes_per_second: 100,
            min_pace_period: 10,
        };
        let mut d = Delivery::start(&read(Some(dc)), now).unwrap();
        assert_eq!(d.gate(60, now), Gate::Open);
        assert!(!d.sent(60, now));
        // 10 ms pace first, then 20 bytes short: 0.2 s more
        assert_eq!(d.gate(60, now), Gate::Wait(now + Duration::from_millis(10)));
        let t = now + Duration::from_millis(10);
        let Gate::Wait(w) = d.gate(60, t) else {
            panic!()
        };
        assert!((w - t).as_millis().abs_diff(190) <= 1, "{:?}", w - t);
        assert_eq!(d.gate(60, w), Gate::Open);
        assert_eq!(d.gate(1, now + Duration::from_secs(2)), Gate::Ended);
    }
}
