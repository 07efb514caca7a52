//! Reflectance at a surface point: Lambert ρd/π plus the material's specular lobe — isotropic
//! or anisotropic Ward, normalised Blinn–Phong or Cook–Torrance GGX — dispatched on
//! [`Model`]. The lobes are the f32 functions of [`crate::materials`]; this module adds the
//! tangent frame, the parameter mapping and the renderer's grazing guard, so grazing light or
//! view never produces NaN, infinity or negative values.

use std::f32::consts::FRAC_1_PI;

use glam::Vec3A;

use super::material::{Material, Model};
use crate::materials::{blinn_phong_f32, cook_torrance_ggx_f32, ward_aniso_f32, ward_iso_f32};

/// Smallest cosine the renderer uses in the Ward normalisation √(cosθi·cosθo), which diverges
/// at grazing (the f32 lobes clamp at 1e-6; the renderer keeps its older, stricter 1e-3 so a
/// silhouette pixel is at most ≈ 31× the lobe's value at normal view, never a firefly).
const MIN_COS: f32 = 1.0e-3;
/// Smallest roughness the renderer accepts for any lobe; below it the lobe is a numerical spike
/// no pixel sample finds.
const MIN_ALPHA: f32 = 1.0e-2;
/// Largest Blinn–Phong exponent (2/α² − 2 at α = [`MIN_ALPHA`]).
const MAX_EXPONENT: f32 = 2.0 / (MIN_ALPHA * MIN_ALPHA) - 2.0;

/// The isotropic Ward lobe exp(−tan²δ/α²) / (4πα²√(cosθi cosθo)) for unit normal `n`,
/// direction to the light `wi` and to the viewer `wo`; 0 when either is below the surface.
/// The cosines in the normalisation are clamped at 1e-3.
#[inline]
pub fn ward_lobe(n: Vec3A, wi: Vec3A, wo: Vec3A, alpha: f32) -> f32 {
    grazing_guard(n.dot(wi), n.dot(wo)) * ward_iso_f32(n, wi, wo, alpha.max(MIN_ALPHA))
}

/// Factor that turns the f32 Ward lobes' 1e-6 cosine clamp into the renderer's 1e-3 clamp:
/// √(max(ci,1e-6)·max(co,1e-6) / (max(ci,1e-3)·max(co,1e-3))), exactly 1 unless a direction is
/// within 0.06° of the horizon.
#[inline]
fn grazing_guard(cos_i: f32, cos_o: f32) -> f32 {
    if cos_i >= MIN_COS && cos_o >= MIN_COS {
        return 1.0;
    }
    let lo = 1.0e-6;
    let g = ((cos_i.max(lo) * cos_o.max(lo)) / (cos_i.max(MIN_COS) * cos_o.max(MIN_COS))).sqrt();
    if g.is_finite() {
        g.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The anisotropic tangent frame at normal `n`: the sample-plane direction at `tangent_rad`
/// from +x, projected onto the tangent plane of `n` and orthonormalised (t, b = n × t). Falls
/// back to the plane direction 90° further on when `n` lies (nearly) along it.
#[inline]
pub fn tangent_frame(n: Vec3A, tangent_rad: f32) -> (Vec3A, Vec3A) {
    let (s, c) = tangent_rad.sin_cos();
    let mut d = Vec3A::new(c, s, 0.0);
    let mut t = d - n * n.dot(d);
    if t.length_squared() < 1.0e-6 {
        d = Vec3A::new(-s, c, 0.0);
        t = d - n * n.dot(d);
    }
    let t = t.normalize_or(Vec3A::X);
    (t, n.cross(t).normalize_or(Vec3A::Y))
}

/// The specular lobe of `m` (without ρs, except for GGX whose F0 is ks) for unit `n`, `wi`,
/// `wo`: finite and ≥ 0, 0 below the horizon.
#[inline]
pub fn specular_lobe(m: &Material, n: Vec3A, wi: Vec3A, wo: Vec3A) -> f32 {
    match m.model {
        Model::Lambert => 0.0,
        Model::WardIso => m.ks * ward_lobe(n, wi, wo, m.alpha),
        Model::WardAniso => {
            let (t, b) = tangent_frame(n, m.tangent_rad);
            let lobe = ward_aniso_f32(
                n,
                t,
                b,
                wi,
                wo,
                m.alpha.max(MIN_ALPHA),
                m.alpha_y.max(MIN_ALPHA),
            );
            m.ks * grazing_guard(n.dot(wi), n.dot(wo)) * lobe
        }
        Model::BlinnPhong => m.ks * blinn_phong_f32(n, wi, wo, blinn_phong_exponent(m.alpha)),
        Model::Ggx => cook_torrance_ggx_f32(n, wi, wo, m.alpha.max(MIN_ALPHA), m.ks),
    }
}

/// Blinn–Phong exponent 2/α² − 2 for roughness `alpha` (α clamped to [1e-2, 1], so the
/// exponent is in [0, 19998]; NaN α gives 0).
#[inline]
pub fn blinn_phong_exponent(alpha: f32) -> f32 {
    if alpha.is_nan() {
        return 0.0;
    }
    let a = alpha.clamp(MIN_ALPHA, 1.0);
    (2.0 / (a * a) - 2.0).clamp(0.0, MAX_EXPONENT)
}

/// Full BRDF ρd/π + specular lobe per channel; `specular` false skips the lobe.
#[inline]
pub fn brdf(m: &Material, n: Vec3A, wi: Vec3A, wo: Vec3A, specular: bool) -> Vec3A {
    let diffuse = m.albedo.max(Vec3A::ZERO) * FRAC_1_PI;
    if specular && m.has_specular() {
        let s = specular_lobe(m, n, wi, wo);
        if s.is_finite() && s > 0.0 {
            return diffuse + Vec3A::splat(s);
        }
    }
    diffuse
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

    /// One material of each model with the given specular parameters.
    fn models(ks: f32, alpha: f32, alpha_y: f32, tangent_rad: f32) -> [Material; 5] {
        [
            Model::Lambert,
            Model::WardIso,
            Model::WardAniso,
            Model::BlinnPhong,
            Model::Ggx,
        ]
        .map(|model| Material {
            model,
            ks,
            alpha,
            alpha_y,
            tangent_rad,
            ..Material::lambert(Vec3A::splat(0.5))
        })
    }

    proptest! {
        #[test]
        fn brdf_is_finite_and_non_negative(
            ti in 0.0f32..1.6, pi_ in 0.0f32..6.3, to in 0.0f32..1.6, po in 0.0f32..6.3,
            alpha in 0.0f32..1.5, ay in 0.0f32..1.5, ks in 0.0f32..1.0, tn in 0.0f32..1.6,
            pn in 0.0f32..6.3, rot in -7.0f32..7.0,
        ) {
            let n = dir(tn, pn);
            let (wi, wo) = (dir(ti, pi_), dir(to, po));
            for m in models(ks, alpha, ay, rot) {
                let f = brdf(&m, n, wi, wo, true);
                prop_assert!(f.is_finite(), "{:?} {f}", m.model);
                prop_assert!(f.min_element() >= 0.0, "{:?} {f}", m.model);
                // What the integrator multiplies by the cosine must stay finite too.
                let e = f * n.dot(wi).max(0.0);
                prop_assert!(e.is_finite() && e.min_element() >= 0.0);
            }
        }

        /// Grazing within 1e-4 rad of the horizon (either direction, both): still finite,
        /// non-negative, and the specular part times cosθi stays below 1/(4πα²)·√(1/1e-3)·2
        /// for Ward (the 1e-3 guard), i.e. no firefly.
        #[test]
        fn grazing_is_bounded(eps in 0.0f32..1e-4, to in 0.0f32..1.6, po in 0.0f32..6.3,
                              alpha in 0.05f32..1.0, rot in 0.0f32..6.3, swap in 0u8..2) {
            let (mut wi, mut wo) = (dir(std::f32::consts::FRAC_PI_2 - eps, 0.0), dir(to, po));
            if swap == 1 {
                std::mem::swap(&mut wi, &mut wo);
            }
            for m in models(1.0, alpha, alpha, rot) {
                let f = brdf(&m, Vec3A::Z, wi, wo, true);
                prop_assert!(f.is_finite() && f.min_element() >= 0.0, "{:?} {f}", m.model);
                let spec = (f.x - 0.5 * FRAC_1_PI) * wi.z.max(0.0);
                let cap = 2.0 / (4.0 * std::f32::consts::PI * alpha * alpha) * (1.0 / MIN_COS).sqrt();
                if matches!(m.model, Model::WardIso | Model::WardAniso) {
                    prop_assert!(spec <= cap, "{:?} {spec} > {cap}", m.model);
                }
            }
        }

        #[test]
        fn tangent_frame_is_orthonormal(tn in 0.0f32..1.6, pn in 0.0f32..6.3, rot in -7.0f32..7.0) {
            let n = dir(tn, pn);
            let (t, b) = tangent_frame(n, rot);
            for (u, v) in [(t, b), (t, n), (b, n)] {
                prop_assert!(u.dot(v).abs() < 1e-4);
            }
            prop_assert!((t.length() - 1.0).abs() < 1e-4 && (b.length() - 1.0).abs() < 1e-4);
        }

        /// Anisotropic Ward with αx = αy is the isotropic lobe (stated bound 1e-4 relative).
        #[test]
        fn aniso_with_equal_alphas_is_iso(ti in 0.0f32..1.5, pi_ in 0.0f32..6.3, to in 0.0f32..1.5,
                                          po in 0.0f32..6.3, alpha in 0.05f32..1.0, rot in 0.0f32..6.3) {
            let [_, iso, aniso, _, _] = models(1.0, alpha, alpha, rot);
            let (wi, wo) = (dir(ti, pi_), dir(to, po));
            let (a, b) = (specular_lobe(&iso, Vec3A::Z, wi, wo), specular_lobe(&aniso, Vec3A::Z, wi, wo));
            prop_assert!((a - b).abs() <= 1e-4 * a.max(b) + 1e-12, "{a} {b}");
        }
    }

    #[test]
    fn exactly_grazing_and_degenerate_inputs() {
        let n = Vec3A::Z;
        for m in models(0.5, 0.0, 0.0, 0.0) {
            for (wi, wo) in [
                (Vec3A::X, -Vec3A::X),
                (Vec3A::X, Vec3A::X),
                (Vec3A::Z, Vec3A::Z),
                (
                    Vec3A::new(1.0, 0.0, 1e-7).normalize(),
                    Vec3A::new(-1.0, 0.0, 1e-7).normalize(),
                ),
                (Vec3A::ZERO, Vec3A::ZERO),
                (Vec3A::NAN, Vec3A::Z),
            ] {
                let f = brdf(&m, n, wi, wo, true);
                assert!(f.is_finite() && f.min_element() >= 0.0, "{wi} {wo}: {f}");
            }
        }
        assert_eq!(blinn_phong_exponent(f32::NAN), 0.0);
        assert_eq!(blinn_phong_exponent(2.0), 0.0);
        assert!((blinn_phong_exponent(0.1) - 198.0).abs() < 1e-3);
    }

    /// Directional albedo ∫ (f − ρd/π) cosθo dωo of the specular part for light at polar angle
    /// `theta_i` (normal +z), over a 512 × 512 half-vector midpoint grid (dωo = 4(wi·h) dωh),
    /// accumulated in f64.
    fn specular_albedo(m: &Material, theta_i: f32) -> f64 {
        const STEPS: usize = 512;
        let wi = dir(theta_i, 0.0);
        let (dt, dp) = (
            std::f64::consts::FRAC_PI_2 / STEPS as f64,
            std::f64::consts::TAU / STEPS as f64,
        );
        let mut sum = 0.0f64;
        for i in 0..STEPS {
            let th = (i as f64 + 0.5) * dt;
            for j in 0..STEPS {
                let ph = (j as f64 + 0.5) * dp;
                let h = dir(th as f32, ph as f32);
                let c = wi.dot(h);
                if c <= 0.0 {
                    continue;
                }
                let wo = h * (2.0 * c) - wi;
                if wo.z <= 0.0 {
                    continue;
                }
                let f = specular_lobe(m, Vec3A::Z, wi, wo) as f64;
                sum += f * wo.z as f64 * 4.0 * c as f64 * th.sin();
            }
        }
        sum * dt * dp
    }

    /// White furnace of the renderer's lobes (ρd = 0, ρs = 1; GGX with F0 = 1 so F = 1),
    /// θi ∈ {0°, 30°, 60°, 80°}. Stated bounds: GGX ≤ 1 + 5e-3 (single scattering loses
    /// energy; 5e-3 covers the 512² grid and f32), anisotropic Ward (αx = 0.1, αy = 0.4, tangent
    /// at 30°) ≤ 1 + 5e-3 (Ward only gains energy within ~1° of grazing), Blinn–Phong ≤ 1.08 (its
    /// (m+8)/(8π) normalisation overshoots by up to 7.5% near m = 10, see
    /// `materials::blinn_phong`).
    #[test]
    fn white_furnace_bounds() {
        let base = Material {
            ks: 1.0,
            ..Material::lambert(Vec3A::ZERO)
        };
        let cases = [
            (Model::Ggx, 0.1, 0.1, 1.0 + 5e-3),
            (Model::Ggx, 0.5, 0.5, 1.0 + 5e-3),
            (Model::WardAniso, 0.1, 0.4, 1.0 + 5e-3),
            (Model::BlinnPhong, 0.4, 0.4, 1.08),
            (Model::BlinnPhong, 0.1, 0.1, 1.08),
        ];
        for (model, alpha, alpha_y, bound) in cases {
            let m = Material {
                model,
                alpha,
                alpha_y,
                tangent_rad: 0.5,
                ..base
            };
            for deg in [0.0f32, 30.0, 60.0, 80.0] {
                let a = specular_albedo(&m, deg.to_radians());
                assert!(
                    a.is_finite() && a >= 0.0 && a <= bound,
                    "{model:?} α {alpha} θ {deg}: {a}"
                );
                if deg == 0.0 && model == Model::Ggx && alpha <= 0.1 {
                    assert!(a >= 0.97, "{model:?} α {alpha}: {a}");
                }
            }
        }
    }

    #[test]
    fn lobe_peaks_at_the_mirror_for_every_model() {
        let wi = dir(0.5, 0.0);
        let mirror = dir(0.5, std::f32::consts::PI);
        let off = dir(0.5, std::f32::consts::PI + 0.4);
        for m in models(0.5, 0.2, 0.2, 0.0).into_iter().skip(1) {
            let (a, b) = (
                specular_lobe(&m, Vec3A::Z, wi, mirror),
                specular_lobe(&m, Vec3A::Z, wi, off),
            );
            assert!(a > b && b >= 0.0, "{:?}: {a} {b}", m.model);
        }
    }

    /// The anisotropic lobe is wider along the tangent (αx = 0.4) than across it (αy = 0.1):
    /// rotating the tangent by 90° swaps which off-mirror direction is brighter.
    #[test]
    fn anisotropic_lobe_follows_the_tangent() {
        let m = |rot: f32| Material {
            model: Model::WardAniso,
            ks: 1.0,
            alpha: 0.4,
            alpha_y: 0.1,
            tangent_rad: rot,
            ..Material::lambert(Vec3A::ZERO)
        };
        let wi = dir(0.3, 0.0);
        let along_x = dir(0.6, std::f32::consts::PI);
        let along_y = Vec3A::new(-0.3f32.sin(), 0.4, 0.3f32.cos()).normalize();
        let s = |m: Material, wo| specular_lobe(&m, Vec3A::Z, wi, wo);
        assert!(s(m(0.0), along_x) > s(m(0.0), along_y));
        assert!(
            s(m(std::f32::consts::FRAC_PI_2), along_x) < s(m(std::f32::consts::FRAC_PI_2), along_y)
        );
    }
}
