//! Recovered inverse responses against the simulated sensor's: the relative error of exp g
//! after the one free scale per channel is removed (the median log ratio), over the DN range
//! the bracket observed above the noise floor and below saturation. The noise floor is where
//! the fit's weight reaches 0.1 and where one DN, averaged over a sample's 5×5 window,
//! resolves the exposure to 1 % (d ln x / dZ ≤ 0.05): below it an 8-bit camera with a strong
//! response cannot tell exposures 1 % apart at all. The error over the whole observed range
//! is reported too (`max_rel_error_observed`).

use serde::Serialize;
use stagehand_processing::calibration_store::{CalibrationKind, StoredCalibration};
use stagehand_processing::response_calibration::ResponseSet;
use stagehand_processing::response_curve::InverseResponse;
use stagehand_processing::weight::RAMP_FRACTION;
use stagehand_simulator::render::sensor::Response;

use super::EvaluateError;

/// Figures of one channel.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelFigures {
    /// Largest relative error of the inverse response, over the evaluated DN range.
    pub max_rel_error: f64,
    /// Largest relative error over everything the bracket observed (noise floor included).
    pub max_rel_error_observed: f64,
    /// RMS relative error over the same range.
    pub rms_rel_error: f64,
    /// The DN range evaluated.
    pub dn_range: [f64; 2],
}

/// Figures of one response calibration.
#[derive(Debug, Clone, Serialize)]
pub struct ResponseFigures {
    /// Calibration id.
    pub calibration: String,
    /// Per camera, red, green and blue.
    pub cameras: std::collections::BTreeMap<String, [ChannelFigures; 3]>,
    /// The largest `max_rel_error` of any channel.
    pub worst_rel_error: f64,
}

/// The true inverse response x(z) (fraction of the full well) of channel `c` of a camera
/// whose truth is `cam` (as_built.json's camera entry).
fn true_exposure(cam: &serde_json::Value, c: usize, z: f64, black: f64, max: f64) -> Option<f64> {
    let r = &cam["response"];
    let channels = |key: &str| -> Option<[f32; 3]> {
        let v = &r[key];
        Some([0, 1, 2].map(|i| v[i].as_f64().unwrap_or(f64::NAN) as f32))
            .filter(|a| a.iter().all(|x| x.is_finite()))
    };
    // The simulator's own sensor model, rebuilt from the recorded truth.
    let response = match r["kind"].as_str()? {
        "gamma" => Response::Gamma(channels("gamma")?),
        "gentle" => Response::Gentle(channels("curvature")?),
        _ => return None,
    };
    Some(response.invert(c, (z - black) / max))
}

/// One camera's recorded truth (as_built.json's entry), for comparing recovered responses.
pub(super) struct CameraTruth<'a> {
    id: &'a str,
    cam: &'a serde_json::Value,
    black: f64,
    max: f64,
}

impl<'a> CameraTruth<'a> {
    /// Camera `id` of `truth` (as_built.json).
    pub(super) fn new(truth: &'a serde_json::Value, id: &'a str) -> Result<Self, EvaluateError> {
        let cam = &truth["cameras"][id];
        let bits = cam["bit_depth"]
            .as_u64()
            .ok_or_else(|| truth_err(id, "no bit_depth"))?;
        Ok(CameraTruth {
            id,
            cam,
            black: stagehand_simulator::render::sensor::black_level_dn(bits as u8),
            max: ((1u64 << bits.min(16)) - 1) as f64,
        })
    }

    /// ln of the true fraction of the full well that gives DN `z` on channel `c`.
    fn ln_x(&self, c: usize, z: f64) -> Result<f64, EvaluateError> {
        true_exposure(self.cam, c, z, self.black, self.max)
            .map(f64::ln)
            .ok_or_else(|| truth_err(self.id, "no response"))
    }

    /// The DN range over which recovered `g` of channel `c` is evaluated: observed, trusted
    /// by the fit (weight ≥ 0.1) and resolved to 1 % by one DN.
    pub(super) fn evaluated_range(
        &self,
        c: usize,
        g: &InverseResponse,
    ) -> Result<(f64, f64), EvaluateError> {
        // The fit's weight ramps up from 0 at its noise floor (`range.lo`) over 5 % of the
        // range; below a weight of 0.1 g is set by the smoothness term, not by data.
        let trusted = g.range.lo + 0.1 * RAMP_FRACTION * (g.range.hi - g.range.lo);
        let hi = g.observed.hi.min(g.range.hi);
        // The first DN at which one DN step moves ln x by at most 0.05.
        let mut resolved = trusted;
        while resolved < hi && self.ln_x(c, resolved + 1.0)? - self.ln_x(c, resolved)? > 0.05 {
            resolved += 1.0;
        }
        Ok((g.observed.lo.max(trusted).max(resolved), hi))
    }

    /// ln x − g at 400 DNs over `[lo, hi]`, and their median: the free constant of `g` (the
    /// solver pins g = 0 at its middle knot), so that x = exp(g + offset).
    pub(super) fn log_offset(
        &self,
        c: usize,
        g: &InverseResponse,
        lo: f64,
        hi: f64,
    ) -> Result<(Vec<f64>, f64), EvaluateError> {
        let logs = (0..400)
            .map(|i| {
                let z = lo + (hi - lo) * f64::from(i) / 399.0;
                Ok(self.ln_x(c, z)? - g.g(z))
            })
            .collect::<Result<Vec<f64>, EvaluateError>>()?;
        let mut sorted = logs.clone();
        sorted.sort_by(f64::total_cmp);
        let offset = sorted[sorted.len() / 2];
        Ok((logs, offset))
    }
}

fn truth_err(id: &str, what: &str) -> EvaluateError {
    EvaluateError::Truth {
        path: "as_built.json".into(),
        message: format!("camera `{id}`: {what}"),
    }
}

/// Evaluates one stored response calibration against `truth` (as_built.json).
pub fn evaluate_response(
    stored: &StoredCalibration,
    truth: &serde_json::Value,
) -> Result<ResponseFigures, EvaluateError> {
    let set: ResponseSet = stored.result(CalibrationKind::Response)?;
    let mut cameras = std::collections::BTreeMap::new();
    let mut worst = 0.0f64;
    for (id, fit) in &set {
        let cam = CameraTruth::new(truth, id)?;
        let mut channels = Vec::with_capacity(3);
        for (c, g) in fit.channels.iter().enumerate() {
            let (lo, hi) = cam.evaluated_range(c, g)?;
            let errors_over = |lo: f64| -> Result<Vec<f64>, EvaluateError> {
                let (logs, offset) = cam.log_offset(c, g, lo, hi)?;
                Ok(logs
                    .iter()
                    .map(|l| ((l - offset).exp() - 1.0).abs())
                    .collect())
            };
            let errors = errors_over(lo)?;
            let max_err = errors.iter().copied().fold(0.0, f64::max);
            let observed = errors_over(g.observed.lo.max(g.range.lo))?
                .into_iter()
                .fold(0.0, f64::max);
            let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
            worst = worst.max(max_err);
            channels.push(ChannelFigures {
                max_rel_error: max_err,
                max_rel_error_observed: observed,
                rms_rel_error: rms,
                dn_range: [lo, hi],
            });
        }
        let [r, g, b]: [ChannelFigures; 3] = channels
            .try_into()
            .map_err(|_| truth_err(id, "a channel is missing"))?;
        cameras.insert(id.clone(), [r, g, b]);
    }
    Ok(ResponseFigures {
        calibration: stored.id.clone(),
        cameras,
        worst_rel_error: worst,
    })
}
