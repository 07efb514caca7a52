//! The laser interlock: the enclosure's door switch, which must be closed for the laser to
//! emit. The laser actor watches it (see [`crate::laser::LaserHandle::spawn_with_interlock`]),
//! so the rule holds for every caller, runs included, and opening the door switches the
//! emission off at once.

use std::sync::Arc;

use serde::Serialize;
use thiserror::Error;
use tokio::sync::watch;

/// Where the interlock state comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum InterlockSource {
    /// A simulated door switch (simulated and emulated rigs): closed at start, opened and
    /// closed by the API to exercise the rule.
    #[serde(rename = "simulated")]
    Simulated,
    /// The rig has no interlock wiring: it reads as closed and cannot be changed.
    #[serde(rename = "not fitted")]
    NotFitted,
}

impl InterlockSource {
    /// The name the API reports: `simulated` or `not fitted`.
    pub fn as_str(self) -> &'static str {
        match self {
            InterlockSource::Simulated => "simulated",
            InterlockSource::NotFitted => "not fitted",
        }
    }
}

/// Why the interlock could not be set.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum InterlockError {
    #[error(
        "the laser interlock is not fitted on this rig (it reads as closed); on real hardware the interlock is the enclosure's door switch, not a software setting"
    )]
    NotSettable,
}

/// The interlock's state, shared by the laser actor (which watches it) and whoever reports it.
/// Cheap to clone.
#[derive(Debug, Clone)]
pub struct Interlock {
    source: InterlockSource,
    tx: Arc<watch::Sender<bool>>,
}

impl Interlock {
    /// A simulated door switch, closed at start.
    pub fn simulated() -> Self {
        Self {
            source: InterlockSource::Simulated,
            tx: Arc::new(watch::channel(true).0),
        }
    }

    /// No interlock wiring: always closed.
    pub fn not_fitted() -> Self {
        Self {
            source: InterlockSource::NotFitted,
            tx: Arc::new(watch::channel(true).0),
        }
    }

    /// Where the state comes from.
    pub fn source(&self) -> InterlockSource {
        self.source
    }

    /// True while the door is closed (the laser may emit).
    pub fn is_closed(&self) -> bool {
        *self.tx.borrow()
    }

    /// A receiver that sees every change (the laser actor holds one).
    pub fn watch(&self) -> watch::Receiver<bool> {
        self.tx.subscribe()
    }

    /// Opens or closes the simulated door switch; refused when the interlock is not fitted.
    pub fn set_closed(&self, closed: bool) -> Result<(), InterlockError> {
        match self.source {
            InterlockSource::Simulated => {
                self.tx.send_replace(closed);
                Ok(())
            }
            InterlockSource::NotFitted => Err(InterlockError::NotSettable),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_simulated_door_starts_closed_and_can_be_opened() {
        let i = Interlock::simulated();
        let rx = i.watch();
        assert!(i.is_closed());
        i.set_closed(false).unwrap();
        assert!(!i.is_closed());
        assert!(!*rx.borrow());
    }

    #[test]
    fn a_missing_interlock_reads_closed_and_cannot_be_set() {
        let i = Interlock::not_fitted();
        assert!(i.is_closed());
        assert_eq!(i.set_closed(false), Err(InterlockError::NotSettable));
        assert!(i.is_closed());
        assert_eq!(i.source().as_str(), "not fitted");
    }
}
