//! Interreflection between the relief's texels: a radiosity-style gather on a coarse texel
//! grid over the sample. Bounce 0 is the direct irradiance E₀ (lamps and laser, shadowed as
//! the plan says); each bounce k gathers E_k(x) = π/N Σ L_{k−1}(hit) over N cosine-distributed
//! hemisphere rays marched through the height field, with L_{k−1} = ρd·E_{k−1}/π the previous
//! bounce's outgoing diffuse radiance (bilinear at the hit; rays that escape or hit the
//! sample's side see nothing). Shading adds ρd/π · Σ_k E_k. Only the Lambert part bounces
//! (specular, subsurface and the dark turntable do not).
//!
//! Deterministic: the ray directions are a rotated Hammersley set per texel from the
//! counter-based hash, so any thread count gives bit-identical maps.

use std::f32::consts::{PI, TAU};

use glam::Vec3A;
use rayon::prelude::*;

use super::bounce_geometry::{BounceGeometry, cosine_dir, rotation};
use super::heightfield::HeightGrid;
use super::irradiance::DirectLight;
use super::shadow::shadow_origin;
use super::surface::Surface;
use super::texgrid::{LitTexels, TexGrid};

/// Most texels per side of the bounce grid.
pub const MAX_TEXELS: usize = 256;
/// Texels per side of the sky-view scan.
pub const SKY_TEXELS: usize = 64;
/// Azimuths of the sky-view horizon scan.
pub const SKY_AZIMUTHS: usize = 16;
/// Most texels per side of the effect plan's light probe.
pub const PROBE_TEXELS: usize = 32;
/// Most hemisphere rays per texel of the light probe.
pub const PROBE_RAYS: u32 = 16;

/// What the pass cost and what each bounce added, for the frame notes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BounceStats {
    /// Texels per side of the grid.
    pub texels: usize,
    /// Bounces simulated.
    pub bounces: u32,
    /// Hemisphere rays marched (all bounces).
    pub rays: u64,
    /// Shadow rays marched for the direct irradiance.
    pub shadow_rays: u64,
    /// Per bounce, the mean added irradiance (RGB mean) over the texels, relative to the mean
    /// direct irradiance.
    pub added: Vec<f32>,
}

/// The frame's indirect diffuse irradiance over the relief.
#[derive(Debug, Clone)]
pub struct BounceMap {
    indirect: TexGrid,
    /// Where `indirect` holds light.
    lit: LitTexels,
    /// What it cost.
    pub stats: BounceStats,
}

impl BounceMap {
    /// True when [`Self::irradiance_at`] is exactly zero over [x0, x1] × [y0, y1] mm.
    pub fn dark_over(&self, x: (f32, f32), y: (f32, f32)) -> bool {
        self.lit.dark_over(x, y)
    }

    /// Indirect irradiance (all simulated bounces) at (x, y), per channel.
    #[inline]
    pub fn irradiance_at(&self, x: f32, y: f32) -> Vec3A {
        self.indirect.at(x, y)
    }
}

/// Texels per side of the bounce grid: as fine as the relief, at most 128 per pixel-sample
/// side (`spp_side`) and at most [`MAX_TEXELS`] — 128² for preview, 256² above.
pub fn texels(cells: usize, spp_side: u32) -> usize {
    cells.clamp(1, MAX_TEXELS.min(128 * spp_side.max(1) as usize))
}

/// Runs `bounces` bounces with `rays` rays per texel per bounce over `surface` (which must
/// have a relief; `None` otherwise) on a grid of at most `max_texels` per side: the geometry
/// traced now (see [`compute_with`] for a kept one).
pub fn compute(
    surface: &dyn Surface,
    light: &DirectLight,
    bounces: u32,
    rays: u32,
    max_texels: usize,
) -> Option<BounceMap> {
    let geometry = BounceGeometry::trace(surface, bounces, rays, max_texels)?;
    Some(compute_with(&geometry, light))
}

/// The bounce pass under `light` over a relief whose rays' landings `geometry` holds: the
/// direct irradiance at each texel, then each bounce gathered from the previous bounce's
/// radiance where the texel's rays land.
pub fn compute_with(geometry: &BounceGeometry, light: &DirectLight) -> BounceMap {
    let (n, size) = (geometry.texels_per_side(), geometry.size_mm());
    let mut map = TexGrid::new(n, size);
    let var = map.cell() * map.cell() / 12.0;
    let sites = geometry.sites();
    let direct: Vec<(Vec3A, u64)> = sites
        .par_iter()
        .map(|site| {
            let mut r = 0;
            let e = light.irradiance(site.p, site.n, var, |_| 1.0, &mut r);
            (e, r)
        })
        .collect();
    let shadow_rays = direct.iter().map(|t| t.1).sum();
    let direct_mean = direct.iter().map(|t| t.0.element_sum()).sum::<f32>() / (3 * n * n) as f32;
    // Outgoing radiance of the previous bounce, and the indirect total.
    let mut radiance = TexGrid::new(n, size);
    for ((v, site), (e, _)) in radiance.values_mut().iter_mut().zip(sites).zip(&direct) {
        *v = site.albedo * *e * (1.0 / PI);
    }
    let rays = geometry.rays();
    let bounces = geometry.bounces();
    let mut added = Vec::new();
    for bounce in 0..bounces {
        let prev = &radiance;
        let gathered: Vec<Vec3A> = (0..sites.len())
            .into_par_iter()
            .map(|k| {
                let sum = geometry
                    .landings(bounce, k)
                    .iter()
                    .filter(|q| BounceGeometry::lands(q))
                    .fold(Vec3A::ZERO, |sum, q| sum + prev.at(q[0], q[1]));
                irradiance_of(sum, rays)
            })
            .collect();
        let mut next = TexGrid::new(n, size);
        for ((out, e), site) in next.values_mut().iter_mut().zip(&gathered).zip(sites) {
            *out = site.albedo * *e * (1.0 / PI);
        }
        for (acc, e) in map.values_mut().iter_mut().zip(&gathered) {
            *acc += *e;
        }
        let mean = gathered.iter().map(|e| e.element_sum()).sum::<f32>() / (3 * n * n) as f32;
        added.push(if direct_mean > 0.0 {
            mean / direct_mean
        } else {
            0.0
        });
        radiance = next;
    }
    BounceMap {
        lit: map.lit_texels(),
        indirect: map,
        stats: BounceStats {
            texels: n,
            bounces,
            rays: (n * n) as u64 * rays as u64 * bounces as u64,
            shadow_rays,
            added,
        },
    }
}

/// Irradiance from the `sum` of the radiance `rays` cosine-distributed rays saw (π/N Σ L),
/// zero where not finite.
#[inline]
fn irradiance_of(sum: Vec3A, rays: u32) -> Vec3A {
    let e = sum * (PI / rays as f32);
    if e.is_finite() {
        e.max(Vec3A::ZERO)
    } else {
        Vec3A::ZERO
    }
}

/// The effect plan's light probe: the first bounce under the frame's actual light on a coarse
/// grid (at most [`PROBE_TEXELS`] per side and [`PROBE_RAYS`] rays, never finer than the pass
/// it decides on, given by `texels` and `rays`), with the direct light evaluated exactly where
/// each ray lands (a coarse texel grid would smear lit tops down unlit walls). Returns the
/// largest added irradiance at any probe texel (any channel) relative to the mean direct
/// irradiance over them; `None` without a relief.
pub fn probe(surface: &dyn Surface, light: &DirectLight, texels: usize, rays: u32) -> Option<f32> {
    let grid = surface.grid()?;
    let n = grid
        .cells()
        .clamp(1, PROBE_TEXELS.min(texels.div_ceil(2)).max(1));
    let tex = TexGrid::new(n, surface.size_mm());
    let rays = rays.clamp(1, PROBE_RAYS);
    let radiance = |q: Vec3A| {
        let (p, nrm) = surface.point(q.x, q.y);
        let albedo = surface
            .material_at(q.x, q.y)
            .albedo
            .clamp(Vec3A::ZERO, Vec3A::ONE);
        albedo * light.irradiance(p, nrm, 0.0, |_| 1.0, &mut 0) * (1.0 / PI)
    };
    let (direct, peak) = (0..n * n)
        .into_par_iter()
        .map(|k| {
            let (x, y) = tex.centre(k % n, k / n);
            let (p, nrm) = surface.point(x, y);
            let direct = light.irradiance(p, nrm, 0.0, |_| 1.0, &mut 0).element_sum() / 3.0;
            let e = gather(grid, p, nrm, k as u64, u64::MAX, rays, &radiance);
            (direct, e.max_element())
        })
        .map(|(d, e)| {
            if d.is_finite() && e.is_finite() {
                (d, e)
            } else {
                (0.0, 0.0)
            }
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1.max(b.1)));
    let mean = direct / (n * n) as f32;
    Some(if mean > 0.0 { peak / mean } else { 0.0 })
}

/// Irradiance at `p` (normal `nrm`) from the `radiance` of the relief points it sees, by
/// `rays` cosine-distributed rays (rotated per `texel` and `bounce`).
fn gather(
    grid: &HeightGrid,
    p: Vec3A,
    nrm: Vec3A,
    texel: u64,
    bounce: u64,
    rays: u32,
    radiance: &dyn Fn(Vec3A) -> Vec3A,
) -> Vec3A {
    let (u, v) = rotation(texel, bounce);
    let o = shadow_origin(p, nrm);
    let mut sum = Vec3A::ZERO;
    for r in 0..rays {
        let d = cosine_dir(nrm, r, rays, u, v);
        if let Some(hit) = grid.first_hit(o, d, 0.0, f32::INFINITY)
            && hit.wall.is_none()
        {
            sum += radiance(o + d * hit.t);
        }
    }
    irradiance_of(sum, rays)
}

/// What the plan needs of a relief for interreflection: its smallest sky-view fraction and
/// largest diffuse albedo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReliefStats {
    /// Smallest cosine-weighted sky-view fraction over the relief (1 = sees the whole sky).
    pub v_min: f32,
    /// Largest diffuse albedo (any channel).
    pub rho_max: f32,
}

impl ReliefStats {
    /// Whether some point of the relief sees a noticeable part of the relief itself
    /// (V < 0.99; the bilinear patches of a convex shape have crease-sized concavities).
    pub fn concave(&self) -> bool {
        self.v_min < 0.99
    }
}

/// The relief's sky-view and albedo bounds: horizon scanning [`SKY_AZIMUTHS`] azimuths from
/// the centre of each of [`SKY_TEXELS`]² texels (capped at the relief's cells). Per azimuth
/// the horizon elevation θh above the horizontal blocks a cosine-weighted fraction sin²θh of
/// the sky, so V = 1 − mean sin²θh (the terrain sky-view factor about +z). `None` for a
/// flat sample.
pub fn relief_stats(surface: &dyn Surface) -> Option<ReliefStats> {
    let grid = surface.grid()?;
    let size = surface.size_mm();
    let n = grid.cells().clamp(1, SKY_TEXELS);
    let tex = TexGrid::new(n, size);
    let step = tex.cell() * 0.5;
    let half = 0.5 * size;
    let zmax = grid.zmax();
    let (v_min, rho_max) = (0..n * n)
        .into_par_iter()
        .map(|k| {
            let (x, y) = tex.centre(k % n, k / n);
            let z = grid.height_at(x, y);
            let mut blocked = 0.0;
            for a in 0..SKY_AZIMUTHS {
                let phi = TAU * a as f32 / SKY_AZIMUTHS as f32;
                let (dx, dy) = (phi.cos(), phi.sin());
                let mut tan_max = 0.0f32;
                let mut dist = step;
                loop {
                    let (qx, qy) = (x + dx * dist, y + dy * dist);
                    if qx.abs() > half || qy.abs() > half || (zmax - z) <= tan_max * dist {
                        break;
                    }
                    tan_max = tan_max.max((grid.height_at(qx, qy) - z) / dist);
                    dist += step;
                }
                blocked += tan_max * tan_max / (1.0 + tan_max * tan_max);
            }
            let v = 1.0 - blocked / SKY_AZIMUTHS as f32;
            let rho = surface
                .material_at(x, y)
                .albedo
                .max_element()
                .clamp(0.0, 1.0);
            (v, rho)
        })
        .reduce(|| (1.0f32, 0.0f32), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    Some(ReliefStats { v_min, rho_max })
}

/// The per-bounce bound factor ρmax·(1 − Vmin) (bounce k's contribution relative to direct
/// light is at most its k-th power) and how many bounces have a bound above `tolerance`:
/// uncapped (at most 64), and capped at `max_bounces` (what the renderer simulates).
pub fn bounces_needed(stats: &ReliefStats, tolerance: f32, max_bounces: u32) -> (f32, u32, u32) {
    let per = (stats.rho_max * (1.0 - stats.v_min)).clamp(0.0, 1.0);
    let mut k = 0u32;
    let mut bound = per;
    while k < 64 && bound > tolerance {
        k += 1;
        bound *= per;
    }
    (per, k, k.min(max_bounces))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::lights::{Emitter, Light};
    use crate::render::material::{Material, Medium};
    use stagehand_devices::rig::LampKind;

    /// White (ρ = 0.8) relief given by `height`.
    struct Relief {
        size: f32,
        grid: HeightGrid,
        albedo: f32,
    }

    impl Surface for Relief {
        fn name(&self) -> &str {
            "relief"
        }
        fn size_mm(&self) -> f32 {
            self.size
        }
        fn grid(&self) -> Option<&HeightGrid> {
            Some(&self.grid)
        }
        fn material_at(&self, _: f32, _: f32) -> Material {
            Material::grey(self.albedo)
        }
        fn media(&self) -> &[Medium] {
            &[]
        }
    }

    /// V-grooves along y: 10 mm pitch, 8 mm deep (the `cavity` scene).
    fn grooves(albedo: f32) -> Relief {
        let grid = HeightGrid::build(128, 40.0, |x, _| {
            let u = (x / 10.0 + 100.0).fract();
            8.0 * (2.0 * (u - 0.5)).abs()
        });
        Relief {
            size: 40.0,
            grid,
            albedo,
        }
    }

    fn overhead() -> [Light; 1] {
        [Light {
            id: "lamp".into(),
            kind: LampKind::Halogen,
            output: 1.0,
            rgb: Vec3A::ONE,
            emitter: Emitter::Halogen {
                centre: Vec3A::new(0.0, 0.0, 800.0),
                u: Vec3A::X,
                v: Vec3A::Y,
                intensity: 640_000.0,
            },
        }]
    }

    fn direct<'a>(lights: &'a [Light], grid: &'a HeightGrid) -> DirectLight<'a> {
        DirectLight {
            lights,
            laser: None,
            grid: Some(grid),
            shadows: true,
            tube_points: 1,
        }
    }

    /// Interreflection brightens the groove's bottom (which sees both walls) more than its
    /// ridge (which sees mostly sky); bounce 2 adds less than bounce 1, and the indirect light
    /// grows with bounces but converges.
    #[test]
    fn grooves_bottoms_brighten_and_bounces_converge() {
        let relief = grooves(0.8);
        let lights = overhead();
        let light = direct(&lights, &relief.grid);
        let one = compute(&relief, &light, 1, 64, 256).expect("relief");
        let three = compute(&relief, &light, 3, 64, 256).expect("relief");
        // Bottom of the groove at x = 5 (u = 0.5), ridge at x = 0.
        let bottom = one.irradiance_at(5.0, 0.0).x;
        let ridge = one.irradiance_at(0.0, 0.0).x;
        assert!(
            bottom > 0.1 && bottom > 4.0 * ridge,
            "bottom {bottom} ridge {ridge}"
        );
        let a = &three.stats.added;
        assert_eq!(a.len(), 3);
        assert!(a[0] > 0.0 && a[1] < a[0] && a[2] < a[1], "{a:?}");
        assert!(three.irradiance_at(5.0, 0.0).x > bottom);
        assert_eq!(one.stats.rays, 128 * 128 * 64);
        assert!(one.stats.shadow_rays > 0);
    }

    /// A bounce pass marching its rays now (the pass before its geometry was kept): bounce
    /// k gathers, by marching, the previous bounce's radiance.
    fn marched(relief: &Relief, light: &DirectLight, bounces: u32, rays: u32) -> TexGrid {
        let n = relief.grid.cells();
        let mut total = TexGrid::new(n, relief.size);
        let var = total.cell() * total.cell() / 12.0;
        let sites: Vec<(Vec3A, Vec3A, Vec3A)> = (0..n * n)
            .map(|k| {
                let (x, y) = total.centre(k % n, k / n);
                let (p, nrm) = relief.point(x, y);
                (p, nrm, light.irradiance(p, nrm, var, |_| 1.0, &mut 0))
            })
            .collect();
        let albedo = Vec3A::splat(relief.albedo);
        let mut radiance = TexGrid::new(n, relief.size);
        for (v, (_, _, e)) in radiance.values_mut().iter_mut().zip(&sites) {
            *v = albedo * *e * (1.0 / PI);
        }
        for bounce in 0..bounces {
            let prev = radiance.clone();
            for (k, (p, nrm, _)) in sites.iter().enumerate() {
                let at = |q: Vec3A| prev.at(q.x, q.y);
                let e = gather(&relief.grid, *p, *nrm, k as u64, bounce as u64, rays, &at);
                total.values_mut()[k] += e;
                radiance.values_mut()[k] = albedo * e * (1.0 / PI);
            }
        }
        total
    }

    /// With the geometry traced once and kept, the pass under a lamp and under the laser is
    /// the marched pass, bit for bit.
    #[test]
    fn a_kept_geometry_gives_the_marched_pass_bit_for_bit() {
        let relief = grooves(0.8);
        let geometry = BounceGeometry::trace(&relief, 2, 8, 256).expect("relief");
        let lamp = overhead();
        let side = [Light {
            emitter: Emitter::Halogen {
                centre: Vec3A::new(600.0, -200.0, 300.0),
                u: Vec3A::X,
                v: Vec3A::Y,
                intensity: 640_000.0,
            },
            ..lamp[0].clone()
        }];
        for lights in [&lamp[..], &side[..]] {
            let light = direct(lights, &relief.grid);
            let kept = compute_with(&geometry, &light);
            assert_eq!(kept.indirect, marched(&relief, &light, 2, 8));
            assert!(kept.irradiance_at(5.0, 0.0).x > 0.0);
        }
    }

    /// Same map at 1 and 4 threads, bit for bit.
    #[test]
    fn bit_identical_at_any_thread_count() {
        let relief = grooves(0.8);
        let lights = overhead();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| {
                    compute(&relief, &direct(&lights, &relief.grid), 2, 8, 256).expect("relief")
                })
        };
        let (a, b) = (run(1), run(4));
        assert_eq!(a.indirect, b.indirect);
        assert_eq!(a.stats, b.stats);
    }

    #[test]
    fn sky_view_of_grooves_bumps_and_a_dome() {
        let g = relief_stats(&grooves(0.8)).expect("relief");
        assert!(g.concave() && g.v_min < 0.7, "{g:?}");
        assert!((g.rho_max - 0.8).abs() < 1e-6);
        let (per, needed, simulated) = bounces_needed(&g, 0.02, 1);
        assert!(per > 0.2 && needed >= 2 && simulated == 1, "{per} {needed}");
        assert_eq!(bounces_needed(&g, 0.99, 4).1, 0);
        // A single dome is convex: every texel sees the whole sky.
        let dome = Relief {
            size: 40.0,
            grid: HeightGrid::build(64, 40.0, |x, y| {
                (100.0 - 0.05 * (x * x + y * y)).max(0.0) * 0.05
            }),
            albedo: 0.5,
        };
        let d = relief_stats(&dome).expect("relief");
        assert!(!d.concave(), "{d:?}");
    }
}
