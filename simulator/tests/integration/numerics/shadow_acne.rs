//! Shadow acne at 1° light elevation: a flat plane lit at grazing elevation has no acne, and
//! area-light sampling gives uniform brightness.

use super::furnace::{
    Stats, flat_against_reference, footprint_within, pixel_on_plane, reference_radiance,
};
use super::*;

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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
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
