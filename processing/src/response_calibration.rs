//! `stagehand calibrate response`: each camera's inverse response per channel from a bracket
//! sweep of a static scene (`sequences/calibration_response.rhai`: the colour checker under
//! steady light at many exposures). Per camera, the capture with the most exposures is used;
//! its usable DN range runs from the black level plus six read-noise σ (or 0.5 % of full
//! scale, whichever is more) to 2 % below full scale.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::response_curve::InverseResponse;
use crate::response_samples::{Bracket, BracketImage};
use crate::response_solve::{ResponseParams, solve_response};
use crate::run_frames::{
    BracketKey, black_level_dn, bracket_keys, decode_bracket, open_run, read_noise_dn,
};
use crate::weight::DnRange;

/// One camera's responses and fit figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraResponse {
    /// Inverse response of red, green and blue.
    pub channels: [InverseResponse; 3],
    /// RMS fit residual per channel, ln units.
    pub rms_residual: [f64; 3],
    /// Samples used per channel.
    pub pixels: [usize; 3],
    /// The frames of the bracket.
    pub frames: Vec<String>,
}

/// Every camera's response, by camera id.
pub type ResponseSet = BTreeMap<String, CameraResponse>;

/// Fits every camera's response from the run at `run_dir`, with `smoothness` λ.
pub fn calibrate_response(run_dir: &Path, smoothness: f64) -> Result<ResponseSet, ProcessingError> {
    let reader = open_run(run_dir)?;
    let keys = bracket_keys(&reader, |_| true)?;
    // Per camera, the capture with the most exposures.
    let mut best: BTreeMap<String, &BracketKey> = BTreeMap::new();
    for key in &keys {
        let n = key.frames.len();
        if n >= 2 && best.get(&key.camera).is_none_or(|b| b.frames.len() < n) {
            best.insert(key.camera.clone(), key);
        }
    }
    if best.is_empty() {
        return Err(ProcessingError::MissingInput {
            run: run_dir.display().to_string(),
            what: "capture with an exposure bracket".into(),
            hint: "capture one with sequences/calibration_response.rhai",
        });
    }
    let mut out = ResponseSet::new();
    for (camera, key) in best {
        let exposures = decode_bracket(&reader, key)?;
        let meta = &key.meta;
        let max = ((1u64 << meta.bit_depth.min(16)) - 1) as f64;
        let lo = black_level_dn(meta) + (6.0 * read_noise_dn(meta)).max(0.005 * max);
        let range = DnRange::new(lo, 0.98 * max)?;
        let mut params = ResponseParams::for_range(range);
        params.smoothness = smoothness;
        let (w, h) = (meta.width as usize, meta.height as usize);
        let mut fits = Vec::with_capacity(3);
        for c in 0..3 {
            let bracket = Bracket {
                width: w,
                height: h,
                images: exposures
                    .iter()
                    .map(|e| BracketImage {
                        exposure_s: e.exposure_s,
                        dn: e.dn.iter().skip(c).step_by(3).copied().collect(),
                    })
                    .collect(),
            };
            let fit = solve_response(&bracket, &params).map_err(|e| ProcessingError::IllPosed {
                what: "response calibration",
                why: format!(
                    "camera `{camera}`, {} channel, step {}: {e}",
                    ["red", "green", "blue"][c],
                    key.step
                ),
            })?;
            fits.push(fit);
        }
        let [r, g, b]: [_; 3] = fits.try_into().map_err(|_| ProcessingError::IllPosed {
            what: "response calibration",
            why: "a channel is missing".into(),
        })?;
        out.insert(
            camera,
            CameraResponse {
                rms_residual: [r.rms_residual, g.rms_residual, b.rms_residual],
                pixels: [r.pixels, g.pixels, b.pixels],
                channels: [r.response, g.response, b.response],
                frames: exposures.into_iter().map(|e| e.path).collect(),
            },
        );
    }
    Ok(out)
}
