//! Which `listen` callback this thread is running, by the address of the
//! object that owns it (a session's [`SessionEnd`](crate::session_end),
//! an RTPS or XRCE driver's shared state): a `close()` of that session
//! there cannot wait for itself, and an RTPS `try_publish` there is sent
//! with the callbacks' other writes.

use std::cell::Cell;

thread_local! {
    /// The owner of the callback this thread runs; 0: none.
    static OWNER: Cell<usize> = const { Cell::new(0) };
}

/// Runs `f`, a callback of `owner`, marked as such on this thread.
pub(crate) fn running<R>(owner: usize, f: impl FnOnce() -> R) -> R {
    let outer = OWNER.with(|c| c.replace(owner));
    let r = f();
    OWNER.with(|c| c.set(outer));
    r
}

/// Whether this thread runs a callback of `owner`.
pub(crate) fn inside(owner: usize) -> bool {
    OWNER.with(|c| c.get()) == owner
}
