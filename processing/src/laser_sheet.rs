//! The laser sheet of a sweep frame as the rig file places the laser (seed 004 §2.2): the unit
//! sits on the light arc at its mount elevation and distance, at the arc's azimuth; its
//! central ray aims at the rig origin and turns by the tilt axis's angle about the arc's
//! horizontal tangent (positive tilt raises the ray, moving the line away from the laser);
//! the fan spreads along that tangent. The sheet is the plane through the emitter holding the
//! central ray and the fan, given in the sample frame (the rig frame turned back by the
//! turntable's angle). This is the nominal sheet; a laser-plane calibration corrects it.

use nalgebra::{Rotation3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera_model::{CameraModel, Pose};
use crate::laser_line::ScanAxis;
use crate::ray_plane::Plane;

/// Where the laser unit is mounted on the light arc.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LaserMount {
    /// Elevation on the arc above the sample plane, degrees.
    pub elevation_deg: f64,
    /// Distance of the emitter from the rig origin, mm.
    pub distance_mm: f64,
}

/// The sheet of `mount` with the light arc at `light_arc_deg`, the fan tilted by `tilt_deg`
/// and the turntable at `turntable_deg`, in the sample frame; `None` for a degenerate mount
/// (zero distance, or a ray along the tangent).
pub fn nominal_sheet(
    mount: &LaserMount,
    light_arc_deg: f64,
    tilt_deg: f64,
    turntable_deg: f64,
) -> Option<Plane> {
    let a = light_arc_deg.to_radians();
    let origin = nominal_emitter(mount, light_arc_deg);
    let tangent = Unit::new_normalize(Vector3::new(-a.sin(), a.cos(), 0.0));
    let aim = (-origin).try_normalize(1e-12)?;
    let centre = Rotation3::from_axis_angle(&tangent, tilt_deg.to_radians()) * aim;
    let normal = centre.cross(&tangent).try_normalize(1e-12)?;
    let to_sample = Rotation3::from_axis_angle(&Vector3::z_axis(), -turntable_deg.to_radians());
    Plane::through((to_sample * origin).into(), (to_sample * normal).into())
}

/// The RGB channel that sees a laser of `nm` best (the simulated cameras' anchors: 473 nm
/// blue, 532 green, 650 red).
pub fn laser_channel(nm: u32) -> usize {
    match nm {
        0..=500 => 2,
        501..=600 => 1,
        _ => 0,
    }
}

/// Which way to scan a camera's image across the line: along the image axis the laser's fan
/// (the arc's horizontal tangent) runs least along.
pub fn scan_axis(model: &CameraModel, pose: &Pose, arc: f64, table: f64) -> ScanAxis {
    let (a, t) = (arc.to_radians(), -table.to_radians());
    let fan = nalgebra::Vector3::new(-(a + t).sin(), (a + t).cos(), 0.0) * 10.0;
    let origin = model.project(pose, &nalgebra::Vector3::zeros());
    let along = model.project(pose, &fan);
    match (origin, along) {
        (Some(o), Some(p)) if (p.y - o.y).abs() > (p.x - o.x).abs() => ScanAxis::Rows,
        _ => ScanAxis::Columns,
    }
}

/// The emitter of `mount` with the light arc at `light_arc_deg`, rig frame (turntable 0°).
pub fn nominal_emitter(mount: &LaserMount, light_arc_deg: f64) -> Vector3<f64> {
    let (a, e) = (light_arc_deg.to_radians(), mount.elevation_deg.to_radians());
    Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin()) * mount.distance_mm
}

/// Half the length of the laser line [`triangulation_volume`] takes through the turntable
/// centre, mm.
pub const VOLUME_LINE_HALF_MM: f64 = 50.0;

/// ν of seed 004 eq. 4.45 (after Bouguet & Perona): the volume of the tetrahedron of the laser
/// `emitter`, the `camera` centre and two points of the laser line through the turntable
/// centre ([`VOLUME_LINE_HALF_MM`] either side of the point of `sheet` on the reference plane
/// nearest the axis), all in one frame, mm³. Large when the camera sees the sheet broadside
/// and far from the emitter (well-conditioned triangulation); zero when the camera lies in
/// the sheet or the sheet is parallel to the reference plane.
pub fn triangulation_volume(emitter: &Vector3<f64>, camera: &Vector3<f64>, sheet: &Plane) -> f64 {
    let n = Vector3::from(sheet.normal);
    let horizontal = n.x * n.x + n.y * n.y;
    if horizontal < 1e-12 {
        return 0.0;
    }
    let foot = Vector3::new(n.x, n.y, 0.0) * (sheet.d / horizontal);
    let along = Vector3::new(-n.y, n.x, 0.0) / horizontal.sqrt();
    let (b, c) = (
        foot + along * VOLUME_LINE_HALF_MM,
        foot - along * VOLUME_LINE_HALF_MM,
    );
    let volume = (b - emitter)
        .dot(&(c - emitter).cross(&(camera - emitter)))
        .abs()
        / 6.0;
    if volume.is_finite() { volume } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mount() -> LaserMount {
        LaserMount {
            elevation_deg: 45.0,
            distance_mm: 1000.0,
        }
    }

    /// Where the sheet crosses the sample plane's x axis (y = 0, z = 0).
    fn crossing_x(p: &Plane) -> f64 {
        p.d / p.normal[0]
    }

    #[test]
    fn the_untilted_sheet_crosses_the_origin_and_tilt_moves_the_line_away_from_the_laser() {
        let flat = nominal_sheet(&mount(), 0.0, 0.0, 0.0).unwrap();
        assert!(flat.d.abs() < 1e-9, "{flat:?}");
        // The fan spreads along y: the line on the sample runs along y.
        assert!(flat.normal[1].abs() < 1e-12);
        let tilted = nominal_sheet(&mount(), 0.0, 2.0, 0.0).unwrap();
        // The laser stands at +x: the line moves to −x, by about 1000·tan 2° / sin 45°.
        let x = crossing_x(&tilted);
        assert!(x < -40.0 && x > -60.0, "{x}");
    }

    #[test]
    fn the_triangulation_volume_vanishes_for_a_camera_in_the_sheet() {
        let sheet = nominal_sheet(&mount(), 0.0, 0.0, 0.0).unwrap();
        let emitter = nominal_emitter(&mount(), 0.0);
        // The sheet holds the central ray (x = z) and the fan (y): a camera in it sees it
        // edge-on.
        let edge_on = Vector3::new(300.0, 200.0, 300.0);
        assert!(triangulation_volume(&emitter, &edge_on, &sheet) < 1e-6);
        // One across the arc sees it broadside: 100 mm of line × the distances involved.
        let broadside = Vector3::new(0.0, 800.0, 400.0);
        let v = triangulation_volume(&emitter, &broadside, &sheet);
        assert!(v > 1e6 && v.is_finite(), "{v}");
        let flat = Plane::through([0.0; 3], [0.0, 0.0, 1.0]).unwrap();
        assert_eq!(triangulation_volume(&emitter, &broadside, &flat), 0.0);
    }

    #[test]
    fn turning_the_table_turns_the_sheet_back_in_the_sample_frame() {
        // The arc at 90° with the table at 90° lights the sample as the arc at 0° with the
        // table at 0° does.
        let a = nominal_sheet(&mount(), 0.0, 1.5, 0.0).unwrap();
        let b = nominal_sheet(&mount(), 90.0, 1.5, 90.0).unwrap();
        for i in 0..3 {
            assert!((a.normal[i] - b.normal[i]).abs() < 1e-12, "{a:?} {b:?}");
        }
        assert!((a.d - b.d).abs() < 1e-9);
        let none = LaserMount {
            elevation_deg: 45.0,
            distance_mm: 0.0,
        };
        assert!(nominal_sheet(&none, 0.0, 0.0, 0.0).is_none());
    }
}
