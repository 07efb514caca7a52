//! Shadows on a height field: which blocks of the sample are surely lit by a light region
//! (so their points skip the shadow march), computed once per frame and light.
//!
//! A block B can only be shadowed by terrain inside the capsule between B and the light
//! region, and only by terrain that rises above the lowest ray from B: from height
//! min(B) climbing at the smallest slope any ray from B to the region can have. If no
//! block's maximum rises above that, every point of B is lit, exactly as the march would
//! find; otherwise its points are marched as usual.

use glam::Vec3A;

use super::heightfield::HeightGrid;

/// Per-block "surely lit" flags for one light region.
#[derive(Debug, Clone, PartialEq)]
pub struct LitMask {
    lit: Vec<bool>,
}

impl LitMask {
    /// Flags for the light region of centre `q` (sample frame) and radius `radius_mm`.
    pub fn new(grid: &HeightGrid, q: Vec3A, radius_mm: f32) -> LitMask {
        let nb = grid.blocks();
        let lit = (0..nb * nb)
            .map(|k| block_lit(grid, k % nb, k / nb, q, radius_mm))
            .collect();
        LitMask { lit }
    }

    /// Whether the point (x, y, z) is surely lit: its block is flagged and the point is not
    /// below the block's lowest vertex (points on the sample's sides can be). False off the
    /// grid.
    #[inline]
    pub fn surely_lit(&self, grid: &HeightGrid, p: Vec3A) -> bool {
        grid.block_of(p.x, p.y)
            .is_some_and(|k| self.lit[k] && p.z >= grid.block_min_at(k))
    }

    /// How many blocks are surely lit.
    pub fn lit_blocks(&self) -> usize {
        self.lit.iter().filter(|&&l| l).count()
    }
}

fn block_lit(grid: &HeightGrid, bi: usize, bj: usize, q: Vec3A, rho: f32) -> bool {
    let size = grid.block_mm();
    let r_block = size * std::f32::consts::FRAC_1_SQRT_2;
    let (cx, cy) = grid.block_centre(bi, bj);
    let (zlo, _) = grid.block_range(bi, bj);
    let to_light = glam::Vec2::new(q.x - cx, q.y - cy);
    let reach = to_light.length();
    // Smallest rise per horizontal mm of any ray from a point of B (height ≥ zlo) to the region.
    let rise = (q.z - rho - zlo) / (reach + r_block + rho);
    if !(rise > 0.0) {
        return false;
    }
    let zmax = grid.zmax();
    // Beyond this horizontal run every ray from B is above all terrain.
    let run_end = (zmax - zlo) / rise + r_block;
    if reach <= r_block + rho {
        // The region is (nearly) overhead: the capsule degenerates; test the run around B.
        return neighbourhood_lit(grid, cx, cy, run_end, zlo, rise, r_block);
    }
    let dir = to_light / reach;
    let nb = grid.blocks() as i64;
    let step = 0.5 * size;
    let mut s = 0.0f32;
    while s <= run_end.min(reach) + step {
        let (mx, my) = (cx + dir.x * s, cy + dir.y * s);
        // Lateral half-width of the capsule here, plus a block's reach and the step.
        let half_width = r_block + rho * (s / reach) + r_block + step;
        let lo_i = grid_index(grid, mx - half_width).max(0);
        let hi_i = grid_index(grid, mx + half_width).min(nb - 1);
        let lo_j = grid_index(grid, my - half_width).max(0);
        let hi_j = grid_index(grid, my + half_width).min(nb - 1);
        for xj in lo_j..=hi_j {
            for xi in lo_i..=hi_i {
                let (xc, yc) = grid.block_centre(xi as usize, xj as usize);
                let (_, xmax) = grid.block_range(xi as usize, xj as usize);
                if xmax <= zlo {
                    continue;
                }
                // Least horizontal distance from a point of B to a point of X.
                let dist = ((xc - cx).hypot(yc - cy) - 2.0 * r_block).max(0.0);
                if xmax > zlo + dist * rise {
                    return false;
                }
            }
        }
        s += step;
    }
    true
}

fn neighbourhood_lit(
    grid: &HeightGrid,
    cx: f32,
    cy: f32,
    run: f32,
    zlo: f32,
    rise: f32,
    r_block: f32,
) -> bool {
    let nb = grid.blocks() as i64;
    let reach = run + r_block;
    for xj in grid_index(grid, cy - reach).max(0)..=grid_index(grid, cy + reach).min(nb - 1) {
        for xi in grid_index(grid, cx - reach).max(0)..=grid_index(grid, cx + reach).min(nb - 1) {
            let (xc, yc) = grid.block_centre(xi as usize, xj as usize);
            let (_, xmax) = grid.block_range(xi as usize, xj as usize);
            let dist = ((xc - cx).hypot(yc - cy) - 2.0 * r_block).max(0.0);
            if xmax > zlo + dist * rise {
                return false;
            }
        }
    }
    true
}

/// Block index along one axis of the coordinate `c` in mm (may be out of range).
fn grid_index(grid: &HeightGrid, c: f32) -> i64 {
    let (x0, _) = grid.block_centre(0, 0);
    let origin = x0 - 0.5 * grid.block_mm();
    ((c - origin) / grid.block_mm()).floor() as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surely_lit_blocks_are_never_shadowed() {
        // A single tall bump: blocks far from it, or on its lit side, are surely lit; the
        // march agrees for every point the mask calls lit.
        let grid = HeightGrid::build(160, 32.0, |x, y| 4.0 * (-(x * x + y * y) / 6.0).exp());
        for (q, rho) in [
            (Vec3A::new(800.0, 0.0, 140.0), 0.0),
            (Vec3A::new(-300.0, 500.0, 300.0), 10.0),
            (Vec3A::new(5.0, 3.0, 60.0), 20.0),
        ] {
            let mask = LitMask::new(&grid, q, rho);
            assert!(mask.lit_blocks() > 0, "some blocks are surely lit for {q}");
            for k in 0..4000u64 {
                let h = crate::render::rng::hash3(9, k, 0, 0);
                let x = crate::render::rng::unit_f32(h) * 31.8 - 15.9;
                let y = crate::render::rng::unit_f32(h.rotate_left(32)) * 31.8 - 15.9;
                let p = Vec3A::new(x, y, grid.height_at(x, y));
                if !mask.surely_lit(&grid, p) {
                    continue;
                }
                let n = grid.normal_at(x, y);
                // Any point of the light region.
                let l = q + Vec3A::new(rho * 0.7, -rho * 0.7, 0.0)
                    * crate::render::rng::unit_f32(h >> 7);
                let v = l - p;
                if n.dot(v) <= 0.0 {
                    continue;
                }
                let o = p + n * 0.02 + Vec3A::Z * 0.005;
                assert!(
                    !grid.occluded(o, v.normalize(), 0.0, v.length()),
                    "({x}, {y}) marked lit but shadowed by {q}"
                );
            }
        }
        // Low light from +x: the block just behind the bump (−x side) is not surely lit.
        let mask = LitMask::new(&grid, Vec3A::new(800.0, 0.0, 50.0), 0.0);
        assert!(!mask.surely_lit(&grid, Vec3A::new(-3.0, 0.0, grid.height_at(-3.0, 0.0))));
    }
}
