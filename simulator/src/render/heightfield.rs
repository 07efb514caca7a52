//! A sample's relief as a piecewise-bilinear height field on a square grid, with the maximum
//! height of every cell and of every 8×8 block of cells, so rays step block by block through
//! empty space and cell by cell only where they could meet the surface.

use glam::Vec3A;
use rayon::prelude::*;

/// How far below the surface a shadow ray must pass to count as blocked, in mm.
const SHADOW_TOLERANCE_MM: f32 = 1.0e-3;
/// Slack on the height slab so rays grazing the top or bottom are not clipped away.
const SLAB_SLACK_MM: f32 = 1.0e-3;

/// Floor without a libm call (baseline x86-64 has no rounding instruction); exact for the
/// grid coordinates used here (|x| < 2^31).
#[inline]
fn floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// Cells per side of a block in the coarse max grid.
const BLOCK: usize = 8;

/// A ray in grid units (cells), rebased at its entry into the grid's box.
struct GridRay {
    u0: f32,
    v0: f32,
    du: f32,
    dv: f32,
    inv_du: f32,
    inv_dv: f32,
}

/// Amanatides–Woo traversal of the square cells of side `size` (in grid units) crossed by a
/// grid ray for t in [t0, t1], limited to the cell index ranges
/// [i_lo, i_hi] × [j_lo, j_hi]. Yields each cell with the ray interval inside it.
struct Dda {
    i: i64,
    j: i64,
    step_i: i64,
    step_j: i64,
    next_u: f32,
    next_v: f32,
    delta_u: f32,
    delta_v: f32,
    t: f32,
    end: f32,
    range: [i64; 4],
}

impl Dda {
    #[inline(always)]
    fn new(ray: &GridRay, t0: f32, t1: f32, size: f32, range: [i64; 4]) -> Dda {
        let inv_size = 1.0 / size;
        let axis = |p0: f32, dp: f32, inv: f32, lo: i64, hi: i64| {
            let k = (floor((p0 + dp * t0) * inv_size) as i64).clamp(lo, hi);
            if dp > 0.0 {
                (k, 1, ((k + 1) as f32 * size - p0) * inv, size * inv)
            } else if dp < 0.0 {
                (k, -1, (k as f32 * size - p0) * inv, -size * inv)
            } else {
                (k, 0, f32::INFINITY, f32::INFINITY)
            }
        };
        let (i, step_i, next_u, delta_u) = axis(ray.u0, ray.du, ray.inv_du, range[0], range[1]);
        let (j, step_j, next_v, delta_v) = axis(ray.v0, ray.dv, ray.inv_dv, range[2], range[3]);
        Dda {
            i,
            j,
            step_i,
            step_j,
            next_u,
            next_v,
            delta_u,
            delta_v,
            t: t0,
            end: t1,
            range,
        }
    }

    /// The current cell (i, j) and the ray interval [t_in, t_out] inside it; then advances.
    #[inline]
    fn next(&mut self) -> Option<(i64, i64, f32, f32)> {
        let [i_lo, i_hi, j_lo, j_hi] = self.range;
        if self.t >= self.end || self.i < i_lo || self.i > i_hi || self.j < j_lo || self.j > j_hi {
            return None;
        }
        let t_out = self.next_u.min(self.next_v).min(self.end).max(self.t);
        let cell = (self.i, self.j, self.t, t_out);
        if self.next_u <= self.next_v {
            self.i += self.step_i;
            self.next_u += self.delta_u;
        } else {
            self.j += self.step_j;
            self.next_v += self.delta_v;
        }
        self.t = t_out;
        Some(cell)
    }
}

/// Heights in mm at the (n+1)² vertices of an n×n grid centred on the origin.
#[derive(Debug, Clone)]
pub struct HeightGrid {
    n: usize,
    cell: f32,
    origin: f32,
    heights: Vec<f32>,
    grads: Vec<[f32; 2]>,
    /// Highest vertex of each cell, n × n.
    cell_max: Vec<f32>,
    /// Highest vertex of each BLOCK × BLOCK block of cells, nb × nb.
    block_max: Vec<f32>,
    nb: usize,
    zmin: f32,
    zmax: f32,
    max_slope: f32,
    edge_max: f32,
}

/// Where a ray first meets the relief.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridHit {
    /// Distance along the (unit) ray in mm.
    pub t: f32,
    /// Outward normal when the ray hit the sample's vertical side rather than its top.
    pub wall: Option<Vec3A>,
}

impl HeightGrid {
    /// Samples `height(x, y)` (mm, x and y in mm from the sample centre) at the vertices of an
    /// n×n grid spanning `size_mm`, then derives gradients, the max pyramid and slope bounds.
    pub fn build(n: usize, size_mm: f32, height: impl Fn(f32, f32) -> f32 + Sync) -> HeightGrid {
        let n = n.max(1);
        let w = n + 1;
        let cell = size_mm / n as f32;
        let origin = -0.5 * size_mm;
        let heights: Vec<f32> = (0..w * w)
            .into_par_iter()
            .map(|k| {
                let h = height(
                    origin + (k % w) as f32 * cell,
                    origin + (k / w) as f32 * cell,
                );
                if h.is_finite() { h } else { 0.0 }
            })
            .collect();
        let grads: Vec<[f32; 2]> = (0..w * w)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % w, k / w);
                let (il, ir) = (i.saturating_sub(1), (i + 1).min(n));
                let (jl, jr) = (j.saturating_sub(1), (j + 1).min(n));
                let gx = (heights[j * w + ir] - heights[j * w + il]) / ((ir - il) as f32 * cell);
                let gy = (heights[jr * w + i] - heights[jl * w + i]) / ((jr - jl) as f32 * cell);
                [gx, gy]
            })
            .collect();
        let level0: Vec<f32> = (0..n * n)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % n, k / n);
                let b = j * w + i;
                heights[b]
                    .max(heights[b + 1])
                    .max(heights[b + w])
                    .max(heights[b + w + 1])
            })
            .collect();
        let slope = (0..n * n)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % n, k / n);
                let b = j * w + i;
                let (h00, h10, h01, h11) = (
                    heights[b],
                    heights[b + 1],
                    heights[b + w],
                    heights[b + w + 1],
                );
                let gx = (h10 - h00).abs().max((h11 - h01).abs()) / cell;
                let gy = (h01 - h00).abs().max((h11 - h10).abs()) / cell;
                (gx * gx + gy * gy).sqrt()
            })
            .reduce(|| 0.0, f32::max);
        let nb = n.div_ceil(BLOCK);
        let block_max: Vec<f32> = (0..nb * nb)
            .into_par_iter()
            .map(|k| {
                let (bi, bj) = (k % nb, k / nb);
                let mut best = f32::NEG_INFINITY;
                for j in bj * BLOCK..((bj + 1) * BLOCK).min(n) {
                    for i in bi * BLOCK..((bi + 1) * BLOCK).min(n) {
                        best = best.max(level0[j * n + i]);
                    }
                }
                best
            })
            .collect();
        // The box reaches down to the turntable (z = 0) so rays meet the sample's sides.
        // The box reaches down to the turntable (z = 0) so rays meet the sample's sides.
        let zmin = heights.iter().copied().fold(0.0, f32::min);
        let zmax = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut edge_max = f32::NEG_INFINITY;
        for k in 0..w {
            for idx in [k, n * w + k, k * w, k * w + n] {
                edge_max = edge_max.max(heights[idx]);
            }
        }
        HeightGrid {
            n,
            cell,
            origin,
            heights,
            grads,
            cell_max: level0,
            block_max,
            nb,
            zmin,
            zmax,
            max_slope: slope,
            edge_max,
        }
    }

    /// Cells per side.
    pub fn cells(&self) -> usize {
        self.n
    }

    /// Highest point of the relief in mm.
    pub fn zmax(&self) -> f32 {
        self.zmax
    }

    /// Upper bound of the bilinear surface's gradient magnitude (rise over run) inside the grid.
    pub fn max_slope(&self) -> f32 {
        self.max_slope
    }

    /// Highest vertex on the grid border: a cliff down to the turntable if above zero.
    pub fn edge_max(&self) -> f32 {
        self.edge_max
    }

    /// Position and shading normal of vertex (i, j).
    pub fn vertex(&self, i: usize, j: usize) -> (Vec3A, Vec3A) {
        let w = self.n + 1;
        let k = j * w + i;
        let [gx, gy] = self.grads[k];
        let p = Vec3A::new(
            self.origin + i as f32 * self.cell,
            self.origin + j as f32 * self.cell,
            self.heights[k],
        );
        (p, Vec3A::new(-gx, -gy, 1.0).normalize_or(Vec3A::Z))
    }

    /// Cell (i, j) containing (x, y), clamped to the grid, and the fractional position in it.
    #[inline]
    pub fn bilinear(&self, x: f32, y: f32) -> (usize, usize, f32, f32) {
        self.local(x, y)
    }

    fn local(&self, x: f32, y: f32) -> (usize, usize, f32, f32) {
        let nf = self.n as f32;
        let u = ((x - self.origin) / self.cell).clamp(0.0, nf);
        let v = ((y - self.origin) / self.cell).clamp(0.0, nf);
        // u, v ≥ 0, so truncation is floor (and avoids a libm call on baseline x86-64).
        let i = (u as usize).min(self.n - 1);
        let j = (v as usize).min(self.n - 1);
        (i, j, u - i as f32, v - j as f32)
    }

    /// Bilinearly interpolated height at (x, y), clamped to the grid.
    pub fn height_at(&self, x: f32, y: f32) -> f32 {
        let (i, j, a, b) = self.local(x, y);
        let w = self.n + 1;
        let k = j * w + i;
        let h = &self.heights;
        let top = h[k] + (h[k + 1] - h[k]) * a;
        let bottom = h[k + w] + (h[k + w + 1] - h[k + w]) * a;
        top + (bottom - top) * b
    }

    /// Smooth shading normal at (x, y): bilinear interpolation of the vertex gradients.
    pub fn normal_at(&self, x: f32, y: f32) -> Vec3A {
        let (i, j, a, b) = self.local(x, y);
        let w = self.n + 1;
        let k = j * w + i;
        let g = &self.grads;
        let lerp =
            |p: [f32; 2], q: [f32; 2], s: f32| [p[0] + (q[0] - p[0]) * s, p[1] + (q[1] - p[1]) * s];
        let top = lerp(g[k], g[k + 1], a);
        let bottom = lerp(g[k + w], g[k + w + 1], a);
        let [gx, gy] = lerp(top, bottom, b);
        Vec3A::new(-gx, -gy, 1.0).normalize_or(Vec3A::Z)
    }

    /// First intersection of the ray o + t·d (d a unit vector, t in (t_min, t_max)) with the
    /// relief, including the sample's vertical sides.
    pub fn first_hit(&self, o: Vec3A, d: Vec3A, t_min: f32, t_max: f32) -> Option<GridHit> {
        self.march::<false>(o, d, t_min, t_max)
    }

    /// Whether the relief blocks the segment o + t·d, t in (t_min, t_max) (a shadow ray).
    pub fn occluded(&self, o: Vec3A, d: Vec3A, t_min: f32, t_max: f32) -> bool {
        self.march::<true>(o, d, t_min, t_max).is_some()
    }

    /// Two-level traversal: step through 8×8 blocks, skipping those the ray passes above;
    /// inside the others step cell by cell, skipping cells likewise, and solve the
    /// ray–bilinear-patch quadratic exactly in the rest.
    fn march<const ANY: bool>(
        &self,
        o: Vec3A,
        d: Vec3A,
        t_min: f32,
        t_max: f32,
    ) -> Option<GridHit> {
        let inv = 1.0 / self.cell;
        let nf = self.n as f32;
        let (ou, ov, du, dv) = (
            (o.x - self.origin) * inv,
            (o.y - self.origin) * inv,
            d.x * inv,
            d.y * inv,
        );
        let (inv_du, inv_dv, inv_dz) = (1.0 / du, 1.0 / dv, 1.0 / d.z);
        // Clip to the grid's box: u, v in [0, n], z in [zmin, zmax].
        let mut ta = t_min;
        let mut tb = t_max;
        let mut entry_axis = 3usize;
        let slabs = [
            (ou, du, inv_du, 0.0, nf),
            (ov, dv, inv_dv, 0.0, nf),
            (
                o.z,
                d.z,
                inv_dz,
                self.zmin - SLAB_SLACK_MM,
                self.zmax + SLAB_SLACK_MM,
            ),
        ];
        for (axis, &(p, dp, inv_dp, lo, hi)) in slabs.iter().enumerate() {
            if dp == 0.0 {
                if p < lo || p > hi {
                    return None;
                }
            } else {
                let (t0, t1) = ((lo - p) * inv_dp, (hi - p) * inv_dp);
                let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
                if near > ta {
                    ta = near;
                    entry_axis = axis;
                }
                tb = tb.min(far);
            }
        }
        if ta.is_nan() || tb.is_nan() || ta >= tb {
            return None;
        }
        // Rebase at the entry point so the arithmetic below works on small numbers.
        let (u0, v0, z0) = (ou + du * ta, ov + dv * ta, o.z + d.z * ta);
        let len = tb - ta;
        if !ANY && entry_axis < 2 {
            let h = self.height_at(self.origin + u0 * self.cell, self.origin + v0 * self.cell);
            if z0 < h {
                let n = if entry_axis == 0 {
                    Vec3A::new(-du.signum(), 0.0, 0.0)
                } else {
                    Vec3A::new(0.0, -dv.signum(), 0.0)
                };
                return Some(GridHit {
                    t: ta,
                    wall: Some(n),
                });
            }
        }
        let last = self.n as i64 - 1;
        let last_block = self.nb as i64 - 1;
        let b = BLOCK as i64;
        let z_at = |t: f32| z0 + d.z * t;
        let ray = GridRay {
            u0,
            v0,
            du,
            dv,
            inv_du,
            inv_dv,
        };
        let mut blocks = Dda::new(&ray, 0.0, len, BLOCK as f32, [0, last_block, 0, last_block]);
        while let Some((bi, bj, t_in, t_out)) = blocks.next() {
            if z_at(t_in).min(z_at(t_out)) > self.block_max[bj as usize * self.nb + bi as usize] {
                continue;
            }
            let range = [
                bi * b,
                (bi * b + b - 1).min(last),
                bj * b,
                (bj * b + b - 1).min(last),
            ];
            let mut cells = Dda::new(&ray, t_in, t_out, 1.0, range);
            while let Some((i, j, s_in, s_out)) = cells.next() {
                let (i, j) = (i as usize, j as usize);
                if z_at(s_in).min(z_at(s_out)) > self.cell_max[j * self.n + i] {
                    continue;
                }
                let (a, bb) = (u0 + du * s_in - i as f32, v0 + dv * s_in - j as f32);
                if let Some(s) =
                    self.patch::<ANY>(i, j, a, bb, z_at(s_in), du, dv, d.z, s_out - s_in)
                {
                    return Some(GridHit {
                        t: ta + s_in + s,
                        wall: None,
                    });
                }
            }
        }
        None
    }

    /// Ray against the bilinear patch of cell (i, j). The ray starts at local coordinates
    /// (a, b) in cell units with height z and runs for `len`; f(s) = z(s) − h(s) is quadratic.
    /// Returns the offset s of the first crossing (first-hit) or of any point more than the
    /// tolerance below the surface (shadow rays).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn patch<const ANY: bool>(
        &self,
        i: usize,
        j: usize,
        a: f32,
        b: f32,
        z: f32,
        du: f32,
        dv: f32,
        dz: f32,
        len: f32,
    ) -> Option<f32> {
        let w = self.n + 1;
        let k = j * w + i;
        let h = &self.heights;
        let (h00, h10, h01, h11) = (h[k], h[k + 1], h[k + w], h[k + w + 1]);
        let bb = h10 - h00;
        let cc = h01 - h00;
        let dd = h11 - h10 - h01 + h00;
        let c0 = z - (h00 + bb * a + cc * b + dd * a * b);
        let c1 = dz - (bb * du + cc * dv + dd * (a * dv + b * du));
        let c2 = -dd * du * dv;
        let f = |s: f32| c0 + s * (c1 + s * c2);
        if ANY {
            if c0 < -SHADOW_TOLERANCE_MM || f(len) < -SHADOW_TOLERANCE_MM {
                return Some(0.0);
            }
            if c2 > 0.0 {
                let s = -c1 / (2.0 * c2);
                if s > 0.0 && s < len && f(s) < -SHADOW_TOLERANCE_MM {
                    return Some(s);
                }
            }
            return None;
        }
        if c0 < 0.0 {
            return Some(0.0);
        }
        let mut best = f32::INFINITY;
        let mut consider = |s: f32| {
            if s.is_finite() && s >= 0.0 && s <= len && s < best {
                best = s;
            }
        };
        if c2.abs() <= 1.0e-7 * (c1.abs() + c0.abs()).max(1.0e-12) {
            if c1 != 0.0 {
                consider(-c0 / c1);
            }
        } else {
            let disc = c1 * c1 - 4.0 * c2 * c0;
            if disc >= 0.0 {
                let q = -0.5 * (c1 + c1.signum() * disc.sqrt());
                consider(q / c2);
                if q != 0.0 {
                    consider(c0 / q);
                }
            }
        }
        if best.is_finite() {
            return Some(best);
        }
        let end = f(len);
        if end < 0.0 {
            // Rounding hid the root; fall back to the secant.
            return Some(len * c0 / (c0 - end));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bumpy() -> HeightGrid {
        HeightGrid::build(64, 16.0, |x, y| {
            let r2 = x * x + y * y;
            2.0 * (-r2 / 8.0).exp() + 0.3 * (x * 0.9).sin() * (y * 0.7).cos() + 0.3
        })
    }

    /// Reference: step along the ray in tiny increments and report the first point below.
    fn brute(g: &HeightGrid, o: Vec3A, d: Vec3A, t_max: f32) -> Option<f32> {
        let step = 0.002;
        let mut t = 0.0;
        while t < t_max {
            let p = o + d * t;
            let inside = p.x.abs() <= 8.0 && p.y.abs() <= 8.0;
            if inside && p.z < g.height_at(p.x, p.y) {
                return Some(t);
            }
            t += step;
        }
        None
    }

    #[test]
    fn hierarchical_march_matches_brute_force() {
        let g = bumpy();
        let mut agree = 0;
        for k in 0..400u64 {
            let h = crate::render::rng::hash3(3, k, 0, 0);
            let r = |s: u32| crate::render::rng::unit_f32(h.rotate_left(s * 16));
            let az = r(0) * std::f32::consts::TAU;
            let el = 0.05 + r(1) * 1.4;
            let target = Vec3A::new(r(2) * 14.0 - 7.0, r(3) * 14.0 - 7.0, 0.0);
            let d = -Vec3A::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let o = target - d * 30.0;
            let fast = g.first_hit(o, d, 0.0, 100.0).map(|h| h.t);
            let slow = brute(&g, o, d, 100.0);
            match (fast, slow) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 0.02, "ray {k}: march {a} vs brute {b}");
                    agree += 1;
                }
                (None, None) => agree += 1,
                other => panic!("ray {k}: {other:?}"),
            }
            // A shadow ray from just above the hit toward the camera is not blocked.
            if let Some(t) = fast {
                let p = o + d * t;
                let n = g.normal_at(p.x, p.y);
                if n.dot(-d) > 0.2 {
                    assert!(
                        !g.occluded(p + n * 0.02, -d, 0.0, t - 0.1),
                        "ray {k} self-shadowed"
                    );
                }
            }
        }
        assert_eq!(agree, 400);
    }

    #[test]
    fn side_wall_is_hit_with_outward_normal() {
        let g = HeightGrid::build(8, 10.0, |_, _| 2.0);
        let hit = g.first_hit(
            Vec3A::new(20.0, 0.0, 1.0),
            Vec3A::new(-1.0, 0.0, 0.0),
            0.0,
            100.0,
        );
        let hit = hit.expect("hits the side");
        assert!((hit.t - 15.0).abs() < 1e-4);
        assert_eq!(hit.wall, Some(Vec3A::X));
    }

    #[test]
    fn vertical_rays_and_slopes() {
        let g = HeightGrid::build(10, 10.0, |x, _| 0.5 * (x + 5.0));
        let hit = g.first_hit(
            Vec3A::new(1.0, 0.5, 50.0),
            Vec3A::new(0.0, 0.0, -1.0),
            0.0,
            100.0,
        );
        assert!((hit.map(|h| h.t).unwrap_or(0.0) - (50.0 - 3.0)).abs() < 1e-3);
        assert!((g.max_slope() - 0.5).abs() < 1e-4);
        assert!((g.edge_max() - 5.0).abs() < 1e-4);
        // Straight up never meets a height field.
        assert!(!g.occluded(Vec3A::new(0.0, 0.0, 2.6), Vec3A::Z, 0.0, 100.0));
        // Toward the rising side at a shallow angle: blocked.
        let d = Vec3A::new(1.0, 0.0, 0.1).normalize();
        assert!(g.occluded(Vec3A::new(-4.0, 0.0, 0.55), d, 0.0, 100.0));
    }
}
