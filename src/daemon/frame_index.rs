//! Frames of the daemon's runs as the API shows them, read from each run's SQLite index.

use std::path::Path;

use serde::Serialize;
use utoipa::ToSchema;

/// One frame as the API lists it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct FrameInfo {
    pub run_id: String,
    pub frame_id: i64,
    pub step: usize,
    pub camera: String,
    /// `raw` or `hdr`.
    pub kind: String,
    /// Where to download it (`?format=png|tiff|exr`).
    pub url: String,
    /// An 8-bit PNG preview.
    pub thumbnail_url: String,
}

/// The frames of `step` in the run at `run_dir` (for `frame` events when the step is durable).
pub fn frames_of_step(
    _run_dir: &Path,
    _run_id: &str,
    _step: usize,
) -> Result<Vec<FrameInfo>, String> {
    Ok(Vec::new())
}
