//! The rig clock: every wait in devices and the executor goes through it.
//!
//! It is built on tokio's clock. In simulation the runtime runs with paused time, so tokio
//! advances the clock to the next timer whenever every task is waiting: a six-hour plan runs in
//! seconds, deterministically, and still reports its rig time. On real hardware the same code
//! waits in real time.

use std::time::Duration;
use tokio::time::Instant;

/// Rig time source; cheap to copy.
#[derive(Debug, Clone, Copy)]
pub struct RigClock {
    start: Instant,
    offset_s: f64,
}

impl RigClock {
    /// A clock reading `offset_s` now (a resumed run continues its rig time).
    pub fn starting_at(offset_s: f64) -> Self {
        Self {
            start: Instant::now(),
            offset_s,
        }
    }

    /// Seconds of rig time.
    pub fn now_s(&self) -> f64 {
        self.offset_s + self.start.elapsed().as_secs_f64()
    }

    /// Waits `seconds` of rig time (negative or NaN waits nothing).
    pub async fn sleep_s(&self, seconds: f64) {
        if seconds.is_finite() && seconds > 0.0 {
            tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
        }
    }
}

impl Default for RigClock {
    fn default() -> Self {
        Self::starting_at(0.0)
    }
}

/// Converts seconds to a `Duration`, saturating absurd values instead of panicking.
pub fn duration_s(seconds: f64) -> Duration {
    if !seconds.is_finite() || seconds <= 0.0 {
        Duration::ZERO
    } else {
        Duration::from_secs_f64(seconds.min(1.0e9))
    }
}
