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
    /// Run id, equal to the run directory name. [`crate::RunStore::create`] fills it in.
    pub run_id: String,
    /// Unix time (seconds) at which the run was created; also names the run directory.
    pub created_unix_s: f64,
    /// Version of the stagehand software that created the run.
    pub software_version: String,
    /// File name of the capture script.
    pub script_name: String,
    /// Full text of the capture script.
    pub script_text: String,
    /// Hex SHA-256 of the plan's canonical JSON ([`crate::plan_hash`]); `create` fills
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
    /// How the frames were simulated (simulated rigs; absent in older runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim: Option<SimManifest>,
    /// The calibrations the rig file named (`[calibration]`), kind → id.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub calibrations: BTreeMap<String, String>,
}

/// The `sim` block of a simulated run's manifest: the renderer's settings and the scene of the
/// rig's sample (`sim.sample`). Fixtures a script places later are named in each frame's
/// notes. The scene text is also written to `scene.toml` in the run directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimManifest {
    /// The preset the knobs started from (`preview`, `standard`, `reference`, or `custom`).
    pub quality: String,
    /// Every accuracy knob as frames of the sample are rendered (preset, rig `[sim.knobs]` and
    /// the scene's `[render]` settings applied).
    pub knobs: serde_json::Value,
    /// The rig's `sim.sample`: a built-in scene name or a scene file path.
    pub sample: String,
    /// Edge length of the sample in mm.
    pub sample_size_mm: f64,
    /// The scene's `[scene] name`.
    pub scene_name: String,
    /// Where the scene file was read from; `None` for a built-in scene.
    pub scene_path: Option<String>,
    /// Hex SHA-256 of the scene text.
    pub scene_sha256: String,
    /// The scene file's full text (as written to `scene.toml`).
    pub scene_text: String,
    /// Ground truth written beside every capture (`sim.ground_truth`).
    pub ground_truth: bool,
    /// The rig as built (`[sim.as_built]`): written to `as_built.json` when the run is
    /// created, for evaluation only, and kept out of the manifest so processing, which reads
    /// the manifest, never sees it.
    #[serde(skip)]
    pub as_built: Option<serde_json::Value>,
}

impl Manifest {
    /// Dataset format version written by this build; `open` refuses anything newer.
    pub const FORMAT_VERSION: u32 = 1;
}
