//! Depth products (and merged MDFs, whose inpainted pixels are measured apart) against the
//! simulator's ground-truth depth (runs with `[sim] ground_truth =
//! true`): the truth is the distance along each pixel-centre ray to the first surface, the
//! same convention the depth products keep, taken beside the sweep's first frame (a sweep's
//! frames share the view). Compared where both know a depth; errors also in pixel footprints
//! (the truth's distance over the calibrated focal length: texel-equivalent).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_planes::decode_exr_planes;
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store;

use super::EvaluateError;

/// Depth figures over every depth product of a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DepthFigures {
    /// Depth images compared.
    pub images: usize,
    /// Pixels where both the product and the truth have a depth.
    pub compared: usize,
    /// Root mean square error, mm.
    pub rmse_mm: f64,
    /// 99th percentile of the absolute error, mm.
    pub p99_mm: f64,
    /// Root mean square error in pixel footprints.
    pub rmse_footprints: f64,
    /// Median absolute error in pixel footprints (robust to the few pixels whose peak is
    /// light from elsewhere: a shadowed point lit by its neighbour's reflection).
    pub median_footprints: f64,
    /// Of the pixels whose ray meets a surface, the fraction with a depth.
    pub known_fraction: f64,
    /// Merged MDFs: pixels filled by inpainting (not in the figures above) and their RMSE, mm.
    pub inpainted_pixels: usize,
    /// RMSE of the inpainted pixels, mm (0 when none).
    pub inpainted_rmse_mm: f64,
    /// Merged MDFs: the mean over views of the fraction of sample pixels that were holes.
    pub hole_fraction: Option<f64>,
}

/// Evaluates the run's depth products of `kind` (`depth`, `depth_per_frame`), if it has any
/// and ground truth beside its frames.
pub fn evaluate_depth(
    run_dir: &Path,
    calibrations_root: &Path,
    kind: &str,
) -> Result<Option<DepthFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((reader, products)) = super::products_of(run_dir, kind)? else {
        return Ok(None);
    };
    let truth_rows: BTreeMap<String, String> = reader
        .ground_truth(None)
        .map_err(|e| err(e.to_string()))?
        .into_iter()
        .filter(|g| g.kind == "depth")
        .map(|g| (g.frame_path, g.path))
        .collect();
    let mut geometries: BTreeMap<String, BTreeMap<String, CameraGeometry>> = BTreeMap::new();
    let (mut errors, mut footprints) = (Vec::new(), Vec::new());
    let (mut hits, mut known, mut images) = (0usize, 0usize, 0usize);
    let (mut inpainted, mut hole_fractions) = (Vec::new(), Vec::new());
    for p in &products {
        // A merged MDF names a frame of its view; a sweep's depth image is made from frames.
        let frame = p.made.parameters["truth_frame"]
            .as_str()
            .map(str::to_string)
            .or_else(|| p.made.inputs.first().cloned());
        let Some(truth_path) = frame.and_then(|f| truth_rows.get(&f)) else {
            continue;
        };
        let Some(geometry_id) = p.made.calibrations.first() else {
            continue;
        };
        if !geometries.contains_key(geometry_id) {
            let stored = calibration_store::load(calibrations_root, geometry_id)?;
            let cameras = stored.cameras()?;
            geometries.insert(
                geometry_id.clone(),
                cameras.into_iter().map(|g| (g.camera.clone(), g)).collect(),
            );
        }
        let camera = p.made.parameters["camera"]
            .as_str()
            .unwrap_or_else(|| p.made.key.rsplit('/').next().unwrap_or_default());
        let fx = geometries[geometry_id]
            .get(camera)
            .map(|g| g.model.intrinsics.fx)
            .ok_or_else(|| err(format!("calibration {geometry_id} has no camera {camera}")))?;
        let read = |path: &str| {
            let bytes =
                std::fs::read(run_dir.join(path)).map_err(|e| err(format!("{path}: {e}")))?;
            decode_exr_planes(path, &bytes).map_err(|e| err(e.to_string()))
        };
        let product = read(&p.path)?;
        let truth = read(truth_path)?;
        let (Some(d), Some(z)) = (product.channel("D"), truth.channel("Z")) else {
            return Err(err(format!(
                "{} or {truth_path} lacks its depth channel",
                p.path
            )));
        };
        if d.len() != z.len() {
            return Err(err(format!("{} and {truth_path} differ in size", p.path)));
        }
        images += 1;
        let sources = product.channel("S");
        if let Some(h) = product
            .metadata
            .as_deref()
            .and_then(|m| serde_json::from_str::<serde_json::Value>(m).ok())
            .and_then(|m| m["hole_fraction"].as_f64())
        {
            hole_fractions.push(h);
        }
        for (i, (&ours, &t)) in d.iter().zip(z).enumerate() {
            if t <= 0.0 {
                continue;
            }
            hits += 1;
            if ours < 0.0 {
                continue;
            }
            if sources.is_some_and(|s| s[i] == 1.0) {
                inpainted.push(f64::from(ours - t));
                continue;
            }
            known += 1;
            let e = f64::from(ours - t).abs();
            errors.push(e);
            footprints.push(e / (f64::from(t) / fx));
        }
    }
    if images == 0 {
        return Ok(None);
    }
    let rms = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt()
        }
    };
    let (rmse_mm, rmse_footprints) = (rms(&errors), rms(&footprints));
    footprints.sort_by(f64::total_cmp);
    let median_footprints = footprints.get(footprints.len() / 2).copied().unwrap_or(0.0);
    errors.sort_by(f64::total_cmp);
    let p99_mm = if errors.is_empty() {
        0.0
    } else {
        errors[((errors.len() - 1) as f64 * 0.99).round() as usize]
    };
    Ok(Some(DepthFigures {
        images,
        compared: errors.len(),
        rmse_mm,
        p99_mm,
        rmse_footprints,
        median_footprints,
        known_fraction: if hits > 0 {
            known as f64 / hits as f64
        } else {
            0.0
        },
        inpainted_pixels: inpainted.len(),
        inpainted_rmse_mm: rms(&inpainted),
        hole_fraction: (!hole_fractions.is_empty())
            .then(|| hole_fractions.iter().sum::<f64>() / hole_fractions.len() as f64),
    }))
}
