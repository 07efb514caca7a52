//! The run manifest: everything needed to know how a dataset came to be. Written once, as
//! `manifest.json`, when the run is created.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Self-description of a run, stored as `manifest.json` in the run directory and as JSON in
/// the `runs` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Dataset format version ([`Manifest::FORMAT_VERSION`] for new runs).
    pub format_version: u32,
    /// Run id, equal to the run directory name. [`super::RunStore::create`] fills it in.
    pub run_id: String,
    /// Unix time (seconds) at which the run was created; also names the run directory.
    pub created_unix_s: f64,
    /// Version of the stagehand software that created the run.
    pub software_version: String,
    /// File name of the capture script.
    pub script_name: String,
    /// Full text of the capture script.
    pub script_text: String,
    /// Hex SHA-256 of the plan's canonical JSON ([`crate::plan::Plan::hash`]); `create` fills
    /// it in when empty and refuses a value that does not match the plan.
    pub plan_hash: String,
    /// Script parameters with the values used.
    pub params: BTreeMap<String, serde_json::Value>,
    /// Name of the rig the run was captured on.
    pub rig_name: String,
    /// Full text of the rig TOML file.
    pub rig_toml: String,
    /// Seed of every random process (simulator noise, jitter).
    pub seed: u64,
    /// True when the frames come from the simulated backend.
    pub simulated: bool,
}

impl Manifest {
    /// Dataset format version written by this build; `open` refuses anything newer.
    pub const FORMAT_VERSION: u32 = 1;
}
