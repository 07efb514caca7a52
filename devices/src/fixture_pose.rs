//! How an operator placed a fixture (the checkerboard, the colour checker, a sample) on the
//! turntable: tilted, turned and shifted from flat and centred. A calibration prompt asks for
//! a placement, the executor records it on every frame, and the simulator renders the fixture
//! so placed; it is the placement asked for, which a processing step may read as a hint (the
//! flat placement defines the reference plane), never the measured pose.

use serde::{Deserialize, Serialize};

/// A fixture's placement in the turntable frame (z up, x along the turntable's 0°): first
/// turned by `turn_deg` about its own normal, then tilted by `tilt_deg` so that its normal
/// leans toward azimuth `tilt_toward_deg`, then its centre moved to (`x_mm`, `y_mm`,
/// `lift_mm`). All zero is flat and centred.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FixturePose {
    /// Angle between the fixture's normal and the turntable's axis, degrees (0 = flat).
    pub tilt_deg: f64,
    /// Azimuth in the turntable frame toward which the normal leans, degrees.
    pub tilt_toward_deg: f64,
    /// Rotation about the fixture's own normal before tilting, degrees.
    pub turn_deg: f64,
    /// Centre offset along the turntable's x (0°) direction, millimetres.
    pub x_mm: f64,
    /// Centre offset along the turntable's y (90°) direction, millimetres.
    pub y_mm: f64,
    /// Height of the centre above the turntable (a tilted board rests on a stand), mm.
    pub lift_mm: f64,
}

/// Steepest tilt a placement may ask for: beyond it the cameras see the board edge-on.
pub const MAX_TILT_DEG: f64 = 80.0;

/// Farthest a fixture's centre may be moved from the turntable's centre, millimetres.
pub const MAX_OFFSET_MM: f64 = 500.0;

impl FixturePose {
    /// Flat and centred: the identity placement.
    pub fn is_flat_centred(&self) -> bool {
        *self == FixturePose::default()
    }

    /// The rotation from the fixture's frame into the turntable frame, row-major:
    /// Rz(toward) · Ry(tilt) · Rz(turn − toward).
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let rz = |deg: f64| {
            let (s, c) = deg.to_radians().sin_cos();
            [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        };
        let (s, c) = self.tilt_deg.to_radians().sin_cos();
        let ry = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]];
        mul(
            mul(rz(self.tilt_toward_deg), ry),
            rz(self.turn_deg - self.tilt_toward_deg),
        )
    }

    /// The fixture centre in the turntable frame, millimetres.
    pub fn offset_mm(&self) -> [f64; 3] {
        [self.x_mm, self.y_mm, self.lift_mm]
    }

    /// A point of the fixture (its frame, mm) in the turntable frame.
    pub fn to_turntable(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotation();
        let o = self.offset_mm();
        std::array::from_fn(|i| o[i] + (0..3).map(|j| r[i][j] * p[j]).sum::<f64>())
    }

    /// What is wrong with this placement, if anything: a non-finite number, a tilt beyond
    /// [`MAX_TILT_DEG`] or below 0, an offset beyond [`MAX_OFFSET_MM`].
    pub fn problem(&self) -> Option<String> {
        let fields = [
            ("tilt_deg", self.tilt_deg),
            ("tilt_toward_deg", self.tilt_toward_deg),
            ("turn_deg", self.turn_deg),
            ("x_mm", self.x_mm),
            ("y_mm", self.y_mm),
            ("lift_mm", self.lift_mm),
        ];
        if let Some((name, v)) = fields.iter().find(|(_, v)| !v.is_finite()) {
            return Some(format!("{name} is {v}; give a finite number"));
        }
        if !(0.0..=MAX_TILT_DEG).contains(&self.tilt_deg) {
            return Some(format!(
                "tilt_deg {} is outside 0…{MAX_TILT_DEG}° (lean the other way with tilt_toward_deg)",
                self.tilt_deg
            ));
        }
        let reach = self.x_mm.hypot(self.y_mm).max(self.lift_mm.abs());
        if reach > MAX_OFFSET_MM {
            return Some(format!(
                "the centre is {reach:.0} mm from the turntable's centre; at most {MAX_OFFSET_MM} mm"
            ));
        }
        None
    }

    /// A short human description, e.g. "tilted 30° toward 90°, turned 45°, at (10, 0, 20) mm".
    pub fn describe(&self) -> String {
        if self.is_flat_centred() {
            return "flat and centred".into();
        }
        let mut parts = Vec::new();
        if self.tilt_deg != 0.0 {
            parts.push(format!(
                "tilted {}° toward {}°",
                self.tilt_deg, self.tilt_toward_deg
            ));
        } else {
            parts.push("flat".into());
        }
        if self.turn_deg != 0.0 {
            parts.push(format!("turned {}°", self.turn_deg));
        }
        if self.offset_mm() != [0.0; 3] {
            parts.push(format!(
                "centre at ({}, {}, {}) mm",
                self.x_mm, self.y_mm, self.lift_mm
            ));
        }
        parts.join(", ")
    }
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn near(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn flat_centred_is_the_identity() {
        let p = FixturePose::default();
        assert!(p.is_flat_centred());
        assert!(near(p.to_turntable([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]));
        assert_eq!(p.describe(), "flat and centred");
        assert!(p.problem().is_none());
    }

    #[test]
    fn the_normal_leans_toward_the_asked_azimuth() {
        let p = FixturePose {
            tilt_deg: 30.0,
            tilt_toward_deg: 90.0,
            ..FixturePose::default()
        };
        let r = p.rotation();
        let normal = [r[0][2], r[1][2], r[2][2]];
        let s = 30f64.to_radians().sin();
        let c = 30f64.to_radians().cos();
        assert!(near(normal, [0.0, s, c]), "{normal:?}");
        // The tilt axis (perpendicular to the lean) stays horizontal and in place.
        assert!(near(p.to_turntable([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]));
    }

    #[test]
    fn turn_is_about_the_fixture_normal_and_the_offset_moves_the_centre() {
        let p = FixturePose {
            turn_deg: 90.0,
            x_mm: 10.0,
            lift_mm: 5.0,
            ..FixturePose::default()
        };
        assert!(near(p.to_turntable([1.0, 0.0, 0.0]), [10.0, 1.0, 5.0]));
        assert!(near(p.to_turntable([0.0, 0.0, 0.0]), [10.0, 0.0, 5.0]));
    }

    #[test]
    fn bad_placements_say_what_is_wrong() {
        let steep = FixturePose {
            tilt_deg: 85.0,
            ..FixturePose::default()
        };
        assert!(steep.problem().expect("too steep").contains("tilt_deg 85"));
        let nan = FixturePose {
            x_mm: f64::NAN,
            ..FixturePose::default()
        };
        assert!(nan.problem().expect("nan").contains("x_mm"));
        let far = FixturePose {
            y_mm: 900.0,
            ..FixturePose::default()
        };
        assert!(far.problem().expect("far").contains("900 mm"));
    }

    #[test]
    fn unknown_fields_are_refused_and_missing_ones_default() {
        let p: FixturePose = serde_json::from_str(r#"{"tilt_deg": 20}"#).expect("parses");
        assert_eq!(p.tilt_deg, 20.0);
        assert!(serde_json::from_str::<FixturePose>(r#"{"tilt": 20}"#).is_err());
    }
}
