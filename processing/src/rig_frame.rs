//! The rig frame from a camera's views of a board lying flat on the turntable (seed 004
//! §3.2): turning the table only spins the board in its own plane, so the board's origin
//! traces a circle about the turntable axis. The axis is that circle's centre and the plane's
//! normal; the rig frame has its origin where the axis meets the board plane (the sample top),
//! Z up the axis towards the cameras, and X along the board's x direction at turntable 0°.

use nalgebra::{DMatrix, DVector, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera_model::Pose;
use crate::error::ProcessingError;

/// The turntable axis in one camera's coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TurntableAxis {
    /// Where the axis meets the board plane, camera coordinates (mm).
    pub point: [f64; 3],
    /// Unit direction of the axis, pointing towards the camera.
    pub direction: [f64; 3],
    /// Radius of the circle the board origin traced, mm.
    pub radius_mm: f64,
    /// RMS distance of the board origins from the fitted circle, mm.
    pub rms_mm: f64,
}

/// Smallest span of turntable angles the axis fit accepts, degrees.
pub const MIN_SPAN_DEG: f64 = 60.0;

/// Fits the turntable axis from the board's poses (board → camera) at several table angles.
pub fn turntable_axis(poses: &[Pose]) -> Result<TurntableAxis, ProcessingError> {
    let ill = |why: String| ProcessingError::IllPosed {
        what: "turntable axis",
        why,
    };
    if poses.len() < 3 {
        return Err(ill(format!(
            "it needs the flat board at 3 or more table angles, got {}",
            poses.len()
        )));
    }
    // The common plane normal (board z in the camera), pointing towards the camera.
    let mut normal = Vector3::zeros();
    for p in poses {
        let mut n = p.rotation_matrix() * Vector3::z();
        if n.dot(&Vector3::from(p.translation)) > 0.0 {
            n = -n;
        }
        normal += n;
    }
    let normal = normal.normalize();
    // Board origins projected into the plane: 2D coordinates on an in-plane basis.
    let e1 = normal
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| normal.cross(&Vector3::y()).normalize());
    let e2 = normal.cross(&e1);
    let origins: Vec<Vector3<f64>> = poses.iter().map(|p| Vector3::from(p.translation)).collect();
    let pts: Vec<(f64, f64)> = origins.iter().map(|o| (o.dot(&e1), o.dot(&e2))).collect();
    // Algebraic circle fit (Kasa): x² + y² + D x + E y + F = 0.
    let mut a = DMatrix::zeros(pts.len(), 3);
    let mut b = DVector::zeros(pts.len());
    for (r, &(x, y)) in pts.iter().enumerate() {
        a[(r, 0)] = x;
        a[(r, 1)] = y;
        a[(r, 2)] = 1.0;
        b[r] = -(x * x + y * y);
    }
    let sol = a
        .clone()
        .svd(true, true)
        .solve(&b, 1e-12)
        .map_err(|e| ill(format!("the circle fit failed: {e}")))?;
    let (cx, cy) = (-sol[0] / 2.0, -sol[1] / 2.0);
    let radius = (cx * cx + cy * cy - sol[2]).sqrt();
    if !radius.is_finite() {
        return Err(ill("the board origins do not lie on a circle".into()));
    }
    // The angles the origins span about the centre.
    let mut angles: Vec<f64> = pts.iter().map(|&(x, y)| (y - cy).atan2(x - cx)).collect();
    angles.sort_by(f64::total_cmp);
    let mut largest_gap = angles[0] + std::f64::consts::TAU - angles[angles.len() - 1];
    for w in angles.windows(2) {
        largest_gap = largest_gap.max(w[1] - w[0]);
    }
    let span = (std::f64::consts::TAU - largest_gap).to_degrees();
    if span < MIN_SPAN_DEG || radius < 1.0 {
        return Err(ill(format!(
            "the placements span {span:.0}° of table rotation around a {radius:.1} mm circle; turn the table through at least {MIN_SPAN_DEG:.0}° with the board off the axis"
        )));
    }
    let rms = (pts
        .iter()
        .map(|&(x, y)| (((x - cx).powi(2) + (y - cy).powi(2)).sqrt() - radius).powi(2))
        .sum::<f64>()
        / pts.len() as f64)
        .sqrt();
    // The centre lies in the board plane: put it at the plane's mean offset along the normal.
    let height = origins.iter().map(|o| o.dot(&normal)).sum::<f64>() / origins.len() as f64;
    let point = e1 * cx + e2 * cy + normal * height;
    Ok(TurntableAxis {
        point: point.into(),
        direction: normal.into(),
        radius_mm: radius,
        rms_mm: rms,
    })
}

/// The rig → camera pose: origin at the axis point, Z along the axis, X along the board's x
/// at the reference placement (turntable 0°) made perpendicular to the axis.
pub fn rig_to_camera(axis: &TurntableAxis, reference: &Pose) -> Result<Pose, ProcessingError> {
    let z = Vector3::from(axis.direction);
    let board_x = reference.rotation_matrix() * Vector3::x();
    let x = (board_x - z * board_x.dot(&z))
        .try_normalize(1e-9)
        .ok_or_else(|| ProcessingError::IllPosed {
            what: "rig frame",
            why: "the board's x direction is parallel to the turntable axis".into(),
        })?;
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    Ok(Pose::from_parts(&r, Vector3::from(axis.point)))
}

/// The sample → camera pose of a camera with `rig_to_camera` when the turntable is at
/// `turntable_deg`: the sample (and anything lying on the table: a chart, a board) turns with
/// the table about the rig's z axis, and the sample frame is the rig frame at 0°.
pub fn sample_to_camera(rig_to_camera: &Pose, turntable_deg: f64) -> Pose {
    let table = Rotation3::from_axis_angle(&Vector3::z_axis(), turntable_deg.to_radians());
    Pose::from_parts(
        &(rig_to_camera.rotation_matrix() * table),
        Vector3::from(rig_to_camera.translation),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_axis_and_the_rig_frame_of_a_turntable() {
        // Truth: rig → camera looking down at 45° from 600 mm.
        let cam_r = Rotation3::from_euler_angles(135f64.to_radians(), 0.0, 10f64.to_radians());
        let cam_t = Vector3::new(5.0, -3.0, 600.0);
        let rig = Pose::from_parts(&cam_r, cam_t);
        // The board lies flat with its origin 40 mm off the axis, turned by the table.
        let poses: Vec<Pose> = (0..8)
            .map(|k| {
                let table =
                    Rotation3::from_axis_angle(&Vector3::z_axis(), (45.0 * k as f64).to_radians());
                let board_in_rig_r = table;
                let board_in_rig_t = table * Vector3::new(40.0, -10.0, 0.0);
                Pose::from_parts(&(cam_r * board_in_rig_r), cam_r * board_in_rig_t + cam_t)
            })
            .collect();
        let axis = turntable_axis(&poses).unwrap();
        assert!(
            (Vector3::from(axis.point) - cam_t).norm() < 1e-6,
            "{axis:?}"
        );
        assert!((axis.radius_mm - 1700f64.sqrt()).abs() < 1e-6);
        let fit = rig_to_camera(&axis, &poses[0]).unwrap();
        assert!((fit.rotation_matrix().matrix() - rig.rotation_matrix().matrix()).norm() < 1e-9);
        assert!((Vector3::from(fit.translation) - cam_t).norm() < 1e-6);
    }

    #[test]
    fn too_little_table_rotation_is_reported() {
        let poses: Vec<Pose> = (0..4)
            .map(|k| {
                let r =
                    Rotation3::from_axis_angle(&Vector3::z_axis(), (5.0 * k as f64).to_radians());
                Pose::from_parts(
                    &r,
                    r * Vector3::new(40.0, 0.0, 0.0) + Vector3::new(0.0, 0.0, 500.0),
                )
            })
            .collect();
        let err = turntable_axis(&poses).unwrap_err();
        assert!(err.to_string().contains("span"), "{err}");
        assert!(turntable_axis(&poses[..2]).is_err());
    }
}
