//! An ordered map for a module's own few entries (its handlers, the
//! variables it read): a sorted vector while small, a B-tree beyond.
//!
//! A `BTreeMap`'s first insert allocates a whole node of eleven entries
//! (720 bytes for a module's handlers), which for an idle module holding
//! one handler was most of central's cost per connection. Iteration order
//! is the key order either way, so nothing that walks the map changes.

use std::borrow::Borrow;
use std::collections::{btree_map, BTreeMap};

/// Entries kept in the vector; the next one moves them into a B-tree (so
/// a module with thousands of entries costs `log n` per insert, not `n`).
const FEW: usize = 8;

#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum SmallMap<K, V> {
    /// Sorted by key, at most [`FEW`] entries.
    Few(Vec<(K, V)>),
    Many(BTreeMap<K, V>),
}

impl<K, V> Default for SmallMap<K, V> {
    fn default() -> Self {
        SmallMap::Few(Vec::new())
    }
}

impl<K: Ord, V> SmallMap<K, V> {
    pub(super) fn new() -> Self {
        Self::default()
    }

    fn find<Q>(v: &[(K, V)], key: &Q) -> Result<usize, usize>
    where
        K: Borrow<Q>,
        Q: Ord + ?Sized,
    {
        v.binary_search_by(|(k, _)| k.borrow().cmp(key))
    }

    pub(super) fn get<Q>(&self, key: &Q) -> Option<&V>
    where
        K: Borrow<Q>,
        Q: Ord + ?Sized,
    {
        match self {
            SmallMap::Few(v) => Self::find(v, key).ok().map(|i| &v[i].1),
            SmallMap::Many(m) => m.get(key),
        }
    }

    pub(super) fn get_mut<Q>(&mut self, key: &Q) -> Option<&mut V>
    where
        K: Borrow<Q>,
        Q: Ord + ?Sized,
    {
        match self {
            SmallMap::Few(v) => Self::find(v, key).ok().map(|i| &mut v[i].1),
            SmallMap::Many(m) => m.get_mut(key),
        }
    }

    pub(super) fn contains_key<Q>(&self, key: &Q) -> bool
    where
        K: Borrow<Q>,
        Q: Ord + ?Sized,
    {
        self.get(key).is_some()
    }

    /// Inserts or replaces; returns the value replaced.
    pub(super) fn insert(&mut self, key: K, value: V) -> Option<V> {
        match self {
            SmallMap::Few(v) => match Self::find(v, &key) {
                Ok(i) => Some(std::mem::replace(&mut v[i].1, value)),
                Err(i) if v.len() < FEW => {
                    // One more slot only: most modules hold one or two.
                    v.reserve_exact(1);
                    v.insert(i, (key, value));
                    None
                }
                Err(_) => {
                    let mut m: BTreeMap<K, V> = std::mem::take(v).into_iter().collect();
                    m.insert(key, value);
                    *self = SmallMap::Many(m);
                    None
                }
            },
            SmallMap::Many(m) => m.insert(key, value),
        }
    }

    pub(super) fn remove<Q>(&mut self, key: &Q) -> Option<V>
    where
        K: Borrow<Q>,
        Q: Ord + ?Sized,
    {
        match self {
            SmallMap::Few(v) => Self::find(v, key).ok().map(|i| v.remove(i).1),
            SmallMap::Many(m) => m.remove(key),
        }
    }

    pub(super) fn len(&self) -> usize {
        match self {
            SmallMap::Few(v) => v.len(),
            SmallMap::Many(m) => m.len(),
        }
    }

    #[cfg(test)]
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entries in key order.
    pub(super) fn iter(&self) -> Iter<'_, K, V> {
        match self {
            SmallMap::Few(v) => Iter::Few(v.iter()),
            SmallMap::Many(m) => Iter::Many(m.iter()),
        }
    }

    /// Values in key order.
    pub(super) fn values(&self) -> impl DoubleEndedIterator<Item = &V> {
        self.iter().map(|(_, v)| v)
    }
}

impl<'a, K: Ord, V> IntoIterator for &'a SmallMap<K, V> {
    type Item = (&'a K, &'a V);
    type IntoIter = Iter<'a, K, V>;

    fn into_iter(self) -> Iter<'a, K, V> {
        self.iter()
    }
}

/// [`SmallMap::iter`].
pub(super) enum Iter<'a, K, V> {
    Few(std::slice::Iter<'a, (K, V)>),
    Many(btree_map::Iter<'a, K, V>),
}

impl<'a, K, V> Iterator for Iter<'a, K, V> {
    type Item = (&'a K, &'a V);

    fn next(&mut self) -> Option<Self::Item> {
        match self {
            Iter::Few(i) => i.next().map(|(k, v)| (k, v)),
            Iter::Many(i) => i.next(),
        }
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        match self {
            Iter::Few(i) => i.size_hint(),
            Iter::Many(i) => i.size_hint(),
        }
    }
}

impl<K, V> DoubleEndedIterator for Iter<'_, K, V> {
    fn next_back(&mut self) -> Option<Self::Item> {
        match self {
            Iter::Few(i) => i.next_back().map(|(k, v)| (k, v)),
            Iter::Many(i) => i.next_back(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same operations on a `SmallMap` and a `BTreeMap` give the same
    /// answers and the same order, across the switch to a B-tree.
    #[test]
    fn behaves_as_a_btree_map() {
        let mut s: SmallMap<String, u32> = SmallMap::new();
        let mut b: BTreeMap<String, u32> = BTreeMap::new();
        // A fixed pseudo-random walk of inserts and removes.
        let mut x: u32 = 12345;
        for step in 0..2000u32 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let key = format!("k{}", (x >> 16) % 24);
            if (x >> 8) % 3 == 0 {
                assert_eq!(s.remove(key.as_str()), b.remove(&key), "step {step}");
            } else {
                assert_eq!(s.insert(key.clone(), step), b.insert(key, step));
            }
            assert_eq!(s.len(), b.len());
            assert_eq!(s.is_empty(), b.is_empty());
            assert!(s.iter().eq(b.iter()));
            assert!(s.iter().rev().eq(b.iter().rev()));
            assert!(s.values().eq(b.values()));
            for k in ["k0", "k7", "k23", "none"] {
                assert_eq!(s.get(k), b.get(k));
                assert_eq!(s.contains_key(k), b.contains_key(k));
                assert_eq!(s.get_mut(k).copied(), b.get_mut(k).copied());
            }
        }
        assert!(matches!(s, SmallMap::Many(_)), "grew past FEW");
    }

    #[test]
    fn stays_a_vector_while_small() {
        let mut s = SmallMap::new();
        for i in 0..FEW {
            s.insert(FEW - i, i);
        }
        let SmallMap::Few(v) = &s else {
            panic!("still few");
        };
        assert!(v.windows(2).all(|w| w[0].0 < w[1].0), "sorted");
        s.insert(0, 0);
        assert!(matches!(s, SmallMap::Many(_)));
    }
}
