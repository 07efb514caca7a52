//! A camera frame as it leaves the sensor: raw digital numbers plus what the camera knows.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::ground_truth::GroundTruthData;

/// One raw exposure from one camera for one trigger id.
///
/// Pixels are interleaved RGB digital numbers in a 16-bit container; `bit_depth` says how many
/// of those bits the sensor produced (values are at most `2^bit_depth - 1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Camera id from the rig file.
    pub camera: String,
    /// Trigger id this frame answers.
    pub trigger_id: u64,
    pub width: u32,
    pub height: u32,
    /// Significant bits per sample (8, 12 or 16).
    pub bit_depth: u8,
    /// Interleaved RGB, `width * height * 3` samples, row-major from the top-left.
    pub pixels: Vec<u16>,
    pub exposure_s: f64,
    pub gain: f64,
    /// Rig time (seconds on the rig clock) at which the exposure started.
    pub rig_time_s: f64,
    /// Backend-specific facts about how the frame came to be (for the simulator: the effect
    /// plan and its reasons, accuracy knobs). Stored verbatim in the frame index.
    pub notes: serde_json::Value,
    /// Per-pixel ground truth of the scene this frame saw (simulated cameras with
    /// `sim.ground_truth = true`). Shared: the exposures of a bracket that saw the same scene
    /// carry the same data. Not serialised with the frame; the storage layer writes it as
    /// files of its own.
    #[serde(skip)]
    pub ground_truth: Option<Arc<GroundTruthData>>,
}

impl Frame {
    /// Largest digital number the sensor can produce.
    pub fn max_value(&self) -> u16 {
        if self.bit_depth >= 16 {
            u16::MAX
        } else {
            ((1u32 << self.bit_depth) - 1) as u16
        }
    }

    /// Number of samples at the sensor's maximum value (clipped).
    pub fn saturated_samples(&self) -> usize {
        let max = self.max_value();
        // A sum of 0/1 rather than a filtered count: the compiler vectorises it.
        self.pixels.iter().map(|&p| usize::from(p >= max)).sum()
    }
}
