//! HDR products against the simulator's noise-free radiance (ground-truth `radiance` planes,
//! rigs with `[sim] ground_truth = true`), and the linear merge the capture writes (`hdr`
//! frames) measured the same way. Only samples some exposure measured are compared: a DN
//! inside the response calibration's usable range in at least one exposure (neither clipped
//! in all, nor lost in the noise in all). A product is in the response calibration's relative
//! units, so each channel of each product is first scaled by the median ratio truth/product;
//! the figure is the relative error left, |k·p − t| / t.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_hdr::decode_exr;
use stagehand_dataset::exr_planes::decode_exr_planes;
use stagehand_dataset::png16::decode_png16;
use stagehand_dataset::{FrameKind, FrameQuery};
use stagehand_processing::calibration_store::{self, CalibrationKind};
use stagehand_processing::response_calibration::ResponseSet;

use super::EvaluateError;

/// Relative errors of one merge over the compared samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorFigures {
    /// Samples compared.
    pub samples: usize,
    /// Median relative error.
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
}

/// The HDR products of a run against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HdrFigures {
    /// Products compared.
    pub products: usize,
    /// The products (response calibration, exposure, white balance); `None` when no sample
    /// was measured by any exposure.
    pub calibrated: Option<ErrorFigures>,
    /// The capture's linear merge of the same brackets, where the run has one.
    pub linear_merge: Option<ErrorFigures>,
}

/// Evaluates the run's `hdr` products, if it has any and ground-truth radiance beside them.
pub fn evaluate_hdr(
    run_dir: &Path,
    calibrations_root: &Path,
) -> Result<Option<HdrFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((reader, products)) = super::products_of(run_dir, "hdr")? else {
        return Ok(None);
    };
    // Every frame row once, by path: each product names its frames by path.
    let frames_by_path: BTreeMap<String, _> = reader
        .frames(&FrameQuery::default())
        .map_err(|e| err(e.to_string()))?
        .frames
        .into_iter()
        .map(|f| (f.path.clone(), f))
        .collect();
    let mut responses: BTreeMap<String, ResponseSet> = BTreeMap::new();
    let (mut ours, mut linear) = (Vec::new(), Vec::new());
    let mut compared = 0;
    for product in &products {
        let Some(id) = product
            .made
            .calibrations
            .iter()
            .find(|id| id.starts_with("response-"))
        else {
            continue;
        };
        if !responses.contains_key(id) {
            let stored = calibration_store::load(calibrations_root, id)?;
            let set = stored
                .result(CalibrationKind::Response)
                .map_err(|e| err(e.to_string()))?;
            responses.insert(id.clone(), set);
        }
        let read =
            |rel: &str| std::fs::read(run_dir.join(rel)).map_err(|e| err(format!("{rel}: {e}")));
        let merged =
            decode_exr(&product.path, &read(&product.path)?).map_err(|e| err(e.to_string()))?;
        // The raw frames of the bracket, and the truth attached to them.
        let first = product
            .made
            .inputs
            .first()
            .ok_or_else(|| err(format!("{} lists no input frames", product.path)))?;
        let frame = frames_by_path
            .get(first)
            .ok_or_else(|| err(format!("{first} is not in the index")))?;
        let (step, camera) = (frame.meta.step, frame.meta.camera.clone());
        let Some(truth) = reader
            .ground_truth(Some(step))
            .map_err(|e| err(e.to_string()))?
            .into_iter()
            .find(|g| g.kind == "radiance" && product.made.inputs.contains(&g.frame_path))
        else {
            continue;
        };
        let planes =
            decode_exr_planes(&truth.path, &read(&truth.path)?).map_err(|e| err(e.to_string()))?;
        let truth_rgb: Vec<&[f32]> = ["R", "G", "B"]
            .iter()
            .map(|c| {
                planes
                    .channel(c)
                    .ok_or_else(|| err(format!("{} has no {c} channel", truth.path)))
            })
            .collect::<Result<_, _>>()?;
        let response = responses[id]
            .get(&camera)
            .ok_or_else(|| err(format!("{id} has no camera {camera}")))?;
        let raws: Vec<Vec<u16>> = product
            .made
            .inputs
            .iter()
            .map(|rel| {
                decode_png16(rel, &read(rel)?)
                    .map(|png| png.pixels)
                    .map_err(|e| err(e.to_string()))
            })
            .collect::<Result<_, _>>()?;
        let n = (merged.width * merged.height) as usize;
        let measured = |i: usize, c: usize| {
            let range = &response.channels[c].range;
            raws.iter().any(|dn| {
                let z = f64::from(dn[i * 3 + c]);
                z > range.lo && z < range.hi
            })
        };
        ours.extend(relative_errors(&merged.pixels, &truth_rgb, n, &measured));
        let hdr_frames = reader
            .frames(&FrameQuery {
                step: Some(step),
                camera: Some(camera.clone()),
                kind: Some(FrameKind::Hdr),
                ..FrameQuery::default()
            })
            .map_err(|e| err(e.to_string()))?;
        if let Some(f) = hdr_frames.frames.first() {
            let exr = decode_exr(&f.path, &read(&f.path)?).map_err(|e| err(e.to_string()))?;
            linear.extend(relative_errors(&exr.pixels, &truth_rgb, n, &measured));
        }
        compared += 1;
    }
    if compared == 0 {
        return Ok(None);
    }
    Ok(Some(HdrFigures {
        products: compared,
        calibrated: figures(ours),
        linear_merge: figures(linear),
    }))
}

/// |k·p − t| / t over the measured samples, k per channel the median of t / p.
fn relative_errors(
    rgb: &[f32],
    truth: &[&[f32]],
    n: usize,
    measured: &dyn Fn(usize, usize) -> bool,
) -> Vec<f64> {
    let mut out = Vec::new();
    for (c, t) in truth.iter().enumerate() {
        let samples: Vec<(f64, f64)> = (0..n)
            .filter(|&i| measured(i, c))
            .map(|i| (f64::from(rgb[i * 3 + c]), f64::from(t[i])))
            .filter(|(p, t)| *p > 0.0 && *t > 0.0 && p.is_finite() && t.is_finite())
            .collect();
        if samples.is_empty() {
            continue;
        }
        let mut ratios: Vec<f64> = samples.iter().map(|(p, t)| t / p).collect();
        let k = median(&mut ratios);
        out.extend(samples.iter().map(|(p, t)| (k * p - t).abs() / t));
    }
    out
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn figures(mut errors: Vec<f64>) -> Option<ErrorFigures> {
    if errors.is_empty() {
        return None;
    }
    errors.sort_by(f64::total_cmp);
    let at = |q: f64| errors[((errors.len() - 1) as f64 * q).round() as usize];
    Some(ErrorFigures {
        samples: errors.len(),
        median: at(0.5),
        p90: at(0.9),
    })
}
