//! Hard numerical cases for the renderer and the reflectance models, through the public API:
//! grazing light and view, extreme roughness and scattering coefficients, degenerate rays in
//! the height-field march, shadow acne at 1° light elevation, one-texel spikes and walls, a
//! white furnace, f32 against f64, and the sensor at its limits.
//!
//! Every bound is a named constant with the reason for its value. Every radiance image the
//! tests render is scanned for NaN, infinity and negative values (`checked`). Cameras are cut
//! to 64×48 so the whole module runs in seconds. This file holds the bounds and the helpers;
//! each topic is a submodule.

mod extremes;
mod furnace;
mod march;
mod sensor_limits;
mod shadow_acne;
mod spikes;

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
        fixture_pose: Default::default(),
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
