//! Deadlines from users' timeouts that cannot overflow the clock (see
//! [`courier_wire::time::later`]).

use std::time::Duration;
use tokio::time::Instant;

/// `now + d` on tokio's clock; `Duration::MAX` (and anything too long for
/// the clock) is 30 years away.
pub(crate) fn after(d: Duration) -> Instant {
    Instant::from_std(courier_wire::time::later(Instant::now().into_std(), d))
}
