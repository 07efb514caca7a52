//! Per-pixel ground truth a simulated camera can attach to a frame: named images of f32
//! channels (depth, normals, noise-free radiance, material parameters). Defined here, beside
//! [`crate::Frame`], so the storage layer can write it without knowing the simulator.

use serde::{Deserialize, Serialize};

/// One ground-truth image: `channels.len()` interleaved f32 samples per pixel, row-major from
/// the top-left pixel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruthPlane {
    /// What the image holds; also the file suffix (`depth`, `normal`, `radiance`, `material`).
    pub kind: String,
    /// Channel names in sample order (e.g. `R`, `G`, `B`, or `albedo.R`, `ks`, …).
    pub channels: Vec<String>,
    /// Interleaved samples, `width * height * channels.len()` of them.
    pub samples: Vec<f32>,
}

/// The ground truth of one frame: every plane has the frame's size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruthData {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// The images, in a fixed order.
    pub planes: Vec<GroundTruthPlane>,
    /// What the planes mean: units, coordinate frame, background sentinel, channel meanings.
    pub notes: serde_json::Value,
}

/// What is wrong with a frame's ground truth.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GroundTruthError {
    /// Two planes of the same kind.
    #[error("ground-truth plane `{0}` appears twice")]
    DuplicatePlane(String),
    /// A plane without channels or with the wrong number of samples.
    #[error(
        "ground-truth plane `{kind}` has {samples} samples for {channels} channels of a {width}x{height} image"
    )]
    WrongSize {
        /// The plane's kind.
        kind: String,
        /// Samples it has.
        samples: usize,
        /// Channels it names.
        channels: usize,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
}

impl GroundTruthData {
    /// The plane of `kind`, if present.
    pub fn plane(&self, kind: &str) -> Option<&GroundTruthPlane> {
        self.planes.iter().find(|p| p.kind == kind)
    }

    /// Checks that plane kinds are distinct and every plane has at least one channel and
    /// `width * height * channels` samples; the error names the first plane that does not.
    pub fn check(&self) -> Result<(), GroundTruthError> {
        let pixels = self.width as usize * self.height as usize;
        for (i, p) in self.planes.iter().enumerate() {
            if self.planes[..i].iter().any(|o| o.kind == p.kind) {
                return Err(GroundTruthError::DuplicatePlane(p.kind.clone()));
            }
            if p.channels.is_empty() || p.samples.len() != pixels * p.channels.len() {
                return Err(GroundTruthError::WrongSize {
                    kind: p.kind.clone(),
                    samples: p.samples.len(),
                    channels: p.channels.len(),
                    width: self.width,
                    height: self.height,
                });
            }
        }
        Ok(())
    }
}
