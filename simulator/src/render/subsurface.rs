//! Subsurface scattering under the sample: the diffusion (dipole) term of the diffuse BSSRDF
//! with the Jensen et al. (2001) profile R_d(r) (see [`crate::materials::dipole`]).
//!
//! Per frame: the irradiance *entering* the medium, E_in = Σ_lights E·F_t(η, cosθi)·meso_in, is
//! gathered on a texel grid over the sample (shadowed when the plan has shadows), convolved per
//! RGB channel with R_d by FFT, and looked up at shading time by interpolating its logarithm
//! (the falloff is convex: a bilinear lookup read it 1–2 % high between texels):
//!
//!   L_o = F_t(η, cosθo) / (π · c(η)) · (R_d ⊛ E_in)(x) · meso_out,
//!   c(η) = 2∫₀¹ F_t(μ; η) μ dμ (= 1 − external diffuse Fresnel reflectance),
//!
//! the Jensen 2001 exit lobe F_t/π normalised by c(η) so that it integrates against cosθo to
//! exactly 1: the surface emits all of R_d ⊛ E_in (the internal boundary reflection is already
//! in R_d through A). Single scattering is omitted (it is small for the high-albedo media the
//! dipole is valid for). The relief is treated as locally flat: entering flux is taken per
//! projected area (E/n_z) and exits per surface area (× n_z).
//!
//! Resolution: texels of 8/`dipole_samples` mean free paths ℓ = 1/max σ′t (at most
//! [`MAX_TEXELS`] per side); the kernel's texel weights are cell integrals of R_d with
//! sub-samples no further apart than ℓ/`dipole_samples` near the core, cut off at the radius
//! beyond which R_d holds less than [`TAIL`] of its energy, then scaled so their sum equals the
//! radial integral of R_d up to that radius (`dipole_samples` midpoint steps per ℓ): uniform
//! irradiance comes out as R_d,total · E within TAIL (tested).

use glam::Vec3A;
use rayon::prelude::*;

use super::fft::{C32, Fft};
use super::irradiance::DirectLight;
use super::material::{Material, Medium};
use super::surface::Surface;
use super::texgrid::TexGrid;
use crate::materials::{Dipole, fresnel_transmittance_f32, hemispherical_transmittance};

/// Fraction of R_d's energy the kernel may drop beyond its cut-off radius. At 10⁻³ the cut
/// took 3 % off the falloff 8 mm beside a laser line in a bright medium (α′ 0.99, the kernel
/// ending at 13 mm), which bent the dipole fit's σ′t (`tests/integration/dipole.rs`); at 10⁻⁴
/// the falloff is whole across the fit's 10 mm window.
pub const TAIL: f64 = 1.0e-4;
/// Most texels per side of the subsurface grid.
pub const MAX_TEXELS: usize = 512;
/// Most sub-samples per side of one kernel texel.
const MAX_SUBSAMPLES: usize = 32;
/// Steps of the c(η) integral.
const NORM_STEPS: usize = 2000;
/// Smallest n_z used for the projected-area factors (slopes steeper than ~78° are walls).
const MIN_NZ: f32 = 0.2;

/// The three per-channel dipoles of a medium.
pub fn dipoles(m: &Medium) -> [Dipole; 3] {
    let (a, s) = (m.sigma_a.to_array(), m.sigma_s_prime.to_array());
    std::array::from_fn(|c| Dipole::new(a[c] as f64, s[c] as f64, m.eta as f64))
}

/// Whether `m` scatters at all (σ′s > 0 in some channel).
pub fn scatters(m: &Medium) -> bool {
    m.sigma_s_prime.max_element() > 0.0 && m.sigma_s_prime.is_finite()
}

/// ∫₀^R 2πr R_d(r) dr by the midpoint rule with `per_mfp` steps per mean free path.
fn radial_integral(d: &Dipole, radius: f64, per_mfp: u32) -> f64 {
    let dr = 1.0 / (d.sigma_t_prime() * per_mfp.max(1) as f64);
    let steps = (radius / dr).ceil().max(1.0) as usize;
    let dr = radius / steps as f64;
    (0..steps)
        .map(|k| {
            let r = (k as f64 + 0.5) * dr;
            2.0 * std::f64::consts::PI * r * d.rd(r) * dr
        })
        .sum()
}

/// The radius (mm) beyond which R_d holds less than [`TAIL`] of its total, capped at
/// `max_mm`: found on the same radial midpoint grid (`per_mfp` steps per mean free path).
pub fn kernel_radius(d: &Dipole, per_mfp: u32, max_mm: f64) -> f64 {
    let total = d.total_diffuse_reflectance();
    if total <= 0.0 {
        return 0.0;
    }
    let dr = 1.0 / (d.sigma_t_prime() * per_mfp.max(1) as f64);
    let mut sum = 0.0;
    let mut r = 0.0;
    while r < max_mm {
        let mid = r + 0.5 * dr;
        sum += 2.0 * std::f64::consts::PI * mid * d.rd(mid) * dr;
        r += dr;
        if sum >= (1.0 - TAIL) * total {
            break;
        }
    }
    r.min(max_mm)
}

/// Texels per side and texel size (mm) of the subsurface grid for `media` on a sample
/// `size_mm` wide at `dipole_samples` radial samples per mean free path.
pub fn resolution(media: &[Medium], size_mm: f32, dipole_samples: u32) -> (usize, f32) {
    let st_max = media
        .iter()
        .flat_map(|m| dipoles(m).map(|d| d.sigma_t_prime()))
        .fold(0.0f64, f64::max);
    let mfp = if st_max > 0.0 { 1.0 / st_max } else { 1.0 } as f32;
    let want = mfp * 8.0 / dipole_samples.max(1) as f32;
    let n = ((size_mm / want.max(1.0e-3)).ceil() as usize).clamp(1, MAX_TEXELS);
    (n, size_mm / n as f32)
}

/// Largest kernel radius (mm) over the channels of `m`, capped at `max_mm`.
pub fn medium_radius(m: &Medium, dipole_samples: u32, max_mm: f64) -> f64 {
    dipoles(m)
        .iter()
        .map(|d| kernel_radius(d, dipole_samples, max_mm))
        .fold(0.0, f64::max)
}

/// One medium's exitance map and exit-lobe constants.
#[derive(Debug, Clone)]
struct MediumMap {
    exitance: TexGrid,
    eta: f32,
    /// 1/(π·c(η)).
    norm: f32,
}

/// What the pass cost, for the frame notes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SubsurfaceStats {
    /// Texels per side of the grid.
    pub texels: usize,
    /// FFT size per side.
    pub fft: usize,
    /// Media convolved.
    pub media: usize,
    /// Shadow rays marched for the entering irradiance.
    pub shadow_rays: u64,
}

/// The frame's subsurface exitance per medium, ready for shading.
#[derive(Debug, Clone)]
pub struct SubsurfaceMap {
    media: Vec<MediumMap>,
    /// What it cost.
    pub stats: SubsurfaceStats,
}

impl SubsurfaceMap {
    /// Radiance leaving the surface toward `wo` at `p` (normal `n`) from the medium under
    /// material `m`; zero for opaque materials. Finite and ≥ 0.
    #[inline]
    pub fn radiance(&self, m: &Material, p: Vec3A, n: Vec3A, wo: Vec3A) -> Vec3A {
        let Some(mm) = (m.medium as usize)
            .checked_sub(1)
            .and_then(|k| self.media.get(k))
        else {
            return Vec3A::ZERO;
        };
        let cos_o = n.dot(wo);
        if cos_o.is_nan() || cos_o <= 0.0 {
            return Vec3A::ZERO;
        }
        let ft = fresnel_transmittance_f32(cos_o, mm.eta);
        let scale = ft * mm.norm * m.meso_out.max(0.0) * n.z.clamp(MIN_NZ, 1.0);
        let v = mm.exitance.at_geometric(p.x, p.y) * scale;
        if v.is_finite() {
            v.max(Vec3A::ZERO)
        } else {
            Vec3A::ZERO
        }
    }

    /// The exitance R_d ⊛ E_in of medium `k` (0-based) at (x, y), for tests and tools.
    pub fn exitance(&self, k: usize, x: f32, y: f32) -> Vec3A {
        self.media
            .get(k)
            .map_or(Vec3A::ZERO, |m| m.exitance.at_geometric(x, y))
    }
}

/// Runs the pass for `surface` under `light`: `None` when no material references a medium.
pub fn compute(
    surface: &dyn Surface,
    light: &DirectLight,
    dipole_samples: u32,
) -> Option<SubsurfaceMap> {
    let media = surface.media();
    if media.is_empty() {
        return None;
    }
    let size = surface.size_mm();
    let (n, h) = resolution(media, size, dipole_samples);
    let grid = TexGrid::new(n, size);
    let var = h * h / 12.0;
    // Entering irradiance per texel, tagged with the texel's medium.
    let texels: Vec<(u8, Vec3A, u64)> = (0..n * n)
        .into_par_iter()
        .map(|k| {
            let (x, y) = grid.centre(k % n, k / n);
            let m = surface.material_at(x, y);
            let Some(medium) = (m.medium as usize)
                .checked_sub(1)
                .and_then(|i| media.get(i))
            else {
                return (0, Vec3A::ZERO, 0);
            };
            let (p, nrm) = surface.point(x, y);
            let mut rays = 0;
            let eta = medium.eta;
            let e = light.irradiance(
                p,
                nrm,
                var,
                |c| fresnel_transmittance_f32(c, eta),
                &mut rays,
            );
            let e = e * (m.meso_in.max(0.0) / nrm.z.max(MIN_NZ));
            (m.medium, e, rays)
        })
        .collect();
    let shadow_rays = texels.iter().map(|t| t.2).sum();
    let max_mm = size as f64;
    let mut fft_size = 1;
    let maps = media
        .iter()
        .enumerate()
        .map(|(k, medium)| {
            let mut e = TexGrid::new(n, size);
            for (v, t) in e.values_mut().iter_mut().zip(&texels) {
                if t.0 as usize == k + 1 {
                    *v = t.1;
                }
            }
            let radius = medium_radius(medium, dipole_samples, max_mm);
            let (exitance, nf) = convolve(&e, medium, radius, dipole_samples);
            fft_size = fft_size.max(nf);
            let c = hemispherical_transmittance(medium.eta as f64, NORM_STEPS);
            MediumMap {
                exitance,
                eta: medium.eta,
                norm: (1.0 / (std::f64::consts::PI * c)) as f32,
            }
        })
        .collect();
    Some(SubsurfaceMap {
        media: maps,
        stats: SubsurfaceStats {
            texels: n,
            fft: fft_size,
            media: media.len(),
            shadow_rays,
        },
    })
}

/// Per-channel kernel texel weights for a grid of side `h` mm out to `k` texels from the
/// centre: w[c][j·(k+1) + i] for offsets (i, j) ≥ 0, each the cell integral of R_d (unitless),
/// zero beyond `radius`, scaled to sum (over all four quadrants) to ∫₀^radius 2πr R_d dr.
fn kernel_quadrant(d: &[Dipole; 3], h: f32, k: usize, radius: f64, per_mfp: u32) -> [Vec<f64>; 3] {
    let h = h as f64;
    let w = k + 1;
    std::array::from_fn(|c| {
        let dip = &d[c];
        let mfp = 1.0 / dip.sigma_t_prime();
        let mut q: Vec<f64> = (0..w * w)
            .into_par_iter()
            .map(|idx| {
                let (i, j) = ((idx % w) as f64, (idx / w) as f64);
                let r = (i * h).hypot(j * h);
                if r > radius + 0.5 * h {
                    return 0.0;
                }
                let near = (r - h).max(mfp);
                let s = ((per_mfp as f64 * h / near).ceil() as usize).clamp(1, MAX_SUBSAMPLES);
                let step = h / s as f64;
                let mut sum = 0.0;
                for a in 0..s {
                    let x = i * h - 0.5 * h + (a as f64 + 0.5) * step;
                    for b in 0..s {
                        let y = j * h - 0.5 * h + (b as f64 + 0.5) * step;
                        sum += dip.rd(x.hypot(y));
                    }
                }
                sum * step * step
            })
            .collect();
        // Sum over the full kernel: offsets with i = 0 or j = 0 appear fewer times.
        let mut total = 0.0;
        for (idx, v) in q.iter().enumerate() {
            let mult = if idx % w == 0 { 1.0 } else { 2.0 } * if idx / w == 0 { 1.0 } else { 2.0 };
            total += mult * v;
        }
        let target = radial_integral(dip, radius, per_mfp);
        if total > 0.0 && target.is_finite() {
            let scale = target / total;
            q.iter_mut().for_each(|v| *v *= scale);
        }
        q
    })
}

/// Convolves the entering irradiance `e` with `medium`'s R_d per channel (kernel cut off at
/// `radius` mm), returning the exitance grid and the FFT size used. Linear, not circular:
/// the grid is zero-padded by the kernel radius (at most the grid itself).
pub fn convolve(e: &TexGrid, medium: &Medium, radius: f64, per_mfp: u32) -> (TexGrid, usize) {
    let n = e.n();
    let h = e.cell();
    let k = ((radius / h as f64).ceil() as usize).min(n);
    let fft = Fft::new(n + k + 1);
    let nf = fft.len();
    let d = dipoles(medium);
    let quad = kernel_quadrant(&d, h, k, radius, per_mfp);
    let w = k + 1;
    // Kernel images, real and even, wrapped around the origin; packed (r + i·g) and (b).
    let mut k_rg = vec![C32::default(); nf * nf];
    let mut k_b = vec![C32::default(); nf * nf];
    for j in 0..w {
        for i in 0..w {
            let idx = j * w + i;
            let (vr, vg, vb) = (
                quad[0][idx] as f32,
                quad[1][idx] as f32,
                quad[2][idx] as f32,
            );
            for (x, y) in [(i, j), (nf - i, j), (i, nf - j), (nf - i, nf - j)] {
                let (x, y) = (x % nf, y % nf);
                k_rg[y * nf + x] = C32::new(vr, vg);
                k_b[y * nf + x] = C32::new(vb, 0.0);
            }
        }
    }
    let mut e_rg = vec![C32::default(); nf * nf];
    let mut e_b = vec![C32::default(); nf * nf];
    for j in 0..n {
        for i in 0..n {
            let v = e.get(i, j);
            e_rg[j * nf + i] = C32::new(v.x, v.y);
            e_b[j * nf + i] = C32::new(v.z, 0.0);
        }
    }
    for buf in [&mut k_rg, &mut k_b, &mut e_rg, &mut e_b] {
        fft.run_2d(buf, false);
    }
    let neg = |idx: usize| {
        let (a, b) = (idx % nf, idx / nf);
        ((nf - b) % nf) * nf + (nf - a) % nf
    };
    let inv = 1.0 / (nf * nf) as f32;
    // W = A·Kr + i·B·Kg with A, B (and Kr, Kg) separated from the packed spectra.
    let w_rg: Vec<C32> = (0..nf * nf)
        .into_par_iter()
        .map(|idx| {
            let (z, zn) = (e_rg[idx], e_rg[neg(idx)].conj());
            let (kz, kzn) = (k_rg[idx], k_rg[neg(idx)].conj());
            // A = (z + zn)/2, B = (z − zn)/(2i); kernel spectra are real (even kernels).
            let a = C32::new(0.5 * (z.re + zn.re), 0.5 * (z.im + zn.im));
            let b = C32::new(0.5 * (z.im - zn.im), -0.5 * (z.re - zn.re));
            let kr = 0.5 * (kz.re + kzn.re);
            let kg = 0.5 * (kz.im - kzn.im);
            // A·kr + i·(B·kg)
            C32::new((a.re * kr - b.im * kg) * inv, (a.im * kr + b.re * kg) * inv)
        })
        .collect();
    let w_b: Vec<C32> = (0..nf * nf)
        .into_par_iter()
        .map(|idx| {
            let kb = k_b[idx].re;
            C32::new(e_b[idx].re * kb * inv, e_b[idx].im * kb * inv)
        })
        .collect();
    let (mut w_rg, mut w_b) = (w_rg, w_b);
    fft.run_2d(&mut w_rg, true);
    fft.run_2d(&mut w_b, true);
    let mut out = TexGrid::new(n, e.cell() * n as f32);
    let values = out.values_mut();
    for j in 0..n {
        for i in 0..n {
            let (rg, b) = (w_rg[j * nf + i], w_b[j * nf + i]);
            let v = Vec3A::new(rg.re, rg.im, b.re).max(Vec3A::ZERO);
            values[j * n + i] = if v.is_finite() { v } else { Vec3A::ZERO };
        }
    }
    (out, nf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::total_diffuse_reflectance;
    use crate::render::heightfield::HeightGrid;
    use crate::render::lights::{Emitter, Light};
    use crate::render::surface::Surface;
    use stagehand_devices::rig::LampKind;

    /// A skin-like validation medium (the felt scene's dipole medium).
    fn felt() -> Medium {
        Medium {
            sigma_a: Vec3A::new(0.5752, 0.8628, 0.0213),
            sigma_s_prime: Vec3A::new(0.4248, 0.6372, 2.1087),
            eta: 1.3,
        }
    }

    /// A test sample: optional relief, one medium under every point, and the entrance
    /// function zero where `masked(x, y)` (no light enters there).
    struct Slab {
        size: f32,
        grid: Option<HeightGrid>,
        media: Vec<Medium>,
        masked: fn(f32, f32) -> bool,
    }

    impl Surface for Slab {
        fn name(&self) -> &str {
            "slab"
        }
        fn size_mm(&self) -> f32 {
            self.size
        }
        fn grid(&self) -> Option<&HeightGrid> {
            self.grid.as_ref()
        }
        fn material_at(&self, x: f32, y: f32) -> Material {
            Material {
                medium: 1,
                meso_in: if (self.masked)(x, y) { 0.0 } else { 1.0 },
                ..Material::lambert(Vec3A::ZERO)
            }
        }
        fn media(&self) -> &[Medium] {
            &self.media
        }
    }

    fn overhead_lamp(z: f32) -> Light {
        Light {
            id: "lamp".into(),
            kind: LampKind::Halogen,
            output: 1.0,
            rgb: Vec3A::ONE,
            emitter: Emitter::Halogen {
                centre: Vec3A::new(0.0, 0.0, z),
                u: Vec3A::X,
                v: Vec3A::Y,
                intensity: z * z,
            },
        }
    }

    /// A line of light (unit power per mm along one texel column) spreads as R_d integrated
    /// along the line, the falloff the dipole fit reads beside a laser line: checked against a
    /// quadrature of R_d at 1 to 9 mm from the line, between texel centres, within 0.6 %
    /// (measured: 0.0–0.41 %; the bilinear lookup read 0.0–1.7 % high, the most at 1 mm, where
    /// its chord meets the falloff's curvature) where it is above 10⁻⁴ of its value at 1 mm
    /// (below, f32 rounding of the FFT shows).
    #[test]
    fn a_line_of_light_falls_off_as_the_line_integral_of_rd() {
        let medium = felt();
        let per_mfp = 32;
        let size = 60.0;
        let (n, h) = resolution(&[medium], size, per_mfp);
        let mut e = TexGrid::new(n, size);
        let column = n / 2;
        for (k, v) in e.values_mut().iter_mut().enumerate() {
            if k % n == column {
                *v = Vec3A::splat(1.0 / h);
            }
        }
        let radius = medium_radius(&medium, per_mfp, size as f64);
        let (m, _) = convolve(&e, &medium, radius, per_mfp);
        let x0 = -0.5 * size + (column as f32 + 0.5) * h;
        for (c, d) in dipoles(&medium).iter().enumerate() {
            let mut near = None;
            for x in [1.0f64, 1.5, 2.0, 3.1, 4.0, 6.0, 9.0] {
                // ∫ R_d(√(x² + y²)) dy by y = x·tan u.
                let steps = 4000;
                let du = std::f64::consts::FRAC_PI_2 / steps as f64;
                let want: f64 = (0..steps)
                    .map(|k| {
                        let u = (k as f64 + 0.5) * du;
                        2.0 * d.rd(x / u.cos()) * x / (u.cos() * u.cos()) * du
                    })
                    .sum();
                let got = f64::from(m.at_geometric(x0 + x as f32, 0.0).to_array()[c]);
                let near = *near.get_or_insert(want);
                if want > 1e-4 * near {
                    assert!(
                        (got / want - 1.0).abs() < 0.006,
                        "channel {c}, {x} mm from the line: {got} against {want}"
                    );
                }
            }
        }
    }

    /// Energy conservation: uniform entering irradiance comes out, far from the edges, as
    /// R_d,total·E per channel (the closed form of Jensen & Buhler 2002). Stated bound: within
    /// TAIL (the energy the cut-off drops) + 2e-3 (the radial midpoint rule the kernel is
    /// scaled to, 1.5e-3 at 8 steps per mean free path, and f32 FFT rounding) relative, at 8
    /// and 32 radial samples per mean free path.
    #[test]
    fn uniform_irradiance_gives_the_total_diffuse_reflectance() {
        for medium in [
            felt(),
            Medium {
                sigma_a: Vec3A::splat(0.01),
                sigma_s_prime: Vec3A::new(1.0, 2.0, 3.0),
                eta: 1.5,
            },
        ] {
            for per_mfp in [8, 32] {
                let size = 120.0;
                let (n, _) = resolution(&[medium], size, per_mfp);
                let mut e = TexGrid::new(n, size);
                e.values_mut().iter_mut().for_each(|v| *v = Vec3A::ONE);
                let radius = medium_radius(&medium, per_mfp, 40.0);
                let (m, _) = convolve(&e, &medium, radius, per_mfp);
                let got = m.at(0.0, 0.0).to_array();
                for (c, d) in dipoles(&medium).iter().enumerate() {
                    let want = total_diffuse_reflectance(d.reduced_albedo(), d.eta());
                    let err = (got[c] as f64 - want).abs() / want;
                    assert!(
                        err <= TAIL + 2e-3,
                        "{medium:?} {per_mfp} ch {c}: {} vs {want} ({err:.2e})",
                        got[c]
                    );
                }
            }
        }
    }

    /// The kernel's texel quadrature before its rescaling agrees with the radial integral:
    /// the rescale only corrects sub-texel quadrature error (stated: within 2%).
    #[test]
    fn kernel_quadrature_is_close_before_rescaling() {
        let d = dipoles(&felt());
        let h = 0.1f32;
        let radius = 20.0;
        let q = kernel_quadrant(&d, h, 200, radius, 8);
        for (c, dip) in d.iter().enumerate() {
            let w = 201;
            let mut total = 0.0;
            for (idx, v) in q[c].iter().enumerate() {
                let mult =
                    if idx % w == 0 { 1.0 } else { 2.0 } * if idx / w == 0 { 1.0 } else { 2.0 };
                total += mult * v;
            }
            let radial = radial_integral(dip, radius, 64);
            assert!(
                (total - radial).abs() <= 0.02 * radial,
                "{c}: {total} vs {radial}"
            );
        }
    }

    /// Translucency: light entering only at x < 0 (the entrance function is zero at x ≥ 0)
    /// still leaves the surface at x > 0, falling off with distance from the light edge —
    /// light bleeds past the sharp edge; and the lit side is dimmer near the edge than far
    /// from it (light diffuses away).
    #[test]
    fn light_bleeds_past_a_sharp_light_edge() {
        let slab = Slab {
            size: 40.0,
            grid: None,
            media: vec![felt()],
            masked: |x, _| x >= 0.0,
        };
        let lights = [overhead_lamp(800.0)];
        let light = DirectLight {
            lights: &lights,
            laser: None,
            grid: None,
            shadows: false,
            tube_points: 1,
        };
        let map = compute(&slab, &light, 16).expect("medium present");
        let at = |x: f32| map.exitance(0, x, 0.0).z;
        let (deep, edge, near, far) = (at(-10.0), at(-0.2), at(0.5), at(3.0));
        assert!(near > 0.05 * deep, "bleeds past the edge: {near} vs {deep}");
        assert!(far < near && far > 0.0, "{far} {near}");
        assert!(edge < deep && edge > near, "{deep} {edge} {near}");
        // Where no light enters and the kernel cannot reach, nothing leaves.
        assert!(at(18.0) < 1e-3 * deep);
        // Blue (α′ = 0.99) diffuses further than red (α′ = 0.42).
        let m = map.exitance(0, 1.0, 0.0);
        let d = map.exitance(0, -10.0, 0.0);
        assert!(m.z / d.z > m.x / d.x, "{m} {d}");
        assert_eq!(map.stats.media, 1);
        assert_eq!(map.stats.shadow_rays, 0);
    }

    /// A wall (a 10 mm step, raised at y > 0) shadows the low side from a grazing lamp: light
    /// entering on the lit side bleeds into the shadow, so the shadowed texels next to the lit
    /// region glow while direct light there is zero.
    #[test]
    fn light_bleeds_into_a_shadow() {
        let grid = HeightGrid::build(128, 32.0, |_, y| if y > 0.0 { 10.0 } else { 0.0 });
        let slab = Slab {
            size: 32.0,
            grid: Some(grid),
            media: vec![felt()],
            masked: |_, _| false,
        };
        // Lamp at +y, low: the wall shades y ∈ (−~10, 0).
        let lights = [Light {
            emitter: Emitter::Halogen {
                centre: Vec3A::new(0.0, 800.0, 800.0),
                u: Vec3A::X,
                v: Vec3A::Z,
                intensity: 1.28e6,
            },
            ..overhead_lamp(1.0)
        }];
        let make = |shadows| DirectLight {
            lights: &lights,
            laser: None,
            grid: slab.grid.as_ref(),
            shadows,
            tube_points: 1,
        };
        let map = compute(&slab, &make(true), 16).expect("medium");
        assert!(map.stats.shadow_rays > 0);
        let mut rays = 0;
        let (p, n) = slab.point(0.0, -13.0);
        assert!(
            make(true)
                .irradiance(p, n, 0.0, |_| 1.0, &mut rays)
                .max_element()
                > 0.0
        );
        let (p, n) = slab.point(0.0, -3.0);
        assert_eq!(
            make(true).irradiance(p, n, 0.0, |_| 1.0, &mut rays),
            Vec3A::ZERO
        );
        // In the shadow, 1 mm from its lit edge (y ≈ −10), light still comes out.
        let lit = map.exitance(0, 0.0, -14.0).z;
        let shadowed = map.exitance(0, 0.0, -9.0).z;
        assert!(shadowed > 0.02 * lit && lit > 0.0, "{shadowed} vs {lit}");
    }

    #[test]
    fn radiance_is_finite_and_zero_for_opaque_points() {
        let slab = Slab {
            size: 10.0,
            grid: None,
            media: vec![felt()],
            masked: |_, _| false,
        };
        let lights = [overhead_lamp(800.0)];
        let light = DirectLight {
            lights: &lights,
            laser: None,
            grid: None,
            shadows: false,
            tube_points: 1,
        };
        let map = compute(&slab, &light, 8).expect("medium");
        let m = slab.material_at(0.0, 0.0);
        for wo in [
            Vec3A::Z,
            Vec3A::new(1.0, 0.0, 1e-6).normalize(),
            -Vec3A::Z,
            Vec3A::NAN,
        ] {
            let l = map.radiance(&m, Vec3A::ZERO, Vec3A::Z, wo);
            assert!(l.is_finite() && l.min_element() >= 0.0, "{wo}: {l}");
        }
        assert!(
            map.radiance(&m, Vec3A::ZERO, Vec3A::Z, Vec3A::Z)
                .max_element()
                > 0.0
        );
        let opaque = Material::grey(0.5);
        assert_eq!(
            map.radiance(&opaque, Vec3A::ZERO, Vec3A::Z, Vec3A::Z),
            Vec3A::ZERO
        );
        // No media, no pass.
        let none = Slab {
            media: vec![],
            ..slab
        };
        assert!(compute(&none, &light, 8).is_none());
    }

    /// The exit lobe F_t(θo)/(π c(η)) integrates against cosθo to 1 (the normalisation):
    /// midpoint rule over θo, stated bound 1e-3.
    #[test]
    fn exit_lobe_is_normalised() {
        let eta = 1.3f32;
        let c = hemispherical_transmittance(eta as f64, NORM_STEPS);
        let norm = 1.0 / (std::f64::consts::PI * c);
        let steps = 4000;
        let dt = std::f64::consts::FRAC_PI_2 / steps as f64;
        let total: f64 = (0..steps)
            .map(|k| {
                let t = (k as f64 + 0.5) * dt;
                let ft = fresnel_transmittance_f32(t.cos() as f32, eta) as f64;
                2.0 * std::f64::consts::PI * ft * norm * t.cos() * t.sin() * dt
            })
            .sum();
        assert!((total - 1.0).abs() < 1e-3, "{total}");
    }
}
