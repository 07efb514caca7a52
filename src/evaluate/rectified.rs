//! Rectified images and the BTF's views against the rig as built: how far from where the
//! product says a pixel lies on the reference plane the sample point it shows truly is. For
//! each rectified view, a 33×33 lattice of output pixel centres is projected into the camera
//! through the calibrated geometry (what rectification sampled), and that image point is
//! traced back through the true camera onto the true reference plane (z = 0 of the sample
//! frame at the capture's turntable angle). The distance between the two plane points, in
//! output pixels, is the misalignment of the product with the sample's texture.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};
use stagehand_dataset::RunReader;
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store;
use stagehand_processing::rectify::RectifyGrid;
use stagehand_processing::rig_frame::sample_to_camera;

use super::EvaluateError;
use super::geometry::TrueCamera;

/// Misalignment over the evaluated views, in output pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RectifiedFigures {
    /// Views evaluated (rectified products and BTF views).
    pub views: usize,
    /// Median misalignment over every lattice point of every view.
    pub median_px: f64,
    /// 99th percentile.
    pub p99_px: f64,
    /// Largest.
    pub max_px: f64,
    /// Per camera, the largest.
    pub worst_by_camera: BTreeMap<String, f64>,
}

/// One rectified view to check.
struct View {
    camera: String,
    turntable_deg: f64,
    grid: RectifyGrid,
    geometry_id: String,
}

/// Lattice points per side.
const LATTICE: usize = 33;

/// Evaluates the run's rectified products and BTF views, if it has any.
pub fn evaluate_rectified(
    run_dir: &Path,
    calibrations_root: &Path,
    truth: &serde_json::Value,
) -> Result<Option<RectifiedFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let reader = RunReader::open(run_dir).map_err(|e| err(e.to_string()))?;
    let mut views = Vec::new();
    for p in reader.products().map_err(|e| err(e.to_string()))? {
        let geometry_id = p
            .made
            .calibrations
            .iter()
            .find(|id| id.starts_with("geometry-"))
            .cloned();
        let params = &p.made.parameters;
        match (p.made.kind.as_str(), geometry_id) {
            ("rectified", Some(geometry_id)) => {
                let grid: RectifyGrid = serde_json::from_value(params["grid"].clone())
                    .map_err(|e| err(format!("product {}: grid: {e}", p.made.key)))?;
                views.push(View {
                    camera: p
                        .made
                        .key
                        .rsplit('/')
                        .next()
                        .unwrap_or_default()
                        .to_string(),
                    turntable_deg: params["turntable_deg"].as_f64().unwrap_or(0.0),
                    grid,
                    geometry_id,
                });
            }
            ("btf", Some(geometry_id)) if p.made.key == "btf/zarr.json" => {
                let bytes = std::fs::read(run_dir.join(&p.path))
                    .map_err(|e| err(format!("{}: {e}", p.path)))?;
                let group: serde_json::Value =
                    serde_json::from_slice(&bytes).map_err(|e| err(format!("{}: {e}", p.path)))?;
                let attrs = &group["attributes"];
                let grid: RectifyGrid = serde_json::from_value(attrs["grid"].clone())
                    .map_err(|e| err(format!("{}: grid: {e}", p.path)))?;
                for v in attrs["views"].as_array().into_iter().flatten() {
                    views.push(View {
                        camera: v["camera"].as_str().unwrap_or_default().to_string(),
                        turntable_deg: v["turntable_deg"].as_f64().unwrap_or(0.0),
                        grid,
                        geometry_id: geometry_id.clone(),
                    });
                }
            }
            _ => {}
        }
    }
    if views.is_empty() {
        return Ok(None);
    }
    // Image sizes from the run's rig: only points inside the image were sampled.
    let manifest = stagehand_dataset::read_manifest(run_dir).map_err(|e| err(e.to_string()))?;
    let rig = stagehand_devices::rig::parse_rig(&manifest.rig_toml, "rig.toml")
        .map_err(|e| err(e.to_string()))?;
    let mut geometries: BTreeMap<String, BTreeMap<String, CameraGeometry>> = BTreeMap::new();
    let mut errors = Vec::new();
    let mut worst_by_camera: BTreeMap<String, f64> = BTreeMap::new();
    for view in &views {
        if !geometries.contains_key(&view.geometry_id) {
            let stored = calibration_store::load(calibrations_root, &view.geometry_id)?;
            let list = stored.cameras()?;
            geometries.insert(
                view.geometry_id.clone(),
                list.into_iter().map(|g| (g.camera.clone(), g)).collect(),
            );
        }
        let fitted = geometries[&view.geometry_id]
            .get(&view.camera)
            .ok_or_else(|| {
                err(format!(
                    "calibration {} has no camera {}",
                    view.geometry_id, view.camera
                ))
            })?;
        let t: TrueCamera =
            serde_json::from_value(truth["cameras"][&view.camera]["geometry"].clone())
                .map_err(|e| err(format!("as_built.json: camera {}: {e}", view.camera)))?;
        let size = rig
            .camera(&view.camera)
            .map(|c| (f64::from(c.width), f64::from(c.height)))
            .ok_or_else(|| err(format!("the run's rig has no camera {}", view.camera)))?;
        let worst = worst_by_camera.entry(view.camera.clone()).or_insert(0.0);
        for e in misalignment(view, fitted, &t, size) {
            *worst = worst.max(e);
            errors.push(e);
        }
    }
    if errors.is_empty() {
        return Err(err(
            "no lattice point of any rectified view is seen by its camera".into(),
        ));
    }
    errors.sort_by(f64::total_cmp);
    let at = |q: f64| errors[((errors.len() - 1) as f64 * q).round() as usize];
    Ok(Some(RectifiedFigures {
        views: views.len(),
        median_px: at(0.5),
        p99_px: at(0.99),
        max_px: at(1.0),
        worst_by_camera,
    }))
}

/// The misalignment (output pixels) at each lattice point of `view` the camera sees.
fn misalignment(
    view: &View,
    fitted: &CameraGeometry,
    t: &TrueCamera,
    (width, height): (f64, f64),
) -> Vec<f64> {
    let pose = sample_to_camera(&fitted.rig_to_camera, view.turntable_deg);
    let true_model = t.model();
    let rows = Matrix3::from_fn(|r, c| t.rotation[r][c]);
    let table = Rotation3::from_axis_angle(&Vector3::z_axis(), view.turntable_deg.to_radians());
    // Sample → camera as built; its inverse takes the ray back to the sample frame.
    let r = rows * table.matrix();
    let origin = -(r.transpose() * Vector3::from(t.translation));
    let pixel_mm = view.grid.size_mm / view.grid.pixels as f64;
    let mut out = Vec::new();
    for j in 0..LATTICE {
        for i in 0..LATTICE {
            let s = view.grid.pixels as f64 / (LATTICE - 1) as f64;
            let (x, y) = view.grid.plane_point(i as f64 * s, j as f64 * s);
            let Some(p) = fitted
                .model
                .project(&pose, &Vector3::new(x, y, 0.0))
                .filter(|p| {
                    (0.0..=width - 1.0).contains(&p.x) && (0.0..=height - 1.0).contains(&p.y)
                })
            else {
                continue;
            };
            let Some((nx, ny)) = true_model.normalise(p.x, p.y) else {
                continue;
            };
            let d = r.transpose() * Vector3::new(nx, ny, 1.0);
            if d.z.abs() < 1e-12 {
                continue;
            }
            let lambda = -origin.z / d.z;
            if lambda <= 0.0 {
                continue;
            }
            let q = origin + d * lambda;
            out.push((q.x - x).hypot(q.y - y) / pixel_mm);
        }
    }
    out
}
