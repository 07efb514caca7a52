//! The daemon's shared state: the rig it owns, its directories, tokens, event hub, the run
//! manager and the e-stop latch. Handlers get it as [`AppState`].

use std::path::PathBuf;
use std::sync::Arc;

use metrics_exporter_prometheus::PrometheusHandle;

use super::auth::Tokens;
use super::estop::EStop;
use super::events::EventHub;
use super::runs::RunManager;
use crate::rig::Emulation;
use crate::rig::{Rig, RigSource};

/// Everything the daemon owns.
pub struct Daemon {
    /// The rig's devices, opened once at start; the daemon is their only owner.
    pub rig: Rig,
    pub rig_source: RigSource,
    /// `--data`: holds `tokens.json`, `runs/` and `scripts/` (uploaded scripts).
    pub data_dir: PathBuf,
    /// Built-in scripts offered for selection (read-only), e.g. the repository's `sequences/`.
    pub scripts_dir: Option<PathBuf>,
    /// Seed of the simulated sensor noise for runs.
    pub seed: u64,
    /// Real drivers against firmware emulators (`serve --emulate`).
    pub emulation: Option<Emulation>,
    pub tokens: Tokens,
    pub hub: EventHub,
    pub runs: RunManager,
    pub estop: EStop,
    pub metrics: PrometheusHandle,
    /// Manual device commands (move, lamps, laser) run one at a time per device.
    pub manual: super::manual::ManualLocks,
    /// Runs submitted ahead of time, started in order when the rig is idle.
    pub queue: super::queue::RunQueue,
    /// When the daemon started (`GET /api/health` reports the uptime).
    pub started: std::time::Instant,
}

impl Daemon {
    /// Where run directories go.
    pub fn runs_dir(&self) -> PathBuf {
        self.data_dir.join("runs")
    }

    /// Where uploaded scripts go.
    pub fn uploads_dir(&self) -> PathBuf {
        self.data_dir.join("scripts")
    }
}

/// Cheap-to-clone handle on the daemon for axum handlers.
#[derive(Clone)]
pub struct AppState(pub Arc<Daemon>);

impl std::ops::Deref for AppState {
    type Target = Daemon;
    fn deref(&self) -> &Daemon {
        &self.0
    }
}
