//! The write side of one IPC direct link (`central -c`): frames go to a
//! task of the link's own, so that a receiving module that stops reading
//! holds up only the publishes sent to it, never the session's driver
//! (which keeps serving central, the other links and every other call).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use tokio::io::{AsyncWriteExt, WriteHalf};
use tokio::sync::mpsc;

use crate::ipc_backend::IpcStream;

/// Bytes queued for one link beyond which publishes that go to it wait
/// (back-pressure on their `publish().await`) until it drains below.
pub(crate) const LINK_QUEUE_LIMIT: usize = 1 << 20;

/// A link's writer task and what it has still to write.
pub(crate) struct LinkWriter {
    tx: mpsc::UnboundedSender<Vec<u8>>,
    queued: Arc<AtomicUsize>,
}

impl LinkWriter {
    /// Starts the writer of `w`: `drained` is called each time the queue
    /// falls to the limit or below from above it, `failed` once if a write
    /// fails (the link is gone).
    pub(crate) fn spawn(
        mut w: WriteHalf<Box<dyn IpcStream>>,
        drained: impl Fn() + Send + 'static,
        failed: impl FnOnce() + Send + 'static,
    ) -> LinkWriter {
        let (tx, mut rx) = mpsc::unbounded_channel::<Vec<u8>>();
        let queued = Arc::new(AtomicUsize::new(0));
        let q = queued.clone();
        tokio::spawn(async move {
            while let Some(frame) = rx.recv().await {
                let r = w.write_all(&frame).await;
                let before = q.fetch_sub(frame.len(), Ordering::AcqRel);
                if r.is_err() {
                    failed();
                    return;
                }
                if before > LINK_QUEUE_LIMIT && before - frame.len() <= LINK_QUEUE_LIMIT {
                    drained();
                }
            }
            let _ = w.shutdown().await;
        });
        LinkWriter { tx, queued }
    }

    /// Queues `frame`; `false` if the writer has ended (the link failed).
    pub(crate) fn send(&self, frame: Vec<u8>) -> bool {
        let len = frame.len();
        self.queued.fetch_add(len, Ordering::AcqRel);
        if self.tx.send(frame).is_err() {
            self.queued.fetch_sub(len, Ordering::AcqRel);
            return false;
        }
        true
    }

    /// More than [`LINK_QUEUE_LIMIT`] bytes wait to be written.
    pub(crate) fn congested(&self) -> bool {
        self.queued.load(Ordering::Acquire) > LINK_QUEUE_LIMIT
    }
}
