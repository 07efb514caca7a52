//! Runs started over the API: one at a time, on the daemon's rig, with prompts answered over
//! the API and progress published on the event hub.

use serde::Serialize;
use utoipa::ToSchema;

/// The daemon's one active run (if any) and what it is doing.
#[derive(Default)]
pub struct RunManager {}

/// What the active run is doing, for `GET /api/status`.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RunState {
    pub run_id: String,
}

impl RunManager {
    /// True while a run is executing (manual device commands are refused then).
    pub fn is_active(&self) -> bool {
        false
    }

    /// The active run, if any.
    pub fn snapshot(&self) -> Option<RunState> {
        None
    }

    /// Aborts the active run (e-stop, shutdown); returns at once.
    pub fn abort(&self) {}

    /// Waits until no run is active (after [`RunManager::abort`]).
    pub async fn wait_idle(&self) {}
}
