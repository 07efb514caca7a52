//! Direct irradiance at a point of the sample from every lit lamp and the laser sheet, with
//! hard shadows by marching the relief when asked: the light the per-frame transport passes
//! (subsurface, interreflection) start from. Lamps are point-sampled (halogen at its centre,
//! the tube at a few stratum midpoints): the passes blur their input over many texels anyway.

use glam::Vec3A;

use super::heightfield::HeightGrid;
use super::laser::LaserSheet;
use super::lights::{Emitter, Light};
use super::shadow::shadow_origin;

/// Most points along the tube per irradiance evaluation.
pub const MAX_TUBE_POINTS: u32 = 16;

/// The lit sources of one frame, fixed for the frame.
#[derive(Debug, Clone, Copy)]
pub struct DirectLight<'a> {
    /// Lit lamps (the backlight contributes nothing here: it lights the sample's back).
    pub lights: &'a [Light],
    /// The laser sheet, if on.
    pub laser: Option<&'a LaserSheet>,
    /// Relief to shadow with; `None` or `shadows == false` for no shadow rays.
    pub grid: Option<&'a HeightGrid>,
    /// Whether to march shadow rays (the effect plan's decision).
    pub shadows: bool,
    /// Points along the tube.
    pub tube_points: u32,
}

impl DirectLight<'_> {
    /// Irradiance per RGB channel at `p` with unit normal `n`, each source's contribution
    /// weighted by `transmit(cosθi)` (e.g. Fresnel transmittance; `|_| 1.0` for plain
    /// irradiance). `footprint_var_mm2` widens the laser profile to the texel (see
    /// [`LaserSheet::irradiance`]). Counts marched shadow rays in `rays`. Finite, ≥ 0.
    pub fn irradiance(
        &self,
        p: Vec3A,
        n: Vec3A,
        footprint_var_mm2: f32,
        transmit: impl Fn(f32) -> f32,
        rays: &mut u64,
    ) -> Vec3A {
        let mut total = Vec3A::ZERO;
        for light in self.lights {
            match light.emitter {
                Emitter::Halogen {
                    centre, intensity, ..
                } => {
                    total += light.rgb * self.point(p, n, centre, intensity, &transmit, rays);
                }
                Emitter::Tube {
                    start,
                    axis,
                    length,
                    per_mm,
                } => {
                    let m = self.tube_points.clamp(1, MAX_TUBE_POINTS);
                    let part = length / m as f32;
                    let mut sum = 0.0;
                    for k in 0..m {
                        let q = start + axis * (part * (k as f32 + 0.5));
                        let to_p = p - q;
                        let emit = (-to_p.z / to_p.length().max(1.0e-6)).max(0.0);
                        sum += self.point(p, n, q, per_mm * part * emit, &transmit, rays);
                    }
                    total += light.rgb * sum;
                }
                Emitter::Backlight { .. } => {}
            }
        }
        if let Some(sheet) = self.laser {
            let (e, wi, r) = sheet.irradiance(p, footprint_var_mm2);
            let cos_i = n.dot(wi);
            if e.is_finite() && e > 0.0 && cos_i.is_finite() && cos_i > 0.0 {
                let v = self.visible(p, n, wi, r, rays);
                total += sheet.camera_rgb * (v * e * cos_i * transmit(cos_i));
            }
        }
        if total.is_finite() {
            total.max(Vec3A::ZERO)
        } else {
            Vec3A::ZERO
        }
    }

    /// Irradiance from a point source of `intensity` at `q`, weighted and shadowed.
    #[inline]
    fn point(
        &self,
        p: Vec3A,
        n: Vec3A,
        q: Vec3A,
        intensity: f32,
        transmit: &impl Fn(f32) -> f32,
        rays: &mut u64,
    ) -> f32 {
        let v = q - p;
        let r2 = v.length_squared();
        if !(r2.is_finite() && r2 > 1.0e-6) || intensity <= 0.0 {
            return 0.0;
        }
        let r = r2.sqrt();
        let wi = v / r;
        let cos_i = n.dot(wi);
        if cos_i.is_nan() || cos_i <= 0.0 {
            return 0.0;
        }
        self.visible(p, n, wi, r, rays) * intensity * cos_i / r2 * transmit(cos_i)
    }

    /// 1 if the light `dist` mm away along `wi` reaches `p`, else 0 (always 1 without shadows).
    #[inline]
    fn visible(&self, p: Vec3A, n: Vec3A, wi: Vec3A, dist: f32, rays: &mut u64) -> f32 {
        match self.grid {
            Some(grid) if self.shadows => {
                *rays += 1;
                if grid.occluded(shadow_origin(p, n), wi, 0.0, dist) {
                    0.0
                } else {
                    1.0
                }
            }
            _ => 1.0,
        }
    }
}
