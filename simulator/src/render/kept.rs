//! Tables the renderer keeps between frames (each camera's lens inversion, each view's primary
//! hits) within a memory budget: built once per key by the first caller (concurrent callers
//! with the same key wait for it), the least recently used dropped first once the budget is
//! exceeded, and a table above an eighth of the budget never kept, so eight cameras' fit.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, OnceLock};

/// A table being made or made.
type Slot<T> = Arc<OnceLock<Arc<T>>>;

/// Tables of type `T` by key `K`, within a memory budget.
#[derive(Debug)]
pub struct Kept<K, T> {
    budget_bytes: usize,
    slots: Mutex<VecDeque<(K, usize, Slot<T>)>>,
}

impl<K: PartialEq, T> Kept<K, T> {
    /// Tables within `budget_bytes`.
    pub fn with_budget(budget_bytes: usize) -> Kept<K, T> {
        Kept {
            budget_bytes,
            slots: Mutex::new(VecDeque::new()),
        }
    }

    /// The table for `key` (`bytes` large), built by `build` on first use; `None` when a
    /// table that large is not kept (the caller computes per frame instead).
    pub fn get(&self, key: K, bytes: usize, build: impl FnOnce() -> T) -> Option<Arc<T>> {
        if bytes > self.budget_bytes / 8 {
            return None;
        }
        let slot = {
            let mut slots = self
                .slots
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner());
            let slot = match slots.iter().position(|(k, _, _)| *k == key) {
                Some(i) => slots.remove(i).map(|(_, _, s)| s).unwrap_or_default(),
                None => Arc::default(),
            };
            slots.push_back((key, bytes, Arc::clone(&slot)));
            while slots.len() > 1
                && slots.iter().map(|(_, b, _)| b).sum::<usize>() > self.budget_bytes
            {
                slots.pop_front();
            }
            slot
        };
        Some(Arc::clone(slot.get_or_init(|| Arc::new(build()))))
    }

    /// True when a table for `key` is held (or being built).
    pub fn contains(&self, key: &K) -> bool {
        self.slots
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .iter()
            .any(|(k, _, _)| k == key)
    }

    /// Tables held now.
    pub fn len(&self) -> usize {
        self.slots
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .len()
    }

    /// True when no table is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same key shares one table; past the budget the least recently used goes first;
    /// a table above an eighth of the budget is not kept.
    #[test]
    fn tables_are_shared_and_the_oldest_dropped_past_the_budget() {
        let kept = Kept::<u32, u32>::with_budget(10 * 100 + 10);
        let a = kept.get(0, 100, || 7).expect("kept");
        let again = kept.get(0, 100, || panic!("built twice")).expect("kept");
        assert!(Arc::ptr_eq(&a, &again));
        for k in 1..=10 {
            kept.get(k, 100, || k);
        }
        assert_eq!(kept.len(), 10);
        let fresh = kept.get(0, 100, || 8).expect("kept");
        assert_eq!(*fresh, 8, "the first was dropped and made again");
        assert!(kept.get(99, 200, || 0).is_none());
        assert_eq!(kept.len(), 10);
    }
}
