//! Grazing light and view, extreme parameters: the renderer's BRDFs, Ward, Cook–Torrance and
//! the dipole at the ends of their ranges.

use super::*;

proptest! {
    /// Light and view within `GRAZING_RAD` of the horizon (and just below it): the renderer's
    /// BRDF for every model and roughness from "→ 0" to 10 is finite and non-negative, and
    /// exactly 0 when a direction is below the horizon.
    #[test]
    fn renderer_brdf_at_grazing_is_finite_and_non_negative(
        di in -GRAZING_RAD..GRAZING_RAD, dout in -GRAZING_RAD..GRAZING_RAD,
        phi in 0.0f64..6.3, k in 0usize..5, ai in 0usize..5, ks in 0.0f32..1.0,
    ) {
        let _turn = crate::grbl_peer::alongside();
        let alpha = [1e-6f32, 0.01, 0.2, 1.0, 10.0][ai];
        let m = render_material(MODELS[k], 0.5, ks, alpha);
        let n = Vec3A::Z;
        let (ti, to) = (FRAC_PI_2 - di, FRAC_PI_2 - dout);
        let (wi, wo) = (dir(ti, 0.0).as_vec3a(), dir(to, phi).as_vec3a());
        for specular in [false, true] {
            let f = brdf(&m, n, wi, wo, specular);
            prop_assert!(f.is_finite() && f.min_element() >= 0.0, "{m:?} {wi} {wo}: {f}");
            // What the integrator multiplies by cosθi stays finite too.
            let e = f * n.dot(wi).max(0.0);
            prop_assert!(e.is_finite() && e.min_element() >= 0.0);
        }
        let lobe = ward_lobe(n, wi, wo, alpha);
        prop_assert!(lobe.is_finite() && lobe >= 0.0, "{lobe}");
        if wi.z <= 0.0 || wo.z <= 0.0 {
            prop_assert_eq!(lobe, 0.0);
        }
    }

    /// The same grazing range for every `materials` model (f64 and the f32 variants), with
    /// Ward α from `WARD_ALPHA_TINY` to 10 and the dipole at σ′t 0.01 and 10, α′ → 1.
    #[test]
    fn materials_at_grazing_are_finite_and_non_negative(
        di in -GRAZING_RAD..GRAZING_RAD, dout in -GRAZING_RAD..GRAZING_RAD,
        phi in 0.0f64..6.3, ai in 0usize..5,
    ) {
        let _turn = crate::grbl_peer::alongside();
        let alpha = [WARD_ALPHA_TINY, 0.01, 0.2, 1.0, 10.0][ai];
        let (n, t, b) = (DVec3::Z, DVec3::X, DVec3::Y);
        let (wi, wo) = (dir(FRAC_PI_2 - di, 0.0), dir(FRAC_PI_2 - dout, phi));
        let below = wi.z <= 0.0 || wo.z <= 0.0;
        let mut values = vec![
            lambert(n, wi, wo, 1.0),
            ward_iso(n, wi, wo, alpha),
            ward_aniso(n, t, b, wi, wo, alpha, 2.0 * alpha),
            blinn_phong(n, wi, wo, 2.0 / (alpha * alpha)),
            cook_torrance_ggx(n, wi, wo, alpha, Fresnel::One),
            cook_torrance_ggx(n, wi, wo, alpha, Fresnel::Dielectric { eta: 1.5 }),
            ward_aniso_f32(Vec3A::Z, Vec3A::X, Vec3A::Y, wi.as_vec3a(), wo.as_vec3a(),
                           alpha as f32, 2.0 * alpha as f32) as f64,
            cook_torrance_ggx_f32(Vec3A::Z, wi.as_vec3a(), wo.as_vec3a(), alpha as f32, 0.04)
                as f64,
        ];
        for sigma_t in [0.01, 10.0] {
            for ap in [0.999999, 1.0] {
                let m = materials::Material::Dipole {
                    alpha_prime: [ap; 3],
                    sigma_t_prime: [sigma_t; 3],
                    eta: 1.3,
                };
                values.extend(m.eval(wi, wo, n, t, b));
            }
        }
        for (k, v) in values.iter().enumerate() {
            prop_assert!(v.is_finite() && *v >= 0.0, "model {k}: {v}");
            if below {
                prop_assert_eq!(*v, 0.0, "model {} below the horizon", k);
            }
        }
    }
}

/// Ward at α = `WARD_ALPHA_TINY` (clamped, a finite spike at the mirror direction, exactly 0
/// elsewhere) and at α = 1 and 10 (broad, below the normalisation bound 1/(4πα²√(cosθi cosθo))),
/// in both the renderer's lobe and the `materials` ones.
#[test]
fn ward_alpha_extremes() {
    let _turn = crate::grbl_peer::alongside();
    let n = DVec3::Z;
    for ti in [0.0, 0.4, 1.2, FRAC_PI_2 - GRAZING_RAD] {
        let wi = dir(ti, 0.0);
        let mirror = dir(ti, PI);
        for v in [
            ward_iso(n, wi, mirror, WARD_ALPHA_TINY),
            ward_aniso(
                n,
                DVec3::X,
                DVec3::Y,
                wi,
                mirror,
                WARD_ALPHA_TINY,
                WARD_ALPHA_TINY,
            ),
            ward_lobe(
                Vec3A::Z,
                wi.as_vec3a(),
                mirror.as_vec3a(),
                WARD_ALPHA_TINY as f32,
            ) as f64,
        ] {
            assert!(v.is_finite() && v > 0.0, "θi {ti}: mirror value {v}");
        }
        // Off the mirror by 0.3 rad the α → 0 lobe vanishes: δ ≈ 0.15 rad gives exponents of
        // 227 at the renderer's α clamp of 0.01 (cut at 30) and 2·10⁴ at materials' 1e-3.
        let off = dir(ti + 0.3, PI);
        assert_eq!(ward_iso(n, wi, off, WARD_ALPHA_TINY), 0.0);
        assert_eq!(
            ward_lobe(
                Vec3A::Z,
                wi.as_vec3a(),
                off.as_vec3a(),
                WARD_ALPHA_TINY as f32
            ),
            0.0
        );
        for alpha in [1.0, 10.0] {
            for to in [0.0, 0.7, 1.5, FRAC_PI_2 - GRAZING_RAD] {
                for po in [0.0, 1.0, PI] {
                    let wo = dir(to, po);
                    let bound =
                        1.0 / (4.0 * PI * alpha * alpha * (wi.z.max(1e-6) * wo.z.max(1e-6)).sqrt());
                    for v in [
                        ward_iso(n, wi, wo, alpha),
                        ward_aniso(n, DVec3::X, DVec3::Y, wi, wo, alpha, alpha),
                    ] {
                        // (0 is right where both directions graze on the same side: the half
                        // vector is then nearly horizontal and the exponent passes 700.)
                        assert!(
                            v.is_finite() && v >= 0.0 && v <= bound * (1.0 + 1e-12),
                            "α {alpha} θi {ti} θo {to} φo {po}: {v} vs bound {bound}"
                        );
                    }
                    let r = ward_lobe(Vec3A::Z, wi.as_vec3a(), wo.as_vec3a(), alpha as f32) as f64;
                    let r_bound =
                        1.0 / (4.0 * PI * alpha * alpha * (wi.z.max(1e-3) * wo.z.max(1e-3)).sqrt());
                    assert!(
                        r.is_finite() && r >= 0.0 && r <= r_bound * (1.0 + 1e-5),
                        "{r} > {r_bound}"
                    );
                }
            }
        }
    }
}

/// Cook–Torrance's 1/(cosθi cosθo) at cosθ = `CT_GRAZING_COS`: finite and non-negative with
/// one or both directions grazing; with one grazing and the other normal, at most the GGX peak
/// max(1/(πα²), α²/π) times the visibility bound ½/min(α, 1) (V = ½/(cosθo Λi + cosθi Λo)
/// there, with Λ of the grazing side ≈ α).
#[test]
fn cook_torrance_at_grazing_cosines() {
    let _turn = crate::grbl_peer::alongside();
    let n = DVec3::Z;
    let grazing = |phi: f64| {
        let s = (1.0 - CT_GRAZING_COS * CT_GRAZING_COS).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), CT_GRAZING_COS)
    };
    for alpha in [WARD_ALPHA_TINY, 0.01, 0.3, 1.0, 10.0] {
        for fr in [
            Fresnel::One,
            Fresnel::Dielectric { eta: 1.5 },
            Fresnel::Schlick { f0: 0.9 },
        ] {
            for (wi, wo) in [
                (grazing(0.0), grazing(PI)),
                (grazing(0.0), grazing(0.0)),
                (grazing(0.0), grazing(2.0)),
                (grazing(0.0), DVec3::Z),
                (DVec3::Z, grazing(1.0)),
            ] {
                let v = cook_torrance_ggx(n, wi, wo, alpha, fr);
                assert!(v.is_finite() && v >= 0.0, "α {alpha} {fr:?}: {v}");
                let a = alpha.max(materials::microfacet::MIN_ALPHA);
                if wi == DVec3::Z || wo == DVec3::Z {
                    let d_peak = (1.0 / (PI * a * a)).max(a * a / PI);
                    let bound = d_peak * 0.5 / a.min(1.0);
                    assert!(v <= bound, "α {alpha}: {v} > {bound}");
                }
                let f = cook_torrance_ggx_f32(
                    Vec3A::Z,
                    wi.as_vec3a(),
                    wo.as_vec3a(),
                    alpha as f32,
                    0.9,
                );
                assert!(f.is_finite() && f >= 0.0, "f32 α {alpha}: {f}");
            }
        }
    }
}

/// The dipole at σ′t = 0.01 and 10 mm⁻¹ and α′ → 1 (0.999999 and exactly 1): the profile is
/// finite and non-negative from r = 0 to 10⁴ mm, the closed-form total diffuse reflectance is
/// below 1 for α′ < 1 (exactly 1 at α′ = 1 — its documented limit) and the numeric plane
/// integral of the profile agrees with it to 1e-6 (the module's measured error at 200 panels
/// is 1e-9).
#[test]
fn dipole_at_extreme_coefficients() {
    let _turn = crate::grbl_peer::alongside();
    for sigma_t in [0.01, 10.0] {
        for ap in [0.5, 0.999999, 1.0] {
            for eta in [1.0, 1.3] {
                let m = Dipole::from_reduced_albedo(ap, sigma_t, eta);
                let mut r = 0.0;
                while r < 1.0e4 {
                    let v = m.rd(r);
                    assert!(
                        v.is_finite() && v >= 0.0,
                        "σ′t {sigma_t} α′ {ap} r {r}: {v}"
                    );
                    r = r * 1.5 + 1.0e-6;
                }
                let line = m.line_source(0.5, 200);
                assert!(line.is_finite() && line >= 0.0, "{line}");
                let total = m.total_diffuse_reflectance();
                assert!(total.is_finite() && total > 0.0, "{total}");
                if ap < 1.0 {
                    assert!(total < 1.0, "σ′t {sigma_t} α′ {ap}: R_d {total}");
                } else {
                    assert!(total <= 1.0, "α′ = 1: R_d {total}");
                }
                let numeric = m.total_diffuse_reflectance_numeric(200);
                assert!(
                    (numeric - total).abs() <= 1e-6 * total,
                    "σ′t {sigma_t} α′ {ap} η {eta}: numeric {numeric} vs closed {total}"
                );
            }
        }
    }
}

proptest! {
    /// Total diffuse reflectance is monotone non-decreasing in α′ over [0, 1] (so the α′ fit
    /// by bisection is well posed) and never above 1.
    #[test]
    fn dipole_total_reflectance_is_monotone_in_alpha(a in 0.0f64..=1.0, b in 0.0f64..=1.0,
                                                     eta in 1.0f64..2.0) {
        let _turn = crate::grbl_peer::alongside();
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        let (rl, rh) = (total_diffuse_reflectance(lo, eta), total_diffuse_reflectance(hi, eta));
        prop_assert!(rl <= rh, "R({lo}) = {rl} > R({hi}) = {rh}");
        prop_assert!(rh <= 1.0 && rl >= 0.0);
    }
}

/// Monotonicity on a dense grid approaching α′ = 1, where √(3(1 − α′)) → 0 and rounding could
/// make consecutive values step backwards.
#[test]
fn dipole_total_reflectance_is_monotone_near_one() {
    let _turn = crate::grbl_peer::alongside();
    for eta in [1.0, 1.3, 1.5] {
        let mut prev = total_diffuse_reflectance(0.99, eta);
        for k in 1..=10_000 {
            let ap = 0.99 + 0.01 * (k as f64 / 10_000.0);
            let v = total_diffuse_reflectance(ap, eta);
            assert!(v >= prev, "η {eta}: R({ap}) = {v} < {prev}");
            assert!(v <= 1.0);
            prev = v;
        }
        for ap in [1.0 - 1e-6, 1.0 - 1e-9, 1.0 - 1e-12, 1.0 - 1e-15] {
            let v = total_diffuse_reflectance(ap, eta);
            assert!(v < 1.0, "α′ {ap}: {v}");
        }
    }
}
