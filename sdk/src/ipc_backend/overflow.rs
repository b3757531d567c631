//! Samples for a keep-all subscription whose queue is full: they wait, in
//! order, in one task per subscription, each acknowledged to central once
//! it is in the queue (so central's capacity holds the rest back), each
//! holding the credit of the direct-link read it came in (so the link's
//! reader waits too).
//!
//! One task per subscription, not one per sample: samples parked by
//! separate tasks would enter the queue in whatever order the tasks wake.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use tokio::sync::{mpsc, OwnedSemaphorePermit};

use crate::mailbox::Mailbox;
use crate::session::{RawSample, SampleQueue};

use super::driver::Cmd;

/// A sample waiting for room, with its delivery and read credit.
struct Parked {
    sample: RawSample,
    delivery: u64,
    credit: Option<Arc<OwnedSemaphorePermit>>,
}

/// One subscription's waiting samples (the driver's side).
#[derive(Default)]
pub(super) struct Overflow {
    tx: Option<mpsc::UnboundedSender<Parked>>,
    /// Samples handed to the task and not yet in the queue.
    waiting: Arc<AtomicUsize>,
    /// Those of them that came from central (the others hold their
    /// direct link's read credit): central sends no more than the module's
    /// capacity, and what it sends ahead, before their acknowledgements,
    /// which wait for room; one that did not wait took a session to 4 GB
    /// in 6 s (audit 22).
    from_central: Arc<AtomicUsize>,
}

impl Overflow {
    /// Samples are waiting for room (the queue was full).
    pub(super) fn is_waiting(&self) -> bool {
        self.waiting.load(Ordering::Acquire) > 0
    }

    /// Samples from central waiting.
    pub(super) fn waiting_from_central(&self) -> usize {
        self.from_central.load(Ordering::Acquire)
    }

    /// Queues `s` for `queue` behind any sample already waiting: `true`
    /// when it went in at once (acknowledge it now), else the task asks
    /// the driver to acknowledge it (`Cmd::Ack`) once it is in.
    ///
    /// The count of waiting samples is lowered only after a sample is in
    /// the queue, so a zero here means every earlier sample is in: the new
    /// one may go straight in without overtaking.
    pub(super) fn push(
        &mut self,
        queue: &Arc<SampleQueue>,
        s: RawSample,
        delivery: u64,
        credit: Option<Arc<OwnedSemaphorePermit>>,
        cmd: &Mailbox<Cmd>,
    ) -> bool {
        let s = if self.waiting.load(Ordering::Acquire) == 0 {
            match queue.push(s) {
                Ok(()) => return true,
                Err(s) => s,
            }
        } else {
            s
        };
        let tx = self.tx.get_or_insert_with(|| {
            spawn(
                queue.clone(),
                self.waiting.clone(),
                self.from_central.clone(),
                cmd.clone(),
            )
        });
        self.waiting.fetch_add(1, Ordering::AcqRel);
        let central = credit.is_none();
        if central {
            self.from_central.fetch_add(1, Ordering::AcqRel);
        }
        // bounded by central's capacity and the links' read credits (a
        // central that does not wait is given up: see `deliver`)
        let parked = Parked {
            sample: s,
            delivery,
            credit,
        };
        if tx.send(parked).is_err() {
            // the task is gone only with the driver's mailbox: nothing to ack
            self.waiting.fetch_sub(1, Ordering::AcqRel);
            if central {
                self.from_central.fetch_sub(1, Ordering::AcqRel);
            }
        }
        false
    }
}

fn spawn(
    queue: Arc<SampleQueue>,
    waiting: Arc<AtomicUsize>,
    from_central: Arc<AtomicUsize>,
    cmd: Mailbox<Cmd>,
) -> mpsc::UnboundedSender<Parked> {
    let (tx, mut rx) = mpsc::unbounded_channel::<Parked>();
    tokio::spawn(async move {
        // ends when the subscription is gone (its sender dropped)
        while let Some(p) = rx.recv().await {
            let central = p.credit.is_none();
            queue.push_wait(p.sample).await;
            waiting.fetch_sub(1, Ordering::AcqRel);
            if central {
                from_central.fetch_sub(1, Ordering::AcqRel);
            }
            // one per delivery
            if cmd.post(Cmd::Ack(p.delivery)).is_err() {
                break;
            }
        }
    });
    tx
}
