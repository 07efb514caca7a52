//! A geometric calibration against the simulated rig as built: per camera the reprojection
//! RMS, the focal length's relative error, the principal point's error, the camera centre's
//! distance from truth (the rig frame is the sample frame at turntable 0°: origin on the axis
//! at the sample top, X along 0°), and the distortion residual: the largest distance, over a
//! grid across the image, between where the true and the fitted camera image the same ray.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store::StoredCalibration;
use stagehand_processing::camera_model::{CameraModel, Distortion, Intrinsics, Pose};
use stagehand_processing::geometry_calibration::GeometryCalibration;

use super::EvaluateError;

/// One camera's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraFigures {
    /// Camera id.
    pub camera: String,
    /// Reprojection RMS of the fit, pixels.
    pub rms_px: f64,
    /// Largest of |fx − fx*|/fx* and |fy − fy*|/fy*.
    pub focal_rel_error: f64,
    /// Distance of the principal point from truth, pixels.
    pub principal_point_error_px: f64,
    /// Distance of the camera centre from truth in the rig frame, mm.
    pub centre_error_mm: f64,
    /// Largest image distance between the true and fitted camera over a 17×13 grid, pixels.
    pub distortion_residual_px: f64,
}

/// The figures of one geometry calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeometryFigures {
    /// Calibration id.
    pub id: String,
    /// Per camera.
    pub cameras: Vec<CameraFigures>,
    /// Worst of each figure over the cameras.
    pub worst: CameraFigures,
    /// Frames where the board was not found.
    pub not_detected: usize,
    /// (camera, why) for the cameras the calibration left out.
    pub failed: Vec<(String, String)>,
}

/// A camera as built, from `as_built.json` (OpenCV's convention, rig frame at table 0°).
#[derive(Deserialize)]
pub(super) struct TrueCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: [f64; 5],
    pub centre_mm: [f64; 3],
    /// Rig → camera rotation, rows.
    pub rotation: [[f64; 3]; 3],
    /// Rig → camera translation, mm.
    pub translation: [f64; 3],
}

impl TrueCamera {
    /// The camera's intrinsics and distortion as processing models them.
    pub fn model(&self) -> CameraModel {
        let [k1, k2, p1, p2, k3] = self.distortion;
        CameraModel {
            intrinsics: Intrinsics {
                fx: self.fx,
                fy: self.fy,
                cx: self.cx,
                cy: self.cy,
            },
            distortion: Distortion { k1, k2, p1, p2, k3 },
        }
    }
}

/// Every camera of `truth` (`as_built.json`) as a geometry calibration places a camera,
/// exactly: `stagehand calibrate geometry --from-truth` stores them, so depth and other
/// products can be measured apart from the geometric calibration's own error.
pub fn truth_geometry(truth: &serde_json::Value) -> Result<Vec<CameraGeometry>, EvaluateError> {
    let bad = |message: String| EvaluateError::Truth {
        path: "as_built.json".into(),
        message,
    };
    let cameras = truth["cameras"]
        .as_object()
        .ok_or_else(|| bad("no `cameras` object".into()))?;
    let mut out = Vec::with_capacity(cameras.len());
    for (id, camera) in cameras {
        let t: TrueCamera = serde_json::from_value(camera["geometry"].clone())
            .map_err(|e| bad(format!("camera {id}: {e}")))?;
        let rotation =
            Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&t.rotation.concat()));
        out.push(CameraGeometry::exact(
            id,
            t.model(),
            Pose::from_parts(&rotation, Vector3::from(t.translation)),
        ));
    }
    Ok(out)
}

/// Evaluates `stored` (a geometry calibration) against `truth` (`as_built.json`).
pub fn evaluate_geometry(
    stored: &StoredCalibration,
    truth: &serde_json::Value,
) -> Result<GeometryFigures, EvaluateError> {
    let bad = |message: String| EvaluateError::Truth {
        path: format!("calibration {}", stored.id),
        message,
    };
    let result: GeometryCalibration = stored
        .result(stagehand_processing::calibration_store::CalibrationKind::Geometry)
        .map_err(|e| bad(e.to_string()))?;
    let mut cameras = Vec::new();
    for g in &result.cameras {
        let t: TrueCamera = serde_json::from_value(truth["cameras"][&g.camera]["geometry"].clone())
            .map_err(|e| bad(format!("camera {}: {e}", g.camera)))?;
        let true_model = t.model();
        let k = &g.model.intrinsics;
        let centre = Vector3::from(g.centre_mm) - Vector3::from(t.centre_mm);
        let (w, h) = (2.0 * t.cx + 1.0, 2.0 * t.cy + 1.0);
        let mut residual: f64 = 0.0;
        for i in 0..17 {
            for j in 0..13 {
                let (u, v) = (w * i as f64 / 16.0, h * j as f64 / 12.0);
                let Some((x, y)) = true_model.normalise(u, v) else {
                    continue;
                };
                if let Some(p) = g.model.project_camera_point(&Vector3::new(x, y, 1.0)) {
                    residual = residual.max((p.x - u).hypot(p.y - v));
                }
            }
        }
        cameras.push(CameraFigures {
            camera: g.camera.clone(),
            rms_px: g.rms_px,
            focal_rel_error: ((k.fx - t.fx) / t.fx)
                .abs()
                .max(((k.fy - t.fy) / t.fy).abs()),
            principal_point_error_px: (k.cx - t.cx).hypot(k.cy - t.cy),
            centre_error_mm: centre.norm(),
            distortion_residual_px: residual,
        });
    }
    let worst_of = |f: fn(&CameraFigures) -> f64| cameras.iter().map(f).fold(0.0, f64::max);
    let worst = CameraFigures {
        camera: "worst".into(),
        rms_px: worst_of(|c| c.rms_px),
        focal_rel_error: worst_of(|c| c.focal_rel_error),
        principal_point_error_px: worst_of(|c| c.principal_point_error_px),
        centre_error_mm: worst_of(|c| c.centre_error_mm),
        distortion_residual_px: worst_of(|c| c.distortion_residual_px),
    };
    Ok(GeometryFigures {
        id: stored.id.clone(),
        cameras,
        worst,
        not_detected: result.not_detected.len(),
        failed: result.failed,
    })
}
