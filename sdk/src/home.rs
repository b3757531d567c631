//! The tokio runtime a session was made on, for calls made from threads
//! outside any runtime.
//!
//! A session runs on the runtime it is made in, and its calls are meant to
//! be awaited there. Some of them make tokio timers or tasks in the
//! caller's context (a query's deadline, `every`, `send_every`,
//! `wait_for_handlers`, a confirmed XRCE publish), which panic in tokio
//! when awaited with another executor (`futures::executor::block_on` on a
//! plain thread, say). Those calls enter the session's runtime first, so
//! that they work from such a thread as they do inside the runtime, as
//! long as that runtime is running: a multi-threaded runtime always is; a
//! current-thread runtime only while its `block_on` runs (tokio's own rule
//! for `Handle::block_on`).

use std::future::Future;

use tokio::runtime::{EnterGuard, Handle};

/// The runtime a session was made on (`None` for a session built with
/// [`Session::with_backend`](crate::Session::with_backend) outside any).
#[derive(Debug, Clone)]
pub(crate) struct Home(Option<Handle>);

impl Home {
    /// The runtime of the calling thread, if it has one.
    pub(crate) fn here() -> Self {
        Home(Handle::try_current().ok())
    }

    /// Enters the session's runtime if the calling thread is in none; the
    /// guard leaves it again. `None`: nothing to enter (already inside a
    /// runtime, or the session knows none).
    pub(crate) fn enter(&self) -> Option<EnterGuard<'_>> {
        if Handle::try_current().is_ok() {
            return None;
        }
        self.0.as_ref().map(Handle::enter)
    }

    /// Whether tokio timers and tasks can be made from the calling thread
    /// (it is in a runtime, or the session knows its own).
    pub(crate) fn reachable(&self) -> bool {
        self.0.is_some() || Handle::try_current().is_ok()
    }

    /// Spawns `f` on the session's runtime (the caller's, inside one).
    pub(crate) fn spawn<F>(&self, f: F) -> tokio::task::JoinHandle<F::Output>
    where
        F: Future + Send + 'static,
        F::Output: Send + 'static,
    {
        match (&self.0, Handle::try_current()) {
            (_, Ok(here)) => here.spawn(f),
            (Some(home), Err(_)) => home.spawn(f),
            (None, Err(_)) => tokio::spawn(f),
        }
    }

    /// `f`, polled with the session's runtime entered when its caller is
    /// in none.
    pub(crate) async fn run<F: Future>(&self, f: F) -> F::Output {
        let mut f = std::pin::pin!(f);
        std::future::poll_fn(|cx| {
            let _in = self.enter();
            f.as_mut().poll(cx)
        })
        .await
    }
}
