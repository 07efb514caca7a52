//! The height-field march against brute force: vertical, axis-aligned, edge and random rays.

use super::*;

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
pub(super) fn compare_march(
    g: &HeightGrid,
    half: f32,
    o: Vec3A,
    d: Vec3A,
    t_max: f32,
) -> Option<String> {
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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
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
        let _turn = crate::grbl_peer::alongside();
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
