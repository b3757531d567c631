//! `-r` ([`Config::resend_on_reconnect`](super::Config::resend_on_reconnect)):
//! the deliveries a module that died had not finished, kept under its name
//! until a module of that name handles their message again, oldest first
//! out when they hold more than
//! [`Config::max_queued_bytes`](super::Config::max_queued_bytes).

use std::collections::{BTreeMap, HashMap, VecDeque};

use super::log::Kind;
use super::tables::{cost, DispatchId};
use super::Central;

/// The kept deliveries, in the order they were kept.
#[derive(Debug, Default)]
pub(super) struct Kept {
    next: u64,
    /// Every kept delivery by when it was kept: the oldest goes first.
    order: BTreeMap<u64, (String, DispatchId)>,
    /// Of those, the ones of each module name, in that order.
    by_name: HashMap<String, VecDeque<u64>>,
}

impl Kept {
    /// Keeps `id` for the next module called `name`.
    pub(super) fn keep(&mut self, name: &str, id: DispatchId) {
        let at = self.next;
        self.next += 1;
        self.order.insert(at, (name.to_string(), id));
        self.by_name
            .entry(name.to_string())
            .or_default()
            .push_back(at);
    }

    /// Takes out the deliveries kept for `name` that `pick` chooses, in the
    /// order they were kept.
    pub(super) fn take(
        &mut self,
        name: &str,
        mut pick: impl FnMut(DispatchId) -> bool,
    ) -> Vec<DispatchId> {
        let Some(list) = self.by_name.get_mut(name) else {
            return Vec::new();
        };
        let mut taken = Vec::new();
        list.retain(|at| match self.order.get(at) {
            Some((_, id)) if pick(*id) => {
                taken.push(*id);
                self.order.remove(at);
                false
            }
            Some(_) => true,
            None => false,
        });
        if list.is_empty() {
            self.by_name.remove(name);
        }
        taken
    }

    /// Takes out the delivery kept longest, and the name it was kept for.
    pub(super) fn take_oldest(&mut self) -> Option<(String, DispatchId)> {
        let (at, (name, id)) = self.order.pop_first()?;
        if let Some(list) = self.by_name.get_mut(&name) {
            // the oldest of all is the oldest of its name
            if list.front() == Some(&at) {
                list.pop_front();
            } else {
                list.retain(|x| *x != at);
            }
            if list.is_empty() {
                self.by_name.remove(&name);
            }
        }
        Some((name, id))
    }

    /// Every kept delivery, with the name it is kept for.
    pub(super) fn iter(&self) -> impl Iterator<Item = (&str, DispatchId)> {
        self.order.values().map(|(n, id)| (n.as_str(), *id))
    }

    /// How many deliveries are kept.
    pub(super) fn len(&self) -> usize {
        self.order.len()
    }

    /// How many module names have deliveries kept.
    #[cfg(test)]
    pub(super) fn names(&self) -> usize {
        self.by_name.len()
    }
}

impl Central {
    /// `-r` kept `ids` for the next module called `name` (it died with
    /// them unfinished). Past
    /// [`Config::max_queued_bytes`](super::Config::max_queued_bytes) of kept
    /// deliveries, the oldest are dropped, with one line: when names are
    /// never used again (modules that name themselves after their process
    /// id) nothing else would ever free them.
    pub(super) fn keep_for_resend(&mut self, name: &str, ids: &[DispatchId]) {
        for &id in ids {
            if let Some(d) = self.dispatches.get(&id) {
                self.stats.kept_bytes += cost(d);
                self.kept.keep(name, id);
            }
        }
        let mut dropped = 0u64;
        let mut whose: Vec<String> = Vec::new();
        while self.stats.kept_bytes > self.config.max_queued_bytes {
            let Some((n, id)) = self.kept.take_oldest() else {
                break;
            };
            if let Some(d) = self.free_dispatch_id(id) {
                self.stats.kept_bytes = self.stats.kept_bytes.saturating_sub(cost(&d));
            }
            dropped += 1;
            if whose.len() < 3 && !whose.contains(&n) {
                whose.push(n);
            }
        }
        if dropped > 0 {
            self.stats.dropped_kept += dropped;
            let limit = self.config.max_queued_bytes;
            let more = if self.stats.dropped_kept > dropped {
                format!(" ({} in all)", self.stats.dropped_kept)
            } else {
                String::new()
            };
            self.log_line(
                Kind::Problem,
                format!(
                    "WARNING: {dropped} message(s) kept to resend to {} dropped, the oldest: \
                     more than {limit} bytes (max_queued_bytes) are kept for modules that have \
                     not reconnected{more}",
                    whose.join(", ")
                ),
            );
        }
    }

    /// A module called `name` handles `msg` again: the deliveries of `msg`
    /// kept for that name, in the order they were kept.
    pub(super) fn take_kept(&mut self, name: &str, msg: &str) -> Vec<DispatchId> {
        let dispatches = &self.dispatches;
        let ids = self
            .kept
            .take(name, |id| dispatches.get(&id).is_some_and(|d| d.msg == msg));
        for id in &ids {
            if let Some(d) = self.dispatches.get(id) {
                self.stats.kept_bytes = self.stats.kept_bytes.saturating_sub(cost(d));
            }
        }
        ids
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(n: i32) -> DispatchId {
        DispatchId(n)
    }

    #[test]
    fn takes_a_names_deliveries_in_order_and_forgets_the_name() {
        let mut k = Kept::default();
        for (n, i) in [("a", 1), ("b", 2), ("a", 3), ("a", 4)] {
            k.keep(n, id(i));
        }
        assert_eq!(k.take("a", |i| i != id(3)), vec![id(1), id(4)]);
        assert_eq!(k.len(), 2);
        assert_eq!(k.take("a", |_| true), vec![id(3)]);
        assert_eq!(k.names(), 1, "a name with nothing kept is forgotten");
        assert!(k.take("nobody", |_| true).is_empty());
    }

    #[test]
    fn the_oldest_goes_first_whatever_its_name() {
        let mut k = Kept::default();
        for (n, i) in [("a", 1), ("b", 2), ("a", 3)] {
            k.keep(n, id(i));
        }
        assert_eq!(k.take_oldest(), Some(("a".to_string(), id(1))));
        assert_eq!(k.take_oldest(), Some(("b".to_string(), id(2))));
        assert_eq!(k.names(), 1);
        assert_eq!(k.take("a", |_| true), vec![id(3)]);
        assert_eq!(k.take_oldest(), None);
        assert_eq!((k.len(), k.names()), (0, 0));
    }
}
