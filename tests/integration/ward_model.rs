//! The Ward lobe the reflectometer fit uses (`stagehand_processing::ward`) is the one the
//! simulator renders with (`stagehand_simulator::materials::ward`): two implementations of
//! Ward 1992, written apart, agree over the hemisphere, at grazing angles and for tiny and
//! huge α, so a fit of simulated reflectometer scans measures the fit, not a convention.

use glam::DVec3;
use nalgebra::Vector3;
use stagehand_processing::ward::ward_iso as ours;
use stagehand_simulator::materials::ward::ward_iso as theirs;

use glam::Vec3A;
use stagehand_devices::rig::LampKind;
use stagehand_processing::ward_fit::{
    WardFitOptions, WardFlag, WardSample, combine_turned_scans, fit_ward,
};
use stagehand_processing::ward_tube::{Tube, ViewPoint};
use stagehand_simulator::render::lights::{Emitter, Light};
use stagehand_simulator::render::material::{Material, Model};
use stagehand_simulator::render::quality::Quality;
use stagehand_simulator::render::sample::Sample;
use stagehand_simulator::render::scene::{Footprint, Hit, Scene, Shading};

fn dir(theta: f64, phi: f64) -> (Vector3<f64>, DVec3) {
    let v = (
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    );
    (Vector3::new(v.0, v.1, v.2), DVec3::new(v.0, v.1, v.2))
}

#[test]
fn processing_and_simulator_share_one_ward_lobe() {
    let _turn = crate::grbl_peer::alongside();
    let thetas = [0.0, 0.3, 0.9, 1.4, std::f64::consts::FRAC_PI_2 - 1e-4, 2.0];
    let (n, dn) = dir(0.0, 0.0);
    let mut compared = 0;
    for alpha in [1e-3, 0.01, 0.1, 0.5, 2.0] {
        for (i, ti) in thetas.iter().enumerate() {
            for to in &thetas[i..] {
                for phi in [0.0, 1.0, std::f64::consts::PI] {
                    let ((wi, dwi), (wo, dwo)) = (dir(*ti, 0.0), dir(*to, phi));
                    let (a, b) = (ours(&n, &wi, &wo, alpha), theirs(dn, dwi, dwo, alpha));
                    assert!(
                        (a - b).abs() <= 1e-12 * b.max(1e-300),
                        "α {alpha}, θi {ti}, θo {to}, φ {phi}: {a} vs {b}"
                    );
                    compared += usize::from(b > 0.0);
                }
            }
        }
    }
    assert!(compared > 100, "{compared} non-zero comparisons");
}

const PER_MM: f32 = 0.5;
const TUBE: Tube = Tube {
    height_mm: 60.0,
    length_mm: 300.0,
    radius_mm: 13.0,
};

/// The reflectometer camera: 60° elevation on the −x side, 600 mm from the sample's centre.
fn camera() -> Vector3<f64> {
    Vector3::new(-300.0, 0.0, 300.0 * 3f64.sqrt())
}

/// What the simulator's renderer shades at `p` (flat, `material`) toward the camera with the
/// tube at `tube_x`: 2,048 stratified points along the tube, no shadows, white tube.
fn rendered(material: Material, p: Vector3<f64>, tube_x: f64) -> [f64; 3] {
    let sample = Sample::build("flat", 80.0, 0.5).expect("the flat fixture");
    let mut knobs = Quality::parse("reference").expect("a preset").knobs();
    knobs.spp_side = 1;
    knobs.tube_samples = 2048;
    let light = Light {
        id: "tube".into(),
        kind: LampKind::Tube,
        output: 1.0,
        rgb: Vec3A::ONE,
        emitter: Emitter::Tube {
            start: Vec3A::new(tube_x as f32, -150.0, 60.0),
            axis: Vec3A::Y,
            length: 300.0,
            per_mm: PER_MM,
        },
    };
    let shading = Shading {
        shadows: false,
        specular: true,
        knobs: &knobs,
    };
    let scene = Scene::new(&sample, vec![light], None, Vec::new(), shading, &|_| None);
    let c = camera();
    let view = ViewPoint::seen_from(p, c).expect("above");
    let hit = Hit {
        p: Vec3A::new(p.x as f32, p.y as f32, 0.0),
        n: Vec3A::Z,
        material,
        on_relief: true,
    };
    let footprint = Footprint {
        origin: Vec3A::new(c.x as f32, c.y as f32, c.z as f32),
        angle: 1e-4,
        neighbours: &|| (Vec3A::X, Vec3A::Y),
        offset: (0.0, 0.0),
    };
    let wo = Vec3A::new(view.wo.x as f32, view.wo.y as f32, view.wo.z as f32);
    let mut rays = 0;
    let l = scene.shade(&hit, wo, &footprint, 0, 7, &mut rays);
    [l.x, l.y, l.z].map(|v| f64::from(v) / f64::from(PER_MM))
}

fn ward(rho_d: [f64; 3], rho_s: f64, alpha: f64) -> Material {
    Material::ward(
        Vec3A::new(rho_d[0] as f32, rho_d[1] as f32, rho_d[2] as f32),
        rho_s as f32,
        alpha as f32,
    )
}

/// The reflectometer tube's response as processing models it (`ward_tube`: D in closed form,
/// S by Gauss–Legendre about the mirror point) is the radiance the simulator's renderer
/// shades a flat Ward surface with under its tube, across the specular peak and for narrow
/// to broad lobes.
#[test]
fn the_tube_response_is_what_the_simulator_renders() {
    let _turn = crate::grbl_peer::alongside();
    let p = Vector3::new(4.0, -6.0, 0.0);
    let view = ViewPoint::seen_from(p, camera()).expect("above");
    let (mirror_x, _) = view.mirror_point(TUBE.height_mm);
    let (rho_d, rho_s) = ([0.3f64, 0.2, 0.1], 0.15f64);
    let mut worst = 0.0f64;
    for alpha in [0.03f64, 0.1, 0.3] {
        for offset in [-40.0, -8.0, -2.0, 0.0, 1.5, 6.0, 30.0] {
            let tube_x = mirror_x + offset;
            let got = rendered(ward(rho_d, rho_s, alpha), p, tube_x);
            let d = TUBE.diffuse(&view, tube_x) / std::f64::consts::PI;
            let s = TUBE.specular(&view, tube_x, alpha);
            for (c, got) in got.into_iter().enumerate() {
                let ours = rho_d[c] * d + rho_s * s;
                let err = (got / ours - 1.0).abs();
                worst = worst.max(err);
                assert!(
                    err < 1e-4,
                    "α {alpha}, tube {offset:+} mm from the mirror point, channel {c}: rendered {got}, modelled {ours}"
                );
            }
        }
    }
    eprintln!("tube response: worst relative difference renderer vs model {worst:.2e}");
}

/// A rendered 121-stop scan (240 mm of travel) of the pixel at `p`.
fn rendered_scan(material: Material, p: Vector3<f64>) -> Vec<WardSample> {
    (0..121)
        .map(|k| {
            let tube_x = -120.0 + 2.0 * k as f64;
            WardSample {
                tube_x_mm: tube_x,
                rgb: rendered(material, p, tube_x),
                saturated: false,
            }
        })
        .collect()
}

/// Scans the renderer made are fitted back to the material it rendered (isotropic: within
/// 0.1 %), and an anisotropic surface scanned twice, turned 90° between the scans, is
/// reported as such, where either scan alone fits some isotropic lobe.
#[test]
fn rendered_scans_fit_back_and_anisotropy_is_reported() {
    let _turn = crate::grbl_peer::alongside();
    let p = Vector3::new(-3.0, 5.0, 0.0);
    let view = ViewPoint::seen_from(p, camera()).expect("above");
    let options = WardFitOptions::default();
    let (rho_d, rho_s, alpha) = ([0.35, 0.25, 0.15], 0.12, 0.08);
    let iso = fit_ward(
        &TUBE,
        &view,
        &rendered_scan(ward(rho_d, rho_s, alpha), p),
        &options,
    )
    .expect("fits");
    assert!(iso.flags.is_empty(), "{iso:?}");
    for (got, truth) in iso.rho_d.iter().zip(rho_d) {
        assert!((got / truth - 1.0).abs() < 1e-3, "{iso:?}");
    }
    assert!((iso.rho_s / rho_s - 1.0).abs() < 1e-3, "{iso:?}");
    assert!((iso.alpha / alpha - 1.0).abs() < 1e-3, "{iso:?}");
    // Brushed: α 0.05 along the tangent, 0.2 across; the tangent along x, then turned to y.
    let brushed = |tangent_rad: f32| Material {
        model: Model::WardAniso,
        alpha_y: 0.2,
        tangent_rad,
        ..ward(rho_d, rho_s, 0.05)
    };
    let first = fit_ward(&TUBE, &view, &rendered_scan(brushed(0.0), p), &options).expect("fits");
    let second = fit_ward(
        &TUBE,
        &view,
        &rendered_scan(brushed(std::f32::consts::FRAC_PI_2), p),
        &options,
    )
    .expect("fits");
    let both = combine_turned_scans(&first, &second, 0.1);
    assert!(
        both.flags.contains(&WardFlag::Anisotropic),
        "{first:?}\n{second:?}\n{both:?}"
    );
    eprintln!(
        "brushed (α 0.05 × 0.2): scan 1 α {:.4} (rms {:.1e}), scan 2 α {:.4} (rms {:.1e})",
        first.alpha, first.relative_rms, second.alpha, second.relative_rms
    );
}
