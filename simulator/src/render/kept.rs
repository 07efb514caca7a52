//! Tables the renderer keeps between frames (each camera's lens inversion, each view's primary
//! hits, each camera's latest radiance) within a memory budget: built once per key by the
//! first caller (concurrent callers with the same key wait for it), the least recently used
//! dropped first once the budget is exceeded, and a table above an eighth of the budget never
//! kept, so eight cameras' fit.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

/// A table: empty until made; locked while being made, so callers with its key wait.
type Slot<T> = Arc<Mutex<Option<Arc<T>>>>;

/// The slot's table, even after a panic in a build (the slot is then empty, built again).
fn lock_slot<T>(slot: &Mutex<Option<Arc<T>>>) -> MutexGuard<'_, Option<Arc<T>>> {
    slot.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

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
        if !self.keeps(bytes) {
            return None;
        }
        let slot = self.claim(key, bytes);
        let mut table = lock_slot(&slot);
        Some(Arc::clone(table.get_or_insert_with(|| Arc::new(build()))))
    }

    /// [`Self::get`] for a build that can fail: the error is returned and nothing kept (a
    /// caller waiting for the same key then builds); a table too large to keep is built and
    /// returned.
    pub fn try_get<E>(
        &self,
        key: K,
        bytes: usize,
        build: impl FnOnce() -> Result<T, E>,
    ) -> Result<Arc<T>, E>
    where
        K: Clone,
    {
        if !self.keeps(bytes) {
            return build().map(Arc::new);
        }
        let slot = self.claim(key.clone(), bytes);
        let mut table = lock_slot(&slot);
        if let Some(table) = table.as_ref() {
            return Ok(Arc::clone(table));
        }
        match build() {
            Ok(built) => Ok(Arc::clone(table.insert(Arc::new(built)))),
            Err(e) => {
                drop(table);
                self.lock()
                    .retain(|(k, _, s)| !(*k == key && Arc::ptr_eq(s, &slot)));
                Err(e)
            }
        }
    }

    /// The table for `key` if one is held (made the most recently used), waiting for it
    /// while it is being built; `None` otherwise, or if its build failed.
    pub fn peek(&self, key: &K) -> Option<Arc<T>> {
        let slot = {
            let mut slots = self.lock();
            let i = slots.iter().position(|(k, _, _)| k == key)?;
            let entry = slots.remove(i)?;
            let slot = Arc::clone(&entry.2);
            slots.push_back(entry);
            slot
        };
        lock_slot(&slot).clone()
    }

    /// Whether a table of `bytes` is kept: not above an eighth of the budget.
    pub fn keeps(&self, bytes: usize) -> bool {
        bytes <= self.budget_bytes / 8
    }

    /// The slot for `key`, made the most recently used (a new, empty one if none is held),
    /// the least recently used dropped while the tables exceed the budget.
    fn claim(&self, key: K, bytes: usize) -> Slot<T> {
        let mut slots = self.lock();
        let slot = match slots.iter().position(|(k, _, _)| *k == key) {
            Some(i) => slots.remove(i).map(|(_, _, s)| s).unwrap_or_default(),
            None => Arc::default(),
        };
        slots.push_back((key, bytes, Arc::clone(&slot)));
        while slots.len() > 1 && slots.iter().map(|(_, b, _)| b).sum::<usize>() > self.budget_bytes
        {
            slots.pop_front();
        }
        slot
    }

    /// The slots, even after a panic elsewhere (they hold finished tables only).
    fn lock(&self) -> MutexGuard<'_, VecDeque<(K, usize, Slot<T>)>> {
        self.slots
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// True when a table for `key` is held (or being built).
    pub fn contains(&self, key: &K) -> bool {
        self.lock().iter().any(|(k, _, _)| k == key)
    }

    /// Every key held and its table (`None` while being built), oldest first (tests).
    #[cfg(test)]
    pub fn held(&self) -> Vec<(K, Option<Arc<T>>)>
    where
        K: Clone,
    {
        let slots: Vec<_> = self
            .lock()
            .iter()
            .map(|(k, _, s)| (k.clone(), Arc::clone(s)))
            .collect();
        slots
            .into_iter()
            .map(|(k, s)| (k, lock_slot(&s).clone()))
            .collect()
    }

    /// Tables held now.
    pub fn len(&self) -> usize {
        self.lock().len()
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
        assert!(kept.peek(&0).is_none(), "the first was dropped");
        assert_eq!(kept.peek(&1).as_deref(), Some(&1));
        let fresh = kept.get(0, 100, || 8).expect("kept");
        assert_eq!(*fresh, 8, "the first was dropped and made again");
        // Peeking at 1 made it the most recent: 2 went instead.
        assert!(kept.peek(&1).is_some() && kept.peek(&2).is_none());
        assert!(kept.get(99, 200, || 0).is_none());
        assert_eq!(kept.len(), 10);
    }

    /// A failed build keeps nothing: the next call builds again; a success is then shared.
    #[test]
    fn a_failed_build_is_not_kept() {
        let kept = Kept::<u32, u32>::with_budget(1000);
        assert_eq!(kept.try_get(1, 100, || Err::<u32, _>("no")), Err("no"));
        assert!(!kept.contains(&1));
        let a = kept.try_get(1, 100, || Ok::<_, &str>(5)).expect("built");
        let again = kept
            .try_get(1, 100, || Err::<u32, _>("not called"))
            .expect("kept");
        assert!(Arc::ptr_eq(&a, &again));
        assert_eq!(kept.try_get(2, 200, || Ok::<_, &str>(1)), Ok(Arc::new(1)));
        assert!(!kept.contains(&2), "too large to keep");
    }
}
