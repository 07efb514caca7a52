//! What a camera ray hits (sample relief, turntable, the tube) and the light it carries back:
//! direct lighting from every lit source, shadowed only when the plan calls for it.

use std::sync::Arc;

use glam::Vec3A;

use super::bounce::BounceMap;
use super::dark_spans;
use super::geometry::CameraPose;
use super::laser::LaserSheet;
use super::lights::{Emitter, HALOGEN_RADIUS_MM, Light, TURNTABLE_RADIUS_MM, TubeBody};
use super::pixel_samples::{JITTER_KEY, LensTable, sample_position};
use super::primary_hits::{HitKind, HitTable, PackedHit, RowRecorder, WallFacing};
use super::quality::Knobs;
use super::rng::{hash3, unit_f32};
use super::sample::{Material, Sample};
use super::shading::brdf;
use super::shadow::{VertexVisibility, shadow_origin};
use super::subsurface::SubsurfaceMap;

/// The dark grey turntable around the sample.
const TURNTABLE: Material = Material::grey(0.05);
/// Points along the tube whose visibility maps shade preview frames: each serves the light
/// samples of a quarter of the tube (a four-step penumbra, a quarter of the cost).
const TUBE_SHADOW_POSITIONS: u32 = 4;

/// A surface point seen by a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Position in the sample frame.
    pub p: Vec3A,
    /// Shading normal.
    pub n: Vec3A,
    /// Reflectance there.
    pub material: Material,
    /// On the top of the sample's relief grid (not its sides, not the turntable).
    pub on_relief: bool,
}

/// The rays through the neighbouring sub-pixel samples, for filtering sub-pixel detail.
#[derive(Clone, Copy)]
pub struct Footprint<'f> {
    /// Camera centre.
    pub origin: Vec3A,
    /// Angle subtended by one sample step, radians.
    pub angle: f32,
    /// The unit rays one sample step to the right and one down: computed only for points
    /// near the laser sheet, which alone needs them.
    pub neighbours: &'f dyn Fn() -> (Vec3A, Vec3A),
    /// Where the sample lies in its stratum, in steps from the stratum's centre (its jitter;
    /// zero for one centred sample per pixel): the laser line is integrated over the stratum,
    /// so a pixel's strata tile it exactly.
    pub offset: (f32, f32),
}

/// Settings that decide how a frame is shaded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shading<'a> {
    /// Shadow the lights (the effect plan's decision).
    pub shadows: bool,
    /// Evaluate the Ward lobe.
    pub specular: bool,
    /// Accuracy knobs.
    pub knobs: &'a Knobs,
}

/// Everything needed to shade one frame, fixed for the frame.
#[derive(Debug, Clone)]
pub struct Scene<'a> {
    sample: &'a Sample,
    lights: Vec<Light>,
    laser: Option<LaserSheet>,
    tubes: Vec<TubeBody>,
    shadows: bool,
    specular: bool,
    knobs: &'a Knobs,
    /// Per light, per light stratum: vertex visibility maps (preview with shadows on).
    maps: Vec<Vec<Arc<VertexVisibility>>>,
    laser_map: Option<Arc<VertexVisibility>>,
    /// Indirect diffuse irradiance over the relief (interreflection pass), if planned.
    indirect: Option<&'a BounceMap>,
    /// Subsurface exitance (dipole pass), if planned.
    subsurface: Option<&'a SubsurfaceMap>,
}

impl<'a> Scene<'a> {
    /// A scene. With shadows on and `knobs.shadow_maps`, every light sample sits at a fixed point
    /// and `visibility` supplies (usually from a cache) that point's per-vertex visibility.
    pub fn new(
        sample: &'a Sample,
        lights: Vec<Light>,
        laser: Option<LaserSheet>,
        tubes: Vec<TubeBody>,
        shading: Shading<'a>,
        visibility: &dyn Fn(Vec3A) -> Option<Arc<VertexVisibility>>,
    ) -> Scene<'a> {
        let Shading {
            shadows,
            specular,
            knobs,
        } = shading;
        let use_maps = shadows && sample.grid.is_some() && knobs.shadow_maps;
        let maps = lights
            .iter()
            .map(|light| match light.emitter {
                _ if !use_maps => Vec::new(),
                Emitter::Halogen { centre, .. } => visibility(centre).into_iter().collect(),
                Emitter::Tube {
                    start,
                    axis,
                    length,
                    ..
                } => {
                    let part = length / TUBE_SHADOW_POSITIONS as f32;
                    (0..TUBE_SHADOW_POSITIONS)
                        .filter_map(|k| visibility(start + axis * (part * (k as f32 + 0.5))))
                        .collect()
                }
                Emitter::Backlight { .. } => Vec::new(),
            })
            .collect();
        let laser_map = laser
            .as_ref()
            .filter(|_| use_maps)
            .and_then(|sheet| visibility(sheet.origin));
        Scene {
            sample,
            lights,
            laser,
            tubes,
            shadows,
            specular,
            knobs,
            maps,
            laser_map,
            indirect: None,
            subsurface: None,
        }
    }

    /// This scene with the frame's light-transport passes: indirect irradiance from
    /// interreflection and subsurface exitance, each added at shading time where present.
    pub fn with_transport(
        mut self,
        indirect: Option<&'a BounceMap>,
        subsurface: Option<&'a SubsurfaceMap>,
    ) -> Scene<'a> {
        self.indirect = indirect;
        self.subsurface = subsurface;
        self
    }

    /// The laser sheet when it is the frame's only source (no lamp, no subsurface pass; the
    /// bounce pass may spread its light).
    fn laser_alone(&self) -> Option<&LaserSheet> {
        self.laser
            .as_ref()
            .filter(|_| self.lights.is_empty() && self.subsurface.is_none())
    }

    /// Whether the laser sheet is the frame's only source (see `laser_alone`).
    pub fn lit_by_laser_alone(&self) -> bool {
        self.laser_alone().is_some()
    }

    /// The lit lamps.
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    /// How many per-vertex visibility maps shade this frame.
    pub fn visibility_maps(&self) -> usize {
        self.maps.iter().map(Vec::len).sum::<usize>() + usize::from(self.laser_map.is_some())
    }

    /// The first surface along the unit ray o + t·d, or `None` for black (void, or the tube).
    pub fn intersect(&self, o: Vec3A, d: Vec3A) -> Option<Hit> {
        self.hit_from(o, d, self.locate(o, d), None)
    }

    /// What the unit ray o + t·d meets first and how far along it: the part of
    /// [`Self::intersect`] that depends on the geometry alone, kept per camera view
    /// ([`super::primary_hits`]).
    pub fn locate(&self, o: Vec3A, d: Vec3A) -> PackedHit {
        let mut hit = None;
        if let Some(grid) = &self.sample.grid
            && let Some(h) = grid.first_hit(o, d, 0.0, f32::INFINITY)
        {
            let kind = match h.wall {
                None => HitKind::Relief,
                Some(n) if n.x < 0.0 => HitKind::Wall(WallFacing::MinusX),
                Some(n) if n.x > 0.0 => HitKind::Wall(WallFacing::PlusX),
                Some(n) if n.y < 0.0 => HitKind::Wall(WallFacing::MinusY),
                Some(_) => HitKind::Wall(WallFacing::PlusY),
            };
            hit = Some(PackedHit {
                t: h.t,
                cos_view: 0.0,
                kind,
            });
        }
        if hit.is_none() && d.z < 0.0 {
            let t = -o.z / d.z;
            let p = o + d * t;
            if self.sample.contains(p.x, p.y) {
                hit = Some(PackedHit {
                    t,
                    cos_view: 0.0,
                    kind: HitKind::SamplePlane,
                });
            } else if p.x * p.x + p.y * p.y <= TURNTABLE_RADIUS_MM * TURNTABLE_RADIUS_MM {
                hit = Some(PackedHit {
                    t,
                    cos_view: 0.0,
                    kind: HitKind::Turntable,
                });
            }
        }
        let Some(h) = hit else {
            return PackedHit::NOTHING;
        };
        if self
            .tubes
            .iter()
            .any(|tube| tube.hit(o, d).is_some_and(|tt| tt < h.t))
        {
            return PackedHit::NOTHING;
        }
        h
    }

    /// The surface point `packed` found along the unit ray o + t·d, with its normal and
    /// material: rebuilt the same way whether `packed` was located now or kept. `normal` is
    /// the shading normal a [`HitTable`] kept for it, if any (the one computed here).
    #[inline]
    pub fn hit_from(
        &self,
        o: Vec3A,
        d: Vec3A,
        packed: PackedHit,
        normal: Option<Vec3A>,
    ) -> Option<Hit> {
        let p = o + d * packed.t;
        let n = self.normal_of(packed.kind, p, normal)?;
        let (material, on_relief) = match packed.kind {
            HitKind::Turntable => (TURNTABLE, false),
            kind => (self.sample.material_at(p.x, p.y), kind == HitKind::Relief),
        };
        Some(Hit {
            p,
            n,
            material,
            on_relief,
        })
    }

    /// The shading normal at point `p` of a hit of `kind` (`kept` when a [`HitTable`] kept
    /// it); `None` where nothing is hit.
    #[inline]
    fn normal_of(&self, kind: HitKind, p: Vec3A, kept: Option<Vec3A>) -> Option<Vec3A> {
        let grid = self.sample.grid.as_ref();
        let relief = |g: &super::heightfield::HeightGrid| match kept {
            Some(n) => n,
            None => g.normal_at(p.x, p.y),
        };
        Some(match kind {
            HitKind::Nothing => return None,
            HitKind::Relief => relief(grid?),
            HitKind::Wall(WallFacing::MinusX) => Vec3A::new(-1.0, 0.0, 0.0),
            HitKind::Wall(WallFacing::PlusX) => Vec3A::new(1.0, 0.0, 0.0),
            HitKind::Wall(WallFacing::MinusY) => Vec3A::new(0.0, -1.0, 0.0),
            HitKind::Wall(WallFacing::PlusY) => Vec3A::new(0.0, 1.0, 0.0),
            HitKind::SamplePlane => grid.map_or(Vec3A::Z, relief),
            HitKind::Turntable => Vec3A::Z,
        })
    }

    /// Fraction of the light from direction `wi`, `dist` mm away, that reaches `h`: from the
    /// vertex visibility map for points on the relief when there is one, else by marching.
    /// Counts the rays marched in `rays`.
    #[inline]
    fn visibility(
        &self,
        h: &Hit,
        wi: Vec3A,
        dist: f32,
        map: Option<&Arc<VertexVisibility>>,
        rays: &mut u64,
    ) -> f32 {
        if !self.shadows {
            return 1.0;
        }
        let Some(grid) = &self.sample.grid else {
            return 1.0;
        };
        if let (Some(map), true) = (map, h.on_relief) {
            return map.at(grid, h.p.x, h.p.y);
        }
        if !h.on_relief && self.cannot_reach_relief(h.p, wi, grid.zmax()) {
            return 1.0;
        }
        *rays += 1;
        if grid.occluded(shadow_origin(h.p, h.n), wi, 0.0, dist) {
            0.0
        } else {
            1.0
        }
    }

    /// Whether a shadow ray from `p` (off the relief: turntable or the sample's sides) along
    /// `wi` rises above `zmax` before it could reach the sample's square: then nothing can
    /// block it. A cheap test that spares most turntable points a march.
    #[inline]
    fn cannot_reach_relief(&self, p: Vec3A, wi: Vec3A, zmax: f32) -> bool {
        let half = 0.5 * self.sample.size_mm;
        let (dx, dy) = ((p.x.abs() - half).max(0.0), (p.y.abs() - half).max(0.0));
        let gap2 = dx * dx + dy * dy;
        if gap2 <= 0.0 || wi.z <= 0.0 {
            return false;
        }
        // Horizontal run before the ray climbs above the relief.
        let climb = (zmax - p.z).max(0.0);
        let horizontal = (1.0 - wi.z * wi.z).max(0.0).sqrt();
        let run = climb * horizontal / wi.z;
        run * run < gap2
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
        map: Option<&Arc<VertexVisibility>>,
        rays: &mut u64,
    ) -> Vec3A {
        let v = q - h.p;
        let r2 = v.length_squared();
        if r2.is_nan() || r2 <= 1.0e-6 {
            return Vec3A::ZERO;
        }
        let r = r2.sqrt();
        let wi = v / r;
        let cos_i = h.n.dot(wi);
        if cos_i.is_nan() || cos_i <= 0.0 || intensity <= 0.0 {
            return Vec3A::ZERO;
        }
        let visible = self.visibility(h, wi, r, map, rays);
        if visible <= 0.0 {
            return Vec3A::ZERO;
        }
        brdf(&h.material, h.n, wi, wo, self.specular) * (visible * intensity * cos_i / r2)
    }

    /// Laser light reflected at `h` toward `wo`: the sheet's profile averaged over the pixel
    /// footprint (a sub-pixel line must not vanish between samples), shadowed like a lamp.
    fn laser_light(
        &self,
        sheet: &LaserSheet,
        h: &Hit,
        wo: Vec3A,
        fp: &Footprint<'_>,
        rays: &mut u64,
    ) -> Vec3A {
        let dist = sheet.distance(h.p);
        // Cheap bound on the footprint before computing it.
        let coarse = sheet.reach(h.p, fp.origin, fp.angle, h.n.dot(wo).abs());
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
        let (dx, dy) = (fp.neighbours)();
        let (gx, gy) = (spread(dx), spread(dy));
        // The profile averaged over the sample's stratum, whose edges span gx and gy.
        let centre = fp.offset.0 * gx + fp.offset.1 * gy;
        let (e, wi, r) = sheet.irradiance_over(h.p, centre, gx, gy);
        let cos_i = h.n.dot(wi);
        if e.is_nan() || e <= 1.0e-4 || cos_i.is_nan() || cos_i <= 0.0 {
            return Vec3A::ZERO;
        }
        let visible = self.visibility(h, wi, r, self.laser_map.as_ref(), rays);
        if visible <= 0.0 {
            return Vec3A::ZERO;
        }
        let m = &h.material;
        let mono = Material {
            albedo: Vec3A::splat(m.albedo.dot(sheet.reflect_weights)),
            ..*m
        };
        let f = brdf(&mono, h.n, wi, wo, self.specular).x;
        sheet.camera_rgb * (visible * e * cos_i * f)
    }

    /// This scene shaded with other knobs (adaptive sampling's first pass takes one sample per
    /// pixel); lights, shadow maps and transport passes are shared.
    pub fn with_knobs(&self, knobs: &'a Knobs) -> Scene<'a> {
        Scene {
            knobs,
            ..self.clone()
        }
    }

    /// Radiance leaving `h` toward `wo` for sub-pixel sample `sub` of pixel `pixel`.
    #[inline(always)]
    pub fn shade(
        &self,
        h: &Hit,
        wo: Vec3A,
        footprint: &Footprint<'_>,
        sub: u32,
        pixel: u64,
        rays: &mut u64,
    ) -> Vec3A {
        let spp = self.knobs.spp();
        let mut total = Vec3A::ZERO;
        for (li, light) in self.lights.iter().enumerate() {
            // One random rotation per pixel, sample and light (Cranley–Patterson) shifts
            // every stratum of the light: stratified, and one hash instead of one per point.
            // Hashed only where a light is sampled at more than one point.
            let rotation = || hash3(JITTER_KEY, pixel, (li as u64) << 32 | sub as u64, 1);
            let maps = self.maps.get(li);
            match light.emitter {
                Emitter::Halogen {
                    centre,
                    u,
                    v,
                    intensity,
                } => {
                    let n = self.knobs.halogen_samples;
                    let map = maps.and_then(|m| m.first());
                    if n <= 1 {
                        total += light.rgb * self.point_light(h, wo, centre, intensity, map, rays);
                        continue;
                    }
                    let per = (n / spp).max(1);
                    let side = (n as f32).sqrt().round().max(1.0) as u32;
                    let rotation = rotation();
                    let jitter = |dim: u32| unit_f32(rotation.rotate_left(24 * dim));
                    let mut sum = Vec3A::ZERO;
                    for m in 0..per {
                        let s = (sub + spp * m) % n;
                        let (a, b) = ((s % side) as f32, (s / side) as f32);
                        let radius = HALOGEN_RADIUS_MM * ((a + jitter(0)) / side as f32).sqrt();
                        let phi = std::f32::consts::TAU * (b + jitter(1)) / side as f32;
                        let q = centre + u * (radius * phi.cos()) + v * (radius * phi.sin());
                        sum += self.point_light(h, wo, q, intensity / per as f32, None, rays);
                    }
                    total += light.rgb * sum;
                }
                Emitter::Tube {
                    start,
                    axis,
                    length,
                    per_mm,
                } => {
                    let n = self.knobs.tube_samples;
                    let per = (n / spp).max(1);
                    let rotation = rotation();
                    let jitter = |dim: u32| unit_f32(rotation.rotate_left(24 * dim));
                    let stratum = length / n as f32;
                    let mut sum = Vec3A::ZERO;
                    for m in 0..per {
                        let s = (sub + spp * m) % n;
                        let q = start + axis * (stratum * (s as f32 + jitter(0)));
                        // Tape on the tube's sides: it emits downward, Lambert about −z.
                        let to_p = h.p - q;
                        let emit = (-to_p.z / to_p.length().max(1.0e-6)).max(0.0);
                        let intensity = per_mm * length / per as f32 * emit;
                        let part = (s * TUBE_SHADOW_POSITIONS / n) as usize;
                        let map = maps.and_then(|m| m.get(part));
                        sum += self.point_light(h, wo, q, intensity, map, rays);
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
        if let Some(bounce) = self.indirect
            && h.on_relief
        {
            total += indirect_radiance(bounce, &h.material, h.p);
        }
        if let Some(sss) = self.subsurface
            && h.material.medium != 0
        {
            total += sss.radiance(&h.material, h.p, h.n, wo);
        }
        total
    }

    /// Mean radiance over the pixel (x, y) of `pose`, in reference units.
    pub fn pixel(&self, pose: &CameraPose, x: u32, y: u32, rays: &mut u64) -> Vec3A {
        self.pixel_with(pose, None, None, None, x, y, rays)
    }

    /// [`Self::pixel`], reading the lens's undistorted sample points from `lens` (the camera's
    /// table, `pixel_samples::LensTables`) when it covers this scene's sampling, and each
    /// sample's primary hit from `hits` (the view's table, `primary_hits::PrimaryHits`) when
    /// given: the same radiance, bit for bit, without the lens inversion or the march.
    /// Without `hits`, each sample's hit is recorded in `record` (the pixel's row of the
    /// view's table being made) when given, as [`Self::locate_sample`] gives it.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn pixel_with(
        &self,
        pose: &CameraPose,
        lens: Option<&LensTable>,
        hits: Option<&HitTable>,
        mut record: Option<&mut RowRecorder<'_>>,
        x: u32,
        y: u32,
        rays: &mut u64,
    ) -> Vec3A {
        let side = self.knobs.spp_side;
        let pixel = y as u64 * pose.width as u64 + x as u64;
        let step = 1.0 / side as f32;
        let lens = lens.filter(|t| t.covers(side, self.laser.is_some()));
        let hits = hits.filter(|t| t.side() == side);
        let ray = |sub: u32, which: usize, px: f32, py: f32| {
            sample_ray(pose, lens, pixel, sub, which, (px, py))
        };
        let laser_alone = self.laser_alone();
        let angle = if self.laser.is_some() {
            step / pose.focal_px
        } else {
            0.0
        };
        let mut sum = Vec3A::ZERO;
        for sub in 0..side * side {
            let (px, py) = sample_position(x, y, pose.width, sub, side);
            let d = ray(sub, 0, px, py);
            let packed = match hits {
                Some(table) => table.get(x, y, sub),
                None => self.locate(pose.origin, d),
            };
            // Lit by the laser alone, a point beyond the sheet's reach gets no direct light,
            // only the bounce pass's indirect light on the relief: skip its normal and the
            // shading (most of a sweep's frame). The reach is the one `laser_light` tests,
            // from the view's cosine the table kept.
            if let (Some(sheet), Some(_)) = (laser_alone, hits)
                && packed.kind != HitKind::Nothing
            {
                let p = pose.origin + d * packed.t;
                if sheet.distance(p).abs() > sheet.reach(p, pose.origin, angle, packed.cos_view) {
                    // Where the bounce brought no light either, the sum is unchanged.
                    if let Some(bounce) = self.indirect
                        && packed.kind == HitKind::Relief
                        && bounce.irradiance_at(p.x, p.y) != Vec3A::ZERO
                    {
                        let material = self.sample.material_at(p.x, p.y);
                        sum += Vec3A::ZERO + indirect_radiance(bounce, &material, p);
                    }
                    continue;
                }
            }
            let normal = hits.and_then(|table| table.normal(x, y, sub));
            let hit = self.hit_from(pose.origin, d, packed, normal);
            if let Some(row) = record.as_mut() {
                match &hit {
                    Some(h) => {
                        let cos_view = h.n.dot(-d).abs();
                        row.record(x, sub, PackedHit { cos_view, ..packed }, h.p, h.n);
                    }
                    None => row.record(x, sub, packed, pose.origin + d * packed.t, Vec3A::ZERO),
                }
            }
            let Some(h) = hit else {
                continue;
            };
            let neighbours = || (ray(sub, 1, px + step, py), ray(sub, 2, px, py + step));
            let (cx, cy) = (
                x as f32 + ((sub % side) as f32 + 0.5) * step,
                y as f32 + ((sub / side) as f32 + 0.5) * step,
            );
            let footprint = Footprint {
                origin: pose.origin,
                angle,
                neighbours: &neighbours,
                offset: ((px - cx) / step, (py - cy) / step),
            };
            sum += self.shade(&h, -d, &footprint, sub, pixel, rays);
        }
        sum / (side * side) as f32
    }

    /// Per run of pixels of `pose` (see [`dark_spans::dark_spans`]), whether this frame leaves
    /// it black: only for a frame lit by the laser alone whose view's hits are kept.
    pub fn dark_spans(&self, pose: &CameraPose, hits: &HitTable) -> Option<Vec<bool>> {
        let sheet = self.laser_alone()?;
        let step = 1.0 / self.knobs.spp_side as f32;
        let angle = step / pose.focal_px;
        Some(dark_spans::dark_spans(hits, sheet, angle, self.indirect))
    }

    /// The primary hit of sample `sub` of pixel (x, y) of `pose`, what a [`HitTable`] keeps,
    /// and its point and shading normal (zero where nothing is hit) as [`Self::pixel_with`]
    /// rebuilds them from the kept distance.
    pub fn locate_sample(
        &self,
        pose: &CameraPose,
        lens: Option<&LensTable>,
        x: u32,
        y: u32,
        sub: u32,
    ) -> (PackedHit, Vec3A, Vec3A) {
        let side = self.knobs.spp_side;
        let pixel = y as u64 * pose.width as u64 + x as u64;
        let lens = lens.filter(|t| t.covers(side, self.laser.is_some()));
        let d = sample_ray(
            pose,
            lens,
            pixel,
            sub,
            0,
            sample_position(x, y, pose.width, sub, side),
        );
        let packed = self.locate(pose.origin, d);
        let p = pose.origin + d * packed.t;
        match self.normal_of(packed.kind, p, None) {
            Some(n) => {
                let cos_view = n.dot(-d).abs();
                (PackedHit { cos_view, ..packed }, p, n)
            }
            None => (packed, p, Vec3A::ZERO),
        }
    }
}

/// Radiance the bounce pass's indirect irradiance leaves at `p` on the relief: Lambert only.
#[inline]
fn indirect_radiance(bounce: &BounceMap, material: &Material, p: Vec3A) -> Vec3A {
    material.albedo.max(Vec3A::ZERO) * std::f32::consts::FRAC_1_PI * bounce.irradiance_at(p.x, p.y)
}

/// Unit ray through point `which` of sample `sub` of pixel index `pixel` (0 the sample at
/// image position `at`, 1 and 2 its neighbours): from the lens table when there is one, else
/// computed, bit for bit the same.
#[inline]
fn sample_ray(
    pose: &CameraPose,
    lens: Option<&LensTable>,
    pixel: u64,
    sub: u32,
    which: usize,
    at: (f32, f32),
) -> Vec3A {
    match lens {
        Some(t) => pose.ray_through(t.uv(pixel, sub, which)),
        None => pose.ray(at.0, at.1),
    }
}
