//! The linear-light reflectometer's tube as the Ward fit sees it (Gardner et al. 2003; seed
//! 004 §2.4): a line of `length_mm` parallel to y, centred on y = 0, `height_mm` above the flat
//! sample (z = 0, normal +z) at x = `tube_x` (the cart position less half the travel). The tape
//! on its sides makes it emit downward, Lambert about −z. A point of the sample seen along
//! `wo` then reflects, per unit of the tube's intensity per millimetre,
//!
//!   L = ρd/π·D + ρs·S(α),  D = ∫ emit·cosθi/r² dl = ∫ h²/r⁴ dl,  S(α) = ∫ h²/r⁴·ψ(wi, wo; α) dl,
//!
//! both linear in the ρ's, so the fit solves them in closed form for each α. D has a closed
//! form; S is integrated by Gauss–Legendre panels on the window where the lobe is not
//! negligible, about the point of the tube the mirror direction meets.

use nalgebra::Vector3;

use crate::ward::MIN_COS;

/// Gauss–Legendre nodes and weights on [−1, 1], 8 points.
const GL_NODES: [f64; 4] = [
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
const GL_WEIGHTS: [f64; 4] = [
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_5,
    0.101_228_536_290_376_3,
];
/// The specular window's half-width in lobe widths (about e^−16 beyond: S within 10⁻⁵ of its
/// peak, far below a sensor's noise).
const WINDOW_WIDTHS: f64 = 4.0;
/// Panels per lobe width (8 nodes over two widths integrate the Gaussian-like lobe to
/// 10⁻⁸), and at most this many panels in all.
const PANELS_PER_WIDTH: f64 = 0.5;
const MAX_PANELS: usize = 256;
/// tan²δ/α² at the tube's closest approach to the mirror point beyond which S is 0
/// (e^−20 ≈ 2·10⁻⁹ of the peak).
const NEGLIGIBLE_EXPONENT: f64 = 20.0;

/// The tube's fixed geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tube {
    /// Height of the tube's axis above the sample, mm.
    pub height_mm: f64,
    /// Length of the emitting tube, mm.
    pub length_mm: f64,
    /// Radius of its glass, mm: the camera cannot see a point whose ray passes the tube's axis
    /// closer than this.
    pub radius_mm: f64,
}

/// A sample point and the direction to the camera that sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewPoint {
    /// The point on the sample plane (z = 0), mm.
    pub p: Vector3<f64>,
    /// Unit direction from the point to the camera.
    pub wo: Vector3<f64>,
}

impl ViewPoint {
    /// The point `p` seen from a camera centred at `camera` (both in mm, sample frame).
    pub fn seen_from(p: Vector3<f64>, camera: Vector3<f64>) -> Option<ViewPoint> {
        let wo = (camera - p).try_normalize(1e-12)?;
        (wo.z > 0.0).then_some(ViewPoint { p, wo })
    }

    /// Where the mirror direction of `wo` meets the tube's height: (x, y), mm. The specular
    /// peak of a cart sweep is at tube x = this x, on the tube at y = this y.
    pub fn mirror_point(&self, height_mm: f64) -> (f64, f64) {
        let t = height_mm / self.wo.z.max(1e-9);
        (self.p.x - self.wo.x * t, self.p.y - self.wo.y * t)
    }
}

/// How far beyond the glass a ray must pass for its point to count as seen (a pixel's
/// footprint and the glass's rim), mm.
const HIDE_MARGIN_MM: f64 = 2.0;

impl Tube {
    /// Whether the tube at `tube_x` stands between the point and the camera (within
    /// [`HIDE_MARGIN_MM`] of its glass): such a sample shows the tube, not the sample.
    pub fn hides(&self, view: &ViewPoint, tube_x: f64) -> bool {
        let h = self.height_mm - view.p.z;
        if view.wo.z <= 0.0 || h <= 0.0 {
            return false;
        }
        // The axis is parallel to y: the distance between the ray and the axis is the
        // distance in the xz-plane from the axis to the ray's projection.
        let (dx, dz) = (view.wo.x, view.wo.z);
        let along = (dx * dx + dz * dz).sqrt();
        let distance = ((tube_x - view.p.x) * dz - h * dx).abs() / along;
        // Where the ray passes the axis' height: within the tube's length?
        let y = view.p.y + view.wo.y * h / dz;
        distance < self.radius_mm + HIDE_MARGIN_MM
            && y.abs() <= 0.5 * self.length_mm + self.radius_mm
    }

    /// D: the diffuse integral ∫ h²/r⁴ dl over the tube at `tube_x` (closed form).
    pub fn diffuse(&self, view: &ViewPoint, tube_x: f64) -> f64 {
        let h = self.height_mm - view.p.z;
        let dx = tube_x - view.p.x;
        let a2 = dx * dx + h * h;
        let a = a2.sqrt();
        // ∫ du/(a²+u²)² = u/(2a²(a²+u²)) + atan(u/a)/(2a³)
        let prim = |u: f64| u / (2.0 * a2 * (a2 + u * u)) + (u / a).atan() / (2.0 * a2 * a);
        let (u0, u1) = (
            -0.5 * self.length_mm - view.p.y,
            0.5 * self.length_mm - view.p.y,
        );
        (h * h * (prim(u1) - prim(u0))).max(0.0)
    }

    /// S(α): the specular integral ∫ h²/r⁴·ψ(wi, wo; α) dl over the tube at `tube_x`.
    pub fn specular(&self, view: &ViewPoint, tube_x: f64, alpha: f64) -> f64 {
        let (_, y_mirror) = view.mirror_point(self.height_mm);
        let half = 0.5 * self.length_mm;
        let centre = y_mirror.clamp(-half, half);
        let q = |l: f64| Vector3::new(tube_x, l, self.height_mm);
        // The lobe's closest approach: past it, nothing.
        let closest = q(centre) - view.p;
        let Some(wi) = closest.try_normalize(1e-12) else {
            return 0.0;
        };
        let hv = wi + view.wo;
        let hn = hv.z;
        if hn.is_nan() || hn <= 0.0 {
            return 0.0;
        }
        let tan2 = (hv.norm_squared() - hn * hn).max(0.0) / (hn * hn);
        let alpha = alpha.max(crate::ward::MIN_ALPHA);
        if tan2 / (alpha * alpha) > NEGLIGIBLE_EXPONENT {
            return 0.0;
        }
        // Along the tube, δ grows about Δl/(2r): the lobe is 2rα wide in l.
        let width = 2.0 * closest.norm() * alpha;
        let (lo, hi) = (
            (centre - WINDOW_WIDTHS * width).max(-half),
            (centre + WINDOW_WIDTHS * width).min(half),
        );
        if hi <= lo {
            return 0.0;
        }
        let panels = (((hi - lo) / width * PANELS_PER_WIDTH).ceil() as usize).clamp(4, MAX_PANELS);
        let step = (hi - lo) / panels as f64;
        let h2 = (self.height_mm - view.p.z).powi(2);
        // ψ of `ward_iso` with n = +z, inlined: its normalisation over the node's cos θi, and
        // the exponential in f32 (seven digits, far below a sensor's noise), which is most of
        // the fit's time.
        let (wo, alpha2) = (view.wo, alpha * alpha);
        let norm = 4.0 * std::f64::consts::PI * alpha2 * wo.z.max(MIN_COS).sqrt();
        let integrand = |l: f64| {
            let v = q(l) - view.p;
            let r2 = v.norm_squared();
            if r2 <= 1e-24 {
                return 0.0;
            }
            let wi = v / r2.sqrt();
            let (hx, hy, hn) = (wi.x + wo.x, wi.y + wo.y, wi.z + wo.z);
            if wi.z <= 0.0 || hn <= 0.0 {
                return 0.0;
            }
            let exponent = (hx * hx + hy * hy) / (hn * hn) / alpha2;
            if exponent >= 700.0 {
                return 0.0;
            }
            let psi = f64::from((-exponent as f32).exp()) / (norm * wi.z.max(MIN_COS).sqrt());
            h2 / (r2 * r2) * psi
        };
        let mut sum = 0.0;
        for k in 0..panels {
            let mid = lo + step * (k as f64 + 0.5);
            for (x, w) in GL_NODES.iter().zip(GL_WEIGHTS) {
                let d = 0.5 * step * x;
                sum += w * (integrand(mid - d) + integrand(mid + d));
            }
        }
        let s = 0.5 * step * sum;
        if s.is_finite() { s.max(0.0) } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ward::ward_iso;

    /// The rig's tube and a point seen from the reflectometer camera (60° elevation, −x side).
    fn setup() -> (Tube, ViewPoint) {
        let tube = Tube {
            height_mm: 60.0,
            length_mm: 300.0,
            radius_mm: 13.0,
        };
        let camera = Vector3::new(-300.0, 0.0, 300.0 * 3f64.sqrt());
        let view = ViewPoint::seen_from(Vector3::new(5.0, -12.0, 0.0), camera).expect("above");
        (tube, view)
    }

    /// The midpoint rule with `n` points: slow, but nothing to get wrong.
    fn brute(tube: &Tube, f: impl Fn(f64) -> f64, n: usize) -> f64 {
        let step = tube.length_mm / n as f64;
        (0..n)
            .map(|k| f(-0.5 * tube.length_mm + step * (k as f64 + 0.5)))
            .sum::<f64>()
            * step
    }

    fn integrand(
        tube: &Tube,
        view: &ViewPoint,
        tube_x: f64,
        alpha: Option<f64>,
    ) -> impl Fn(f64) -> f64 {
        let (tube, view) = (*tube, *view);
        move |l| {
            let v = Vector3::new(tube_x, l, tube.height_mm) - view.p;
            let r2 = v.norm_squared();
            let wi = v / r2.sqrt();
            let lobe = alpha.map_or(1.0, |a| ward_iso(&Vector3::z(), &wi, &view.wo, a));
            tube.height_mm.powi(2) / (r2 * r2) * lobe
        }
    }

    #[test]
    fn the_tube_hides_the_points_whose_ray_passes_its_glass() {
        let (tube, view) = setup();
        // The ray reaches the tube's height at `crossing`, and passes a tube Δx from there
        // at Δx·sin θ, θ its elevation in the xz-plane (about 60°); glass 13 mm + 2 mm margin.
        let crossing = view.p.x + view.wo.x * 60.0 / view.wo.z;
        let sin = view.wo.z / view.wo.x.hypot(view.wo.z);
        assert!(tube.hides(&view, crossing));
        assert!(
            tube.hides(&view, crossing + 14.5 / sin),
            "14.5 mm: inside glass + margin"
        );
        assert!(!tube.hides(&view, crossing - 15.5 / sin), "15.5 mm: clear");
        assert!(
            !tube.hides(&view, view.p.x + 34.64),
            "the mirror side is clear"
        );
        let short = Tube {
            length_mm: 10.0,
            ..tube
        };
        let aside = ViewPoint::seen_from(
            Vector3::new(5.0, 60.0, 0.0),
            Vector3::new(-300.0, 60.0, 520.0),
        )
        .expect("above");
        assert!(
            !short.hides(&aside, aside.p.x + aside.wo.x * 60.0 / aside.wo.z),
            "beyond its end"
        );
    }

    #[test]
    fn the_integrals_match_a_fine_midpoint_sum() {
        let (tube, view) = setup();
        let (xm, _) = view.mirror_point(tube.height_mm);
        for tube_x in [-120.0, xm - 20.0, xm - 2.0, xm, xm + 0.7, 100.0] {
            let d = tube.diffuse(&view, tube_x);
            let d_ref = brute(&tube, integrand(&tube, &view, tube_x, None), 200_000);
            assert!(
                (d / d_ref - 1.0).abs() < 1e-7,
                "D at {tube_x}: {d} vs {d_ref}"
            );
            for alpha in [0.01, 0.05, 0.3, 1.0] {
                let s = tube.specular(&view, tube_x, alpha);
                let s_ref = brute(&tube, integrand(&tube, &view, tube_x, Some(alpha)), 400_000);
                let scale = tube.specular(&view, xm, alpha);
                assert!(
                    (s - s_ref).abs() <= 1e-5 * scale,
                    "S at {tube_x}, α {alpha}: {s} vs {s_ref} (peak {scale})"
                );
            }
        }
    }

    #[test]
    fn a_mirror_point_beyond_the_tube_end_and_grazing_views_stay_finite() {
        let tube = Tube {
            height_mm: 60.0,
            length_mm: 300.0,
            radius_mm: 13.0,
        };
        // Seen from far along +y: the mirror point lies beyond the tube's −y end.
        let view =
            ViewPoint::seen_from(Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.0, 1000.0, 10.0))
                .expect("above");
        for alpha in [1e-6, 0.01, 0.2, 5.0, f64::NAN] {
            for x in [-100.0, 0.0, 100.0] {
                let s = tube.specular(&view, x, alpha);
                assert!(s.is_finite() && s >= 0.0, "{s}");
                assert!(tube.diffuse(&view, x).is_finite());
            }
        }
        assert!(ViewPoint::seen_from(Vector3::zeros(), Vector3::new(1.0, 0.0, -1.0)).is_none());
    }
}
