//! The pinhole camera with Brown–Conrady lens distortion that geometric calibration fits:
//! intrinsics (focal lengths and principal point in pixels), radial k1, k2, k3 and tangential
//! p1, p2 distortion, and a pose (world → camera) as a Rodrigues rotation vector and a
//! translation. Projection follows OpenCV's convention, so its results compare directly.

use nalgebra::{Rotation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Focal lengths and principal point, in pixels (no skew: square-pixel sensors).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel centres at integers).
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

/// Brown–Conrady distortion of normalised image coordinates (OpenCV's k1, k2, p1, p2, k3).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Distortion {
    /// Radial r² coefficient.
    pub k1: f64,
    /// Radial r⁴ coefficient.
    pub k2: f64,
    /// Tangential coefficient 1.
    pub p1: f64,
    /// Tangential coefficient 2.
    pub p2: f64,
    /// Radial r⁶ coefficient.
    pub k3: f64,
}

impl Distortion {
    /// The distorted normalised coordinates of undistorted `(x, y)`.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// The undistorted normalised coordinates of distorted `(xd, yd)`, by fixed-point
    /// iteration (converges for the mild distortion of measurement lenses); `None` if it does
    /// not converge to 1e-12 within 50 steps.
    pub fn remove(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (dx, dy) = self.apply(x, y);
            let (ex, ey) = (dx - xd, dy - yd);
            if ex.abs() < 1e-12 && ey.abs() < 1e-12 {
                return Some((x, y));
            }
            x -= ex;
            y -= ey;
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
        }
        None
    }
}

/// A rigid transform from world (board or rig) coordinates to camera coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Rotation as a Rodrigues vector (axis × angle in radians).
    pub rotation: [f64; 3],
    /// Translation, in the world's length unit (millimetres on the rig).
    pub translation: [f64; 3],
}

impl Pose {
    /// The rotation matrix.
    pub fn rotation_matrix(&self) -> Rotation3<f64> {
        Rotation3::new(Vector3::from(self.rotation))
    }

    /// A pose from a rotation matrix and translation. The rotation vector goes through a unit
    /// quaternion: `Rotation3::scaled_axis` loses the axis at exactly 180° (a board turned
    /// half way on the turntable), the quaternion's logarithm does not.
    pub fn from_parts(rotation: &Rotation3<f64>, translation: Vector3<f64>) -> Pose {
        let q = UnitQuaternion::from_rotation_matrix(rotation);
        Pose {
            rotation: q.scaled_axis().into(),
            translation: translation.into(),
        }
    }

    /// `p` in camera coordinates.
    pub fn transform(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation_matrix() * p + Vector3::from(self.translation)
    }

    /// The camera centre in world coordinates: −Rᵀt.
    pub fn centre(&self) -> Vector3<f64> {
        -(self.rotation_matrix().transpose() * Vector3::from(self.translation))
    }

    /// `self` after `first`: the transform that applies `first`, then `self`.
    pub fn after(&self, first: &Pose) -> Pose {
        let r = self.rotation_matrix();
        Pose::from_parts(
            &(r * first.rotation_matrix()),
            r * Vector3::from(first.translation) + Vector3::from(self.translation),
        )
    }

    /// The inverse transform (camera → world).
    pub fn inverse(&self) -> Pose {
        let rt = self.rotation_matrix().transpose();
        Pose::from_parts(&rt, -(rt * Vector3::from(self.translation)))
    }
}

/// A calibrated camera: intrinsics and distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    /// Focal lengths and principal point.
    pub intrinsics: Intrinsics,
    /// Lens distortion.
    pub distortion: Distortion,
}

impl CameraModel {
    /// The pixel where camera-frame point `pc` images; `None` behind or on the camera plane.
    pub fn project_camera_point(&self, pc: &Vector3<f64>) -> Option<Vector2<f64>> {
        if pc.z <= 1e-12 {
            return None;
        }
        let (xd, yd) = self.distortion.apply(pc.x / pc.z, pc.y / pc.z);
        let k = &self.intrinsics;
        Some(Vector2::new(k.fx * xd + k.cx, k.fy * yd + k.cy))
    }

    /// The pixel where world point `p` images through `pose`.
    pub fn project(&self, pose: &Pose, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.project_camera_point(&pose.transform(p))
    }

    /// The undistorted normalised coordinates (x/z, y/z) of pixel `(u, v)`.
    pub fn normalise(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let k = &self.intrinsics;
        self.distortion.remove((u - k.cx) / k.fx, (v - k.cy) / k.fy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distortion_round_trips() {
        let d = Distortion {
            k1: -0.2,
            k2: 0.05,
            p1: 0.001,
            p2: -0.0008,
            k3: -0.01,
        };
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.45, 0.35), (0.5, 0.5)] {
            let (xd, yd) = d.apply(x, y);
            let (ux, uy) = d.remove(xd, yd).unwrap();
            assert!((ux - x).abs() < 1e-10 && (uy - y).abs() < 1e-10, "{x},{y}");
        }
    }

    #[test]
    fn poses_round_trip_through_half_turns() {
        for angle in [0.0f64, 90.0, 179.99, 180.0] {
            for axis in [
                Vector3::new(0.3, -0.8, 0.52),
                Vector3::new(0.0, 0.6, -0.8),
                Vector3::new(1.0, 0.0, 0.0),
            ] {
                let r = Rotation3::from_axis_angle(
                    &nalgebra::Unit::new_normalize(axis),
                    angle.to_radians(),
                );
                let back = Pose::from_parts(&r, Vector3::zeros()).rotation_matrix();
                assert!(
                    (back.matrix() - r.matrix()).norm() < 1e-9,
                    "{angle}° about {axis:?}"
                );
            }
        }
    }

    #[test]
    fn projection_follows_opencv() {
        let cam = CameraModel {
            intrinsics: Intrinsics {
                fx: 1000.0,
                fy: 1001.0,
                cx: 511.5,
                cy: 383.5,
            },
            distortion: Distortion::default(),
        };
        let pose = Pose {
            rotation: [0.0, 0.0, 0.0],
            translation: [0.0, 0.0, 500.0],
        };
        let p = cam.project(&pose, &Vector3::new(50.0, -25.0, 0.0)).unwrap();
        assert!((p.x - (511.5 + 100.0)).abs() < 1e-9);
        assert!((p.y - (383.5 - 50.05)).abs() < 1e-9);
        assert!(
            cam.project(&pose, &Vector3::new(0.0, 0.0, -600.0))
                .is_none()
        );
        assert!((pose.centre() - Vector3::new(0.0, 0.0, -500.0)).norm() < 1e-12);
    }
}
