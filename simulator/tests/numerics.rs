//! Hard numerical cases for the renderer and the reflectance models, through the public API:
//! grazing light and view, extreme roughness and scattering coefficients, degenerate rays in
//! the height-field march, shadow acne at 1° light elevation, one-texel spikes and walls, a
//! white furnace, f32 against f64, and the sensor at its limits.
//!
//! Every bound is a named constant with the reason for its value. Every radiance image the
//! tests render is scanned for NaN, infinity and negative values (`checked`). Cameras are cut
//! to 64×48 so the whole file runs in seconds.

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_1_PI, FRAC_PI_2, PI};

use glam::{DVec3, Vec3A};
use proptest::prelude::*;
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, RigSpec, parse_rig};
use stagehand_simulator::materials::{
    self, Dipole, Fresnel, blinn_phong, cook_torrance_ggx, cook_torrance_ggx_f32, lambert,
    total_diffuse_reflectance, ward_aniso, ward_aniso_f32, ward_iso,
};
use stagehand_simulator::render::config::SimSpec;
use stagehand_simulator::render::geometry::{CameraPose, ToSample};
use stagehand_simulator::render::heightfield::HeightGrid;
use stagehand_simulator::render::lights::{HALOGEN_RADIUS_MM, HALOGEN_RGB, REFERENCE_DISTANCE_MM};
use stagehand_simulator::render::material::{Material, Model};
use stagehand_simulator::render::sample::Sample;
use stagehand_simulator::render::sensor::{self, Sensor};
use stagehand_simulator::render::shading::{brdf, ward_lobe};
use stagehand_simulator::render::shadow::{VertexVisibility, shadow_origin};
use stagehand_simulator::render::{RadianceImage, RenderError, Renderer};
use stagehand_simulator::world_snapshot::{LaserBeam, WorldSnapshot};

// ---------------------------------------------------------------------------------------------
// Bounds
// ---------------------------------------------------------------------------------------------

/// Test camera width: small enough that a frame costs a few milliseconds.
const W: u32 = 64;
/// Test camera height.
const H: u32 = 48;

/// Grazing angles tested: polar angles this close to 90° (radians) and closer.
const GRAZING_RAD: f64 = 1.0e-3;
/// Ward α "→ 0": far below both Ward modules' clamps (1e-2 renderer, 1e-3 materials).
const WARD_ALPHA_TINY: f64 = 1.0e-6;
/// Cosine used for "exactly grazing" Cook–Torrance: below `microfacet::MIN_COS` (1e-6), so
/// the clamp, not the formula, must keep 1/(cosθi cosθo) finite.
const CT_GRAZING_COS: f64 = 1.0e-7;

/// Marching step of the brute-force height-field reference, mm (a fifth of the finest cell).
const BRUTE_STEP_MM: f32 = 0.002;
/// How far the march's first hit may lie from the brute-force one after bisection, mm: f32
/// positions near 50 mm carry ~4e-6 mm of rounding; the patch quadratic adds a few ulps more.
const HIT_TOL_MM: f32 = 2.0e-3;
/// How far a reported surface hit may lie off the bilinear surface (|z − h|), mm: the same
/// rounding as `HIT_TOL_MM`, applied to heights of up to 5 mm.
const SURFACE_TOL_MM: f32 = 2.0e-3;
/// A brute-force penetration shallower than this may be missed by the march, mm: the march's
/// own shadow tolerance is 1e-3 mm, and a ray that only dips this deep is a numerical graze.
const GRAZE_DEPTH_MM: f32 = 2.0e-3;

/// Relative error allowed between the renderer's radiance (f32) and the f64 reference built
/// from the lamp model: about 30 f32 operations (ε = 6e-8 each) plus the f32 pixel ray.
const FURNACE_REL_TOL: f64 = 1.0e-4;
/// Irradiance at the pixel nearest the sample centre under the overhead reference lamp must be
/// 1 within this: that pixel lies up to ~2 mm off centre, and E falls as 1 − 1.5(r/800 mm)².
const CENTRE_IRRADIANCE_TOL: f64 = 1.0e-4;
/// Largest relative standard deviation of rendered/reference radiance over the lit region of
/// a flat sample: noise-free point-light rendering has no source of variation beyond rounding
/// (`FURNACE_REL_TOL`); one shadow-acne pixel in 1000 would already give ~3e-2.
const SPECKLE_REL_STD: f64 = 1.0e-4;
/// Energy conservation tolerance of the directional-albedo integrals: the 512×512 midpoint
/// half-vector grid integrates Lambert to within 1e-4 and smooth lobes to within 1e-3.
const ALBEDO_TOL: f64 = 2.0e-3;
/// Steps per axis of the directional-albedo integrator (half-vector θ and φ).
const ALBEDO_STEPS: usize = 512;
/// Largest θi at which the Ward lobe is held to energy conservation: beyond ~89° its
/// 1/√(cosθi cosθo) normalisation gains energy (documented in `materials::ward`).
const WARD_CONSERVING_DEG: f64 = 89.0;
/// The (m+8)/(8π) Blinn–Phong normalisation overshoots 1 by up to 7.5 % (its module doc).
const BLINN_PHONG_MAX_ALBEDO: f64 = 1.08;

/// f32 against f64 for Ward and GGX: relative, where the f64 value is above
/// `F32_FLOOR_OF_PEAK` of the lobe's peak (f32 keeps ~7 digits; exponents up to ~14 in the
/// tail amplify the exponent's rounding to ~1e-5).
const F32_REL_TOL: f64 = 1.0e-4;
/// Below this fraction of the peak, the f32 tail is compared in absolute terms
/// (`F32_TAIL_ABS_OF_PEAK`): it is numerically noise there.
const F32_FLOOR_OF_PEAK: f64 = 1.0e-6;
/// Absolute tolerance in the tail, as a fraction of the peak.
const F32_TAIL_ABS_OF_PEAK: f64 = 2.0e-6;
/// GGX in f32 loses relative precision near its peak at small α: D's denominator
/// 1 − cos²θh(1 − α²) cancels to ~α², so one f32 rounding ε of cos²θh becomes ε/α² in it and
/// twice that in D (squared); allowed: this many ε/α² on top of `F32_REL_TOL`.
const GGX_CANCELLATION_EPS: f64 = 4.0;
/// The renderer's f32 Ward lobe against `materials::ward_iso`: looser than `F32_REL_TOL`, as
/// the renderer adds its own clamps (α ≥ 0.01, cos ≥ 1e-3) and may cut the far tail.
const SHADING_WARD_REL_TOL: f64 = 1.0e-3;

/// Read noise may differ from its nominal σ by this fraction over the ~9000 dark pixels
/// sampled (the sample standard deviation's own spread is ~1 %, the 12-bit Gaussian table
/// and rounding to whole DN add a few %).
const READ_NOISE_REL_TOL: f64 = 0.1;
/// Standard errors allowed between the dark-frame mean and the black level.
const DARK_MEAN_SIGMAS: f64 = 5.0;
/// Largest excursion of one dark pixel from the black level, in read-noise σ: the Gaussian
/// table's extreme entries are Φ⁻¹(0.5/4096) = ±3.67 before its unit-variance rescale
/// (`render::rng` says "cut at ±3.5σ", which understates it), plus half a DN of rounding.
const DARK_MAX_SIGMAS: f64 = 3.8;

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

/// The built-in light stage with 64×48 cameras, `fixture` on the stage and preset `quality`.
fn rig(fixture: &str, quality: &str) -> RigSpec {
    let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("built-in rig parses");
    for c in &mut rig.cameras {
        c.width = W;
        c.height = H;
    }
    SimSpec::edit(&mut rig, |s| s.sample = fixture.into()).expect("sim");
    SimSpec::edit(&mut rig, |s| s.quality = quality.into()).expect("sim");
    rig
}

/// A world with `fixture`, the lamps at the given output and the light arc at `arc_deg`.
fn world(fixture: &str, lamps: &[(&str, f64)], arc_deg: f64) -> WorldSnapshot {
    WorldSnapshot {
        rig_time_s: 1.0,
        axes: BTreeMap::from([
            ("turntable".to_string(), 0.0),
            ("light_arc".to_string(), arc_deg),
        ]),
        lamps: lamps.iter().map(|(id, v)| (id.to_string(), *v)).collect(),
        laser: None,
        cart_mm: 0.0,
        fixture: fixture.into(),
    }
}

/// Fails unless every radiance value is finite and non-negative.
fn check_radiance(img: &RadianceImage, what: &str) {
    assert_eq!(
        img.rgb.len(),
        (img.width * img.height * 3) as usize,
        "{what}"
    );
    for (k, v) in img.rgb.iter().enumerate() {
        assert!(
            v.is_finite() && *v >= 0.0,
            "{what}: pixel {} channel {}: {v}",
            k / 3,
            k % 3
        );
    }
}

/// The noise-free radiance of `cam`, scanned by [`check_radiance`].
fn checked(r: &Renderer, w: &WorldSnapshot, cam: &str) -> RadianceImage {
    let img = r.radiance(w, cam).expect("radiance");
    check_radiance(&img, &format!("{} {cam}", w.fixture));
    img
}

/// Unit vector at polar angle `theta` from +Z and azimuth `phi`.
fn dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

/// Directional albedo ∫ f(wi, wo) cosθo dωo for wi at polar angle `theta_i` (normal +Z), by the
/// midpoint rule over the half vector h (`ALBEDO_STEPS`² cells of the upper hemisphere), with
/// wo = 2(wi·h)h − wi and dωo = 4(wi·h) dωh: the grid sits where glossy lobes live.
fn directional_albedo(theta_i: f64, f: impl Fn(DVec3, DVec3) -> f64) -> f64 {
    let wi = dir(theta_i, 0.0);
    let (dt, dp) = (
        FRAC_PI_2 / ALBEDO_STEPS as f64,
        2.0 * PI / ALBEDO_STEPS as f64,
    );
    let mut sum = 0.0;
    for i in 0..ALBEDO_STEPS {
        let th = (i as f64 + 0.5) * dt;
        let (st, ct) = th.sin_cos();
        for j in 0..ALBEDO_STEPS {
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

/// A renderer `Material` with the given model, albedo, ks and roughness.
fn render_material(model: Model, albedo: f32, ks: f32, alpha: f32) -> Material {
    Material {
        model,
        ks,
        alpha,
        alpha_y: 2.0 * alpha,
        ..Material::lambert(Vec3A::splat(albedo))
    }
}

/// Every renderer BRDF model.
const MODELS: [Model; 5] = [
    Model::Lambert,
    Model::WardIso,
    Model::WardAniso,
    Model::BlinnPhong,
    Model::Ggx,
];

// ---------------------------------------------------------------------------------------------
// Grazing light and view, extreme parameters
// ---------------------------------------------------------------------------------------------

proptest! {
    /// Light and view within `GRAZING_RAD` of the horizon (and just below it): the renderer's
    /// BRDF for every model and roughness from "→ 0" to 10 is finite and non-negative, and
    /// exactly 0 when a direction is below the horizon.
    #[test]
    fn renderer_brdf_at_grazing_is_finite_and_non_negative(
        di in -GRAZING_RAD..GRAZING_RAD, dout in -GRAZING_RAD..GRAZING_RAD,
        phi in 0.0f64..6.3, k in 0usize..5, ai in 0usize..5, ks in 0.0f32..1.0,
    ) {
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

// ---------------------------------------------------------------------------------------------
// Energy conservation and the white furnace
// ---------------------------------------------------------------------------------------------

/// Directional albedo ≤ 1 + `ALBEDO_TOL` for the renderer's BRDF with ρd + ρs = 1 (Ward up to
/// `WARD_CONSERVING_DEG`), and for the `materials` models: Lambert, Ward, GGX with F = 1 at
/// every θi up to 89°, the dipole's far-field BRDF (≤ R_d ≤ 1) and Blinn–Phong within its
/// documented overshoot. Lambert alone must also reach 1 (the integrator is sound).
#[test]
fn directional_albedo_never_exceeds_one() {
    let lambert_albedo = directional_albedo(0.3, |wi, wo| lambert(DVec3::Z, wi, wo, 1.0));
    assert!(
        (lambert_albedo - 1.0).abs() <= ALBEDO_TOL,
        "Lambert integrates to {lambert_albedo}"
    );
    let mut worst: Vec<(String, f64)> = Vec::new();
    for deg in [0.0, 30.0, 60.0, 80.0, WARD_CONSERVING_DEG] {
        let ti = f64::to_radians(deg);
        for (ks, alpha) in [(0.04f32, 0.15f32), (0.5, 0.05), (1.0, 0.2), (1.0, 0.5)] {
            let m = Material::ward(Vec3A::splat(1.0 - ks), ks, alpha);
            let a = directional_albedo(ti, |wi, wo| {
                brdf(&m, Vec3A::Z, wi.as_vec3a(), wo.as_vec3a(), true).x as f64
            });
            worst.push((format!("renderer ward ks {ks} α {alpha} θi {deg}"), a));
        }
        for alpha in [0.05, 0.2, 0.5] {
            let a = directional_albedo(ti, |wi, wo| ward_iso(DVec3::Z, wi, wo, alpha));
            worst.push((format!("ward_iso α {alpha} θi {deg}"), a));
            let a = directional_albedo(ti, |wi, wo| {
                cook_torrance_ggx(DVec3::Z, wi, wo, alpha, Fresnel::One)
            });
            worst.push((format!("ggx α {alpha} θi {deg}"), a));
        }
        let dipole = materials::Material::Dipole {
            alpha_prime: [0.999999; 3],
            sigma_t_prime: [0.01; 3],
            eta: 1.3,
        };
        let a = directional_albedo(ti, |wi, wo| {
            dipole.eval(wi, wo, DVec3::Z, DVec3::X, DVec3::Y)[0]
        });
        worst.push((format!("dipole θi {deg}"), a));
        for m in [1.0, 10.0, 100.0] {
            let a = directional_albedo(ti, |wi, wo| blinn_phong(DVec3::Z, wi, wo, m));
            assert!(
                a.is_finite() && a <= BLINN_PHONG_MAX_ALBEDO,
                "blinn-phong m {m} θi {deg}: {a}"
            );
        }
    }
    for (what, a) in &worst {
        assert!(a.is_finite() && *a >= 0.0, "{what}: {a}");
        assert!(*a <= 1.0 + ALBEDO_TOL, "{what}: albedo {a}");
    }
}

/// Where a pixel's centre ray (f32, as the renderer casts it) meets the plane z = `z`, in f64.
fn pixel_on_plane(pose: &CameraPose, x: u32, y: u32, z: f64) -> Option<DVec3> {
    let d = pose.ray(x as f32 + 0.5, y as f32 + 0.5).as_dvec3();
    let o = pose.origin.as_dvec3();
    if d.z >= 0.0 {
        return None;
    }
    Some(o + d * ((z - o.z) / d.z))
}

/// The f64 reference radiance at `p` (normal +Z) seen from `eye`, from a halogen point lamp at
/// light-arc azimuth `arc_deg`, `elevation_deg`, `distance_mm` with `power`: the lamp model of
/// `render::lights` (power 1 at `REFERENCE_DISTANCE_MM` gives unit irradiance at normal
/// incidence, E = P·d_ref²·cosθi / r²) times the material's BRDF evaluated by `materials`.
fn reference_radiance(m: &Material, p: DVec3, eye: DVec3, lamp: (f64, f64, f64, f64)) -> DVec3 {
    let (arc_deg, elevation_deg, distance_mm, power) = lamp;
    let (az, el) = (arc_deg.to_radians(), elevation_deg.to_radians());
    let q = distance_mm * DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    let v = q - p;
    let r2 = v.length_squared();
    let wi = v / r2.sqrt();
    let wo = (eye - p).normalize();
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return DVec3::ZERO;
    }
    let reference = REFERENCE_DISTANCE_MM as f64;
    let e = power * reference * reference * wi.z / r2;
    let lobe = match m.model {
        Model::Lambert => 0.0,
        Model::WardIso => m.ks as f64 * ward_iso(DVec3::Z, wi, wo, m.alpha as f64),
        other => panic!("the flat fixture's model {other:?} needs a reference here"),
    };
    let f = m.albedo.as_dvec3() * FRAC_1_PI + DVec3::splat(lobe);
    HALOGEN_RGB.as_dvec3() * f * e
}

/// Whether the four corners of pixel (x, y) land on the plane z = 0 where `inside` holds.
fn footprint_within(pose: &CameraPose, x: u32, y: u32, inside: impl Fn(DVec3) -> bool) -> bool {
    [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
        .iter()
        .all(|&(dx, dy)| {
            let d = pose.ray(x as f32 + dx, y as f32 + dy).as_dvec3();
            let o = pose.origin.as_dvec3();
            d.z < 0.0 && inside(o + d * (-o.z / d.z))
        })
}

/// Summary of rendered/reference radiance ratios over a set of pixels.
#[derive(Debug, Clone, Copy)]
struct Stats {
    /// Pixels compared.
    n: usize,
    /// Mean ratio.
    mean: f64,
    /// Standard deviation over the mean.
    rel_std: f64,
    /// Smallest ratio.
    min: f64,
    /// Largest relative error of any channel of any pixel.
    worst: f64,
}

impl Stats {
    fn of(ratios: &[f64], worst: f64) -> Stats {
        let n = ratios.len() as f64;
        let mean = ratios.iter().sum::<f64>() / n;
        let std = (ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n).sqrt();
        Stats {
            n: ratios.len(),
            mean,
            rel_std: std / mean,
            min: ratios.iter().copied().fold(f64::INFINITY, f64::min),
            worst,
        }
    }
}

/// Compares the radiance of `cam` on the flat sample with the f64 reference pixel by pixel
/// over the pixels whose whole footprint lies on the sample (2 mm in from its edges): ratios
/// are of the green channel, `worst` covers every channel.
fn flat_against_reference(
    rig: &RigSpec,
    img: &RadianceImage,
    cam: &str,
    lamp: (f64, f64, f64, f64),
) -> Stats {
    let spec = rig.camera(cam).expect("camera");
    let pose = CameraPose::new(spec, ToSample::new(0.0));
    let size_mm = SimSpec::of(rig).expect("sim").sample_size_mm;
    let sample = Sample::build("flat", size_mm as f32, 0.2).expect("flat builds");
    let half = 0.5 * size_mm - 2.0;
    let eye = pose.origin.as_dvec3();
    let (mut ratios, mut worst) = (Vec::new(), 0.0f64);
    for y in 0..H {
        for x in 0..W {
            let Some(p) = pixel_on_plane(&pose, x, y, 0.0) else {
                continue;
            };
            // The whole pixel footprint (sub-pixel samples land anywhere in it) on the sample.
            if !footprint_within(&pose, x, y, |c| c.x.abs() <= half && c.y.abs() <= half) {
                continue;
            }
            let m = sample.material_at(p.x as f32, p.y as f32);
            let want = reference_radiance(&m, p, eye, lamp);
            let k = ((y * W + x) * 3) as usize;
            let got = DVec3::new(
                img.rgb[k] as f64,
                img.rgb[k + 1] as f64,
                img.rgb[k + 2] as f64,
            );
            for c in 0..3 {
                let rel = (got[c] - want[c]).abs() / want[c].max(1e-30);
                worst = worst.max(rel);
            }
            ratios.push(got.y / want.y);
        }
    }
    Stats::of(&ratios, worst)
}

/// The white furnace through the renderer: the `flat` fixture under one halogen lamp must
/// return, at every pixel on the sample, E·BRDF with E from the lamp model — for its Lambert
/// part, E·ρd/π, i.e. E/π for albedo 1. The lamp is moved straight overhead at the reference
/// distance (E = 1 at the centre: the centre pixel must read ρd/π · colour) and to 40° with the
/// light arc turned by 180° (the Ward lobe then contributes near the mirror direction).
#[test]
fn white_furnace_through_the_renderer() {
    for (cam, elevation, arc) in [
        ("cam1", 90.0, 0.0),
        ("cam4", 40.0, 180.0),
        ("cam8", 60.0, 90.0),
    ] {
        let mut rig = rig("flat", "preview");
        rig.lamps[0].elevation_deg = elevation;
        rig.lamps[0].distance_mm = REFERENCE_DISTANCE_MM as f64;
        rig.lamps[0].power = 1.0;
        let r = Renderer::new(&rig).expect("renderer");
        let img = checked(&r, &world("flat", &[("lamp1", 1.0)], arc), cam);
        let lamp = (arc, elevation, REFERENCE_DISTANCE_MM as f64, 1.0);
        let stats = flat_against_reference(&rig, &img, cam, lamp);
        assert!(stats.n > 50, "{cam}: only {} pixels on the sample", stats.n);
        assert!(
            stats.worst <= FURNACE_REL_TOL,
            "{cam} lamp at {elevation}°: {stats:?}"
        );
    }
    // The unit-irradiance statement itself: overhead reference lamp, pixel nearest the centre,
    // seen by cam3 (25°), where the Ward lobe is e⁻¹⁸ of its peak: radiance = E·ρd/π.
    let mut rig = rig("flat", "preview");
    rig.lamps[0].elevation_deg = 90.0;
    let r = Renderer::new(&rig).expect("renderer");
    let img = checked(&r, &world("flat", &[("lamp1", 1.0)], 0.0), "cam3");
    let pose = CameraPose::new(rig.camera("cam3").expect("cam3"), ToSample::new(0.0));
    let (cx, cy) = pose.project(Vec3A::ZERO).expect("centre visible");
    let (x, y) = (cx as u32, cy as u32);
    let p = pixel_on_plane(&pose, x, y, 0.0).expect("on the plane");
    let material = Sample::build("flat", 80.0, 0.2)
        .expect("flat")
        .material_at(p.x as f32, p.y as f32);
    let albedo = material.albedo.as_dvec3();
    let with_lobe = reference_radiance(
        &material,
        p,
        pose.origin.as_dvec3(),
        (0.0, 90.0, 800.0, 1.0),
    );
    let lambert_only = reference_radiance(
        &Material::lambert(material.albedo),
        p,
        pose.origin.as_dvec3(),
        (0.0, 90.0, 800.0, 1.0),
    );
    assert!(
        (with_lobe - lambert_only).max_element() <= 1e-3 * FURNACE_REL_TOL * lambert_only.y,
        "the Ward lobe is not negligible here: {with_lobe} vs {lambert_only}"
    );
    let e = (REFERENCE_DISTANCE_MM as f64).powi(2) * (800.0 - p.z)
        / (p - DVec3::new(0.0, 0.0, 800.0)).length().powi(3);
    assert!(
        (e - 1.0).abs() < CENTRE_IRRADIANCE_TOL,
        "irradiance near the centre {e}"
    );
    let k = ((y * W + x) * 3) as usize;
    for c in 0..3 {
        let want = e * albedo[c] * FRAC_1_PI * HALOGEN_RGB[c] as f64;
        let got = img.rgb[k + c] as f64;
        assert!(
            (got - want).abs() <= FURNACE_REL_TOL * want,
            "channel {c}: {got} vs E·ρ/π = {want}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Shadow acne at 1° light elevation
// ---------------------------------------------------------------------------------------------

/// Points on a grid: every vertex, cell-edge midpoints and a hashed scatter of interior points.
fn surface_points(n: usize, size: f32) -> Vec<(f32, f32)> {
    let cell = size / n as f32;
    let o = -0.5 * size;
    let mut pts = Vec::new();
    for j in (0..=n).step_by(3) {
        for i in (0..=n).step_by(3) {
            pts.push((o + i as f32 * cell, o + j as f32 * cell));
            pts.push((o + (i as f32 + 0.5) * cell, o + j as f32 * cell));
        }
    }
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..2000 {
        h ^= h << 13;
        h ^= h >> 7;
        h ^= h << 17;
        let u = (h >> 40) as f32 / (1u64 << 24) as f32;
        let v = ((h >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32;
        pts.push((o + u * size, o + v * size));
    }
    pts
}

/// A flat plane (constant height 0, 3.7 and −2 mm) and a uniformly tilted one, lit from 1° above
/// the plane in 16 azimuths: no shadow ray from any surface point is occluded — neither from
/// the renderer's offset origin (`shadow_origin`) nor from exactly on the surface — and every
/// vertex of the preview visibility map toward a 1° lamp at 800 mm is lit.
#[test]
fn flat_plane_at_one_degree_has_no_shadow_acne() {
    const N: usize = 200;
    const SIZE: f32 = 40.0;
    let elevation = 1.0f32.to_radians();
    let planes: [(&str, f32); 4] = [("z=0", 0.0), ("z=3.7", 3.7), ("z=-2", -2.0), ("tilt", 0.3)];
    for (name, param) in planes {
        let tilted = name == "tilt";
        let grid = HeightGrid::build(N, SIZE, |x, _| if tilted { param * x } else { param });
        // The plane's unit normal and two tangents spanning it.
        let normal = if tilted {
            Vec3A::new(-param, 0.0, 1.0).normalize()
        } else {
            Vec3A::Z
        };
        let tx = if tilted {
            Vec3A::new(1.0, 0.0, param).normalize()
        } else {
            Vec3A::X
        };
        let ty = normal.cross(tx);
        let mut blocked = Vec::new();
        for (x, y) in surface_points(N, SIZE) {
            let p = Vec3A::new(x, y, grid.height_at(x, y));
            let n = grid.normal_at(x, y);
            assert!(n.dot(normal) > 0.999_99, "{name}: normal {n}");
            for k in 0..16 {
                let az = k as f32 * std::f32::consts::TAU / 16.0;
                let along = tx * az.cos() + ty * az.sin();
                let d = (along * elevation.cos() + normal * elevation.sin()).normalize();
                for (label, o) in [("offset", shadow_origin(p, n)), ("surface", p)] {
                    if grid.occluded(o, d, 0.0, 1.0e3) {
                        blocked.push(format!("{name} {label} ({x}, {y}) az {k}"));
                    }
                }
            }
        }
        assert!(
            blocked.is_empty(),
            "{} acne rays, e.g. {:?}",
            blocked.len(),
            &blocked[..blocked.len().min(5)]
        );
        // Preview maps: a 1° lamp at 800 mm in 8 azimuths lights every vertex.
        for k in 0..8 {
            let az = k as f32 * std::f32::consts::TAU / 8.0;
            let along = tx * az.cos() + ty * az.sin();
            let light = (along * elevation.cos() + normal * elevation.sin()) * 800.0;
            let vis = VertexVisibility::compute(&grid, light);
            for (x, y) in surface_points(N, SIZE).into_iter().take(500) {
                let v = vis.at(&grid, x, y);
                assert_eq!(v, 1.0, "{name} az {k}: visibility {v} at ({x}, {y})");
            }
        }
    }
}

/// The standard preset's sampled lamp disk at `elevation_deg` and 800 mm: (bound on the
/// relative standard deviation of a pixel's irradiance, smallest possible ratio to the point
/// lamp). A uniform point on the 10 mm disk (nearly vertical at low elevation) has height
/// z₀ + ρ sinφ with Var = R²/4, so one sample's cosθi has relative σ = (R/2)/z₀; n stratified
/// samples do at least as well as independent ones, σ/√n. No sample sits lower than z₀ − R,
/// so no pixel falls below (z₀ − R)/z₀ of the point-lamp value (10 % margin for the 1/r² and
/// view changes across the disk). Shadow acne would put pixels at 0.
fn disk_sampling_bounds(elevation_deg: f64, samples: u32) -> (f64, f64) {
    let z0 = 800.0 * elevation_deg.to_radians().sin();
    let r = HALOGEN_RADIUS_MM as f64;
    (0.5 * r / z0 / (samples as f64).sqrt(), 0.9 * (z0 - r) / z0)
}

/// At renderer level, a lamp at 1° elevation lights the `flat` fixture uniformly: the ratio
/// of rendered to reference radiance over the sample has a relative standard deviation below
/// `SPECKLE_REL_STD` with a point lamp (preview; every pixel within `FURNACE_REL_TOL`) and
/// below the disk-sampling bound of [`disk_sampling_bounds`] with the standard preset's
/// sampled 10 mm disk, and no pixel is darker than that bound allows. The lower plane of the
/// `planes` fixture — a relief grid, so shadows are planned: per-vertex visibility maps in
/// preview, exact shadow rays in standard — must show the same uniformity (no acne).
#[test]
fn low_elevation_light_gives_uniform_brightness() {
    const ELEVATION_DEG: f64 = 1.0;
    for quality in ["preview", "standard"] {
        let samples = if quality == "preview" { 1 } else { 4 };
        let (spread, lowest) = if quality == "preview" {
            (SPECKLE_REL_STD, 1.0 - FURNACE_REL_TOL)
        } else {
            disk_sampling_bounds(ELEVATION_DEG, samples)
        };
        for (cam, arc) in [("cam1", 0.0), ("cam4", 0.0), ("cam2", 180.0)] {
            let mut rig = rig("flat", quality);
            rig.lamps[0].elevation_deg = ELEVATION_DEG;
            let r = Renderer::new(&rig).expect("renderer");
            let img = checked(&r, &world("flat", &[("lamp1", 1.0)], arc), cam);
            let lamp = (
                arc,
                ELEVATION_DEG,
                rig.lamps[0].distance_mm,
                rig.lamps[0].power,
            );
            let stats = flat_against_reference(&rig, &img, cam, lamp);
            assert!(stats.n > 50, "{quality} {cam}: {} pixels", stats.n);
            assert!(
                stats.rel_std <= spread && stats.min >= lowest,
                "{quality} {cam} arc {arc}: {stats:?}, bounds: rel std {spread:e}, min {lowest}"
            );
            // The mean ratio is 1 within three standard errors (at least the rounding bound).
            let standard_error = (spread / (stats.n as f64).sqrt()).max(FURNACE_REL_TOL);
            assert!(
                (stats.mean - 1.0).abs() <= 3.0 * standard_error,
                "{quality} {cam}: {stats:?}"
            );
            if quality == "preview" {
                assert!(stats.worst <= FURNACE_REL_TOL, "{cam}: {stats:?}");
            }
        }
        let mut rig = rig("planes", quality);
        rig.lamps[0].elevation_deg = ELEVATION_DEG;
        // Direct light only: light bounced off the step's wall would brighten the lower plane.
        SimSpec::edit(&mut rig, |s| s.knobs.bounces = Some(0)).expect("sim");
        let r = Renderer::new(&rig).expect("renderer");
        let planes = Sample::build(
            "planes",
            SimSpec::of(&rig).expect("sim").sample_size_mm as f32,
            0.2,
        )
        .expect("planes");
        for cam in ["cam1", "cam3", "cam5"] {
            let w = world("planes", &[("lamp1", 1.0)], 0.0);
            let out = r.render(&w, cam, 0.02, 1.0, 1).expect("render");
            assert_eq!(
                out.notes["effects"]["shadows"]["on"], true,
                "{}",
                out.notes["effects"]
            );
            let img = checked(&r, &w, cam);
            let pose = CameraPose::new(rig.camera(cam).expect("camera"), ToSample::new(0.0));
            let mut ratios = Vec::new();
            for y in 0..H {
                for x in 0..W {
                    let Some(p) = pixel_on_plane(&pose, x, y, 0.0) else {
                        continue;
                    };
                    // The lower plane, away from the 20 mm step at y = 0 and the edges.
                    let lower = |c: DVec3| c.x.abs() <= 38.0 && c.y >= -38.0 && c.y <= -2.0;
                    if !footprint_within(&pose, x, y, lower) {
                        continue;
                    }
                    let m = planes.material_at(p.x as f32, p.y as f32);
                    let lamp = (0.0, ELEVATION_DEG, rig.lamps[0].distance_mm, 1.0);
                    let want = reference_radiance(&m, p, pose.origin.as_dvec3(), lamp);
                    ratios.push(img.rgb[((y * W + x) * 3 + 1) as usize] as f64 / want.y);
                }
            }
            let stats = Stats::of(&ratios, 0.0);
            assert!(stats.n > 20, "planes {quality} {cam}: {stats:?}");
            let standard_error = (spread / (stats.n as f64).sqrt()).max(FURNACE_REL_TOL);
            assert!(
                stats.rel_std <= spread
                    && stats.min >= lowest
                    && (stats.mean - 1.0).abs() <= 3.0 * standard_error,
                "planes {quality} {cam}: {stats:?}, bounds: rel std {spread:e}, min {lowest}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Height-field march against brute force
// ---------------------------------------------------------------------------------------------

/// A bumpy test relief on a 16 mm square of `n` cells: a Gaussian hill, ripples and an offset.
fn bumpy(n: usize) -> HeightGrid {
    HeightGrid::build(n, 16.0, |x, y| {
        let r2 = x * x + y * y;
        2.0 * (-r2 / 8.0).exp() + 0.3 * (x * 0.9).sin() * (y * 0.7).cos() + 0.3
    })
}

/// Brute-force first hit: steps `BRUTE_STEP_MM` along o + t·d (t in [0, t_max]) and reports the
/// first point inside the square of half-width `half` and below the surface, refined by
/// bisection, with the deepest penetration found while below.
fn brute(g: &HeightGrid, half: f32, o: Vec3A, d: Vec3A, t_max: f32) -> Option<(f32, f32)> {
    let below = |t: f32| {
        let p = o + d * t;
        p.x.abs() <= half && p.y.abs() <= half && p.z < g.height_at(p.x, p.y)
    };
    let depth = |t: f32| {
        let p = o + d * t;
        g.height_at(p.x, p.y) - p.z
    };
    let mut t = 0.0f32;
    let mut prev = None;
    while t <= t_max {
        if below(t) {
            let mut lo = prev.unwrap_or(t);
            let mut hi = t;
            if prev.is_some() {
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    if below(mid) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
            }
            let mut deepest = depth(t);
            let mut s = t;
            while s <= t_max && below(s) {
                deepest = deepest.max(depth(s));
                s += BRUTE_STEP_MM;
            }
            return Some((hi, deepest));
        }
        prev = Some(t);
        t += BRUTE_STEP_MM;
    }
    None
}

/// Checks `first_hit` against [`brute`] for one ray; returns a description of any disagreement.
fn compare_march(g: &HeightGrid, half: f32, o: Vec3A, d: Vec3A, t_max: f32) -> Option<String> {
    let fast = g.first_hit(o, d, 0.0, t_max);
    let slow = brute(g, half, o, d, t_max);
    match (fast, slow) {
        (Some(hit), slow) => {
            let p = o + d * hit.t;
            let h = g.height_at(p.x, p.y);
            let valid = if hit.wall.is_some() {
                let edge = p.x.abs().max(p.y.abs());
                (edge - half).abs() <= HIT_TOL_MM && p.z <= h + SURFACE_TOL_MM
            } else {
                (p.z - h).abs() <= SURFACE_TOL_MM || (hit.t <= HIT_TOL_MM && p.z < h)
            };
            if !valid {
                return Some(format!(
                    "hit at t {} is off the surface: z {} h {h}",
                    hit.t, p.z
                ));
            }
            match slow {
                Some((b, _)) if b < hit.t - HIT_TOL_MM => {
                    Some(format!("tunnelled: march {} but brute force {b}", hit.t))
                }
                Some((b, depth)) if (b - hit.t).abs() > HIT_TOL_MM && depth > GRAZE_DEPTH_MM => {
                    // The brute force skipped a graze the march found; only a shallow one.
                    let q = o + d * hit.t;
                    let clearance = q.z - g.height_at(q.x, q.y);
                    (clearance.abs() > SURFACE_TOL_MM)
                        .then(|| format!("march {} vs brute force {b}", hit.t))
                }
                _ => None,
            }
        }
        (None, Some((b, depth))) if depth > GRAZE_DEPTH_MM => {
            Some(format!("missed: brute force hits at {b}, {depth} mm deep"))
        }
        _ => None,
    }
}

/// Vertical rays (d = −z and +z) at random points, at vertices and along cell edges: the
/// march (whose per-axis inverse directions are infinite) agrees with the brute force; a ray
/// straight down hits at the surface height, straight up from above never hits.
#[test]
fn vertical_rays_match_brute_force() {
    let g = bumpy(64);
    let cell = 16.0 / 64.0;
    let mut failures = Vec::new();
    let mut points: Vec<(f32, f32)> = Vec::new();
    for k in 0..=16 {
        let a = -8.0 + k as f32 * 4.0 * cell;
        points.push((a, a)); // vertices on the diagonal
        points.push((a, 0.37)); // on an edge line x = const
        points.push((-3.11, a)); // on an edge line y = const
    }
    points.extend([
        (8.0, 8.0),
        (-8.0, -8.0),
        (8.0, -8.0),
        (-8.0, 3.0),
        (1.234, -5.678),
    ]);
    for (x, y) in points {
        let h = g.height_at(x, y);
        for d in [Vec3A::NEG_Z, Vec3A::new(-0.0, -0.0, -1.0)] {
            let o = Vec3A::new(x, y, 10.0);
            if let Some(e) = compare_march(&g, 8.0, o, d, 20.0) {
                failures.push(format!("down at ({x}, {y}): {e}"));
            }
            match g.first_hit(o, d, 0.0, 20.0) {
                Some(hit) if (hit.t - (10.0 - h)).abs() <= HIT_TOL_MM => {}
                other => failures.push(format!("down at ({x}, {y}): {other:?}, h {h}")),
            }
        }
        // Straight up from just above the surface: never a hit, never occluded.
        let above = Vec3A::new(x, y, h + 0.01);
        if g.first_hit(above, Vec3A::Z, 0.0, 100.0).is_some()
            || g.occluded(above, Vec3A::Z, 0.0, 100.0)
        {
            failures.push(format!("up from ({x}, {y}) hits"));
        }
        // Straight up from below the surface but above the turntable (inside the slab): hit at
        // once, like the brute force. (Below z = 0 the ray starts outside the relief's box.)
        let inside = Vec3A::new(x, y, h - 0.05f32.min(0.5 * h));
        if let Some(e) = compare_march(&g, 8.0, inside, Vec3A::Z, 10.0) {
            failures.push(format!("up from below at ({x}, {y}): {e}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Axis-aligned rays (d.x = 0 or d.y = 0) at elevations from 0.2° to 80°, including rays
/// running exactly along cell-edge lines and diagonals through vertices, from outside the box
/// and from inside the slab (above and below the surface).
#[test]
fn axis_aligned_and_edge_rays_match_brute_force() {
    let g = bumpy(64);
    let cell = 16.0f32 / 64.0;
    let mut failures = Vec::new();
    let mut rays = 0;
    for el_deg in [0.2f32, 1.0, 5.0, 20.0, 45.0, 80.0] {
        let el = el_deg.to_radians();
        for sign in [1.0f32, -1.0] {
            // Lateral offsets: on an edge line, a third of a cell off, and on the centre line.
            for lateral in [
                0.0f32,
                2.0 * cell,
                2.0 * cell + cell / 3.0,
                -5.0 * cell,
                7.5,
            ] {
                for axis in 0..2 {
                    let horizontal = if axis == 0 {
                        Vec3A::new(sign, 0.0, 0.0)
                    } else {
                        Vec3A::new(0.0, sign, 0.0)
                    };
                    let side = if axis == 0 {
                        Vec3A::new(0.0, lateral, 0.0)
                    } else {
                        Vec3A::new(lateral, 0.0, 0.0)
                    };
                    let d = (horizontal * el.cos() - Vec3A::Z * el.sin()).normalize();
                    // From outside (aimed at the far half) and from inside the slab.
                    let target = side + horizontal * 3.0;
                    let outside = target - d * (6.0 / el.sin().max(0.05)).min(60.0);
                    let inside = side - horizontal * 4.0 + Vec3A::Z * 1.2;
                    for o in [outside, inside] {
                        rays += 1;
                        if let Some(e) = compare_march(&g, 8.0, o, d, 80.0) {
                            failures
                                .push(format!("el {el_deg} lateral {lateral} o {o} d {d}: {e}"));
                        }
                    }
                }
            }
            // Diagonals through vertices (|d.x| = |d.y|), starting exactly at a vertex column.
            for start in [-8.0f32, -6.0, -2.0 * cell] {
                let d = Vec3A::new(sign * el.cos(), el.cos(), -el.sin() * 2f32.sqrt()).normalize();
                let o = Vec3A::new(start * sign, start, 4.0);
                rays += 1;
                if let Some(e) = compare_march(&g, 8.0, o, d, 80.0) {
                    failures.push(format!("diagonal el {el_deg} start {start}: {e}"));
                }
            }
        }
    }
    assert!(rays > 100);
    assert!(
        failures.is_empty(),
        "{} of {rays}: {failures:#?}",
        failures.len()
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    /// Random rays starting inside the slab (0 to 3 mm up, anywhere over the grid) in any
    /// direction, half of them axis-aligned: the march agrees with the brute force.
    #[test]
    fn rays_starting_inside_the_slab_match_brute_force(
        x in -8.0f32..8.0, y in -8.0f32..8.0, z in 0.0f32..3.0,
        az in 0.0f32..6.3, el in -1.5f32..1.5, snap in 0usize..4,
    ) {
        let g = bumpy(64);
        let (c, s) = (az.cos(), az.sin());
        let (c, s) = match snap {
            0 => (c.signum(), 0.0),
            1 => (0.0, s.signum()),
            _ => (c, s),
        };
        let d = Vec3A::new(c * el.cos(), s * el.cos(), el.sin()).normalize();
        let o = Vec3A::new(x, y, z);
        let e = compare_march(&g, 8.0, o, d, 40.0);
        prop_assert!(e.is_none(), "o {} d {}: {:?}", o, d, e);
    }
}

// ---------------------------------------------------------------------------------------------
// One-texel spikes and walls
// ---------------------------------------------------------------------------------------------

/// Heights on a 256-cell grid over 32 mm: 0 except one vertex at 5 mm (the spike), at a vertex
/// on an 8-cell block boundary or inside a block.
fn spike(i0: usize, j0: usize) -> (HeightGrid, Vec3A) {
    let n = 256;
    let size = 32.0f32;
    let cell = size / n as f32;
    let o = -0.5 * size;
    let (sx, sy) = (o + i0 as f32 * cell, o + j0 as f32 * cell);
    let g = HeightGrid::build(n, size, |x, y| {
        if (x - sx).abs() < 0.25 * cell && (y - sy).abs() < 0.25 * cell {
            5.0
        } else {
            0.0
        }
    });
    (g, Vec3A::new(sx, sy, 5.0))
}

/// A single-vertex spike (inside an 8×8 block and on a block corner): rays aimed at it from
/// many azimuths and elevations — including long shallow ones that cross several empty blocks
/// first — hit it as the brute force does (no tunnelling through the block or cell skips), and
/// shadow rays across it at 1 mm height are blocked while those passing 0.01 mm above its top
/// are not.
#[test]
fn single_texel_spike_is_hit_and_blocks() {
    for (i0, j0) in [(131, 77), (128, 64)] {
        let (g, top) = spike(i0, j0);
        assert!((g.zmax() - 5.0).abs() < 1e-6);
        let mut failures = Vec::new();
        for k in 0..24 {
            let az = k as f32 * std::f32::consts::TAU / 24.0;
            let horizontal = Vec3A::new(az.cos(), az.sin(), 0.0);
            for el_deg in [0.5f32, 3.0, 30.0, 70.0] {
                let el = el_deg.to_radians();
                let d = (horizontal * el.cos() - Vec3A::Z * el.sin()).normalize();
                // Aimed 1 mm below the tip, from up to 14 mm away horizontally.
                let aim = top - Vec3A::Z * 1.0;
                let back = (14.0f32).min(5.0 / el.tan().max(1e-3)) / el.cos();
                let o = aim - d * back;
                let hit = g.first_hit(o, d, 0.0, 100.0);
                if hit.is_none() {
                    failures.push(format!("spike ({i0},{j0}) az {k} el {el_deg}: tunnelled"));
                }
                if let Some(e) = compare_march(&g, 16.0, o, d, back + 2.0) {
                    failures.push(format!("spike ({i0},{j0}) az {k} el {el_deg}: {e}"));
                }
                // Shadow ray from a ground point behind the spike toward a light over it.
                let ground = top - Vec3A::Z * 5.0 - horizontal * 2.0;
                let up = (aim - ground).normalize();
                let ground = ground + Vec3A::Z * 0.01;
                if !g.occluded(ground, up, 0.0, 100.0) {
                    failures.push(format!("spike ({i0},{j0}) az {k}: shadow ray passes"));
                }
                let over = (top + Vec3A::Z * 0.01 - ground).normalize();
                if g.occluded(ground, over, 0.0, 100.0) {
                    failures.push(format!(
                        "spike ({i0},{j0}) az {k}: ray above the tip blocked"
                    ));
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
    }
}

/// A one-cell-wide wall (two adjacent vertex rows at 4 mm) across the grid: rays crossing it
/// below its top at any angle — nearly parallel to it too — hit it as the brute force does,
/// shadow rays across it are blocked, and rays 0.01 mm above its crest pass.
#[test]
fn one_texel_wall_is_hit_and_blocks() {
    let n = 256;
    let size = 32.0f32;
    let cell = size / n as f32;
    let wall_y = -0.5 * size + 100.0 * cell;
    let g = HeightGrid::build(n, size, |_, y| {
        if y > wall_y - 0.25 * cell && y < wall_y + 1.25 * cell {
            4.0
        } else {
            0.0
        }
    });
    let crest = wall_y + 0.5 * cell;
    let mut failures = Vec::new();
    for k in 0..36 {
        // Crossing angles from 2.5° to 177.5° against the wall's direction.
        let az = (2.5 + k as f32 * 5.0).to_radians();
        let horizontal = Vec3A::new(az.cos(), az.sin(), 0.0);
        for el_deg in [0.3f32, 5.0, 45.0] {
            let el = el_deg.to_radians();
            let d = (horizontal * el.cos() - Vec3A::Z * el.sin()).normalize();
            for x in [-10.0f32, 0.0, 3.3] {
                let aim = Vec3A::new(x, crest, 2.0);
                // Start on the −y side, at most 12 mm away horizontally and inside the box.
                let run = (1.5 / horizontal.y).min(12.0);
                let o = aim - d * (run / el.cos());
                if g.first_hit(o, d, 0.0, 100.0).is_none() {
                    failures.push(format!("az {k} el {el_deg} x {x}: tunnelled"));
                }
                if let Some(e) = compare_march(&g, 16.0, o, d, run / el.cos() + 2.0) {
                    failures.push(format!("az {k} el {el_deg} x {x}: {e}"));
                }
                // Shadow rays from the ground on the −y side (up to 12 mm away, possibly off the
                // grid on the turntable) that cross the wall at (x, crest) 1 mm below its top.
                let crossing = Vec3A::new(x, crest, 3.0);
                let back = horizontal * (1.5 / horizontal.y).min(12.0);
                let ground = Vec3A::new(crossing.x - back.x, crossing.y - back.y, 0.01);
                let blocked = (crossing - ground).normalize();
                if !g.occluded(ground, blocked, 0.0, 100.0) {
                    failures.push(format!("az {k} x {x}: shadow ray crosses the wall"));
                }
            }
        }
    }
    // Just over the near edge of the wall's flat top (the ray keeps rising beyond it): lit.
    let ground = Vec3A::new(0.0, wall_y - 8.0, 0.0);
    let over = (Vec3A::new(0.0, wall_y, 4.01) - ground).normalize();
    assert!(
        !g.occluded(ground + Vec3A::Z * 0.01, over, 0.0, 100.0),
        "over the crest is blocked"
    );
    assert!(
        failures.is_empty(),
        "{} failures: {failures:#?}",
        failures.len()
    );
}

// ---------------------------------------------------------------------------------------------
// f32 against f64
// ---------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    /// `ward_aniso_f32` against `ward_aniso` over the whole upper hemisphere up to
    /// `GRAZING_RAD` from the horizon, α from 0.01 to 10: within `F32_REL_TOL` where the lobe is
    /// above `F32_FLOOR_OF_PEAK` of its peak, within `F32_TAIL_ABS_OF_PEAK` of the peak below.
    #[test]
    fn ward_aniso_f32_agrees_with_f64(
        ti in 0.0f64..(FRAC_PI_2 - GRAZING_RAD), pi_ in 0.0f64..6.3,
        to in 0.0f64..(FRAC_PI_2 - GRAZING_RAD), po in 0.0f64..6.3,
        lax in -2.0f64..1.0, lay in -2.0f64..1.0,
    ) {
        let (ax, ay) = (10f64.powf(lax), 10f64.powf(lay));
        let (wi, wo) = (dir(ti, pi_), dir(to, po));
        let x = ward_aniso(DVec3::Z, DVec3::X, DVec3::Y, wi, wo, ax, ay);
        let y = ward_aniso_f32(Vec3A::Z, Vec3A::X, Vec3A::Y, wi.as_vec3a(), wo.as_vec3a(),
                               ax as f32, ay as f32) as f64;
        let peak = 1.0 / (4.0 * PI * ax * ay * (wi.z.max(1e-6) * wo.z.max(1e-6)).sqrt());
        prop_assert!(y.is_finite() && y >= 0.0);
        if x > F32_FLOOR_OF_PEAK * peak {
            prop_assert!((x - y).abs() <= F32_REL_TOL * x, "f64 {x} f32 {y}");
        } else {
            prop_assert!((x - y).abs() <= F32_TAIL_ABS_OF_PEAK * peak, "f64 {x} f32 {y}");
        }
    }

    /// `cook_torrance_ggx_f32` against `cook_torrance_ggx` with Schlick Fresnel, cosines down
    /// to ~1e-3 (θ up to 90° − `GRAZING_RAD`), α from 0.01 to 10: within `F32_REL_TOL` above
    /// `F32_FLOOR_OF_PEAK` of the lobe's peak (the value at the mirror direction with F = 1),
    /// plus the cancellation allowance `GGX_CANCELLATION_EPS`·ε/α², within
    /// `F32_TAIL_ABS_OF_PEAK` of the peak below. (The module's doc claims 1e-4 relative for
    /// α ≥ 0.01; near the peak at α = 0.011 the error is 1.5e-4.)
    #[test]
    fn ggx_f32_agrees_with_f64(
        ti in 0.0f64..(FRAC_PI_2 - GRAZING_RAD), pi_ in 0.0f64..6.3,
        to in 0.0f64..(FRAC_PI_2 - GRAZING_RAD), po in 0.0f64..6.3,
        la in -2.0f64..1.0, f0 in 0.0f64..1.0,
    ) {
        let a = 10f64.powf(la);
        let (wi, wo) = (dir(ti, pi_), dir(to, po));
        let x = cook_torrance_ggx(DVec3::Z, wi, wo, a, Fresnel::Schlick { f0 });
        let y = cook_torrance_ggx_f32(Vec3A::Z, wi.as_vec3a(), wo.as_vec3a(), a as f32, f0 as f32)
            as f64;
        let tol = F32_REL_TOL + GGX_CANCELLATION_EPS * f64::from(f32::EPSILON) / (a * a);
        let mirror = DVec3::new(-wi.x, -wi.y, wi.z);
        let peak = cook_torrance_ggx(DVec3::Z, wi, mirror, a, Fresnel::One);
        prop_assert!(y.is_finite() && y >= 0.0);
        if x > F32_FLOOR_OF_PEAK * peak {
            prop_assert!((x - y).abs() <= tol * x, "f64 {x} f32 {y} tol {tol:e}");
        } else {
            prop_assert!((x - y).abs() <= F32_TAIL_ABS_OF_PEAK * peak, "f64 {x} f32 {y}");
        }
    }

    /// The renderer's f32 Ward lobe against `materials::ward_iso` inside the renderer's own
    /// clamps (α ≥ 0.01, cosines ≥ 1e-3): within `SHADING_WARD_REL_TOL` down to e⁻²⁹ of the
    /// peak, within `F32_TAIL_ABS_OF_PEAK` of the peak beyond.
    /// Half the cases put wo within a few α of the mirror direction, where the lobe lives.
    #[test]
    fn shading_ward_agrees_with_materials(
        ti in 0.0f64..1.569, pi_ in 0.0f64..6.3, dto in -3.0f64..3.0, dpo in -3.0f64..3.0,
        la in -2.0f64..1.0, near in proptest::bool::ANY,
    ) {
        let a = 10f64.powf(la);
        let (to, po) = if near {
            (ti + dto * a, pi_ + PI + dpo * a)
        } else {
            (0.5 * (dto + 3.0) * 0.523, pi_ + dpo)
        };
        prop_assume!((0.0..1.569).contains(&to));
        let (wi, wo) = (dir(ti, pi_), dir(to, po));
        let x = ward_iso(DVec3::Z, wi, wo, a);
        let y = ward_lobe(Vec3A::Z, wi.as_vec3a(), wo.as_vec3a(), a as f32) as f64;
        let h = wi + wo;
        let exponent = (h.length_squared() - h.z * h.z) / (h.z * h.z) / (a * a);
        let peak = 1.0 / (4.0 * PI * a * a * (wi.z * wo.z).sqrt());
        prop_assert!(y.is_finite() && y >= 0.0);
        if exponent < 29.0 {
            prop_assert!((x - y).abs() <= SHADING_WARD_REL_TOL * x,
                         "f64 {x} f32 {y} exp {exponent}");
        } else {
            // Below e⁻²⁹ of the peak the renderer may cut the tail to 0.
            prop_assert!((x - y).abs() <= F32_TAIL_ABS_OF_PEAK * peak, "{x} {y}");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Sensor limits and invalid inputs
// ---------------------------------------------------------------------------------------------

/// A huge exposure (the camera maximum of 4 s at gain 16, then f64::MAX seconds, then gain
/// 1e300) saturates every lit pixel at exactly 2^bits − 1 for 8, 12 and 16 bits, and nothing
/// wraps around: no pixel anywhere exceeds the maximum, and lit pixels never read low.
#[test]
fn huge_exposure_saturates_at_the_bit_depth_maximum() {
    for bits in [8u8, 12, 16] {
        let mut rig = rig("bumps", "preview");
        for c in &mut rig.cameras {
            c.bit_depth = bits;
        }
        let r = Renderer::new(&rig).expect("renderer");
        let max = sensor::max_dn(bits) as u16;
        let w = world("bumps", &[("lamp4", 1.0)], 0.0);
        let radiance = checked(&r, &w, "cam5");
        for (exposure, gain) in [
            (4.0, 16.0),
            (f64::MAX, 1.0),
            (1.0, 1e300),
            (f64::MAX, f64::MAX),
        ] {
            let out = r.render(&w, "cam5", exposure, gain, 3).expect("render");
            let mut lit = 0;
            for (k, (&dn, &rad)) in out.pixels.iter().zip(&radiance.rgb).enumerate() {
                assert!(dn <= max, "{bits} bits: pixel {k} = {dn} > {max}");
                // Radiance ≥ 1e-3 collects ≥ 1e-3 × 1.9e6 × 4 s electrons: far past full well.
                if rad >= 1e-3 {
                    lit += 1;
                    assert_eq!(
                        dn, max,
                        "{bits} bits, exposure {exposure:e} s, gain {gain:e}: lit pixel {k} (radiance {rad}) = {dn}"
                    );
                }
            }
            assert!(lit > 1000, "{bits} bits: {lit} lit values");
        }
    }
    // The sensor alone, at non-finite and extreme radiance.
    for bits in [8u8, 12, 16] {
        let max = sensor::max_dn(bits) as u16;
        for (exposure, gain) in [(4.0, 16.0), (f64::MAX, 1.0), (1.0, 1e300), (1e40, 1e40)] {
            let s = Sensor::new(bits, exposure, gain, 5);
            for p in 0..2000u64 {
                let dn = s.digitise_rgb([1.0, 1e30, f32::MAX], p);
                assert_eq!(
                    dn, [max; 3],
                    "{bits} bits exposure {exposure:e} gain {gain:e} pixel {p}"
                );
                let dn = s.digitise_rgb([f32::INFINITY, f32::NAN, 0.0], p);
                assert!(dn.iter().all(|&v| v <= max), "{dn:?}");
                assert_eq!(dn[0], max, "infinite radiance saturates");
            }
        }
    }
}

/// Zero (and negative) exposure gives the black level plus read noise: mean within
/// `DARK_MEAN_SIGMAS` standard errors of the black level, spread within `READ_NOISE_REL_TOL` of
/// the nominal read noise, no pixel more than `DARK_MAX_SIGMAS` σ from black, and at 8 bits and
/// gain 16 (σ = 3 DN around a black level of 5 DN) values clip at 0 rather than wrapping.
#[test]
fn zero_exposure_gives_black_level_plus_read_noise() {
    for (bits, gain) in [(12u8, 1.0), (16, 4.0), (8, 16.0)] {
        let mut rig = rig("bumps", "preview");
        for c in &mut rig.cameras {
            c.bit_depth = bits;
        }
        let r = Renderer::new(&rig).expect("renderer");
        let black = r.black_level_dn("cam3");
        let sigma = sensor::READ_NOISE_DN_12BIT * gain * sensor::max_dn(bits) / 4095.0;
        for exposure in [0.0, -1.0] {
            let out = r
                .render(
                    &world("bumps", &[("lamp3", 1.0)], 0.0),
                    "cam3",
                    exposure,
                    gain,
                    11,
                )
                .expect("render");
            let v: Vec<f64> = out.pixels.iter().map(|&p| p as f64).collect();
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let std = (v.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
            let max = v.iter().copied().fold(0.0, f64::max);
            if bits == 8 && gain == 16.0 {
                // Clipped at 0 from below: the mean rises above black, nothing wraps.
                assert!(v.contains(&0.0), "8-bit dark frame never clips at 0");
                assert!(
                    max <= black + DARK_MAX_SIGMAS * sigma + 0.5,
                    "wrapped: max {max}"
                );
                assert!(mean >= black - 0.5, "mean {mean}");
                continue;
            }
            assert!(
                (mean - black).abs() <= DARK_MEAN_SIGMAS * sigma / n.sqrt() + 0.5 / n.sqrt(),
                "{bits} bits exposure {exposure}: mean {mean} vs black {black}"
            );
            assert!(
                (std - sigma).abs() <= READ_NOISE_REL_TOL * sigma,
                "{bits} bits: read noise {std} vs {sigma}"
            );
            for &d in &v {
                assert!(
                    (d - black).abs() <= DARK_MAX_SIGMAS * sigma + 0.5,
                    "{bits} bits: dark pixel {d} (black {black}, σ {sigma})"
                );
            }
            assert_eq!(out.notes["sensor"]["light_integrated"], false);
        }
    }
}

/// NaN and infinite inputs to `render` and `radiance` — exposure, gain, axis angles, lamp
/// output, cart position, laser angles — are `InvalidInput` errors naming the value, never a
/// panic and never a frame.
#[test]
fn non_finite_inputs_are_errors_not_panics() {
    let rig = rig("bumps", "preview");
    let r = Renderer::new(&rig).expect("renderer");
    let base = world("bumps", &[("lamp2", 1.0)], 0.0);
    let bad_numbers = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
    let mut cases: Vec<(String, WorldSnapshot, f64, f64)> = Vec::new();
    for x in bad_numbers {
        cases.push((format!("exposure {x}"), base.clone(), x, 1.0));
        cases.push((format!("gain {x}"), base.clone(), 0.02, x));
        for axis in ["turntable", "light_arc", "laser_tilt"] {
            let mut w = base.clone();
            w.axes.insert(axis.into(), x);
            cases.push((format!("axis {axis} {x}"), w, 0.02, 1.0));
        }
        let mut w = base.clone();
        w.lamps.insert("lamp2".into(), x);
        cases.push((format!("lamp output {x}"), w, 0.02, 1.0));
        let mut w = base.clone();
        w.cart_mm = x;
        cases.push((format!("cart {x}"), w, 0.02, 1.0));
        for field in 0..2 {
            let mut beam = LaserBeam {
                colour_nm: 650,
                tilt_deg: 0.0,
                mount_elevation_deg: 45.0,
            };
            if field == 0 {
                beam.tilt_deg = x;
            } else {
                beam.mount_elevation_deg = x;
            }
            let w = WorldSnapshot {
                laser: Some(beam),
                ..base.clone()
            };
            cases.push((format!("laser field {field} {x}"), w, 0.02, 1.0));
        }
    }
    cases.push(("gain 0".into(), base.clone(), 0.02, 0.0));
    cases.push(("gain -1".into(), base.clone(), 0.02, -1.0));
    let mut w = base.clone();
    w.lamps.insert("lamp2".into(), -0.5);
    cases.push(("lamp output -0.5".into(), w, 0.02, 1.0));
    for (what, w, exposure, gain) in cases {
        let result = std::panic::catch_unwind(|| r.render(&w, "cam2", exposure, gain, 1));
        match result {
            Ok(Err(RenderError::InvalidInput { .. })) => {}
            Ok(other) => panic!(
                "{what}: expected InvalidInput, got {:?}",
                other.map(|o| o.notes)
            ),
            Err(_) => panic!("{what}: render panicked"),
        }
        // `radiance` checks the world the same way (exposure and gain are not its inputs).
        if !what.starts_with("exposure") && !what.starts_with("gain") {
            let result = std::panic::catch_unwind(|| r.radiance(&w, "cam2"));
            assert!(
                matches!(result, Ok(Err(RenderError::InvalidInput { .. }))),
                "{what}: radiance did not reject it"
            );
        }
    }
}

/// Every fixture under the most grazing lamp (10°, then moved to 1°), every camera, with the
/// laser on, at preview and standard: no NaN, infinity or negative radiance anywhere.
#[test]
fn every_fixture_renders_finite_non_negative_radiance() {
    for quality in ["preview", "standard"] {
        for elevation in [10.0, 1.0] {
            for fixture in stagehand_simulator::render::sample::FIXTURES {
                let mut rig = rig(fixture, quality);
                rig.lamps[0].elevation_deg = elevation;
                let r = Renderer::new(&rig).expect("renderer");
                let mut w = world(fixture, &[("lamp1", 1.0), ("lamp8", 0.5)], 30.0);
                w.axes.insert("turntable".into(), 17.0);
                w.laser = Some(LaserBeam {
                    colour_nm: 532,
                    tilt_deg: 3.0,
                    mount_elevation_deg: 45.0,
                });
                let cams: &[&str] = if quality == "preview" {
                    &[
                        "cam1", "cam2", "cam3", "cam4", "cam5", "cam6", "cam7", "cam8",
                    ]
                } else {
                    // Standard costs ~15× preview per pixel: its most grazing camera only.
                    &["cam1"]
                };
                for cam in cams {
                    checked(&r, &w, cam);
                }
            }
        }
    }
}
