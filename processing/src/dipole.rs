//! The dipole diffusion model of subsurface scattering (Jensen et al. 2001; seed 004 eq. 1.25):
//! the diffuse reflectance R_d(r) at distance r from a point of incidence, its total over the
//! plane (the closed form of Jensen's eq. 6), and its integral along a line source, the
//! falloff a laser line shows beside itself. Lengths in mm, coefficients in mm⁻¹.

use std::f64::consts::{FRAC_PI_2, PI};

/// A homogeneous medium as the dipole sees it: reduced albedo α′ = σ′s/σ′t, reduced extinction
/// σ′t (mm⁻¹) and relative index of refraction η.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DipoleMedium {
    /// Reduced albedo α′, in (0, 1].
    pub alpha_p: f64,
    /// Reduced extinction coefficient σ′t, mm⁻¹ (> 0).
    pub sigma_t_p: f64,
    /// Relative index of refraction η (> 0).
    pub eta: f64,
}

/// The internal reflection parameter A = (1 + F_dr)/(1 − F_dr), with F_dr the diffuse Fresnel
/// reflectance of Egan & Hilgeman's fit (as Jensen uses).
pub fn internal_reflection(eta: f64) -> f64 {
    let f_dr = -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta;
    (1.0 + f_dr) / (1.0 - f_dr)
}

impl DipoleMedium {
    /// σ_tr = σ′t·√(3(1 − α′)), the effective transport coefficient.
    pub fn sigma_tr(&self) -> f64 {
        self.sigma_t_p * (3.0 * (1.0 - self.alpha_p).max(0.0)).sqrt()
    }

    /// Depths of the real and the virtual source, mm: z_r = 1/σ′t, z_v = z_r(1 + 4A/3).
    fn depths(&self) -> (f64, f64) {
        let z_r = 1.0 / self.sigma_t_p;
        (z_r, z_r * (1.0 + 4.0 / 3.0 * internal_reflection(self.eta)))
    }

    /// R_d(r): light leaving the surface per unit area at distance `r_mm` from a unit point
    /// source of incidence, mm⁻².
    pub fn rd(&self, r_mm: f64) -> f64 {
        let s = self.sigma_tr();
        let (z_r, z_v) = self.depths();
        let term = |z: f64| {
            let d = (r_mm * r_mm + z * z).sqrt();
            z * (1.0 + s * d) * (-s * d).exp() / (d * d * d)
        };
        self.alpha_p / (4.0 * PI) * (term(z_r) + term(z_v))
    }

    /// The total diffuse reflectance R = ∫ R_d dA (Jensen 2001 eq. 6):
    /// (α′/2)(1 + e^{−(4/3)A√(3(1−α′))})·e^{−√(3(1−α′))}. Independent of σ′t.
    pub fn total_reflectance(&self) -> f64 {
        let a = internal_reflection(self.eta);
        let k = (3.0 * (1.0 - self.alpha_p).max(0.0)).sqrt();
        0.5 * self.alpha_p * (1.0 + (-4.0 / 3.0 * a * k).exp()) * (-k).exp()
    }

    /// The line-source profile ∫ R_d(√(x² + y²)) dy at distance `x_mm` from a line of unit
    /// power per unit length, mm⁻¹. Each source's term is integrated over θ with
    /// y = s·tan θ (s = √(x² + z²)), which turns its 1/d³ peak into the smooth cos θ, by
    /// composite Simpson over [0, π/2].
    pub fn line_profile(&self, x_mm: f64) -> f64 {
        let s_tr = self.sigma_tr();
        let (z_r, z_v) = self.depths();
        let term = |z: f64| {
            let s = (x_mm * x_mm + z * z).sqrt();
            let f = |theta: f64| {
                let c = theta.cos();
                if c < 1e-12 {
                    return 0.0;
                }
                let d = s / c;
                (1.0 + s_tr * d) * (-s_tr * d).exp() * c
            };
            2.0 * z / (s * s) * simpson(f, 0.0, FRAC_PI_2, LINE_INTERVALS)
        };
        self.alpha_p / (4.0 * PI) * (term(z_r) + term(z_v))
    }
}

/// Fresnel transmittance F_t = 1 − F_r of unpolarised light crossing a smooth boundary into a
/// medium of relative index `eta` at incidence cosine `cos_i` (clamped to [0, 1]); total
/// internal reflection (η < 1) transmits 0. The dipole's entry and exit factors.
pub fn fresnel_transmittance(cos_i: f64, eta: f64) -> f64 {
    let c = if cos_i.is_nan() {
        0.0
    } else {
        cos_i.clamp(0.0, 1.0)
    };
    if eta == 1.0 {
        return 1.0;
    }
    let sin2_t = (1.0 - c * c) / (eta * eta);
    if sin2_t >= 1.0 {
        return 0.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (c - eta * cos_t) / (c + eta * cos_t);
    let rp = (eta * c - cos_t) / (eta * c + cos_t);
    (1.0 - 0.5 * (rs * rs + rp * rp)).clamp(0.0, 1.0)
}

/// c(η) = 2∫₀¹ F_t(μ; η) μ dμ, the fraction of diffuse light crossing the boundary: the
/// normalisation of the exit lobe F_t(θo)/(π·c(η)) so that the surface emits all of R_d's
/// light (the simulator's convention, `simulator/src/render/subsurface.rs`). Midpoint rule,
/// 2000 steps (error below 10⁻⁶).
pub fn hemispherical_transmittance(eta: f64) -> f64 {
    const STEPS: usize = 2000;
    let d = 1.0 / STEPS as f64;
    (0..STEPS)
        .map(|k| {
            let mu = (k as f64 + 0.5) * d;
            2.0 * fresnel_transmittance(mu, eta) * mu * d
        })
        .sum::<f64>()
        .clamp(1e-6, 1.0)
}

/// Intervals of [`DipoleMedium::line_profile`]'s Simpson rule (even).
pub const LINE_INTERVALS: usize = 32;

/// Composite Simpson's rule of `f` over [a, b] in `n` (even) intervals.
fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let h = (b - a) / n as f64;
    let mut sum = f(a) + f(b);
    for i in 1..n {
        sum += f(a + h * i as f64) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn medium(alpha_p: f64, sigma_t_p: f64) -> DipoleMedium {
        DipoleMedium {
            alpha_p,
            sigma_t_p,
            eta: 1.3,
        }
    }

    /// ∫ f over (−∞, ∞) for an even, decaying `f`, by x = w·tan(u).
    fn over_line(f: impl Fn(f64) -> f64, w: f64) -> f64 {
        2.0 * simpson(
            |u| {
                let c = u.cos();
                if c < 1e-12 {
                    0.0
                } else {
                    f(w * u.tan()) * w / (c * c)
                }
            },
            0.0,
            FRAC_PI_2,
            4000,
        )
    }

    #[test]
    fn the_line_profile_integrates_to_the_closed_form_reflectance() {
        // Independent of the line integral's substitution: the closed form of Jensen's eq. 6.
        for alpha_p in [0.01, 0.425, 0.9, 0.99, 1.0] {
            for sigma_t_p in [0.05, 1.0, 10.0] {
                let m = medium(alpha_p, sigma_t_p);
                let total = over_line(|x| m.line_profile(x), 1.0 / sigma_t_p);
                let closed = m.total_reflectance();
                assert!(
                    (total - closed).abs() < 1e-3 * closed,
                    "α′ {alpha_p}, σ′t {sigma_t_p}: {total} against {closed}"
                );
            }
        }
        assert!((medium(1.0, 1.0).total_reflectance() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_line_profile_is_the_point_response_summed_along_the_line() {
        let m = medium(0.8, 0.7);
        for x in [0.0, 0.3, 2.0, 9.0] {
            let direct = over_line(|y| m.rd((x * x + y * y).sqrt()), 1.0);
            let line = m.line_profile(x);
            assert!((direct - line).abs() < 1e-6 * line, "{x}: {direct} {line}");
        }
    }

    #[test]
    fn the_profile_scales_with_the_extinction() {
        // R_d(r; σ′t) = σ′t²·R̂_d(σ′t·r), so the line profile scales as σ′t·L̂(σ′t·x).
        let (a, b) = (medium(0.7, 1.0), medium(0.7, 4.0));
        for x in [0.0, 0.5, 3.0] {
            let scaled = 4.0 * a.line_profile(4.0 * x);
            assert!((b.line_profile(x) - scaled).abs() < 1e-9 * scaled);
        }
    }

    #[test]
    fn fresnel_transmittance_at_normal_incidence_and_grazing() {
        // Normal incidence: 1 − ((η − 1)/(η + 1))².
        for eta in [1.0f64, 1.3, 1.5, 2.5] {
            let r0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
            assert!((fresnel_transmittance(1.0, eta) - (1.0 - r0)).abs() < 1e-12);
            assert_eq!(
                fresnel_transmittance(0.0, eta),
                if eta == 1.0 { 1.0 } else { 0.0 }
            );
        }
        // From the denser side beyond the critical angle: nothing crosses.
        assert_eq!(fresnel_transmittance(0.1, 1.0 / 1.5), 0.0);
        assert_eq!(fresnel_transmittance(f64::NAN, 1.3), 0.0);
        // c(η) = 1 − the external diffuse reflectance: 0.939 at η 1.3, 0.908 at 1.5.
        assert!((hemispherical_transmittance(1.3) - 0.939).abs() < 1e-3);
        assert!((hemispherical_transmittance(1.5) - 0.908).abs() < 1e-3);
        assert!((hemispherical_transmittance(1.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn extremes_stay_finite() {
        for (alpha_p, sigma_t_p) in [(1e-6, 0.01), (1.0, 0.01), (1.0, 10.0), (1e-6, 10.0)] {
            let m = medium(alpha_p, sigma_t_p);
            for x in [0.0, 1e-9, 1.0, 1e3] {
                let (p, r) = (m.line_profile(x), m.rd(x));
                assert!(p.is_finite() && p >= 0.0 && r.is_finite() && r >= 0.0);
            }
        }
    }
}
