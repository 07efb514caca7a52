//! Laser triangulation: a pixel's ray intersected with the laser sheet that lit it. The
//! distance is measured along the unit view ray from the camera centre (the MDF convention
//! stagehand keeps: seed 004 §3.3 leaves it open between this and the height over the
//! reference plane; along the ray it needs no sample geometry and is what the camera saw).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera_model::{CameraModel, Pose};
use crate::space_time::{NO_TIME, PeakTimes};

/// The MDF value of a pixel whose depth is unknown (never lit, occluded, or no intersection).
pub const NO_DEPTH: f32 = -1.0;

/// A plane n·x = d in the sample frame (mm), n of unit length.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plane {
    /// Unit normal.
    pub normal: [f64; 3],
    /// Offset along the normal, mm.
    pub d: f64,
}

impl Plane {
    /// The plane through `point` with normal `normal` (any length but zero).
    pub fn through(point: [f64; 3], normal: [f64; 3]) -> Option<Plane> {
        let n = Vector3::from(normal).try_normalize(1e-12)?;
        Some(Plane {
            normal: n.into(),
            d: n.dot(&Vector3::from(point)),
        })
    }
}

/// Pixel `(u, v)`'s ray (pixel centres at integers) in the sample frame: the camera centre
/// and the unit direction; `None` when the pixel cannot be undistorted.
pub fn pixel_ray(
    camera: &CameraModel,
    pose: &Pose,
    (u, v): (f64, f64),
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let (x, y) = camera.normalise(u, v)?;
    let dir = (pose.rotation_matrix().transpose() * Vector3::new(x, y, 1.0)).normalize();
    Some((pose.centre(), dir))
}

/// The distance along pixel `(u, v)`'s unit ray (pixel centres at integers) from the camera
/// centre to `plane`; `None` when the pixel cannot be undistorted, or the ray runs parallel
/// to the plane (within 0.1°) or meets it behind the camera.
pub fn ray_distance(
    camera: &CameraModel,
    pose: &Pose,
    (u, v): (f64, f64),
    plane: &Plane,
) -> Option<f64> {
    let (centre, dir) = pixel_ray(camera, pose, (u, v))?;
    let n = Vector3::from(plane.normal);
    let along = n.dot(&dir);
    if along.abs() < 0.1f64.to_radians().sin() {
        return None;
    }
    let distance = (plane.d - n.dot(&centre)) / along;
    (distance.is_finite() && distance > 0.0).then_some(distance)
}

/// Every pixel's distance to the sheet that lit it: `sheet_at(t)` is the laser sheet at
/// (fractional) frame time `t` of the sweep, `None` outside it. [`NO_DEPTH`] where the time
/// or the intersection is unknown.
pub fn depth_map(
    times: &PeakTimes,
    camera: &CameraModel,
    pose: &Pose,
    sheet_at: impl Fn(f64) -> Option<Plane>,
) -> Vec<f32> {
    times
        .time
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            if t == NO_TIME {
                return NO_DEPTH;
            }
            let (u, v) = ((i % times.width) as f64, (i / times.width) as f64);
            sheet_at(f64::from(t))
                .and_then(|plane| ray_distance(camera, pose, (u, v), &plane))
                .map_or(NO_DEPTH, |d| d as f32)
        })
        .collect()
}
