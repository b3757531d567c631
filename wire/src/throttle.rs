//! A warning said at most once in a while, with a count of the times it
//! was not said: for conditions that come back over and over (a slow
//! subscriber filling its queue at every refill, central holding modules
//! back for memory). Sans-I/O: the caller gives the time.

use std::time::{Duration, SystemTime};

/// Says whether a warning may be said now (see the [module docs](self)).
#[derive(Debug, Clone)]
pub struct Throttle {
    every: Duration,
    /// When it was last said, and the times since that it was not.
    said: Option<(SystemTime, u64)>,
}

impl Throttle {
    /// At most once per `every`.
    pub const fn new(every: Duration) -> Self {
        Throttle { every, said: None }
    }

    /// The condition happened at `now`: `Some(n)` if it is to be said,
    /// `n` the times it was left unsaid since the last time; `None` if it
    /// was said less than `every` ago (it is counted).
    pub fn admit(&mut self, now: SystemTime) -> Option<u64> {
        let again = match &mut self.said {
            Some((at, unsaid)) if now.duration_since(*at).unwrap_or_default() < self.every => {
                *unsaid += 1;
                return None;
            }
            Some((_, unsaid)) => std::mem::take(unsaid),
            None => 0,
        };
        self.said = Some((now, 0));
        Some(again)
    }

    /// Whether it was said, and every time since (nothing left unsaid):
    /// what follows it (its end) may be said too.
    pub fn all_said(&self) -> bool {
        self.said.is_some_and(|(_, unsaid)| unsaid == 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn says_once_per_period_and_counts_the_rest() {
        let t0 = SystemTime::UNIX_EPOCH;
        let s = Duration::from_secs;
        let mut t = Throttle::new(s(10));
        assert!(!t.all_said());
        assert_eq!(t.admit(t0), Some(0));
        assert!(t.all_said());
        assert_eq!(t.admit(t0 + s(1)), None);
        assert_eq!(t.admit(t0 + s(9)), None);
        assert!(!t.all_said());
        assert_eq!(t.admit(t0 + s(10)), Some(2));
        // a clock that went back counts as no time passed
        assert_eq!(t.admit(t0), None);
    }
}
