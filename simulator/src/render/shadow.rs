//! Shadows on a height field for preview frames: the visibility of a point light from every
//! relief vertex, found by marching the height field toward the light once per vertex and
//! interpolated bilinearly between vertices (a hard shadow, anti-aliased over one relief
//! cell). The maps are cached per fixture and light position, so the cameras of one rig step
//! share them. Higher qualities march one shadow ray per light sample instead.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use glam::Vec3A;
use rayon::prelude::*;

use super::heightfield::HeightGrid;

/// How far shadow-ray origins are pushed off the surface along the normal, in mm.
pub const SHADOW_OFFSET_MM: f32 = 0.02;
/// Cached maps kept before the cache is emptied (each is one byte per relief vertex).
const CACHE_CAPACITY: usize = 96;

/// Start of a shadow ray from surface point `p` with normal `n`.
#[inline]
pub fn shadow_origin(p: Vec3A, n: Vec3A) -> Vec3A {
    p + n * SHADOW_OFFSET_MM + Vec3A::Z * (0.25 * SHADOW_OFFSET_MM)
}

/// Visibility (0 or 1) of one point light from each relief vertex.
#[derive(Debug, Clone, PartialEq)]
pub struct VertexVisibility {
    lit: Vec<u8>,
}

impl VertexVisibility {
    /// Marches from every vertex of `grid` toward the point `light`.
    pub fn compute(grid: &HeightGrid, light: Vec3A) -> VertexVisibility {
        let w = grid.cells() + 1;
        let lit = (0..w * w)
            .into_par_iter()
            .map(|k| {
                let (p, n) = grid.vertex(k % w, k / w);
                let o = shadow_origin(p, n);
                let v = light - o;
                let dist = v.length();
                if dist.is_nan() || dist <= 0.0 {
                    return 1;
                }
                let dir = v / dist;
                if n.dot(dir) <= 0.0 || grid.occluded(o, dir, 0.0, dist) {
                    0
                } else {
                    1
                }
            })
            .collect();
        VertexVisibility { lit }
    }

    /// Interpolated visibility in [0, 1] at (x, y) on the grid.
    #[inline]
    pub fn at(&self, grid: &HeightGrid, x: f32, y: f32) -> f32 {
        let (i, j, a, b) = grid.bilinear(x, y);
        let w = grid.cells() + 1;
        let k = j * w + i;
        let l = |idx: usize| self.lit[idx] as f32;
        let top = l(k) + (l(k + 1) - l(k)) * a;
        let bottom = l(k + w) + (l(k + w + 1) - l(k + w)) * a;
        top + (bottom - top) * b
    }
}

type Key = (String, usize, [i64; 3]);

/// Visibility maps by fixture, relief resolution and light position (to 1 µm).
#[derive(Debug, Default)]
pub struct VisibilityCache {
    maps: Mutex<HashMap<Key, Arc<OnceLock<Arc<VertexVisibility>>>>>,
}

impl VisibilityCache {
    /// The map for `light` over the relief of `fixture`, computed at most once even when
    /// several cameras ask at the same time.
    pub fn get(&self, fixture: &str, grid: &HeightGrid, light: Vec3A) -> Arc<VertexVisibility> {
        let q = |c: f32| (c as f64 * 1000.0).round() as i64;
        let key = (
            fixture.to_string(),
            grid.cells(),
            [q(light.x), q(light.y), q(light.z)],
        );
        let slot = {
            let mut maps = self
                .maps
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner());
            if maps.len() >= CACHE_CAPACITY && !maps.contains_key(&key) {
                maps.clear();
            }
            Arc::clone(maps.entry(key).or_default())
        };
        Arc::clone(slot.get_or_init(|| Arc::new(VertexVisibility::compute(grid, light))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_visibility_matches_marching_at_the_vertices() {
        let grid = HeightGrid::build(64, 32.0, |x, y| 4.0 * (-(x * x + y * y) / 6.0).exp());
        let light = Vec3A::new(800.0, 0.0, 100.0);
        let vis = VertexVisibility::compute(&grid, light);
        // Behind the bump (−x side), in its shadow; in front, lit; far away, lit.
        assert_eq!(vis.at(&grid, -4.0, 0.0), 0.0);
        assert_eq!(vis.at(&grid, 4.0, 0.0), 1.0);
        assert_eq!(vis.at(&grid, -14.0, 12.0), 1.0);
        // Between vertices the value is interpolated.
        let cache = VisibilityCache::default();
        let a = cache.get("bump", &grid, light);
        let b = cache.get("bump", &grid, light + Vec3A::splat(1e-5));
        assert!(Arc::ptr_eq(&a, &b), "the cache returns the same map");
        assert_eq!(*a, vis);
    }
}
