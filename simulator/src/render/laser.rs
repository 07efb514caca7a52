//! The line laser's sheet of light: its plane from the arc angle, mount elevation and tilt,
//! the Gaussian irradiance profile across it, and the camera's colour response to its line.

use glam::Vec3A;
use stagehand_devices::rig::LaserSpec;

use super::geometry::{ToSample, horizontal_tangent, rotate_about, spherical};
use crate::as_built::LaserAsBuilt;
use crate::world_snapshot::LaserBeam;

/// Half of the fan's opening angle within the sheet.
pub const FAN_HALF_ANGLE_DEG: f32 = 30.0;
/// Peak irradiance per milliwatt at `distance_mm` for a 0.4 mm sheet, in units of the
/// reference lamp's irradiance (power 1 at 800 mm): a 10 mW line is ~50× a halogen lamp.
const IRRADIANCE_PER_MW: f32 = 5.0;
/// Sheet half-width the constant above is quoted for.
const REFERENCE_HALF_WIDTH_MM: f32 = 0.4;

/// The laser sheet in the sample frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserSheet {
    /// Position of the emitter (the fan's apex).
    pub origin: Vec3A,
    /// Central ray direction (unit).
    pub centre: Vec3A,
    /// Direction the fan spreads along and the tilt axis (unit; horizontal in the world
    /// unless the unit as built is rolled).
    pub fan_axis: Vec3A,
    /// Unit normal of the sheet plane.
    pub normal: Vec3A,
    /// 1/e² half-thickness of the sheet.
    pub half_width_mm: f32,
    /// Peak irradiance at the reference distance, in reference-lamp units.
    pub peak: f32,
    /// Emitter distance from the origin: the distance at which `peak` applies.
    pub ref_distance_mm: f32,
    /// Camera RGB response to the laser wavelength.
    pub camera_rgb: Vec3A,
    /// Weights that turn an RGB albedo into the reflectance at the laser wavelength.
    pub reflect_weights: Vec3A,
    cos_fan: f32,
}

impl LaserSheet {
    /// The sheet of `spec` emitting `beam`, with the light arc at `light_arc_deg`. Positive
    /// tilt turns the central ray upward about the arc tangent, moving the line away from the
    /// laser.
    pub fn new(
        spec: &LaserSpec,
        beam: &LaserBeam,
        light_arc_deg: f64,
        to_sample: ToSample,
    ) -> LaserSheet {
        LaserSheet::built(
            spec,
            beam,
            light_arc_deg,
            to_sample,
            &LaserAsBuilt::nominal(),
        )
    }

    /// The sheet as [`LaserSheet::new`] places it, with the unit as built: its mount off the
    /// marked elevation and the arc's azimuth, the tilt axis's zero off, and the whole unit
    /// (tilt axis and fan) rolled about its untilted central ray.
    pub fn built(
        spec: &LaserSpec,
        beam: &LaserBeam,
        light_arc_deg: f64,
        to_sample: ToSample,
        built: &LaserAsBuilt,
    ) -> LaserSheet {
        let origin = spherical(
            light_arc_deg + built.azimuth_deg,
            beam.mount_elevation_deg + built.elevation_deg,
            spec.distance_mm,
        );
        let aim = (-origin).normalize_or(-Vec3A::Z);
        let t = rotate_about(
            horizontal_tangent(light_arc_deg + built.azimuth_deg),
            aim,
            built.roll_deg.to_radians() as f32,
        );
        let centre = rotate_about(
            aim,
            t,
            (beam.tilt_deg + built.tilt_zero_deg).to_radians() as f32,
        );
        let normal = centre.cross(t).normalize_or(Vec3A::X);
        let width = spec.sheet_half_width_mm as f32;
        let rgb = camera_response(beam.colour_nm);
        LaserSheet {
            origin: to_sample.point(origin),
            centre: to_sample.dir(centre),
            fan_axis: to_sample.dir(t),
            normal: to_sample.dir(normal),
            half_width_mm: width,
            peak: IRRADIANCE_PER_MW * spec.power_mw as f32 * REFERENCE_HALF_WIDTH_MM
                / width.max(1.0e-3),
            ref_distance_mm: spec.distance_mm as f32,
            camera_rgb: rgb,
            reflect_weights: rgb / rgb.element_sum().max(1.0e-6),
            cos_fan: FAN_HALF_ANGLE_DEG.to_radians().cos(),
        }
    }

    /// Signed distance of `p` from the sheet plane in mm.
    #[inline]
    pub fn distance(&self, p: Vec3A) -> f32 {
        (p - self.origin).dot(self.normal)
    }

    /// How far from the sheet (in [`Self::distance`]) the sheet can still light a pixel
    /// footprint at `p`, seen from `eye` with samples `angle` radians apart, on a surface
    /// whose normal makes cosine `cos_view` with the view: three half-widths plus twice the
    /// footprint. The cosine counts as at least 0.05, so `cos_view = 0` gives the widest reach
    /// of any surface at `p`.
    #[inline]
    pub fn reach(&self, p: Vec3A, eye: Vec3A, angle: f32, cos_view: f32) -> f32 {
        self.reach_from((p - eye).length(), angle, cos_view)
    }

    /// [`Self::reach`] for a point `t` mm from the eye: grows with `t`, shrinks with the
    /// cosine (so the largest `t` and smallest cosine of a set bound all of theirs).
    #[inline]
    pub fn reach_from(&self, t: f32, angle: f32, cos_view: f32) -> f32 {
        3.0 * self.half_width_mm + 2.0 * t * angle / cos_view.max(0.05)
    }

    /// Irradiance at `p` on a surface square to the incoming ray (multiply by the cosine of
    /// incidence), the unit direction from `p` toward the emitter, and the distance to it.
    /// `footprint_var_mm2` is the variance of the sheet distance over the footprint (a relief
    /// texel): the Gaussian profile is averaged over it (energy-preserving), so a line thinner
    /// than a texel still shows. Zero outside the fan or more than three (effective)
    /// half-widths from the sheet.
    #[inline]
    pub fn irradiance(&self, p: Vec3A, footprint_var_mm2: f32) -> (f32, Vec3A, f32) {
        let sigma2 = 0.25 * self.half_width_mm * self.half_width_mm;
        let var = sigma2 + footprint_var_mm2.max(0.0);
        // Three half-widths (= 6σ) on either side.
        self.lit(p, 36.0 * var, |d| {
            (sigma2 / var).sqrt() * (-0.5 * d * d / var).exp()
        })
    }

    /// [`Self::irradiance`] averaged exactly over a pixel sample's footprint, a parallelogram
    /// whose centre lies `shift` from `p` in sheet distance and across which the sheet distance
    /// runs ±`a`/2 and ±`b`/2 along its two edges: a line thinner than a pixel integrates over
    /// it as on a camera's pixel, where a variance-matched Gaussian would spread it into the
    /// neighbours.
    #[inline]
    pub fn irradiance_over(&self, p: Vec3A, shift: f32, a: f32, b: f32) -> (f32, Vec3A, f32) {
        let sigma = 0.5 * self.half_width_mm;
        let reach = 6.0 * sigma + 0.5 * (a.abs() + b.abs()) + shift.abs();
        self.lit(p, reach * reach, |d| {
            profile_over_footprint(d - shift, a, b, sigma)
        })
    }

    /// The sheet's irradiance at `p` with the profile `across` (of the sheet distance, zero
    /// where its square exceeds `reach2`), the direction toward the emitter and its distance.
    #[inline]
    fn lit(&self, p: Vec3A, reach2: f32, across: impl Fn(f32) -> f32) -> (f32, Vec3A, f32) {
        let v = p - self.origin;
        let d = v.dot(self.normal);
        if d * d > reach2 {
            return (0.0, Vec3A::Z, 0.0);
        }
        let r = v.length();
        if r <= 1.0e-3 {
            return (0.0, Vec3A::Z, 0.0);
        }
        // Angle from the central ray, measured within the sheet.
        let in_plane = v - self.normal * d;
        let along = in_plane.dot(self.centre);
        if along <= self.cos_fan * in_plane.length() {
            return (0.0, Vec3A::Z, 0.0);
        }
        (self.peak * across(d) * self.ref_distance_mm / r, -v / r, r)
    }

    /// Where the central ray crosses the plane z = `z`, if it descends.
    pub fn centre_hit(&self, z: f32) -> Option<Vec3A> {
        if self.centre.z >= 0.0 {
            return None;
        }
        let t = (z - self.origin.z) / self.centre.z;
        Some(self.origin + self.centre * t)
    }
}

/// Mean of the sheet's profile exp(−x²/2σ²) over x = `d` + u·`a` + v·`b`, u and v uniform in
/// [−½, ½], in closed form: a box along each footprint edge is a difference of the normal CDF
/// Φ, and the second box a difference of its integral Ψ(x) = x·Φ(x/σ) + σ·φ(x/σ). In f64; an
/// edge shorter than σ/1000 counts as a point. In [0, 1].
pub fn profile_over_footprint(d: f32, a: f32, b: f32, sigma: f32) -> f32 {
    let (d, s) = (d as f64, (sigma as f64).max(1.0e-9));
    let (a, b) = {
        let (a, b) = ((a as f64).abs(), (b as f64).abs());
        (a.max(b), a.min(b))
    };
    let small = 1.0e-3 * s;
    let root_2pi = (2.0 * std::f64::consts::PI).sqrt();
    let cdf = |x: f64| 0.5 * libm::erfc(-x / (s * std::f64::consts::SQRT_2));
    let value = if a < small {
        (-0.5 * d * d / (s * s)).exp()
    } else if b < small {
        s * root_2pi * (cdf(d + 0.5 * a) - cdf(d - 0.5 * a)) / a
    } else {
        let psi = |x: f64| x * cdf(x) + s / root_2pi * (-0.5 * x * x / (s * s)).exp();
        let (h, k) = (0.5 * a, 0.5 * b);
        let second = psi(d + h + k) - psi(d + h - k) - psi(d - h + k) + psi(d - h - k);
        s * root_2pi * second / (a * b)
    };
    if value.is_finite() {
        value.clamp(0.0, 1.0) as f32
    } else {
        0.0
    }
}

/// RGB response of the simulated cameras to monochromatic light of `nm`, interpolated
/// between anchors (650 nm → (1.0, 0.08, 0.02), 532 → (0.10, 1.0, 0.12), 473 → (0.02, 0.20, 1.0)).
pub fn camera_response(nm: u32) -> Vec3A {
    const ANCHORS: [(f32, [f32; 3]); 8] = [
        (380.0, [0.0, 0.0, 0.0]),
        (420.0, [0.03, 0.02, 0.5]),
        (473.0, [0.02, 0.20, 1.0]),
        (532.0, [0.10, 1.0, 0.12]),
        (590.0, [0.7, 0.55, 0.03]),
        (650.0, [1.0, 0.08, 0.02]),
        (720.0, [0.35, 0.02, 0.01]),
        (800.0, [0.0, 0.0, 0.0]),
    ];
    let x = nm as f32;
    for pair in ANCHORS.windows(2) {
        let ((x0, a), (x1, b)) = (pair[0], pair[1]);
        if x >= x0 && x <= x1 {
            let s = (x - x0) / (x1 - x0);
            return Vec3A::new(
                a[0] + (b[0] - a[0]) * s,
                a[1] + (b[1] - a[1]) * s,
                a[2] + (b[2] - a[2]) * s,
            );
        }
    }
    Vec3A::ZERO
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> LaserSpec {
        LaserSpec {
            id: "laser".into(),
            backend: stagehand_devices::rig::Backend::Sim,
            port: None,
            colours_nm: vec![650],
            fitted_nm: 650,
            tilt_axis: "tilt".into(),
            mount_elevation_deg: 45.0,
            distance_mm: 700.0,
            power_mw: 10.0,
            sheet_half_width_mm: 0.4,
            bank: None,
            channel: None,
        }
    }

    #[test]
    fn untilted_sheet_passes_through_the_origin_along_the_tangent() {
        let beam = LaserBeam {
            colour_nm: 650,
            tilt_deg: 0.0,
            mount_elevation_deg: 45.0,
        };
        let s = LaserSheet::new(&spec(), &beam, 0.0, ToSample::new(0.0));
        let (e0, _, _) = s.irradiance(Vec3A::ZERO, 0.0);
        let (e1, _, _) = s.irradiance(Vec3A::new(0.0, 30.0, 0.0), 0.0);
        let (e2, _, _) = s.irradiance(Vec3A::new(2.0, 0.0, 0.0), 0.0);
        assert!((e0 - 50.0).abs() < 0.5, "peak {e0}");
        assert!(e1 > 0.9 * e0, "the fan spreads along y");
        assert_eq!(e2, 0.0, "2 mm off the sheet is dark");
        assert!(s.centre_hit(0.0).is_some_and(|p| p.length() < 1e-3));
    }

    /// The closed form matches a fine numeric average over the footprint, for lines thinner
    /// and wider than the footprint, tiny and long edges, on and off the line; and the
    /// profile's integral across the sheet is σ√(2π) whatever the footprint (energy kept).
    #[test]
    fn footprint_average_is_exact_and_keeps_the_lines_energy() {
        let sigma = 0.2f32;
        let numeric = |d: f32, a: f32, b: f32| {
            let n = 400;
            let mut sum = 0.0f64;
            for i in 0..n {
                for j in 0..n {
                    let u = (i as f32 + 0.5) / n as f32 - 0.5;
                    let v = (j as f32 + 0.5) / n as f32 - 0.5;
                    let x = (d + u * a + v * b) as f64;
                    sum += (-0.5 * x * x / (sigma as f64).powi(2)).exp();
                }
            }
            sum / (n * n) as f64
        };
        for (d, a, b) in [
            (0.0, 0.0, 0.0),
            (0.1, 0.0, 0.0),
            (0.0, 2.0, 0.0),
            (0.3, 2.0, 1e-5),
            (0.0, 2.0, 1.5),
            (-0.7, 1.2, -0.8),
            (0.05, 0.1, 0.05),
            (1.3, 2.0, 1.0),
            (5.0, 0.5, 0.5),
        ] {
            let exact = profile_over_footprint(d, a, b, sigma) as f64;
            let approx = numeric(d, a, b);
            assert!(
                (exact - approx).abs() < 2e-4 + 1e-3 * approx,
                "d {d} a {a} b {b}: {exact} vs {approx}"
            );
        }
        for (a, b) in [(0.0, 0.0), (1.5, 0.0), (1.5, 0.7), (0.01, 3.0)] {
            let step = 0.005;
            let total: f64 = (-2000..=2000)
                .map(|k| profile_over_footprint(k as f32 * step, a, b, sigma) as f64 * step as f64)
                .sum();
            let expected = sigma as f64 * (2.0 * std::f64::consts::PI).sqrt();
            assert!((total / expected - 1.0).abs() < 1e-3, "{a} {b}: {total}");
        }
        assert_eq!(profile_over_footprint(f32::NAN, 1.0, 1.0, sigma), 0.0);
    }

    #[test]
    fn tilt_moves_the_line_away_from_the_laser() {
        let beam = LaserBeam {
            colour_nm: 650,
            tilt_deg: 2.0,
            mount_elevation_deg: 45.0,
        };
        let s = LaserSheet::new(&spec(), &beam, 0.0, ToSample::new(0.0));
        let hit = s.centre_hit(0.0).expect("descends");
        assert!(hit.x < -20.0, "{hit}");
    }

    #[test]
    fn a_unit_built_off_its_marks_moves_and_rolls_the_sheet() {
        let beam = LaserBeam {
            colour_nm: 650,
            tilt_deg: 0.0,
            mount_elevation_deg: 45.0,
        };
        let nominal = LaserSheet::new(&spec(), &beam, 0.0, ToSample::new(0.0));
        let same = LaserSheet::built(
            &spec(),
            &beam,
            0.0,
            ToSample::new(0.0),
            &LaserAsBuilt::nominal(),
        );
        assert_eq!(nominal, same);
        let rolled = LaserSheet::built(
            &spec(),
            &beam,
            0.0,
            ToSample::new(0.0),
            &LaserAsBuilt {
                roll_deg: 1.0,
                ..LaserAsBuilt::nominal()
            },
        );
        // Rolled about the central ray: the line still crosses the origin, at 1°/sin 45° to y.
        assert!(rolled.centre_hit(0.0).is_some_and(|p| p.length() < 1e-3));
        let line = rolled.normal.cross(Vec3A::Z).normalize();
        let angle = line.x.atan2(line.y).to_degrees().abs();
        let expected = (1f32.to_radians().tan() / 45f32.to_radians().sin())
            .atan()
            .to_degrees();
        assert!(
            (angle.min(180.0 - angle) - expected).abs() < 0.01,
            "{angle} vs {expected}"
        );
        let zero_off = LaserSheet::built(
            &spec(),
            &beam,
            0.0,
            ToSample::new(0.0),
            &LaserAsBuilt {
                tilt_zero_deg: 0.2,
                ..LaserAsBuilt::nominal()
            },
        );
        let tilted = LaserSheet::new(
            &spec(),
            &LaserBeam {
                tilt_deg: 0.2,
                ..beam
            },
            0.0,
            ToSample::new(0.0),
        );
        assert!((zero_off.normal - tilted.normal).length() < 1e-6);
    }

    #[test]
    fn response_matches_the_anchors() {
        let close = |a: Vec3A, b: Vec3A| (a - b).abs().max_element() < 1e-6;
        assert!(close(camera_response(650), Vec3A::new(1.0, 0.08, 0.02)));
        assert!(close(camera_response(532), Vec3A::new(0.10, 1.0, 0.12)));
        assert!(close(camera_response(473), Vec3A::new(0.02, 0.20, 1.0)));
        assert_eq!(camera_response(1064), Vec3A::ZERO);
    }
}
