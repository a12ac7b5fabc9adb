//! [`Counts`]: how many times each reason (or topic) came up, the one counter behind every
//! `skipped: <reason>` line of `/diagnostics` and the bag summary.

use std::collections::btree_map;
use std::collections::BTreeMap;

/// A count per key, in key order: sets or depth maps skipped by reason
/// ([`SkipCounts`], keyed by a `label()`), messages that could not be read by topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Counts<K: Ord>(BTreeMap<K, u64>);

/// Skips counted by their reason's label (`SkipKind::label`, `FuseSkip::label`, ...).
pub type SkipCounts = Counts<&'static str>;

impl<K: Ord> Default for Counts<K> {
    fn default() -> Self {
        Self(BTreeMap::new())
    }
}

impl<K: Ord> Counts<K> {
    /// One more for `key`.
    pub fn add(&mut self, key: K) {
        *self.0.entry(key).or_default() += 1;
    }

    /// The count of `key` (0 when it never came up).
    pub fn get<Q>(&self, key: &Q) -> u64
    where
        K: std::borrow::Borrow<Q>,
        Q: Ord + ?Sized,
    {
        self.0.get(key).copied().unwrap_or(0)
    }

    /// All the counts together.
    pub fn total(&self) -> u64 {
        self.0.values().sum()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The keys that came up, in order.
    pub fn keys(&self) -> impl Iterator<Item = &K> {
        self.0.keys()
    }

    /// Each key with its count, in key order.
    pub fn iter(&self) -> btree_map::Iter<'_, K, u64> {
        self.0.iter()
    }
}

impl<'a, K: Ord> IntoIterator for &'a Counts<K> {
    type Item = (&'a K, &'a u64);
    type IntoIter = btree_map::Iter<'a, K, u64>;

    fn into_iter(self) -> Self::IntoIter {
        self.0.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_by_key_in_order() {
        let mut c = SkipCounts::default();
        assert!(c.is_empty());
        c.add("b");
        c.add("a");
        c.add("b");
        assert_eq!((c.get("a"), c.get("b"), c.get("c")), (1, 2, 0));
        assert_eq!(c.total(), 3);
        assert_eq!(c.keys().copied().collect::<Vec<_>>(), ["a", "b"]);
        let mut topics = Counts::<String>::default();
        topics.add("/cam0/image".to_string());
        assert_eq!(topics.get("/cam0/image"), 1);
    }
}
