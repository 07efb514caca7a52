//! Calibrated laser planes: for each laser position (colour, mount elevation and light-arc
//! angle) the sheet measured at one or more tilts, in the rig frame (turntable at 0°), and the
//! sheet at any tilt of a sweep from them. With two or more calibrated tilts the sheets of a
//! sweep form the pencil of planes through the tilt axis, which is where two calibrated sheets
//! meet: the sheet at tilt t turns from the first calibrated sheet toward the last by the
//! fraction of their angle that t is of their tilts (slerp of the normals, exact for a stepper
//! tilt). With one calibrated tilt the pivot is taken from the rig file (the nominal emitter
//! and the fan's horizontal direction), which is exact only for a unit mounted square.

use nalgebra::{Matrix3, Rotation3, SymmetricEigen, Unit, Vector3};
use serde::{Deserialize, Serialize};

use crate::ray_plane::Plane;

/// One calibrated sheet: the laser's plane at one tilt, rig frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibratedSheet {
    /// Tilt-axis angle the sheet was measured at, degrees.
    pub tilt_deg: f64,
    /// The plane, rig frame, normal pointing the way the nominal sheet's does.
    pub plane: Plane,
    /// Points on the low plane of the fixture that fitted.
    pub points_low: usize,
    /// Points on the raised plane that fitted.
    pub points_high: usize,
    /// RMS distance of the fitted points from the plane, mm.
    pub rms_mm: f64,
    /// Cameras whose frames gave points.
    pub cameras: Vec<String>,
}

/// One laser position's calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserPosition {
    /// Laser colour, nm.
    pub colour_nm: u32,
    /// Mount elevation on the light arc, degrees (as the script recorded it).
    pub mount_deg: f64,
    /// Light-arc angle, degrees.
    pub light_arc_deg: f64,
    /// The calibrated sheets, by tilt ascending (distinct tilts).
    pub sheets: Vec<CalibratedSheet>,
    /// The rig file's emitter position, rig frame, mm: the pivot when one tilt was measured.
    pub nominal_emitter_mm: [f64; 3],
    /// The rig file's fan direction (the arc's horizontal tangent), rig frame.
    pub nominal_fan: [f64; 3],
    /// Angle between the first calibrated sheet and the nominal sheet at its tilt, degrees.
    pub nominal_angle_deg: f64,
    /// With three or more tilts: the largest angle (degrees) and offset at the rig origin (mm)
    /// of a middle sheet from the pencil through the first and last, a check of the model.
    pub pencil_check: Option<[f64; 2]>,
    /// Tilts left out and why (the line missed the fixture there).
    #[serde(default)]
    pub skipped: Vec<String>,
}

/// Every laser position calibrated from one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct LaserPlanes {
    /// The positions, by colour, mount and arc angle.
    pub positions: Vec<LaserPosition>,
}

/// The fixture of the laser-plane calibration frames, which are not sweeps of the sample.
pub const PLANES_FIXTURE: &str = "planes";

/// Two angles in degrees name the same setting when closer than this (recorded angles are
/// commanded ones, printed with at most a few decimals).
pub const SAME_ANGLE_DEG: f64 = 0.005;

/// Whether two angles are the same setting, modulo 360°.
pub fn same_angle(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d) < SAME_ANGLE_DEG
}

/// The angle between two planes' normals in degrees, ignoring their sign.
pub fn angle_between(a: &Plane, b: &Plane) -> f64 {
    let dot = Vector3::from(a.normal).dot(&Vector3::from(b.normal)).abs();
    let cross = Vector3::from(a.normal)
        .cross(&Vector3::from(b.normal))
        .norm();
    cross.atan2(dot).to_degrees()
}

/// `plane` with its normal turned to agree with `reference`'s (the same plane).
pub fn oriented_like(plane: Plane, reference: &Plane) -> Plane {
    if Vector3::from(plane.normal).dot(&Vector3::from(reference.normal)) < 0.0 {
        Plane {
            normal: (-Vector3::from(plane.normal)).into(),
            d: -plane.d,
        }
    } else {
        plane
    }
}

/// A plane of the rig frame seen from the sample frame with the turntable at `turntable_deg`.
pub fn rig_to_sample(plane: &Plane, turntable_deg: f64) -> Plane {
    let to_sample = Rotation3::from_axis_angle(&Vector3::z_axis(), -turntable_deg.to_radians());
    Plane {
        normal: (to_sample * Vector3::from(plane.normal)).into(),
        d: plane.d,
    }
}

/// A plane of the sample frame (turntable at `turntable_deg`) in the rig frame.
pub fn sample_to_rig(plane: &Plane, turntable_deg: f64) -> Plane {
    rig_to_sample(plane, -turntable_deg)
}

impl LaserPosition {
    /// Whether this is the position of a sweep's frames.
    pub fn matches(&self, colour_nm: u32, mount_deg: f64, light_arc_deg: f64) -> bool {
        self.colour_nm == colour_nm
            && same_angle(self.mount_deg, mount_deg)
            && same_angle(self.light_arc_deg, light_arc_deg)
    }

    /// The sheet at `tilt_deg`, rig frame; `None` without calibrated sheets or for a
    /// degenerate pivot.
    pub fn sheet(&self, tilt_deg: f64) -> Option<Plane> {
        let first = self.sheets.first()?;
        let last = self.sheets.last()?;
        if self.sheets.len() >= 2 && last.tilt_deg > first.tilt_deg {
            let s = (tilt_deg - first.tilt_deg) / (last.tilt_deg - first.tilt_deg);
            return Some(pencil(&first.plane, &last.plane, s));
        }
        // One tilt: turn about the nominal fan direction, projected into the sheet, through
        // the nominal emitter projected onto it.
        let n = Vector3::from(first.plane.normal);
        let e = Vector3::from(self.nominal_emitter_mm);
        let pivot = e - n * (n.dot(&e) - first.plane.d);
        let fan = Vector3::from(self.nominal_fan);
        let axis = Unit::try_new(fan - n * n.dot(&fan), 1e-9)?;
        let turned =
            Rotation3::from_axis_angle(&axis, (tilt_deg - first.tilt_deg).to_radians()) * n;
        Plane::through(pivot.into(), turned.into())
    }
}

impl LaserPlanes {
    /// The calibrated position of a sweep's laser, if any.
    pub fn position(
        &self,
        colour_nm: u32,
        mount_deg: f64,
        light_arc_deg: f64,
    ) -> Option<&LaserPosition> {
        self.positions
            .iter()
            .find(|p| p.matches(colour_nm, mount_deg, light_arc_deg))
    }

    /// The sheet of a sweep frame in the sample frame (turntable at `turntable_deg`), or
    /// `None` when no calibrated position matches.
    pub fn sheet(
        &self,
        colour_nm: u32,
        mount_deg: f64,
        light_arc_deg: f64,
        tilt_deg: f64,
        turntable_deg: f64,
    ) -> Option<Plane> {
        let rig = self
            .position(colour_nm, mount_deg, light_arc_deg)?
            .sheet(tilt_deg)?;
        Some(rig_to_sample(&rig, turntable_deg))
    }
}

/// The plane of the pencil through `a` and `b` (normals oriented alike) at fraction `s` of the
/// angle from `a` to `b` (0 gives `a`, 1 gives `b`; outside extrapolates). Parallel planes
/// blend linearly.
pub fn pencil(a: &Plane, b: &Plane, s: f64) -> Plane {
    let (na, nb) = (Vector3::from(a.normal), Vector3::from(b.normal));
    let phi = na.cross(&nb).norm().atan2(na.dot(&nb));
    let (wa, wb) = if phi < 1e-9 {
        (1.0 - s, s)
    } else {
        (
            ((1.0 - s) * phi).sin() / phi.sin(),
            (s * phi).sin() / phi.sin(),
        )
    };
    let n = na * wa + nb * wb;
    let d = a.d * wa + b.d * wb;
    // Unit already for the slerp weights; normalise both for the linear blend.
    let len = n.norm();
    Plane {
        normal: (n / len).into(),
        d: d / len,
    }
}

/// The least-squares plane through `points` (total least squares: the normal is the direction
/// of least spread) and the spreads (standard deviations, mm) along its three principal
/// directions, smallest first; `None` for fewer than three points.
pub fn fit_plane(points: &[Vector3<f64>]) -> Option<(Plane, [f64; 3])> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let centroid = points.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for p in points {
        let q = p - centroid;
        cov += q * q.transpose();
    }
    cov /= n;
    let eigen = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eigen.eigenvalues[i].total_cmp(&eigen.eigenvalues[j]));
    let normal = eigen.eigenvectors.column(order[0]).into_owned();
    let spreads = order.map(|i| eigen.eigenvalues[i].max(0.0).sqrt());
    let plane = Plane::through(centroid.into(), normal.into())?;
    Some((plane, spreads))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(normal: [f64; 3], d: f64) -> Plane {
        let n = Vector3::from(normal).normalize();
        Plane {
            normal: n.into(),
            d: d / Vector3::from(normal).norm(),
        }
    }

    #[test]
    fn the_pencil_turns_about_the_line_the_two_sheets_share() {
        // Two planes through the line x = 100, z = 0 (along y), 8° apart.
        let a = Plane::through([100.0, 0.0, 0.0], [1.0, 0.0, 0.0]).unwrap();
        let tilt = 8f64.to_radians();
        let b = Plane::through([100.0, 0.0, 0.0], [tilt.cos(), 0.0, tilt.sin()]).unwrap();
        for s in [-0.5, 0.0, 0.25, 0.5, 1.0, 1.5] {
            let p = pencil(&a, &b, s);
            // Contains the shared line.
            for y in [-50.0, 0.0, 80.0] {
                let x = Vector3::new(100.0, y, 0.0);
                assert!((Vector3::from(p.normal).dot(&x) - p.d).abs() < 1e-9);
            }
            assert!(
                (angle_between(&a, &p) - (8.0 * s).abs()).abs() < 1e-9,
                "{s}"
            );
        }
        // Parallel sheets blend linearly.
        let c = plane([0.0, 0.0, 1.0], 10.0);
        let d = plane([0.0, 0.0, 1.0], 20.0);
        assert!((pencil(&c, &d, 0.3).d - 13.0).abs() < 1e-12);
    }

    #[test]
    fn the_fit_finds_the_plane_and_a_line_has_no_width() {
        let truth = plane([0.3, -0.2, 1.0], 5.0);
        let n = Vector3::from(truth.normal);
        let u = n.cross(&Vector3::x()).normalize();
        let v = n.cross(&u);
        let mut points = Vec::new();
        for i in 0..20 {
            for j in 0..3 {
                let p = n * truth.d + u * (i as f64 * 4.0 - 40.0) + v * (j as f64 * 10.0);
                points.push(p);
            }
        }
        let (fit, spread) = fit_plane(&points).unwrap();
        let fit = oriented_like(fit, &truth);
        assert!(angle_between(&fit, &truth) < 1e-9);
        assert!((fit.d - truth.d).abs() < 1e-9);
        assert!(spread[0] < 1e-9 && spread[1] > 5.0);
        // Points along one line: the second spread is zero, which callers refuse.
        let line: Vec<_> = (0..10).map(|i| u * f64::from(i)).collect();
        let (_, spread) = fit_plane(&line).unwrap();
        assert!(spread[1] < 1e-9);
        assert!(fit_plane(&line[..2]).is_none());
    }

    #[test]
    fn one_calibrated_tilt_turns_about_the_nominal_pivot() {
        // Emitter at x = 1000, z = 0, fan along y: the sheet x = 1000 − ... through the origin.
        let sheet = Plane::through([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]).unwrap();
        let position = LaserPosition {
            colour_nm: 650,
            mount_deg: 0.0,
            light_arc_deg: 0.0,
            sheets: vec![CalibratedSheet {
                tilt_deg: 0.0,
                plane: sheet,
                points_low: 10,
                points_high: 10,
                rms_mm: 0.0,
                cameras: vec![],
            }],
            nominal_emitter_mm: [1000.0, 0.0, 0.0],
            nominal_fan: [0.0, 1.0, 0.0],
            nominal_angle_deg: 0.0,
            pencil_check: None,
            skipped: Vec::new(),
        };
        let turned = position.sheet(2.0).unwrap();
        assert!((angle_between(&turned, &sheet) - 2.0).abs() < 1e-9);
        // Still through the emitter.
        let e = Vector3::new(1000.0, 0.0, 0.0);
        assert!((Vector3::from(turned.normal).dot(&e) - turned.d).abs() < 1e-9);
        assert!(position.matches(650, 360.0, 0.001));
        assert!(!position.matches(532, 0.0, 0.0));
    }
}
