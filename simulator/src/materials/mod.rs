//! Reflectance and subsurface-scattering models behind the renderer's materials: exact and
//! approximate Fresnel, Lambert, isotropic/anisotropic Ward, normalised Blinn–Phong,
//! Cook–Torrance GGX and the Jensen dipole.
//!
//! Everything is f64 with angles in radians; directions are unit `glam::DVec3` vectors pointing
//! *away* from the surface (`wi` to the light, `wo` to the viewer). Every function is total:
//! for any input (including NaN, infinities, directions at or below the horizon) it returns a
//! finite, non-negative value, with each clamp documented where it applies. The renderer
//! (`render::shading`, `render::subsurface`) uses the f32 variants in its hot loops.

pub mod blinn_phong;
pub mod dipole;
pub mod fresnel;
pub mod lambert;
pub mod microfacet;
pub mod ward;

pub use blinn_phong::{blinn_phong, blinn_phong_f32};
pub use dipole::{Dipole, reduced_albedo_from_total, total_diffuse_reflectance};
pub use fresnel::{
    boundary_coefficient, diffuse_fresnel_reflectance, fresnel_reflectance, fresnel_transmittance,
    fresnel_transmittance_f32, hemispherical_transmittance, schlick, schlick_f0,
};
pub use lambert::lambert;
pub use microfacet::{
    Fresnel, cook_torrance_ggx, cook_torrance_ggx_f32, ggx_d, smith_ggx_visibility,
};
pub use ward::{ward_aniso, ward_aniso_f32, ward_iso, ward_iso_f32};

use glam::DVec3;

/// `x` clamped into [lo, hi], with NaN replaced by `nan_default` (±∞ clamp to the bounds).
#[inline]
fn sanitize(x: f64, lo: f64, hi: f64, nan_default: f64) -> f64 {
    if x.is_nan() {
        nan_default
    } else {
        x.clamp(lo, hi)
    }
}

/// Per-channel coefficient clamp used by [`Material::eval`]: into [0, 1], NaN → 0
/// (reflectances are fractions of incident energy).
#[inline]
fn coeff(x: f64) -> f64 {
    sanitize(x, 0.0, 1.0, 0.0)
}

/// A surface reflectance model with RGB coefficients, evaluated as a BRDF (sr⁻¹) by
/// [`Material::eval`]. Why: one type the renderer can store per surface and switch on, instead
/// of the fixed Lambert + Ward of `render::shading`.
///
/// Coefficients (`albedo`, `diffuse`, `specular`) are per-channel fractions clamped into
/// [0, 1] (NaN → 0) at evaluation. `diffuse + specular ≤ 1` per channel is the caller's job if
/// energy conservation is wanted (Ward additionally gains energy at grazing; see `ward`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Material {
    /// ρ_d/π.
    Lambert {
        /// Diffuse albedo ρ_d per channel.
        albedo: [f64; 3],
    },
    /// ρ_d/π + ρ_s·ψ_Ward(α) — the thesis' SVBRDF model.
    WardIso {
        /// Diffuse albedo ρ_d per channel.
        diffuse: [f64; 3],
        /// Specular albedo ρ_s per channel.
        specular: [f64; 3],
        /// Roughness α (slope standard deviation), see [`ward::MIN_ALPHA`].
        alpha: f64,
    },
    /// ρ_d/π + ρ_s·ψ_Ward(α_x along t, α_y along b).
    WardAniso {
        /// Diffuse albedo ρ_d per channel.
        diffuse: [f64; 3],
        /// Specular albedo ρ_s per channel.
        specular: [f64; 3],
        /// Roughness along the tangent `t`.
        alpha_x: f64,
        /// Roughness along the bitangent `b`.
        alpha_y: f64,
    },
    /// ρ_d/π + ρ_s·(m+8)/(8π)(n·h)^m.
    BlinnPhong {
        /// Diffuse albedo ρ_d per channel.
        diffuse: [f64; 3],
        /// Specular scale ρ_s per channel.
        specular: [f64; 3],
        /// Blinn–Phong exponent m ≥ 0.
        exponent: f64,
    },
    /// ρ_d/π + k_s·F·D·G₂/(4 cosθ_i cosθ_o), GGX with height-correlated Smith masking.
    CookTorranceGgx {
        /// Diffuse albedo ρ_d per channel.
        diffuse: [f64; 3],
        /// Specular tint k_s per channel (multiplies F).
        specular: [f64; 3],
        /// GGX roughness α, see [`microfacet::MIN_ALPHA`].
        alpha: f64,
        /// The Fresnel model.
        fresnel: Fresnel,
    },
    /// A homogeneous translucent medium (Jensen dipole). As a BRDF, [`Material::eval`] returns
    /// its far-field limit under uniform illumination, F_t(θ_i) R_d F_t(θ_o)/π with R_d the
    /// closed-form total diffuse reflectance (eq. 1.20 integrated over the surface); the spatial
    /// profile is available from [`Material::dipoles`].
    Dipole {
        /// Reduced albedo α′ per channel.
        alpha_prime: [f64; 3],
        /// Reduced extinction σ′_t per channel (mm⁻¹).
        sigma_t_prime: [f64; 3],
        /// Relative index of refraction (the thesis uses 1.3).
        eta: f64,
    },
}

impl Material {
    /// The BRDF value per RGB channel for light from `wi` seen from `wo` at a surface with
    /// orthonormal frame (`n`, `t`, `b`); `t`/`b` matter only for [`Material::WardAniso`].
    ///
    /// Always finite and ≥ 0; exactly 0 in every channel when `wi` or `wo` is at or below the
    /// horizon (n·w ≤ 0). Reciprocal: eval(wi, wo) = eval(wo, wi).
    pub fn eval(&self, wi: DVec3, wo: DVec3, n: DVec3, t: DVec3, b: DVec3) -> [f64; 3] {
        let (ci, co) = (n.dot(wi), n.dot(wo));
        if ci.is_nan() || co.is_nan() || ci <= 0.0 || co <= 0.0 {
            return [0.0; 3];
        }
        let mix = |d: &[f64; 3], s: &[f64; 3], lobe: f64| {
            let l = lambert(n, wi, wo, 1.0);
            std::array::from_fn(|c| coeff(d[c]) * l + coeff(s[c]) * lobe)
        };
        let out: [f64; 3] = match self {
            Material::Lambert { albedo } => std::array::from_fn(|c| lambert(n, wi, wo, albedo[c])),
            Material::WardIso {
                diffuse,
                specular,
                alpha,
            } => mix(diffuse, specular, ward_iso(n, wi, wo, *alpha)),
            Material::WardAniso {
                diffuse,
                specular,
                alpha_x,
                alpha_y,
            } => mix(
                diffuse,
                specular,
                ward_aniso(n, t, b, wi, wo, *alpha_x, *alpha_y),
            ),
            Material::BlinnPhong {
                diffuse,
                specular,
                exponent,
            } => mix(diffuse, specular, blinn_phong(n, wi, wo, *exponent)),
            Material::CookTorranceGgx {
                diffuse,
                specular,
                alpha,
                fresnel,
            } => mix(
                diffuse,
                specular,
                cook_torrance_ggx(n, wi, wo, *alpha, *fresnel),
            ),
            Material::Dipole {
                alpha_prime, eta, ..
            } => {
                let ft = fresnel_transmittance(ci, *eta) * fresnel_transmittance(co, *eta);
                std::array::from_fn(|c| {
                    ft * total_diffuse_reflectance(alpha_prime[c], *eta)
                        * std::f64::consts::FRAC_1_PI
                })
            }
        };
        out.map(|v| if v.is_finite() && v >= 0.0 { v } else { 0.0 })
    }

    /// The per-channel dipole media of a [`Material::Dipole`] (for spatial profiles R_d(r) and
    /// laser-line integrals); `None` for surface materials.
    pub fn dipoles(&self) -> Option<[Dipole; 3]> {
        match self {
            Material::Dipole {
                alpha_prime,
                sigma_t_prime,
                eta,
            } => Some(std::array::from_fn(|c| {
                Dipole::from_reduced_albedo(alpha_prime[c], sigma_t_prime[c], *eta)
            })),
            _ => None,
        }
    }
}

#[cfg(test)]
pub(crate) mod testutil {
    //! Shared test helpers: spherical directions, random frames and the white-furnace
    //! integrator.
    use glam::DVec3;
    use std::f64::consts::{FRAC_PI_2, PI};

    /// Unit vector at polar angle `theta` from +Z and azimuth `phi`.
    pub fn dir(theta: f64, phi: f64) -> DVec3 {
        DVec3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    /// An orthonormal frame (n, t, b) with n at (tn, pn) and the tangent rotated by `rot`.
    pub fn frame(tn: f64, pn: f64, rot: f64) -> (DVec3, DVec3, DVec3) {
        let n = dir(tn, pn);
        let (t0, b0) = n.any_orthonormal_pair();
        let t = t0 * rot.cos() + b0 * rot.sin();
        (n, t, n.cross(t))
    }

    /// Maps local (z-up) directions into the frame (n, t, b).
    pub fn in_frame(n: DVec3, t: DVec3, b: DVec3, a: DVec3, c: DVec3) -> (DVec3, DVec3) {
        let m = |v: DVec3| t * v.x + b * v.y + n * v.z;
        (m(a), m(c))
    }

    /// θ_h steps of the white-furnace integrator.
    pub const FURNACE_THETA_STEPS: usize = 1024;
    /// φ_h steps of the white-furnace integrator.
    pub const FURNACE_PHI_STEPS: usize = 1024;

    /// Directional albedo ∫ f(wi, wo) cosθ_o dω_o for wi at polar angle `theta_i` (normal +Z),
    /// integrated over the half vector h (midpoint rule, [`FURNACE_THETA_STEPS`] ×
    /// [`FURNACE_PHI_STEPS`] over the upper hemisphere of h) with wo = 2(wi·h)h − wi and
    /// dω_o = 4(wi·h) dω_h. Half-vector space puts the grid where glossy lobes live.
    pub fn albedo(theta_i: f64, f: impl Fn(DVec3, DVec3) -> f64) -> f64 {
        let wi = dir(theta_i, 0.0);
        let (dt, dp) = (
            FRAC_PI_2 / FURNACE_THETA_STEPS as f64,
            2.0 * PI / FURNACE_PHI_STEPS as f64,
        );
        let mut sum = 0.0;
        for i in 0..FURNACE_THETA_STEPS {
            let th = (i as f64 + 0.5) * dt;
            let (st, ct) = th.sin_cos();
            for j in 0..FURNACE_PHI_STEPS {
                let ph = (j as f64 + 0.5) * dp;
                let h = DVec3::new(st * ph.cos(), st * ph.sin(), ct);
                let c = wi.dot(h);
                if c <= 0.0 {
                    continue;
                }
                let wo = 2.0 * c * h - wi;
                if wo.z <= 0.0 {
                    continue;
                }
                sum += f(wi, wo) * wo.z * 4.0 * c * st;
            }
        }
        sum * dt * dp
    }
}

#[cfg(test)]
mod tests {
    use super::testutil::{albedo, dir, frame, in_frame};
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::FRAC_PI_2;

    fn materials() -> Vec<Material> {
        vec![
            Material::Lambert {
                albedo: [0.8, 0.5, 0.2],
            },
            Material::WardIso {
                diffuse: [0.3, 0.3, 0.3],
                specular: [0.2, 0.1, 0.05],
                alpha: 0.15,
            },
            Material::WardAniso {
                diffuse: [0.3, 0.3, 0.3],
                specular: [0.2, 0.1, 0.05],
                alpha_x: 0.05,
                alpha_y: 0.4,
            },
            Material::BlinnPhong {
                diffuse: [0.5, 0.4, 0.3],
                specular: [0.3, 0.3, 0.3],
                exponent: 50.0,
            },
            Material::CookTorranceGgx {
                diffuse: [0.5, 0.4, 0.3],
                specular: [1.0, 1.0, 1.0],
                alpha: 0.2,
                fresnel: Fresnel::Dielectric { eta: 1.5 },
            },
            Material::Dipole {
                alpha_prime: [0.4248, 0.4248, 0.99],
                sigma_t_prime: [1.0, 1.5, 2.13],
                eta: 1.3,
            },
        ]
    }

    #[test]
    fn grazing_and_below_horizon() {
        let (n, t, b) = (DVec3::Z, DVec3::X, DVec3::Y);
        for m in materials() {
            for (ti, to) in [
                (FRAC_PI_2, 0.3),
                (FRAC_PI_2, FRAC_PI_2),
                (FRAC_PI_2 - 1e-9, FRAC_PI_2 - 1e-9),
                (FRAC_PI_2 + 1e-9, 0.2),
                (0.2, FRAC_PI_2 + 1e-3),
                (0.0, 0.0),
            ] {
                let v = m.eval(dir(ti, 0.0), dir(to, 3.0), n, t, b);
                assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{m:?} {v:?}");
                if ti > FRAC_PI_2 || to > FRAC_PI_2 {
                    assert_eq!(v, [0.0; 3]);
                }
            }
            assert_eq!(m.eval(DVec3::X, DVec3::Z, n, t, b), [0.0; 3]);
            assert_eq!(m.eval(DVec3::NAN, DVec3::Z, n, t, b), [0.0; 3]);
        }
    }

    proptest! {
        #[test]
        fn reciprocal_finite_non_negative(ti in 0.0f64..1.6, pi_ in 0.0f64..6.3, to in 0.0f64..1.6,
                                          po in 0.0f64..6.3, tn in 0.0f64..1.2, pn in 0.0f64..6.3,
                                          rot in 0.0f64..6.3) {
            let (n, t, b) = frame(tn, pn, rot);
            let (wi, wo) = in_frame(n, t, b, dir(ti, pi_), dir(to, po));
            for m in materials() {
                let f = m.eval(wi, wo, n, t, b);
                let g = m.eval(wo, wi, n, t, b);
                for c in 0..3 {
                    prop_assert!(f[c].is_finite() && f[c] >= 0.0);
                    prop_assert!((f[c] - g[c]).abs() <= 1e-12 * f[c].max(g[c]), "{m:?} {f:?} {g:?}");
                }
            }
        }
    }

    /// White furnace for the dipole's far-field BRDF: albedo = R_d·(1 − F_r averaged) ≤ R_d ≤ 1.
    #[test]
    fn dipole_brdf_furnace() {
        let m = Material::Dipole {
            alpha_prime: [0.999999, 0.5, 0.01],
            sigma_t_prime: [1.0; 3],
            eta: 1.3,
        };
        for deg in [0.0, 60.0, 89.0] {
            for c in 0..3 {
                let a = albedo(f64::to_radians(deg), |wi, wo| {
                    m.eval(wi, wo, DVec3::Z, DVec3::X, DVec3::Y)[c]
                });
                assert!(a.is_finite() && (0.0..=1.0).contains(&a), "{deg} {c}: {a}");
            }
        }
        assert!(m.dipoles().is_some());
        assert!(materials()[0].dipoles().is_none());
    }
}
