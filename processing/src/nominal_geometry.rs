//! A camera's geometry as the rig file describes it (nominal: what a user typed, not what was
//! built), in the same [`CameraGeometry`] a geometric calibration produces, so every consumer
//! takes either. The camera sits at (azimuth, elevation, distance) about the rig origin, looks
//! at the origin with image up towards +z, and has the focal length its horizontal field of
//! view gives; its principal point is the rig file's offset from the image centre.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibrate_geometry::CameraGeometry;
use crate::camera_model::{CameraModel, Distortion, Intrinsics, Pose};
use crate::error::ProcessingError;

/// A camera as the rig file describes it (the fields of its `[[camera]]` table that place it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NominalCamera {
    /// Camera id.
    pub id: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Azimuth about the turntable axis from the rig's x axis, degrees.
    pub azimuth_deg: f64,
    /// Elevation above the reference plane, degrees.
    pub elevation_deg: f64,
    /// Distance from the rig origin, mm.
    pub distance_mm: f64,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
    /// Principal point offset from the image centre, pixels (+x right, +y down).
    pub principal_offset_px: [f64; 2],
    /// Brown–Conrady coefficients.
    pub distortion: Distortion,
}

/// The geometry `cam` would have if it were built exactly as described. It has no fit, so its
/// residuals and standard deviations are zero and its turntable axis is the rig's z axis.
pub fn nominal_geometry(cam: &NominalCamera) -> Result<CameraGeometry, ProcessingError> {
    let bad = |name, value, why| ProcessingError::BadParameter { name, value, why };
    if !(cam.distance_mm.is_finite() && cam.distance_mm > 0.0) {
        return Err(bad(
            "camera distance_mm",
            cam.distance_mm,
            "a camera must stand a finite positive distance from the rig origin",
        ));
    }
    if !(cam.fov_deg.is_finite() && cam.fov_deg > 0.0 && cam.fov_deg < 180.0) {
        return Err(bad(
            "camera fov_deg",
            cam.fov_deg,
            "the field of view must lie strictly between 0° and 180°",
        ));
    }
    if cam.width == 0 || cam.height == 0 {
        return Err(bad(
            "camera width",
            f64::from(cam.width.min(cam.height)),
            "an image needs at least one pixel",
        ));
    }
    let (a, e) = (cam.azimuth_deg.to_radians(), cam.elevation_deg.to_radians());
    let centre = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin()) * cam.distance_mm;
    let forward = -centre.normalize();
    // Image right is horizontal; looking straight down it is the light arc's tangent.
    let right = forward
        .cross(&Vector3::z())
        .try_normalize(1e-9)
        .unwrap_or_else(|| Vector3::new(-a.sin(), a.cos(), 0.0));
    let up = right.cross(&forward);
    // OpenCV rows: image x (right), image y (down), optical axis.
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        right.transpose(),
        (-up).transpose(),
        forward.transpose(),
    ]));
    let pose = Pose::from_parts(&r, -(r * centre));
    let focal = 0.5 * f64::from(cam.width) / (0.5 * cam.fov_deg.to_radians()).tan();
    let model = CameraModel {
        intrinsics: Intrinsics {
            fx: focal,
            fy: focal,
            // Pixel centres at integers: the image centre is at (w − 1)/2.
            cx: 0.5 * f64::from(cam.width) - 0.5 + cam.principal_offset_px[0],
            cy: 0.5 * f64::from(cam.height) - 0.5 + cam.principal_offset_px[1],
        },
        distortion: cam.distortion,
    };
    Ok(CameraGeometry::exact(&cam.id, model, pose))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(elevation_deg: f64) -> NominalCamera {
        NominalCamera {
            id: "cam".into(),
            width: 480,
            height: 360,
            azimuth_deg: 0.0,
            elevation_deg,
            distance_mm: 600.0,
            fov_deg: 11.0,
            principal_offset_px: [3.0, -2.0],
            distortion: Distortion::default(),
        }
    }

    #[test]
    fn the_origin_images_at_the_principal_point_and_plus_y_to_the_right() {
        let g = nominal_geometry(&camera(30.0)).unwrap();
        let k = g.model.intrinsics;
        let o = g
            .model
            .project(&g.rig_to_camera, &Vector3::zeros())
            .unwrap();
        assert!((o.x - k.cx).abs() < 1e-9 && (o.y - k.cy).abs() < 1e-9);
        assert!((k.cx - (239.5 + 3.0)).abs() < 1e-12);
        let y = g
            .model
            .project(&g.rig_to_camera, &Vector3::new(0.0, 10.0, 0.0))
            .unwrap();
        assert!(y.x > o.x + 10.0 && (y.y - o.y).abs() < 1e-6);
        let z = g
            .model
            .project(&g.rig_to_camera, &Vector3::new(0.0, 0.0, 10.0))
            .unwrap();
        assert!(z.y < o.y, "+z images above the origin");
        assert!((Vector3::from(g.centre_mm).norm() - 600.0).abs() < 1e-9);
        assert!((g.rig_to_camera.centre() - Vector3::from(g.centre_mm)).norm() < 1e-9);
    }

    #[test]
    fn looking_straight_down_is_well_defined_and_bad_specs_are_refused() {
        let g = nominal_geometry(&camera(90.0)).unwrap();
        assert!(g.rig_to_camera.rotation.iter().all(|v| v.is_finite()));
        let mut bad = camera(30.0);
        bad.fov_deg = 0.0;
        assert!(nominal_geometry(&bad).is_err());
        bad = camera(30.0);
        bad.distance_mm = f64::NAN;
        assert!(nominal_geometry(&bad).is_err());
    }
}
