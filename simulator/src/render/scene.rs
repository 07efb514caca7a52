//! What a camera ray hits (sample relief, turntable, the tube) and the light it carries back:
//! direct lighting from every lit source, with shadow rays only when the plan calls for them.

use glam::Vec3A;

use super::geometry::CameraPose;
use super::laser::LaserSheet;
use super::lights::{Emitter, HALOGEN_RADIUS_MM, Light, TURNTABLE_RADIUS_MM, TubeBody};
use super::quality::Quality;
use super::rng::{hash3, unit_f32};
use super::sample::{Material, Sample};
use super::shading::brdf;
use super::shadow::LitMask;

/// The dark grey turntable around the sample.
const TURNTABLE: Material = Material::grey(0.05);
/// Shadow-ray origins are pushed this far off the surface along the normal.
const SHADOW_OFFSET_MM: f32 = 0.02;
/// Key for sub-pixel and light-sample jitter: fixed, so only the sensor noise depends on the
/// caller's seed.
const JITTER_KEY: u64 = 0x5a3e_11c0_77aa_0001;

/// A surface point seen by a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Position in the sample frame.
    pub p: Vec3A,
    /// Shading normal.
    pub n: Vec3A,
    /// Reflectance there.
    pub material: Material,
}

/// The rays through the neighbouring sub-pixel samples, for filtering sub-pixel detail.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Camera centre.
    pub origin: Vec3A,
    /// Unit ray one sample step to the right.
    pub dx: Vec3A,
    /// Unit ray one sample step down.
    pub dy: Vec3A,
    /// Angle subtended by one sample step, radians.
    pub angle: f32,
}

/// Everything needed to shade one frame, fixed for the frame.
#[derive(Debug)]
pub struct Scene<'a> {
    sample: &'a Sample,
    lights: Vec<Light>,
    laser: Option<LaserSheet>,
    tubes: Vec<TubeBody>,
    shadows: bool,
    specular: bool,
    quality: Quality,
    /// Per light, per light stratum: blocks surely lit (empty unless shadows are on).
    masks: Vec<Vec<LitMask>>,
    laser_mask: Option<LitMask>,
}

/// Settings that decide how a frame is shaded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shading {
    /// Cast shadow rays (the effect plan's decision).
    pub shadows: bool,
    /// Evaluate the Ward lobe.
    pub specular: bool,
    /// Sampling preset.
    pub quality: Quality,
}

impl<'a> Scene<'a> {
    /// A scene; with shadows on, precomputes which sample blocks each light region surely
    /// lights so their points skip the march.
    pub fn new(
        sample: &'a Sample,
        lights: Vec<Light>,
        laser: Option<LaserSheet>,
        tubes: Vec<TubeBody>,
        shading: Shading,
    ) -> Scene<'a> {
        let Shading {
            shadows,
            specular,
            quality,
        } = shading;
        let grid = sample.grid.as_ref().filter(|_| shadows);
        let masks = lights
            .iter()
            .map(|light| match (grid, light.emitter) {
                (Some(g), Emitter::Halogen { centre, .. }) => {
                    let radius = if quality.halogen_samples() > 1 {
                        HALOGEN_RADIUS_MM
                    } else {
                        0.0
                    };
                    vec![LitMask::new(g, centre, radius)]
                }
                (
                    Some(g),
                    Emitter::Tube {
                        start,
                        axis,
                        length,
                        ..
                    },
                ) => {
                    let n = quality.tube_samples();
                    let stratum = length / n as f32;
                    (0..n)
                        .map(|k| {
                            LitMask::new(
                                g,
                                start + axis * (stratum * (k as f32 + 0.5)),
                                0.5 * stratum,
                            )
                        })
                        .collect()
                }
                _ => Vec::new(),
            })
            .collect();
        let laser_mask = match (grid, &laser) {
            (Some(g), Some(sheet)) => Some(LitMask::new(g, sheet.origin, 0.0)),
            _ => None,
        };
        Scene {
            sample,
            lights,
            laser,
            tubes,
            shadows,
            specular,
            quality,
            masks,
            laser_mask,
        }
    }

    /// The lit lamps.
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    /// Whether anything emits light this frame.
    pub fn has_light(&self) -> bool {
        !self.lights.is_empty() || self.laser.is_some()
    }

    /// Surely-lit blocks summed over every light region (for the notes).
    pub fn lit_blocks(&self) -> usize {
        self.masks
            .iter()
            .flatten()
            .chain(self.laser_mask.iter())
            .map(LitMask::lit_blocks)
            .sum()
    }

    /// The first surface along the unit ray o + t·d, or `None` for black (void, or the tube).
    pub fn intersect(&self, o: Vec3A, d: Vec3A) -> Option<Hit> {
        let mut hit = None;
        if let Some(grid) = &self.sample.grid {
            if let Some(h) = grid.first_hit(o, d, 0.0, f32::INFINITY) {
                let p = o + d * h.t;
                let n = h.wall.unwrap_or_else(|| grid.normal_at(p.x, p.y));
                hit = Some((
                    h.t,
                    Hit {
                        p,
                        n,
                        material: self.sample.material_at(p.x, p.y),
                    },
                ));
            }
        }
        if hit.is_none() && d.z < 0.0 {
            let t = -o.z / d.z;
            let p = o + d * t;
            if self.sample.contains(p.x, p.y) {
                let n = self
                    .sample
                    .grid
                    .as_ref()
                    .map_or(Vec3A::Z, |g| g.normal_at(p.x, p.y));
                hit = Some((
                    t,
                    Hit {
                        p,
                        n,
                        material: self.sample.material_at(p.x, p.y),
                    },
                ));
            } else if p.x * p.x + p.y * p.y <= TURNTABLE_RADIUS_MM * TURNTABLE_RADIUS_MM {
                hit = Some((
                    t,
                    Hit {
                        p,
                        n: Vec3A::Z,
                        material: TURNTABLE,
                    },
                ));
            }
        }
        let (t, h) = hit?;
        if self
            .tubes
            .iter()
            .any(|tube| tube.hit(o, d).is_some_and(|tt| tt < t))
        {
            return None;
        }
        Some(h)
    }

    /// Whether the relief blocks the way from `p` (normal `n`) toward the unit direction `wi`
    /// for `dist` mm; `mask` may vouch that the point is lit without marching. Counts the
    /// rays marched in `rays`.
    #[inline]
    fn occluded(
        &self,
        p: Vec3A,
        n: Vec3A,
        wi: Vec3A,
        dist: f32,
        mask: Option<&LitMask>,
        rays: &mut u64,
    ) -> bool {
        let Some(grid) = &self.sample.grid else {
            return false;
        };
        if mask.is_some_and(|m| m.surely_lit(grid, p)) {
            return false;
        }
        *rays += 1;
        let o = p + n * SHADOW_OFFSET_MM + Vec3A::Z * (0.25 * SHADOW_OFFSET_MM);
        grid.occluded(o, wi, 0.0, dist)
    }

    /// Radiance from a point light of intensity `intensity` at `q`, or zero if it is behind
    /// the surface or shadowed.
    #[inline]
    fn point_light(
        &self,
        h: &Hit,
        wo: Vec3A,
        q: Vec3A,
        intensity: f32,
        mask: Option<&LitMask>,
        rays: &mut u64,
    ) -> Vec3A {
        let v = q - h.p;
        let r2 = v.length_squared();
        if !(r2 > 1.0e-6) {
            return Vec3A::ZERO;
        }
        let r = r2.sqrt();
        let wi = v / r;
        let cos_i = h.n.dot(wi);
        if !(cos_i > 0.0) || intensity <= 0.0 {
            return Vec3A::ZERO;
        }
        if self.shadows && self.occluded(h.p, h.n, wi, r, mask, rays) {
            return Vec3A::ZERO;
        }
        brdf(&h.material, h.n, wi, wo, self.specular) * (intensity * cos_i / r2)
    }

    /// Laser light reflected at `h` toward `wo`: the sheet's profile averaged over the pixel
    /// footprint (a sub-pixel line must not vanish between samples), shadowed like a lamp.
    fn laser_light(
        &self,
        sheet: &LaserSheet,
        h: &Hit,
        wo: Vec3A,
        fp: &Footprint,
        rays: &mut u64,
    ) -> Vec3A {
        let dist = sheet.distance(h.p);
        // Cheap bound on the footprint before computing it.
        let t = (h.p - fp.origin).length();
        let coarse = 3.0 * sheet.half_width_mm + 2.0 * t * fp.angle / h.n.dot(wo).abs().max(0.05);
        if dist.abs() > coarse {
            return Vec3A::ZERO;
        }
        // Where the neighbouring sample rays meet the tangent plane at h.
        let spread = |d: Vec3A| {
            let denom = d.dot(h.n);
            if denom.abs() < 1.0e-4 {
                return coarse;
            }
            let q = fp.origin + d * ((h.p - fp.origin).dot(h.n) / denom);
            (q - h.p).dot(sheet.normal).clamp(-coarse, coarse)
        };
        let (gx, gy) = (spread(fp.dx), spread(fp.dy));
        // A box of width g has variance g²/12.
        let (e, wi, r) = sheet.irradiance(h.p, (gx * gx + gy * gy) / 12.0);
        let cos_i = h.n.dot(wi);
        if !(e > 1.0e-4 && cos_i > 0.0)
            || (self.shadows && self.occluded(h.p, h.n, wi, r, self.laser_mask.as_ref(), rays))
        {
            return Vec3A::ZERO;
        }
        let m = &h.material;
        let mono = Material {
            albedo: Vec3A::splat(m.albedo.dot(sheet.reflect_weights)),
            ..*m
        };
        sheet.camera_rgb * (e * cos_i * brdf(&mono, h.n, wi, wo, self.specular).x)
    }

    /// Radiance leaving `h` toward `wo` for sub-pixel sample `sub` of pixel `pixel`.
    pub fn shade(
        &self,
        h: &Hit,
        wo: Vec3A,
        footprint: &Footprint,
        sub: u32,
        pixel: u64,
        rays: &mut u64,
    ) -> Vec3A {
        let spp = self.quality.spp();
        let mut total = Vec3A::ZERO;
        for (li, light) in self.lights.iter().enumerate() {
            let key = |stratum: u32, dim: u64| {
                unit_f32(hash3(
                    JITTER_KEY,
                    pixel,
                    (li as u64) << 32 | stratum as u64,
                    dim,
                ))
            };
            match light.emitter {
                Emitter::Halogen {
                    centre,
                    u,
                    v,
                    intensity,
                } => {
                    let n = self.quality.halogen_samples();
                    if n <= 1 {
                        let mask = self.masks[li].first();
                        total += light.rgb * self.point_light(h, wo, centre, intensity, mask, rays);
                        continue;
                    }
                    let per = (n / spp).max(1);
                    let side = (n as f32).sqrt().round().max(1.0) as u32;
                    let mask = self.masks[li].first();
                    let mut sum = Vec3A::ZERO;
                    for m in 0..per {
                        let s = (sub + spp * m) % n;
                        let (a, b) = ((s % side) as f32, (s / side) as f32);
                        let radius = HALOGEN_RADIUS_MM * ((a + key(s, 0)) / side as f32).sqrt();
                        let phi = std::f32::consts::TAU * (b + key(s, 1)) / side as f32;
                        let q = centre + u * (radius * phi.cos()) + v * (radius * phi.sin());
                        sum += self.point_light(h, wo, q, intensity / per as f32, mask, rays);
                    }
                    total += light.rgb * sum;
                }
                Emitter::Tube {
                    start,
                    axis,
                    length,
                    per_mm,
                } => {
                    let n = self.quality.tube_samples();
                    let per = (n / spp).max(1);
                    let stratum = length / n as f32;
                    let mut sum = Vec3A::ZERO;
                    for m in 0..per {
                        let s = (sub + spp * m) % n;
                        let q = start + axis * (stratum * (s as f32 + key(s, 0)));
                        // Tape on the tube's sides: it emits downward, Lambert about −z.
                        let to_p = h.p - q;
                        let emit = (-to_p.z / to_p.length().max(1.0e-6)).max(0.0);
                        let mask = self.masks[li].get(s as usize);
                        sum += self.point_light(
                            h,
                            wo,
                            q,
                            per_mm * length / per as f32 * emit,
                            mask,
                            rays,
                        );
                    }
                    total += light.rgb * sum;
                }
                Emitter::Backlight { radiance } => {
                    total += light.rgb * h.material.transmittance * radiance;
                }
            }
        }
        if let Some(sheet) = &self.laser {
            total += self.laser_light(sheet, h, wo, footprint, rays);
        }
        total
    }

    /// Mean radiance over the pixel (x, y) of `pose`, in reference units.
    pub fn pixel(&self, pose: &CameraPose, x: u32, y: u32, rays: &mut u64) -> Vec3A {
        let side = self.quality.grid_side();
        let pixel = y as u64 * pose.width as u64 + x as u64;
        let mut sum = Vec3A::ZERO;
        for sub in 0..side * side {
            let (jx, jy) = if side == 1 {
                (0.5, 0.5)
            } else {
                let h = hash3(JITTER_KEY, pixel, sub as u64, 7);
                (unit_f32(h), unit_f32(h.rotate_left(24)))
            };
            let px = x as f32 + ((sub % side) as f32 + jx) / side as f32;
            let py = y as f32 + ((sub / side) as f32 + jy) / side as f32;
            let d = pose.ray(px, py);
            if let Some(h) = self.intersect(pose.origin, d) {
                let step = 1.0 / side as f32;
                let footprint = if self.laser.is_some() {
                    Footprint {
                        origin: pose.origin,
                        dx: pose.ray(px + step, py),
                        dy: pose.ray(px, py + step),
                        angle: step / pose.focal_px,
                    }
                } else {
                    Footprint {
                        origin: pose.origin,
                        dx: d,
                        dy: d,
                        angle: 0.0,
                    }
                };
                sum += self.shade(&h, -d, &footprint, sub, pixel, rays);
            }
        }
        sum / (side * side) as f32
    }
}
