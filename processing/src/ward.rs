//! The isotropic Ward (1992) lobe the reflectometer fit uses (Gardner et al. 2003; seed 004
//! §2.4): ψ(wi, wo) = exp(−tan²δ/α²) / (4πα²·√(cosθi·cosθo)), δ the angle between the half
//! vector and the normal. The BRDF is ρd/π + ρs·ψ, ρd per colour channel, ρs grey.
//!
//! Written here from the paper, apart from the simulator's, so that each checks the other
//! (`tests/integration/ward_model.rs`).

use nalgebra::Vector3;

/// Smallest roughness α accepted (smaller α is clamped up): below it the lobe is a spike no
/// quadrature resolves, and no cart spacing could measure it.
pub const MIN_ALPHA: f64 = 1.0e-3;
/// Smallest cosine used in the normalisation √(cosθi·cosθo), which diverges at grazing.
pub const MIN_COS: f64 = 1.0e-6;
/// Exponents beyond this give a zero lobe (e^−700 is near the end of f64's range).
const MAX_EXPONENT: f64 = 700.0;

/// ψ for unit normal `n`, unit `wi` (towards the light) and `wo` (towards the viewer).
/// 0 when either direction is at or below the horizon or an input is NaN; finite always.
pub fn ward_iso(n: &Vector3<f64>, wi: &Vector3<f64>, wo: &Vector3<f64>, alpha: f64) -> f64 {
    let (ci, co) = (n.dot(wi), n.dot(wo));
    if !(ci > 0.0 && co > 0.0) {
        return 0.0;
    }
    let alpha = if alpha.is_nan() {
        MIN_ALPHA
    } else {
        alpha.max(MIN_ALPHA)
    };
    let h = wi + wo;
    let hn = h.dot(n);
    if hn.is_nan() || hn <= 0.0 {
        return 0.0;
    }
    // tan²δ = (|h|² − (h·n)²)/(h·n)², without trigonometry.
    let tan2 = ((h.norm_squared() - hn * hn).max(0.0)) / (hn * hn);
    let exponent = tan2 / (alpha * alpha);
    if exponent.is_nan() || exponent >= MAX_EXPONENT {
        return 0.0;
    }
    let norm =
        4.0 * std::f64::consts::PI * alpha * alpha * (ci.max(MIN_COS) * co.max(MIN_COS)).sqrt();
    (-exponent).exp() / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(theta: f64, phi: f64) -> Vector3<f64> {
        Vector3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    #[test]
    fn the_lobe_peaks_at_the_mirror_direction_and_is_reciprocal() {
        let n = Vector3::z();
        let wi = dir(0.6, 0.3);
        let mirror = dir(0.6, 0.3 + std::f64::consts::PI);
        let peak = ward_iso(&n, &wi, &mirror, 0.1);
        let expected = 1.0 / (4.0 * std::f64::consts::PI * 0.01 * 0.6f64.cos());
        assert!(
            (peak / expected - 1.0).abs() < 1e-12,
            "{peak} vs {expected}"
        );
        for (a, b) in [
            (dir(0.2, 1.0), dir(1.1, 2.5)),
            (dir(1.5, 0.0), dir(0.1, 3.0)),
        ] {
            let (f, g) = (ward_iso(&n, &a, &b, 0.2), ward_iso(&n, &b, &a, 0.2));
            assert!((f - g).abs() <= 1e-15 * f.max(1.0), "{f} vs {g}");
        }
    }

    #[test]
    fn grazing_below_horizon_tiny_alpha_and_nan_stay_finite() {
        let n = Vector3::z();
        let grazing = dir(std::f64::consts::FRAC_PI_2 - 1e-12, 0.0);
        let up = dir(0.3, 3.0);
        for alpha in [
            0.0,
            1e-9,
            MIN_ALPHA,
            0.05,
            1.0,
            1e9,
            f64::NAN,
            f64::INFINITY,
        ] {
            for (wi, wo) in [(grazing, up), (up, grazing), (dir(2.0, 0.0), up), (up, up)] {
                let f = ward_iso(&n, &wi, &wo, alpha);
                assert!(f.is_finite() && f >= 0.0, "α {alpha}: {f}");
            }
        }
        assert_eq!(ward_iso(&n, &dir(2.0, 0.0), &up, 0.1), 0.0);
        let nan = Vector3::new(f64::NAN, 0.0, 1.0);
        assert_eq!(ward_iso(&n, &nan, &up, 0.1), 0.0);
    }
}
