//! Energy conservation and the white furnace: directional albedo of every model, and the
//! renderer's radiance against an f64 reference of the lamp model.

use super::*;

/// Directional albedo ≤ 1 + `ALBEDO_TOL` for the renderer's BRDF with ρd + ρs = 1 (Ward up to
/// `WARD_CONSERVING_DEG`), and for the `materials` models: Lambert, Ward, GGX with F = 1 at
/// every θi up to 89°, the dipole's far-field BRDF (≤ R_d ≤ 1) and Blinn–Phong within its
/// documented overshoot. Lambert alone must also reach 1 (the integrator is sound).
#[test]
fn directional_albedo_never_exceeds_one() {
    let _turn = crate::grbl_peer::alongside();
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
pub(super) fn pixel_on_plane(pose: &CameraPose, x: u32, y: u32, z: f64) -> Option<DVec3> {
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
pub(super) fn reference_radiance(
    m: &Material,
    p: DVec3,
    eye: DVec3,
    lamp: (f64, f64, f64, f64),
) -> DVec3 {
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
pub(super) fn footprint_within(
    pose: &CameraPose,
    x: u32,
    y: u32,
    inside: impl Fn(DVec3) -> bool,
) -> bool {
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
pub(super) struct Stats {
    /// Pixels compared.
    pub(super) n: usize,
    /// Mean ratio.
    pub(super) mean: f64,
    /// Standard deviation over the mean.
    pub(super) rel_std: f64,
    /// Smallest ratio.
    pub(super) min: f64,
    /// Largest relative error of any channel of any pixel.
    pub(super) worst: f64,
}

impl Stats {
    pub(super) fn of(ratios: &[f64], worst: f64) -> Stats {
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
pub(super) fn flat_against_reference(
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
    let _turn = crate::grbl_peer::alongside();
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
