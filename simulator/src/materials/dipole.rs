//! Jensen et al. (2001) dipole diffusion profile for homogeneous, optically thick translucent
//! media, with the total diffuse reflectance of Jensen & Buhler (2002), its inverse, and the
//! line-source integral used to fit laser-line scans.
//!
//! R_d(r) = (α′/4π) [ z_r (σ_tr d_r + 1) e^{−σ_tr d_r} / d_r³ + z_v (σ_tr d_v + 1) e^{−σ_tr d_v} / d_v³ ]
//! with σ′_t = σ′_s + σ_a, α′ = σ′_s/σ′_t, σ_tr = √(3σ_a σ′_t) = σ′_t √(3(1−α′)),
//! z_r = 1/σ′_t, z_v = z_r(1 + 4A/3), d_{r,v} = √(r² + z_{r,v}²), A from
//! [`boundary_coefficient`]. Corrections to the thesis print: the prefactor is α′/(4π)
//! (printed as σ_s/(4πσ′_t)), and the normalisation is 1/(4π).
//!
//! Units: lengths in mm, coefficients in mm⁻¹ (any consistent unit works); R_d in mm⁻².

use std::f64::consts::PI;

use super::fresnel::boundary_coefficient;
use super::sanitize;

/// Smallest reduced extinction σ′_t accepted (mm⁻¹); smaller, zero or NaN σ′_t is clamped up to
/// it (z_r = 1/σ′_t must stay finite). The thesis searches σ′_t over [0.01, 10] mm⁻¹.
pub const MIN_SIGMA_T: f64 = 1.0e-6;
/// Largest reduced extinction σ′_t accepted (mm⁻¹); larger or infinite σ′_t is clamped down.
pub const MAX_SIGMA_T: f64 = 1.0e6;
/// Exponents σ_tr·d beyond this give a zero term (e^−700 is at the edge of f64 range).
const MAX_EXPONENT: f64 = 700.0;
/// Integration cut-off, as a multiple of the dipole depth scale, when σ_tr = 0 (α′ = 1): the
/// neglected tail of the plane integral is then ≈ 10⁻¹² of the total.
const FAR_FACTOR: f64 = 1.0e12;
/// As [`FAR_FACTOR`] for the line integral, whose α′ = 1 tail falls as 1/s² (neglected part
/// ≈ (L/s_max)² ≈ 10⁻¹²).
const LINE_FAR_FACTOR: f64 = 1.0e6;
/// Integration cut-off in decay lengths 1/σ_tr: e^−60 ≈ 10⁻²⁶ of the profile is neglected.
const DECAY_LENGTHS: f64 = 60.0;

/// A homogeneous dipole medium with its derived quantities precomputed. Why a struct: the
/// profile is evaluated millions of times per laser-line frame with fixed optical parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dipole {
    alpha_prime: f64,
    sigma_t_prime: f64,
    eta: f64,
    a: f64,
    sigma_tr: f64,
    z_r: f64,
    z_v: f64,
}

impl Dipole {
    /// A medium from absorption `sigma_a`, reduced scattering `sigma_s_prime` (both mm⁻¹) and
    /// relative index `eta`. Clamps: negative or NaN coefficients become 0; σ′_t is clamped to
    /// [[`MIN_SIGMA_T`], [`MAX_SIGMA_T`]]; if both coefficients are 0 (vacuum) α′ = 0, so R_d ≡ 0;
    /// η is clamped as in [`boundary_coefficient`].
    pub fn new(sigma_a: f64, sigma_s_prime: f64, eta: f64) -> Self {
        let sa = sanitize(sigma_a, 0.0, f64::MAX, 0.0);
        let ss = sanitize(sigma_s_prime, 0.0, f64::MAX, 0.0);
        let st = sa + ss;
        let alpha_prime = if st > 0.0 && st.is_finite() {
            ss / st
        } else if st.is_infinite() && ss.is_finite() {
            0.0
        } else if st.is_infinite() {
            1.0
        } else {
            0.0
        };
        Self::from_reduced_albedo(alpha_prime, st, eta)
    }

    /// A medium from reduced albedo `alpha_prime` = σ′_s/σ′_t, reduced extinction
    /// `sigma_t_prime` (mm⁻¹) and relative index `eta` — the parametrisation the thesis fits.
    /// Clamps: α′ into [0, 1] (NaN → 0), σ′_t into [[`MIN_SIGMA_T`], [`MAX_SIGMA_T`]] (NaN → 1),
    /// η as in [`boundary_coefficient`].
    pub fn from_reduced_albedo(alpha_prime: f64, sigma_t_prime: f64, eta: f64) -> Self {
        let alpha_prime = sanitize(alpha_prime, 0.0, 1.0, 0.0);
        let st = sanitize(sigma_t_prime, MIN_SIGMA_T, MAX_SIGMA_T, 1.0);
        let eta = if eta.is_nan() { 1.0 } else { eta };
        let a = boundary_coefficient(eta);
        let z_r = 1.0 / st;
        Self {
            alpha_prime,
            sigma_t_prime: st,
            eta,
            a,
            // σ′_t √(3(1−α′)) equals √(3σ_aσ′_t) and is exact at α′ = 1.
            sigma_tr: st * (3.0 * (1.0 - alpha_prime)).sqrt(),
            z_r,
            z_v: z_r * (1.0 + 4.0 * a / 3.0),
        }
    }

    /// Reduced albedo α′ = σ′_s/σ′_t, in [0, 1].
    pub fn reduced_albedo(&self) -> f64 {
        self.alpha_prime
    }

    /// Reduced extinction coefficient σ′_t (mm⁻¹), after clamping.
    pub fn sigma_t_prime(&self) -> f64 {
        self.sigma_t_prime
    }

    /// Relative index of refraction η as given (NaN replaced by 1).
    pub fn eta(&self) -> f64 {
        self.eta
    }

    /// Boundary coefficient A = (1 + F_dr)/(1 − F_dr).
    pub fn boundary(&self) -> f64 {
        self.a
    }

    /// Effective transport coefficient σ_tr = √(3σ_aσ′_t) (mm⁻¹): the exponential falloff rate.
    pub fn sigma_tr(&self) -> f64 {
        self.sigma_tr
    }

    /// Depth of the real source z_r = 1/σ′_t (mm).
    pub fn z_r(&self) -> f64 {
        self.z_r
    }

    /// Height of the virtual (negative) source z_v = z_r(1 + 4A/3) (mm).
    pub fn z_v(&self) -> f64 {
        self.z_v
    }

    /// One source's contribution z(σ_tr d + 1)e^{−σ_tr d}/d³ with d = √(r² + z²); 0 on
    /// underflow/overflow.
    #[inline]
    fn source(&self, r: f64, z: f64) -> f64 {
        let d = r.hypot(z);
        let x = self.sigma_tr * d;
        if x.is_nan() || x > MAX_EXPONENT {
            return 0.0;
        }
        let v = z * (x + 1.0) * (-x).exp() / (d * d * d);
        if v.is_finite() { v } else { 0.0 }
    }

    /// Diffuse reflectance profile R_d(r) (mm⁻²): the radiant exitance at distance `r` (mm)
    /// from a unit-power point of entry. Why: the global term of the quasi-homogeneous model
    /// (eqs 2.35–2.37) and the laser-line falloff.
    ///
    /// Finite at r = 0 (d ≥ z_r > 0), positive for α′ > 0 until e^{−σ_tr d} underflows, strictly
    /// decreasing in r. Negative `r` is treated as |r|; NaN `r` gives 0.
    pub fn rd(&self, r: f64) -> f64 {
        if r.is_nan() {
            return 0.0;
        }
        let r = r.abs();
        let v =
            self.alpha_prime / (4.0 * PI) * (self.source(r, self.z_r) + self.source(r, self.z_v));
        if v.is_finite() && v >= 0.0 { v } else { 0.0 }
    }

    /// Closed-form total diffuse reflectance ∫ R_d dA (Jensen & Buhler 2002); see the free
    /// function [`total_diffuse_reflectance`]. Independent of σ′_t.
    pub fn total_diffuse_reflectance(&self) -> f64 {
        total_diffuse_reflectance(self.alpha_prime, self.eta)
    }

    /// Outer integration limit for a profile with length scale `scale` (mm).
    fn cutoff(&self, scale: f64, far_factor: f64) -> f64 {
        let far = far_factor * scale;
        if self.sigma_tr > 0.0 {
            (DECAY_LENGTHS / self.sigma_tr + 10.0 * scale).min(far)
        } else {
            far
        }
    }

    /// Numeric plane integral 2π ∫₀^∞ r R_d(r) dr — a check on [`Self::rd`] against the closed
    /// form, and the template for integrating measured profiles.
    ///
    /// Resolution knob: `steps` composite 3-point Gauss–Legendre panels (≥ 1; 3 evaluations
    /// each) in u = ln(1 + r/z_r), which resolves both the r ≈ z_r core and the long 1/r² tail
    /// (α′ → 1). The range ends where the neglected tail is below 10⁻¹² of the total.
    /// Measured worst relative error against the closed form over σ′_t ∈ {0.01, 1, 10},
    /// α′ ∈ [0, 1], η ∈ [1, 2]: 1.2e-5 at 50 panels, 1.0e-9 at 200, 1.6e-11 at 400, 7.6e-13 at
    /// 1000.
    pub fn total_diffuse_reflectance_numeric(&self, steps: usize) -> f64 {
        let z = self.z_r;
        let u_max = (self.cutoff(self.z_v, FAR_FACTOR) / z).ln_1p();
        gauss_legendre(steps, u_max, |u| {
            let e = u.exp();
            let r = z * (e - 1.0);
            2.0 * PI * r * self.rd(r) * z * e
        })
    }

    /// Line-source profile I(d) = ∫_{−∞}^{∞} R_d(√(d² + s²)) ds (mm⁻¹): the exitance at
    /// distance `d` (mm) from an infinitely long, thin laser line of unit power per unit
    /// length. It has no closed form for σ_tr > 0 hence numeric.
    ///
    /// Resolution knob: `steps` composite 3-point Gauss–Legendre panels (≥ 1) over half the
    /// line in u = ln(1 + s/L), L = √(d² + z_r²); the neglected tail is below 10⁻¹² of I(d). Measured worst relative error against the α′ = 1
    /// closed form: 9e-8 at 50 panels, 3.3e-11 at 200, 4e-13 at 400. Negative `d` is treated as |d|; NaN gives 0.
    pub fn line_source(&self, d: f64, steps: usize) -> f64 {
        if d.is_nan() {
            return 0.0;
        }
        let d = d.abs();
        let l = d.hypot(self.z_r);
        let lv = d.hypot(self.z_v);
        let u_max = (self.cutoff(lv, LINE_FAR_FACTOR) / l).ln_1p();
        let v = 2.0
            * gauss_legendre(steps, u_max, |u| {
                let e = u.exp();
                let s = l * (e - 1.0);
                self.rd(d.hypot(s)) * l * e
            });
        if v.is_finite() && v >= 0.0 { v } else { 0.0 }
    }
}

/// Composite 3-point Gauss–Legendre rule for ∫₀^{u_max} f(u) du with `panels` equal panels
/// (at least 1; error O(h⁶) for smooth f). Open rule: f is never sampled at the end points.
/// Non-finite samples count as 0.
fn gauss_legendre(panels: usize, u_max: f64, f: impl Fn(f64) -> f64) -> f64 {
    let n = panels.max(1);
    if !(u_max.is_finite() && u_max > 0.0) {
        return 0.0;
    }
    let h = u_max / n as f64;
    let x = 0.5 * h * (3.0f64 / 5.0).sqrt();
    let g = |u: f64| {
        let v = f(u);
        if v.is_finite() { v } else { 0.0 }
    };
    let mut sum = 0.0;
    for k in 0..n {
        let c = (k as f64 + 0.5) * h;
        sum += 5.0 * g(c - x) + 8.0 * g(c) + 5.0 * g(c + x);
    }
    (sum * h / 18.0).max(0.0)
}

/// Closed-form total diffuse reflectance of the dipole (Jensen & Buhler 2002):
/// R_d = (α′/2)(1 + e^{−(4/3)A√(3(1−α′))}) e^{−√(3(1−α′))}.
///
/// Why: a fit recovers α′ from the measured total reflectance —
/// see [`reduced_albedo_from_total`]. α′ is clamped into [0, 1] (NaN → 0); η as in
/// [`boundary_coefficient`]. Strictly increasing in α′, from 0 at α′ = 0 to 1 at α′ = 1.
pub fn total_diffuse_reflectance(alpha_prime: f64, eta: f64) -> f64 {
    let ap = sanitize(alpha_prime, 0.0, 1.0, 0.0);
    let a = boundary_coefficient(if eta.is_nan() { 1.0 } else { eta });
    let s = (3.0 * (1.0 - ap)).sqrt();
    0.5 * ap * (1.0 + (-(4.0 / 3.0) * a * s).exp()) * (-s).exp()
}

/// Numeric inverse of [`total_diffuse_reflectance`]: the α′ ∈ [0, 1] whose total diffuse
/// reflectance is `rd`, by bisection to 10⁻¹⁵ in α′ (at most 200 iterations).
///
/// Why: first step of the thesis' sequential fit (R → α′, then σ′_t). Clamps: `rd` into
/// [0, 1] (the range of the forward map; NaN → 0).
pub fn reduced_albedo_from_total(rd: f64, eta: f64) -> f64 {
    let target = sanitize(rd, 0.0, 1.0, 0.0);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..200 {
        if hi - lo <= 1.0e-15 {
            break;
        }
        let mid = 0.5 * (lo + hi);
        if total_diffuse_reflectance(mid, eta) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const SIGMA_TS: [f64; 3] = [0.01, 1.0, 10.0];
    const ALPHAS: [f64; 4] = [0.01, 0.5, 0.99, 0.999999];

    #[test]
    fn profile_positive_decreasing_finite_at_zero() {
        for st in SIGMA_TS {
            for ap in ALPHAS {
                for eta in [1.0, 1.3, 1.5] {
                    let m = Dipole::from_reduced_albedo(ap, st, eta);
                    let r0 = m.rd(0.0);
                    assert!(r0.is_finite() && r0 > 0.0, "{st} {ap}: {r0}");
                    let mut prev = r0;
                    // r from 0 to 10⁴ mm, geometric.
                    for k in 0..=400 {
                        let r = 1e-6 * 10f64.powf(k as f64 * 0.025);
                        let v = m.rd(r);
                        assert!(v.is_finite() && v >= 0.0);
                        assert!(v <= prev, "not decreasing at r={r}: {v} > {prev}");
                        if m.sigma_tr() * r.hypot(m.z_r()) < 600.0 && r < 1e4 {
                            assert!(v > 0.0, "{st} {ap} r={r}");
                        }
                        prev = v;
                    }
                    // Strictly decreasing where it is well above underflow.
                    assert!(m.rd(0.5 * m.z_r()) < r0);
                }
            }
        }
    }

    /// Plane integral (400 Gauss–Legendre panels) against the closed form. Stated tolerance:
    /// 1e-10 relative (plus 1e-15 absolute for α′ = 0); measured worst 1.6e-11.
    #[test]
    fn plane_integral_matches_closed_form() {
        let mut worst = 0.0f64;
        for st in SIGMA_TS {
            for ap in [0.0, 0.01, 0.2, 0.5, 0.8, 0.99, 0.999999, 1.0] {
                for eta in [1.0, 1.3, 1.5, 2.0] {
                    let m = Dipole::from_reduced_albedo(ap, st, eta);
                    let exact = m.total_diffuse_reflectance();
                    let num = m.total_diffuse_reflectance_numeric(400);
                    let err = (num - exact).abs();
                    assert!(
                        err <= 1e-10 * exact + 1e-15,
                        "{st} {ap} {eta}: {num} vs {exact}"
                    );
                    if exact > 0.0 {
                        worst = worst.max(err / exact);
                    }
                }
            }
        }
        assert!(worst <= 1e-10, "{worst}");
    }

    #[test]
    fn total_reflectance_limits_and_monotonic() {
        assert_eq!(total_diffuse_reflectance(0.0, 1.3), 0.0);
        assert!((total_diffuse_reflectance(1.0, 1.3) - 1.0).abs() < 1e-15);
        let mut prev = 0.0;
        for k in 1..=1000 {
            let v = total_diffuse_reflectance(k as f64 / 1000.0, 1.3);
            assert!(v > prev);
            prev = v;
        }
        for x in [f64::NAN, -1.0, 2.0, f64::INFINITY] {
            let v = total_diffuse_reflectance(x, x);
            assert!(v.is_finite() && (0.0..=1.0).contains(&v));
            let w = reduced_albedo_from_total(x, x);
            assert!(w.is_finite() && (0.0..=1.0).contains(&w));
        }
    }

    proptest! {
        /// α′ → R_d → α′ round trip: stated bound 1e-9 absolute in α′.
        #[test]
        fn inverse_round_trips(ap in 0.0f64..=1.0, eta in 1.0f64..2.0) {
            let rd = total_diffuse_reflectance(ap, eta);
            let back = reduced_albedo_from_total(rd, eta);
            prop_assert!((back - ap).abs() < 1e-9, "{ap} -> {rd} -> {back}");
        }

        #[test]
        fn profile_finite_non_negative(ap in -0.5f64..1.5, st in 0.0f64..100.0, eta in 0.5f64..4.0,
                                       r in -100.0f64..100.0) {
            let m = Dipole::from_reduced_albedo(ap, st, eta);
            let v = m.rd(r);
            prop_assert!(v.is_finite() && v >= 0.0);
            let l = m.line_source(r, 64);
            prop_assert!(l.is_finite() && l >= 0.0);
        }
    }

    #[test]
    fn new_matches_reduced_albedo_form() {
        let m = Dipole::new(0.1, 0.9, 1.3);
        let n = Dipole::from_reduced_albedo(0.9, 1.0, 1.3);
        assert!((m.reduced_albedo() - 0.9).abs() < 1e-15);
        assert!((m.sigma_tr() - (3.0f64 * 0.1 * 1.0).sqrt()).abs() < 1e-12);
        assert!((m.rd(0.7) - n.rd(0.7)).abs() < 1e-12 * n.rd(0.7));
        for (a, s) in [
            (0.0, 0.0),
            (f64::NAN, 1.0),
            (-1.0, f64::INFINITY),
            (f64::INFINITY, 1.0),
        ] {
            let m = Dipole::new(a, s, 1.3);
            let v = m.rd(0.0);
            assert!(v.is_finite() && v >= 0.0);
        }
    }

    /// Media of the Monte Carlo validation set the dipole is usually checked against evaluate
    /// finitely.
    #[test]
    fn thesis_validation_materials() {
        let media = [(0.4248, 1.0), (0.4248, 1.5), (0.99, 2.13), (0.98, 1.5)];
        for (ap, st) in media {
            let m = Dipole::from_reduced_albedo(ap, st, 1.3);
            for r in [0.0, 0.1, 1.0, 10.0, 100.0] {
                let v = m.rd(r);
                assert!(v.is_finite() && v >= 0.0);
                let l = m.line_source(r, 400);
                assert!(l.is_finite() && l > 0.0, "{ap} {st} {r}: {l}");
            }
            let t = m.total_diffuse_reflectance();
            assert!(t.is_finite() && t > 0.0 && t < 1.0);
            assert!((m.total_diffuse_reflectance_numeric(1000) - t).abs() < 1e-9 * t);
        }
    }

    /// At α′ = 1 (σ_tr = 0) the line integral has the closed form
    /// I(d) = (1/2π)(z_r/(d² + z_r²) + z_v/(d² + z_v²)). Stated tolerance: 1e-11 relative at 400
    /// panels (measured worst 4e-13).
    #[test]
    fn line_source_closed_form_at_unit_albedo() {
        for st in SIGMA_TS {
            let m = Dipole::from_reduced_albedo(1.0, st, 1.3);
            let (zr, zv) = (m.z_r(), m.z_v());
            for d in [0.0, 0.1 * zr, zr, 3.0 * zr, 100.0 * zr] {
                let exact = (zr / (d * d + zr * zr) + zv / (d * d + zv * zv)) / (2.0 * PI);
                let num = m.line_source(d, 400);
                assert!(
                    (num - exact).abs() <= 1e-11 * exact,
                    "{st} {d}: {num} vs {exact}"
                );
            }
        }
    }

    /// Integrating the line profile across the line recovers the plane total:
    /// ∫ I(d) dd = ∫ R_d dA. 400 outer × 400 inner Gauss–Legendre panels; stated tolerance 1e-6 relative.
    #[test]
    fn line_source_integrates_to_total() {
        for st in SIGMA_TS {
            for ap in [0.01, 0.5, 0.99, 0.999999] {
                let m = Dipole::from_reduced_albedo(ap, st, 1.3);
                let z = m.z_r();
                let u_max = (m.cutoff(m.z_v(), FAR_FACTOR) / z).ln_1p();
                let total = 2.0
                    * gauss_legendre(400, u_max, |u| {
                        let e = u.exp();
                        m.line_source(z * (e - 1.0), 400) * z * e
                    });
                let exact = m.total_diffuse_reflectance();
                assert!(
                    (total - exact).abs() <= 1e-6 * exact,
                    "{st} {ap}: {total} vs {exact}"
                );
            }
        }
    }

    #[test]
    fn line_source_decreasing() {
        let m = Dipole::from_reduced_albedo(0.9, 1.0, 1.3);
        let mut prev = f64::INFINITY;
        for k in 0..100 {
            let v = m.line_source(k as f64 * 0.1, 200);
            assert!(v < prev && v > 0.0);
            prev = v;
        }
    }
}
