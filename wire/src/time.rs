//! Instants after a duration that cannot overflow: timeouts, periods and
//! intervals come from users, and `Duration::MAX` is how many of them say
//! "never" (`Instant + Duration::MAX` panics).

use std::time::{Duration, Instant};

/// Later than any timeout in practice (about 30 years): what a deadline
/// that would not fit in an `Instant` becomes.
pub const NEVER: Duration = Duration::from_secs(30 * 365 * 86_400);

/// `now + d`, or `now` + [`NEVER`] where that would overflow.
pub fn later(now: Instant, d: Duration) -> Instant {
    now.checked_add(d)
        .or_else(|| now.checked_add(NEVER))
        .unwrap_or(now)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_duration_too_long_for_the_clock_is_never() {
        let now = Instant::now();
        assert_eq!(
            later(now, Duration::from_secs(3)),
            now + Duration::from_secs(3)
        );
        assert_eq!(later(now, Duration::MAX), now + NEVER);
    }
}
