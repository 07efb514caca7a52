//! What a bounce pass ([`super::bounce`]) marches that does not depend on the light: each
//! texel's point, normal and albedo, and where each of its hemisphere rays lands on the relief,
//! per bounce. The ray directions come from the counter-based hash of (texel, bounce), so a
//! fixture's landings are the same under every lamp, laser line and turntable angle (the
//! relief is in the sample's frame): traced once per fixture and kept, a bounce pass is a
//! lookup per ray instead of a march. The landing point is stored exactly as the march found
//! it, so the maps are bit-identical to marching every pass.

use std::f32::consts::TAU;

use glam::Vec3A;
use rayon::prelude::*;

use super::heightfield::HeightGrid;
use super::rng::{hash3, unit_f32};
use super::shadow::shadow_origin;
use super::surface::Surface;
use super::texgrid::TexGrid;

/// Key of the bounce-ray hash.
const BOUNCE_KEY: u64 = 0xb0_u64 << 56 | 0x0c_e5a1;

/// Where no ray landed: it escaped or met the sample's side (never a real coordinate).
const NOWHERE: [f32; 2] = [f32::NAN, f32::NAN];

/// A texel of the bounce grid: its relief point, normal and diffuse albedo (clamped to [0, 1]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelSite {
    pub p: Vec3A,
    pub n: Vec3A,
    pub albedo: Vec3A,
}

/// The light-independent part of a bounce pass over one relief: `n` × `n` texel sites and,
/// per bounce, texel and ray, where the ray lands.
#[derive(Debug, Clone, PartialEq)]
pub struct BounceGeometry {
    n: usize,
    size_mm: f32,
    bounces: u32,
    rays: u32,
    sites: Vec<TexelSite>,
    /// (x, y) of each landing on the relief, [`NOWHERE`] when the ray sees nothing; indexed
    /// by (bounce · texels + texel) · rays + ray.
    landings: Vec<[f32; 2]>,
}

/// Texels per side of the bounce grid of `grid` capped at `max_texels` (and the module's
/// [`super::bounce::MAX_TEXELS`]).
pub fn texels_per_side(grid: &HeightGrid, max_texels: usize) -> usize {
    grid.cells()
        .clamp(1, max_texels.clamp(1, super::bounce::MAX_TEXELS))
}

/// Bytes the geometry of `n` texels a side with `bounces` × `rays` rays a texel takes.
pub fn geometry_bytes(n: usize, bounces: u32, rays: u32) -> usize {
    let texels = n * n;
    texels
        .saturating_mul(std::mem::size_of::<TexelSite>())
        .saturating_add(
            texels
                .saturating_mul(bounces.max(1) as usize)
                .saturating_mul(rays.max(1) as usize)
                .saturating_mul(std::mem::size_of::<[f32; 2]>()),
        )
}

impl BounceGeometry {
    /// Marches every hemisphere ray of `bounces` bounces with `rays` rays a texel over the
    /// relief of `surface` (`None` without one), on at most `max_texels` texels a side.
    pub fn trace(
        surface: &dyn Surface,
        bounces: u32,
        rays: u32,
        max_texels: usize,
    ) -> Option<BounceGeometry> {
        let grid = surface.grid()?;
        let size_mm = surface.size_mm();
        let n = texels_per_side(grid, max_texels);
        let rays = rays.max(1);
        let tex = TexGrid::new(n, size_mm);
        let sites: Vec<TexelSite> = (0..n * n)
            .into_par_iter()
            .map(|k| {
                let (x, y) = tex.centre(k % n, k / n);
                let (p, nrm) = surface.point(x, y);
                let albedo = surface
                    .material_at(x, y)
                    .albedo
                    .clamp(Vec3A::ZERO, Vec3A::ONE);
                TexelSite { p, n: nrm, albedo }
            })
            .collect();
        let per_bounce = n * n * rays as usize;
        let mut landings = vec![NOWHERE; per_bounce * bounces as usize];
        for (bounce, of_bounce) in landings.chunks_mut(per_bounce.max(1)).enumerate() {
            of_bounce
                .par_chunks_mut(rays as usize)
                .zip(&sites)
                .enumerate()
                .for_each(|(k, (out, site))| {
                    land(grid, site, k as u64, bounce as u64, out);
                });
        }
        Some(BounceGeometry {
            n,
            size_mm,
            bounces,
            rays,
            sites,
            landings,
        })
    }

    /// Texels per side.
    pub fn texels_per_side(&self) -> usize {
        self.n
    }

    /// Width of the sample in mm.
    pub fn size_mm(&self) -> f32 {
        self.size_mm
    }

    /// Bounces traced.
    pub fn bounces(&self) -> u32 {
        self.bounces
    }

    /// Hemisphere rays a texel per bounce.
    pub fn rays(&self) -> u32 {
        self.rays
    }

    /// The texel sites, row by row.
    pub fn sites(&self) -> &[TexelSite] {
        &self.sites
    }

    /// Where texel `texel`'s rays of bounce `bounce` land, (x, y) or NaN (see [`Self::lands`]).
    pub fn landings(&self, bounce: u32, texel: usize) -> &[[f32; 2]] {
        let rays = self.rays as usize;
        let start = (bounce as usize * self.n * self.n + texel) * rays;
        &self.landings[start..start + rays]
    }

    /// Whether a landing is on the relief (rays that escape or meet a side are not).
    #[inline]
    pub fn lands(landing: &[f32; 2]) -> bool {
        !landing[0].is_nan()
    }
}

/// Unit direction for sample `r` of `n` about normal `nrm`: cosine-distributed (Malley),
/// Hammersley point shifted by the per-texel rotation (u, v).
#[inline]
pub(super) fn cosine_dir(nrm: Vec3A, r: u32, n: u32, u: f32, v: f32) -> Vec3A {
    let a = ((r as f32 + u) / n as f32).fract();
    let b = ((r.reverse_bits() as f32) * (1.0 / 4_294_967_296.0) + v).fract();
    let rad = a.sqrt();
    let phi = TAU * b;
    let (t, bt) = nrm.any_orthonormal_pair();
    let d = t * (rad * phi.cos()) + bt * (rad * phi.sin()) + nrm * (1.0 - a).max(0.0).sqrt();
    d.normalize_or(nrm)
}

/// The per-texel rotation of the Hammersley set for `texel` at `bounce`.
#[inline]
pub(super) fn rotation(texel: u64, bounce: u64) -> (f32, f32) {
    let h = hash3(BOUNCE_KEY, texel, bounce, 0);
    (unit_f32(h), unit_f32(h.rotate_left(24)))
}

/// Marches `out.len()` rays from `site` for `texel` at `bounce`, writing where each lands.
fn land(grid: &HeightGrid, site: &TexelSite, texel: u64, bounce: u64, out: &mut [[f32; 2]]) {
    let (u, v) = rotation(texel, bounce);
    let o = shadow_origin(site.p, site.n);
    let rays = out.len() as u32;
    for (r, landing) in out.iter_mut().enumerate() {
        let d = cosine_dir(site.n, r as u32, rays, u, v);
        *landing = match grid.first_hit(o, d, 0.0, f32::INFINITY) {
            Some(hit) if hit.wall.is_none() => {
                let q = o + d * hit.t;
                [q.x, q.y]
            }
            _ => NOWHERE,
        };
    }
}
