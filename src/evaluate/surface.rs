//! The surface products (height and normal maps) against the simulated sample's own height
//! field: each measured cell's height against the sample's height at the cell centre, and its
//! normal against the normal the same central differences give on the true heights. Inpainted
//! cells are measured apart.

use std::path::Path;

use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_planes::decode_exr_planes;
use stagehand_processing::rectify::RectifyGrid;
use stagehand_simulator::render::material::{Material, Medium};
use stagehand_simulator::render::sample::Sample;

use super::EvaluateError;

/// Figures of a run's height and normal maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFigures {
    /// Cells measured (some point fell in them).
    pub measured_cells: usize,
    /// RMSE of their heights, mm.
    pub height_rmse_mm: f64,
    /// Median absolute height error, mm.
    pub height_median_mm: f64,
    /// 99th percentile, mm.
    pub height_p99_mm: f64,
    /// Cells inpainted, and their height RMSE, mm.
    pub inpainted_cells: usize,
    /// RMSE of the inpainted cells' heights, mm (0 when none).
    pub inpainted_rmse_mm: f64,
    /// Median angle between measured and true normals, degrees.
    pub normal_median_deg: f64,
}

/// The simulated run's sample, its material at the centre and the subsurface medium there
/// (what the dipole's processing compares with); an error, saying there is nothing to
/// compare `what` with, for a sample without one.
pub(super) fn centre_medium(
    run_dir: &Path,
    what: &str,
) -> Result<(Sample, Material, Medium), EvaluateError> {
    let sample = simulated_sample(run_dir)?;
    let centre = sample.material_at(0.0, 0.0);
    let medium = (centre.medium as usize)
        .checked_sub(1)
        .and_then(|k| sample.media.get(k))
        .copied()
        .ok_or_else(|| EvaluateError::Truth {
            path: run_dir.display().to_string(),
            message: format!(
                "the sample `{}` has no subsurface medium at its centre: there is no {what} to compare with",
                sample.name
            ),
        })?;
    Ok((sample, centre, medium))
}

/// The simulated run's sample as the simulator built it (its relief at the run's step).
pub(super) fn simulated_sample(run_dir: &Path) -> Result<Sample, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let manifest = stagehand_dataset::read_manifest(run_dir).map_err(|e| err(e.to_string()))?;
    let sim = manifest
        .sim
        .ok_or_else(|| err("the run is not simulated: no sample to compare with".into()))?;
    let relief = sim.knobs["relief_mm"].as_f64().unwrap_or(0.2) as f32;
    Sample::build(&sim.sample, sim.sample_size_mm as f32, relief)
        .map_err(|e| err(format!("sample `{}`: {e}", sim.sample)))
}

/// Evaluates the run's height map and normal map, if it has them.
pub fn evaluate_surface(run_dir: &Path) -> Result<Option<SurfaceFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((_, products)) = super::products_of(run_dir, "height")? else {
        return Ok(None);
    };
    let Some((_, normals)) = super::products_of(run_dir, "normal")? else {
        return Ok(None);
    };
    let sample = simulated_sample(run_dir)?;
    let read = |path: &str| {
        let bytes = std::fs::read(run_dir.join(path)).map_err(|e| err(format!("{path}: {e}")))?;
        decode_exr_planes(path, &bytes).map_err(|e| err(e.to_string()))
    };
    let height = &products[0];
    let grid: RectifyGrid = serde_json::from_value(height.made.parameters["grid"].clone())
        .map_err(|e| err(format!("{}: grid: {e}", height.path)))?;
    let h = read(&height.path)?;
    let nm = read(&normals[0].path)?;
    let (Some(z), Some(s), Some(nx), Some(ny), Some(nz)) = (
        h.channel("Z"),
        h.channel("S"),
        nm.channel("X"),
        nm.channel("Y"),
        nm.channel("Z"),
    ) else {
        return Err(err("the height or normal map lacks a channel".into()));
    };
    let n = grid.pixels;
    let step = grid.size_mm / n as f64;
    let truth = |i: f64, j: f64| {
        let (x, y) = grid.plane_point(i, j);
        f64::from(sample.height_at(x as f32, y as f32))
    };
    let (mut errors, mut inpainted, mut angles) = (Vec::new(), Vec::new(), Vec::new());
    for cell in 0..(n * n).min(z.len()) {
        let (i, j) = ((cell % n) as f64 + 0.5, (cell / n) as f64 + 0.5);
        let e = f64::from(z[cell]) - truth(i, j);
        if s[cell] == 2.0 {
            errors.push(e.abs());
        } else if s[cell] == 1.0 {
            inpainted.push(e);
        } else {
            continue;
        }
        if s[cell] == 2.0 && nz[cell] > 0.0 {
            let dx = (truth(i + 1.0, j) - truth(i - 1.0, j)) / (2.0 * step);
            let dy = (truth(i, j + 1.0) - truth(i, j - 1.0)) / (2.0 * step);
            let t = nalgebra::Vector3::new(-dx, -dy, 1.0).normalize();
            let m = nalgebra::Vector3::new(
                f64::from(nx[cell]),
                f64::from(ny[cell]),
                f64::from(nz[cell]),
            );
            angles.push(m.angle(&t).to_degrees());
        }
    }
    let rms = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt()
        }
    };
    let at = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            0.0
        } else {
            v[((v.len() - 1) as f64 * q).round() as usize]
        }
    };
    let height_rmse_mm = rms(&errors);
    let inpainted_rmse_mm = rms(&inpainted);
    Ok(Some(SurfaceFigures {
        measured_cells: errors.len(),
        height_rmse_mm,
        height_median_mm: at(&mut errors, 0.5),
        height_p99_mm: at(&mut errors, 0.99),
        inpainted_cells: inpainted.len(),
        inpainted_rmse_mm,
        normal_median_deg: at(&mut angles, 0.5),
    }))
}
