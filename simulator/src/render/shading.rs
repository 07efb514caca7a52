//! Reflectance: Lambert plus the isotropic Ward lobe, guarded so grazing light or view never
//! produces NaN, infinity or negative values.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::Vec3A;

use super::material::Material;

/// Smallest cosine used in the Ward normalisation √(cosθi·cosθo), which diverges at grazing.
const MIN_COS: f32 = 1.0e-3;
/// Smallest roughness accepted; below it the lobe is a numerical spike.
const MIN_ALPHA: f32 = 1.0e-2;

/// The isotropic Ward lobe exp(−tan²δ/α²) / (4πα²√(cosθi cosθo)) for unit normal `n`,
/// direction to the light `wi` and to the viewer `wo`; 0 when either is below the surface.
#[inline]
pub fn ward_lobe(n: Vec3A, wi: Vec3A, wo: Vec3A, alpha: f32) -> f32 {
    let cos_i = n.dot(wi);
    let cos_o = n.dot(wo);
    if cos_i.is_nan() || cos_o.is_nan() || cos_i <= 0.0 || cos_o <= 0.0 {
        return 0.0;
    }
    let h = wi + wo;
    let len2 = h.length_squared();
    if len2.is_nan() || len2 <= 1.0e-12 {
        return 0.0;
    }
    let cos_d2 = {
        let c = n.dot(h);
        if c <= 0.0 {
            return 0.0;
        }
        c * c / len2
    };
    let alpha2 = alpha.max(MIN_ALPHA) * alpha.max(MIN_ALPHA);
    let exponent = ((1.0 - cos_d2) / (cos_d2.max(1.0e-12) * alpha2)).max(0.0);
    // Beyond this the lobe is below 1e-13 of its peak: skip the exp.
    if exponent.is_nan() || exponent > 30.0 {
        return 0.0;
    }
    let norm = 4.0 * PI * alpha2 * (cos_i.max(MIN_COS) * cos_o.max(MIN_COS)).sqrt();
    let v = (-exponent).exp() / norm;
    if v.is_finite() { v } else { 0.0 }
}

/// Full BRDF ρd/π + ρs·lobe per channel; `specular` false skips the lobe.
#[inline]
pub fn brdf(m: &Material, n: Vec3A, wi: Vec3A, wo: Vec3A, specular: bool) -> Vec3A {
    let diffuse = m.albedo.max(Vec3A::ZERO) * FRAC_1_PI;
    if specular && m.ks > 0.0 {
        diffuse + Vec3A::splat(m.ks * ward_lobe(n, wi, wo, m.alpha))
    } else {
        diffuse
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn dir(theta: f32, phi: f32) -> Vec3A {
        Vec3A::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    proptest! {
        #[test]
        fn brdf_is_finite_and_non_negative(
            ti in 0.0f32..1.6, pi_ in 0.0f32..6.3, to in 0.0f32..1.6, po in 0.0f32..6.3,
            alpha in 0.0f32..1.0, ks in 0.0f32..1.0, tn in 0.0f32..1.6, pn in 0.0f32..6.3,
        ) {
            let n = dir(tn, pn);
            let (wi, wo) = (dir(ti, pi_), dir(to, po));
            let m = Material::ward(Vec3A::splat(0.5), ks, alpha);
            let f = brdf(&m, n, wi, wo, true);
            prop_assert!(f.is_finite(), "{f}");
            prop_assert!(f.min_element() >= 0.0, "{f}");
            // What the integrator multiplies by the cosine must stay finite too.
            let e = f * n.dot(wi).max(0.0);
            prop_assert!(e.is_finite() && e.min_element() >= 0.0);
        }

        #[test]
        fn lobe_peaks_at_the_mirror_azimuth(t in 0.05f32..1.4, alpha in 0.02f32..0.8, dphi in 0.1f32..3.0) {
            // At equal view elevation the normalisation is the same, so the mirror wins.
            let n = Vec3A::Z;
            let wi = dir(t, 0.0);
            let mirror = dir(t, std::f32::consts::PI);
            let off = dir(t, std::f32::consts::PI + dphi);
            prop_assert!(ward_lobe(n, wi, mirror, alpha) >= ward_lobe(n, wi, off, alpha));
        }
    }

    #[test]
    fn exactly_grazing_and_degenerate_inputs() {
        let n = Vec3A::Z;
        let m = Material::ward(Vec3A::splat(0.5), 0.5, 0.0);
        for (wi, wo) in [
            (Vec3A::X, -Vec3A::X),
            (Vec3A::X, Vec3A::X),
            (Vec3A::Z, Vec3A::Z),
            (
                Vec3A::new(1.0, 0.0, 1e-7).normalize(),
                Vec3A::new(-1.0, 0.0, 1e-7).normalize(),
            ),
            (Vec3A::ZERO, Vec3A::ZERO),
        ] {
            let f = brdf(&m, n, wi, wo, true);
            assert!(f.is_finite() && f.min_element() >= 0.0, "{wi} {wo}: {f}");
        }
    }
}
