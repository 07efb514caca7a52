//! A small cache for per-frame light-transport results (subsurface, interreflection) and
//! per-sample relief statistics, keyed by an exact description of their inputs: the cameras
//! of one rig step see the same lights on the same sample, so the first computes and the
//! others wait for it and share the result. Different inputs never share an entry.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Entries kept before the cache is emptied.
const CAPACITY: usize = 32;

/// Results of type `T` by input key, each computed at most once.
#[derive(Debug)]
pub struct PassCache<T> {
    slots: Mutex<HashMap<String, Arc<OnceLock<Arc<T>>>>>,
}

impl<T> Default for PassCache<T> {
    fn default() -> Self {
        PassCache {
            slots: Mutex::new(HashMap::new()),
        }
    }
}

impl<T> PassCache<T> {
    /// The result for `key`, computed by `make` if no one has yet (concurrent callers with the
    /// same key wait for the first).
    pub fn get(&self, key: String, make: impl FnOnce() -> T) -> Arc<T> {
        let slot = {
            let mut slots = self
                .slots
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner());
            if slots.len() >= CAPACITY && !slots.contains_key(&key) {
                slots.clear();
            }
            Arc::clone(slots.entry(key).or_default())
        };
        Arc::clone(slot.get_or_init(|| Arc::new(make())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_computes_once_other_key_recomputes() {
        let cache = PassCache::<u32>::default();
        let a = cache.get("k".into(), || 1);
        let b = cache.get("k".into(), || 2);
        assert!(Arc::ptr_eq(&a, &b));
        assert_eq!(*cache.get("other".into(), || 3), 3);
    }
}
