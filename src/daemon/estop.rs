//! The emergency stop latch. `POST /api/estop` aborts any run and puts every device in its safe
//! state (axes stopped, lamps and laser off, laser disarmed); motion and emission stay refused
//! until `POST /api/estop/reset`.

use std::sync::atomic::{AtomicBool, Ordering};

/// Latched e-stop state.
#[derive(Debug, Default)]
pub struct EStop {
    latched: AtomicBool,
}

impl EStop {
    pub fn is_latched(&self) -> bool {
        self.latched.load(Ordering::SeqCst)
    }

    pub fn latch(&self) {
        self.latched.store(true, Ordering::SeqCst);
    }

    pub fn reset(&self) {
        self.latched.store(false, Ordering::SeqCst);
    }
}
