//! One-texel spikes and walls: hit by the march and casting their shadows.

use super::march::compare_march;
use super::*;

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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
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
        let _turn = crate::grbl_peer::alongside();
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
        let _turn = crate::grbl_peer::alongside();
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
        let _turn = crate::grbl_peer::alongside();
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
