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
//! negligible, about the lobe's peak along the tube ([`Tube::lobe`], found once per stop
//! and pixel, whatever α), with its slope in α beside it (the fit's search steps by it).
//! The nodes run branch-free in vector lanes: the fit's time is almost all here.

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
/// Panels per lobe width (plus α/2: a wide lobe is less like a Gaussian), at least
/// [`MIN_PANELS`] and at most [`MAX_PANELS`]: S within 10⁻⁵ of its peak
/// (`the_integrals_match_a_fine_midpoint_sum`). Plus α (the earlier rule) was as accurate with
/// a third more panels.
const PANELS_PER_WIDTH: f64 = 0.25;
const PANELS_PER_WIDTH_AND_ALPHA: f64 = 0.75;
const MIN_PANELS: usize = 2;
const MAX_PANELS: usize = 256;
/// tan²δ/α² at the lobe's centre beyond which S is 0 (e^−16 ≈ 10⁻⁷ of the peak, where the
/// tube is as far; a stop nearer the point may see 100 times more of the lobe's tail).
const NEGLIGIBLE_EXPONENT: f64 = 16.0;

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

/// How closely [`Tube::specular_of`] integrates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quadrature {
    /// Within 10⁻⁵ of the sweep's peak: what the fit's answer rests on.
    Fine,
    /// One 8-node panel over the lobe: rougher, used only to find the basin of α, at a
    /// fraction of the cost.
    Coarse,
}

/// One stop's specular lobe along the tube, whatever α ([`Tube::lobe`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lobe {
    /// The tube's x, mm.
    tube_x: f64,
    /// Where along the tube the lobe peaks, mm (within the tube).
    centre: f64,
    /// d²tan²δ/dl² there, where tan²δ grows.
    curvature: Option<f64>,
    /// Distance from the point to the tube's point there, mm.
    distance: f64,
    /// tan²δ there (infinite where the lobe is not seen).
    tan2: f64,
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

    /// Where along the tube at `tube_x` the lobe peaks (least tan²δ), and how fast tan²δ
    /// grows there (d²tan²δ/dl², `None` where it does not): the lobe's centre and width. It
    /// starts from the point whose direction from the sample point is nearest the mirror
    /// direction m of `wo`: with v = (vx, u, h) and u = l − p.y, cos∠(v, m) =
    /// (A + m_y·u)/√(C + u²), A = vx·m_x + h·m_z, C = vx² + h², is largest at u = m_y·C/A.
    /// Two Newton steps on tan²δ then move it to the peak (the half vector weighs the two
    /// directions across the lobe unequally). At the mirror stop this is the mirror point's
    /// y; away from it, for a camera off the tube's plane, the lobe moves along the tube and
    /// widens.
    fn lobe_centre(&self, view: &ViewPoint, tube_x: f64) -> (f64, Option<f64>) {
        let h = self.height_mm - view.p.z;
        let vx = tube_x - view.p.x;
        let wo = view.wo;
        let (mx, my, mz) = (-wo.x, -wo.y, wo.z);
        let a = vx * mx + h * mz;
        let c = vx * vx + h * h;
        if a.is_nan() || a <= 1e-9 * (vx.abs() + h) {
            return (view.mirror_point(self.height_mm).1, None);
        }
        let tan2 = |u: f64| tan2_along(view, h, vx, u);
        let mut u = my * c / a;
        let step = 1e-3 * c.sqrt();
        let mut curvature = None;
        for _ in 0..2 {
            let (below, at, above) = (tan2(u - step), tan2(u), tan2(u + step));
            let second = (above - 2.0 * at + below) / (step * step);
            if !(second > 0.0 && second.is_finite()) {
                curvature = None;
                break;
            }
            curvature = Some(second);
            // A step that does not lower tan²δ (far from the peak, where tan²δ is not a
            // parabola) is not taken.
            let next = u - 0.5 * (above - below) / step / second;
            if !(next.is_finite() && tan2(next) < at) {
                break;
            }
            u = next;
        }
        (view.p.y + u, curvature)
    }

    /// S(α): the specular integral ∫ h²/r⁴·ψ(wi, wo; α) dl over the tube at `tube_x`.
    pub fn specular(&self, view: &ViewPoint, tube_x: f64, alpha: f64) -> f64 {
        self.specular_slope(view, tube_x, alpha).0
    }

    /// S(α) and its slope dS/d(ln α) over the tube at `tube_x`: the fit's search in α steps
    /// by the slope, which costs one multiply per node beside S.
    pub fn specular_slope(&self, view: &ViewPoint, tube_x: f64, alpha: f64) -> (f64, f64) {
        self.specular_of(view, &self.lobe(view, tube_x), alpha, Quadrature::Fine)
    }

    /// The lobe of the tube at `tube_x` as seen from `view`, whatever α: computed once per
    /// stop and pixel, it serves every α the fit tries.
    pub fn lobe(&self, view: &ViewPoint, tube_x: f64) -> Lobe {
        let half = 0.5 * self.length_mm;
        let (centre, curvature) = self.lobe_centre(view, tube_x);
        let centre = centre.clamp(-half, half);
        let h = self.height_mm - view.p.z;
        let vx = tube_x - view.p.x;
        let distance = (Vector3::new(tube_x, centre, self.height_mm) - view.p).norm();
        // A tube below the point, or a camera below the sample, sees no lobe.
        let tan2 = if h > 0.0 && view.wo.z > 0.0 {
            tan2_along(view, h, vx, centre - view.p.y)
        } else {
            f64::INFINITY
        };
        Lobe {
            tube_x,
            centre,
            curvature,
            distance,
            tan2: if tan2.is_nan() { f64::INFINITY } else { tan2 },
        }
    }

    /// S(α) and dS/d(ln α) of a [`Tube::lobe`] of this point, to `quadrature`'s accuracy.
    pub fn specular_of(
        &self,
        view: &ViewPoint,
        lobe: &Lobe,
        alpha: f64,
        quadrature: Quadrature,
    ) -> (f64, f64) {
        let half = 0.5 * self.length_mm;
        let h = self.height_mm - view.p.z;
        let Lobe {
            tube_x,
            centre,
            curvature,
            distance,
            tan2,
        } = *lobe;
        let alpha = if alpha.is_nan() {
            crate::ward::MIN_ALPHA
        } else {
            alpha.max(crate::ward::MIN_ALPHA)
        };
        // Past the lobe (or where it is not seen), nothing.
        let exponent = tan2 / (alpha * alpha);
        if exponent.is_nan() || exponent > NEGLIGIBLE_EXPONENT {
            return (0.0, 0.0);
        }
        // The lobe is a Gaussian in l of standard deviation α/√(d²tan²δ/dl²) near its
        // peak, √2 times which is its width; in the plane of incidence, where δ grows as
        // Δl/(2r), that is 2rα. The window spans the wider of the two, the panels are as
        // dense as the narrower, or the falloff h²/r⁴, needs (a wide lobe is far from a
        // Gaussian).
        let in_plane = 2.0 * distance * alpha;
        let curved = curvature.map_or(in_plane, |k| {
            (std::f64::consts::SQRT_2 * alpha / k.sqrt()).min(self.length_mm)
        });
        // No wider than the tube's own falloff (h²/r⁴, about r) for the panels.
        let narrow = in_plane.min(curved).min(distance);
        let wide = in_plane.max(curved);
        let (lo, hi) = (
            (centre - WINDOW_WIDTHS * wide).max(-half),
            (centre + WINDOW_WIDTHS * wide).min(half),
        );
        if hi <= lo {
            return (0.0, 0.0);
        }
        // A wide lobe is far from a Gaussian in l: more panels as α grows.
        let panels = match quadrature {
            Quadrature::Fine => (((hi - lo) / narrow
                * (PANELS_PER_WIDTH + PANELS_PER_WIDTH_AND_ALPHA * alpha))
                .ceil() as usize)
                .clamp(MIN_PANELS, MAX_PANELS),
            Quadrature::Coarse => 1,
        };
        let step = (hi - lo) / panels as f64;
        // ψ of `ward_iso` with n = +z, inlined and rearranged so that each node costs two
        // square roots, two divisions and [`exp_neg`] (seven digits, far below a sensor's
        // noise). With v = q − p, r = |v| and wi = v/r, cos θi = h/r, and
        //   h²/r⁴ · 1/√cos θi = h^1.5 · r^−3.5,
        //   tan²δ = ((vx + wo.x·r)² + (vy + wo.y·r)²) / (h + wo.z·r)².
        let wo = view.wo;
        let inv_alpha2 = 1.0 / (alpha * alpha);
        let scale =
            h * h.sqrt() / (4.0 * std::f64::consts::PI * alpha * alpha * wo.z.max(MIN_COS).sqrt());
        let stop = StopGeometry {
            vx: tube_x - view.p.x,
            h,
            py: view.p.y,
            wo: [wo.x, wo.y, wo.z],
            inv_alpha2,
        };
        let (sum, slope) = node_sums(&stop, lo, step, panels);
        let (s, ds) = (0.5 * step * scale * sum, 0.5 * step * scale * slope);
        if s.is_finite() && ds.is_finite() {
            (s.max(0.0), ds)
        } else {
            (0.0, 0.0)
        }
    }
}

/// tan²δ of the tube's point `u` mm along it from the point's y, the tube `vx` mm off in x
/// and `h` mm above: with v = (vx, u, h), r = |v| and wi = v/r, the half vector wi + wo scaled
/// by r is (vx + wo.x·r, u + wo.y·r, h + wo.z·r).
fn tan2_along(view: &ViewPoint, h: f64, vx: f64, u: f64) -> f64 {
    let wo = view.wo;
    let r = (vx * vx + h * h + u * u).sqrt();
    let (hx, hy, hz) = (vx + wo.x * r, u + wo.y * r, h + wo.z * r);
    (hx * hx + hy * hy) / (hz * hz)
}

/// What the nodes of one stop share: the tube's offset from the point in x, its height
/// above it, the point's y, the direction to the camera and 1/α².
struct StopGeometry {
    vx: f64,
    h: f64,
    py: f64,
    wo: [f64; 3],
    inv_alpha2: f64,
}

/// Σ w·e and Σ w·e·(2T/α² − 2) over `panels` Gauss–Legendre panels of `step` from `lo`, e
/// the specular integrand without its constant factor: the fit's inner loop. Compiled for the
/// wide vector units too and chosen at run time (`multiversion`): the nodes of a panel run
/// in parallel lanes.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma"))]
fn node_sums(stop: &StopGeometry, lo: f64, step: f64, panels: usize) -> (f64, f64) {
    let StopGeometry {
        vx,
        h,
        py,
        wo,
        inv_alpha2,
    } = *stop;
    let vx2h2 = vx * vx + h * h;
    let (mut sum, mut slope) = (0.0, 0.0);
    const N: usize = 2 * GL_NODES.len();
    let (mut l, mut e, mut de) = ([0.0; N], [0.0; N], [0.0; N]);
    for k in 0..panels {
        let mid = lo + step * (k as f64 + 0.5);
        for (j, x) in GL_NODES.iter().enumerate() {
            l[2 * j] = mid - 0.5 * step * x;
            l[2 * j + 1] = mid + 0.5 * step * x;
        }
        // The panel's nodes without a branch, in parallel lanes.
        for ((l, e), de) in l.iter().zip(&mut e).zip(&mut de) {
            let vy = l - py;
            let r2 = vx2h2 + vy * vy;
            let r = r2.sqrt();
            let (hx, hy, hz) = (vx + wo[0] * r, vy + wo[1] * r, h + wo[2] * r);
            // hz > 0: the tube is above the sample and the camera too.
            let exponent = (hx * hx + hy * hy) / (hz * hz) * inv_alpha2;
            let value = exp_neg(exponent) / (r2 * r * r.sqrt());
            // d/d ln α of exp(−T/α²)/α² is that times 2T/α² − 2.
            *e = value;
            *de = value * (2.0 * exponent - 2.0);
        }
        for (j, w) in GL_WEIGHTS.iter().enumerate() {
            sum += w * (e[2 * j] + e[2 * j + 1]);
            slope += w * (de[2 * j] + de[2 * j + 1]);
        }
    }
    (sum, slope)
}

/// e^−t for t ≥ 0 to about 10⁻⁷ relative, and 0 (or a subnormal) beyond t = 708: a
/// polynomial on the reduced argument, scaled by 2ⁿ through the exponent bits, without a
/// branch or a library call, so that the tube's nodes evaluate in parallel lanes.
#[inline(always)]
fn exp_neg(t: f64) -> f64 {
    // Adding 1.5·2⁵² rounds to an integer, left in the low bits of the sum.
    const ROUND: f64 = 6_755_399_441_055_744.0;
    const LN2_HI: f64 = 0.693_147_180_369_123_8;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    let x = (-t).clamp(-708.0, 0.0);
    let k = x * std::f64::consts::LOG2_E + ROUND;
    let n = k - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    // Taylor to r⁷ on |r| ≤ ln2/2: within 2·10⁻⁹.
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r / 5040.0))))));
    // The low 12 bits of k's mantissa are n mod 4096; n + 1023 is the biased exponent.
    p * f64::from_bits(k.to_bits().wrapping_add(1023) << 52)
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
        }
        // S along a whole sweep, from the reflectometer camera and from a low one off the
        // tube's plane, over the α range the fit searches.
        let low = ViewPoint::seen_from(
            Vector3::new(-30.0, 25.0, 0.0),
            Vector3::new(-500.0, 80.0, 200.0),
        )
        .expect("above");
        for view in [view, low] {
            for alpha in [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.6, 1.0] {
                let sweep: Vec<(f64, f64, f64)> = (0..25)
                    .map(|k| {
                        let tube_x = -120.0 + 10.0 * k as f64 + 0.37;
                        let exact =
                            brute(&tube, integrand(&tube, &view, tube_x, Some(alpha)), 200_000);
                        (tube_x, tube.specular(&view, tube_x, alpha), exact)
                    })
                    .collect();
                let peak = sweep.iter().map(|s| s.2).fold(0.0f64, f64::max);
                for (tube_x, s, s_ref) in sweep {
                    assert!(
                        (s - s_ref).abs() <= 1e-5 * peak,
                        "S at {tube_x}, α {alpha}: {s} vs {s_ref} (peak {peak})"
                    );
                }
            }
        }
    }

    #[test]
    fn the_slope_in_alpha_matches_a_central_difference() {
        let (tube, view) = setup();
        let (xm, _) = view.mirror_point(tube.height_mm);
        for tube_x in [xm - 20.0, xm - 2.0, xm, xm + 5.0] {
            for alpha in [0.01, 0.05, 0.3, 1.0] {
                let (_, slope) = tube.specular_slope(&view, tube_x, alpha);
                let e = 1e-4;
                let central = (tube.specular(&view, tube_x, alpha * f64::exp(e))
                    - tube.specular(&view, tube_x, alpha * f64::exp(-e)))
                    / (2.0 * e);
                let scale = tube.specular(&view, xm, alpha);
                assert!(
                    (slope - central).abs() <= 1e-4 * scale,
                    "dS/dlnα at {tube_x}, α {alpha}: {slope} vs {central} (peak {scale})"
                );
            }
        }
    }

    #[test]
    fn the_branchless_exponential_matches_the_library_one() {
        let mut worst: f64 = 0.0;
        for k in 0..=700_000 {
            let t = k as f64 * 1e-3;
            let (got, want) = (exp_neg(t), (-t).exp());
            worst = worst.max((got / want - 1.0).abs());
        }
        assert!(worst < 1e-8, "worst relative error {worst}");
        assert_eq!(exp_neg(0.0), 1.0);
        for t in [708.0, 750.0, 1e6, f64::INFINITY] {
            let e = exp_neg(t);
            assert!(e.is_finite() && (0.0..1e-300).contains(&e), "{t}: {e}");
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
