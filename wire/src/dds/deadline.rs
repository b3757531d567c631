//! DEADLINE bookkeeping shared by readers (requested: a sample must come
//! within the period) and writers (offered: the writer promised one): per
//! instance, when the period next runs out, and the misses so far.

use foldhash::{HashMap, HashMapExt};
use std::time::{Duration, Instant};

/// The deadline of one endpoint.
pub(super) struct Deadline {
    period: Duration,
    /// Per instance (key hash; all zero for a topic without key): when the
    /// period runs out.
    due: HashMap<[u8; 16], Instant>,
    misses: u64,
}

impl Deadline {
    /// `None` for an infinite period (no deadline).
    pub(super) fn new(period: Option<Duration>) -> Option<Self> {
        period.map(|period| Deadline {
            period,
            due: HashMap::new(),
            misses: 0,
        })
    }

    /// A sample of `instance` came (reader) or was written (writer) at `now`.
    pub(super) fn arm(&mut self, instance: [u8; 16], now: Instant) {
        self.due
            .insert(instance, crate::time::later(now, self.period));
    }

    /// The instance was disposed or unregistered: no deadline until it
    /// lives again.
    pub(super) fn forget(&mut self, instance: &[u8; 16]) {
        self.due.remove(instance);
    }

    /// The instances it watches (tests).
    #[cfg(test)]
    pub(super) fn instances(&self) -> impl Iterator<Item = &[u8; 16]> + '_ {
        self.due.keys()
    }

    pub(super) fn next_due(&self) -> Option<Instant> {
        self.due.values().min().copied()
    }

    /// The instances whose period ran out by `now`, each re-armed for the
    /// next period, with the miss count after each.
    pub(super) fn expire(&mut self, now: Instant) -> Vec<([u8; 16], u64)> {
        let mut missed = Vec::new();
        for (instance, due) in self.due.iter_mut() {
            if *due <= now {
                self.misses += 1;
                *due = crate::time::later(now, self.period);
                missed.push((*instance, self.misses));
            }
        }
        missed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_instance_misses_once_per_period_until_it_is_armed_again_or_forgotten() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut d = Deadline::new(Some(ms(100))).unwrap();
        assert!(Deadline::new(None).is_none());
        assert_eq!(
            d.next_due(),
            None,
            "nothing is due before an instance lives"
        );
        d.arm([1; 16], t0);
        d.arm([2; 16], t0 + ms(50));
        assert_eq!(d.next_due(), Some(t0 + ms(100)));
        assert!(d.expire(t0 + ms(99)).is_empty());
        assert_eq!(d.expire(t0 + ms(100)), vec![([1; 16], 1)]);
        // re-armed from the miss, not from the last sample
        assert_eq!(d.next_due(), Some(t0 + ms(150)));
        d.arm([2; 16], t0 + ms(140));
        d.forget(&[1; 16]);
        assert!(d.expire(t0 + ms(200)).is_empty());
        assert_eq!(d.expire(t0 + ms(240)), vec![([2; 16], 2)]);
    }
}
