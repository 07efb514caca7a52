//! The lit light sources in the sample frame: halogen lamps on the light arc (points or 10 mm
//! disks), the reflectometer's tube (a line along y) and the backlight panel.
//!
//! Radiometric units: irradiance is in multiples of the reference lamp (power 1 at 800 mm,
//! normal incidence); radiance in those units over π, so white Lambert under the reference
//! lamp has radiance 1/π.

use glam::Vec3A;
use stagehand_devices::rig::{LampKind, RigSpec};

use super::geometry::{RigAngles, ToSample, spherical};
use crate::as_built::AsBuilt;
use crate::world_snapshot::WorldSnapshot;

/// Distance at which a power-1 lamp gives unit irradiance.
pub const REFERENCE_DISTANCE_MM: f32 = 800.0;
/// Radius of a halogen lamp's emitting disk (used above preview quality).
pub const HALOGEN_RADIUS_MM: f32 = 10.0;
/// Height at which a power-1 tube gives unit irradiance directly below it.
const TUBE_REFERENCE_HEIGHT_MM: f32 = 60.0;
/// Points on the turntable that can be lit lie within this radius (black beyond).
pub const TURNTABLE_RADIUS_MM: f32 = 200.0;

/// Warm-white halogen colour.
pub const HALOGEN_RGB: Vec3A = Vec3A::new(1.0, 0.78, 0.52);
/// Cool-white fluorescent colour of the tube.
pub const TUBE_RGB: Vec3A = Vec3A::new(0.90, 1.0, 0.95);
/// Backlight panel colour.
pub const BACKLIGHT_RGB: Vec3A = Vec3A::new(0.95, 1.0, 1.0);

/// Geometry and strength of one lit source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Emitter {
    /// A small disk facing the origin; `intensity` × cosθi / r² is the irradiance.
    Halogen {
        /// Disk centre.
        centre: Vec3A,
        /// Disk basis vectors (unit, perpendicular to the facing direction).
        u: Vec3A,
        /// Second disk basis vector.
        v: Vec3A,
        /// Radiant intensity in reference units × mm².
        intensity: f32,
    },
    /// A line from `start` along unit `axis` for `length` mm, emitting downward (Lambert
    /// about −z) with `per_mm` intensity per millimetre.
    Tube {
        /// One end of the tube.
        start: Vec3A,
        /// Unit direction along the tube.
        axis: Vec3A,
        /// Tube length.
        length: f32,
        /// Intensity per mm of tube in reference units × mm².
        per_mm: f32,
    },
    /// A diffuse panel under the sample; cameras see `radiance` × transmittance.
    Backlight {
        /// Panel radiance in reference units (1/π = reference white).
        radiance: f32,
    },
}

/// A lit lamp.
#[derive(Debug, Clone, PartialEq)]
pub struct Light {
    /// Lamp id from the rig.
    pub id: String,
    /// The rig's lamp kind.
    pub kind: LampKind,
    /// Output fraction from the world (warm-up), > 0.
    pub output: f32,
    /// Colour weights.
    pub rgb: Vec3A,
    /// Where and how strongly it emits.
    pub emitter: Emitter,
}

impl Light {
    /// Lowest elevation (radians) at which this light is seen from any point of the turntable
    /// disk at height `zmax`: a shadow can only fall if some slope rises above it. `None` for
    /// lights that cast no shadows (backlight).
    pub fn min_elevation_rad(&self, zmax: f32) -> Option<f32> {
        let elev = |q: Vec3A| (q.z - zmax).atan2(q.truncate().length() + TURNTABLE_RADIUS_MM);
        match self.emitter {
            Emitter::Halogen { centre, .. } => Some(elev(centre - Vec3A::Z * HALOGEN_RADIUS_MM)),
            Emitter::Tube {
                start,
                axis,
                length,
                ..
            } => Some(elev(start).min(elev(start + axis * length))),
            Emitter::Backlight { .. } => None,
        }
    }
}

/// The tube as an opaque cylinder the camera can see (it is there whether lit or not).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TubeBody {
    /// Midpoint of the tube axis.
    pub centre: Vec3A,
    /// Unit axis.
    pub axis: Vec3A,
    /// Length of the glass, mm.
    pub length: f32,
    /// Radius of the glass, mm.
    pub radius: f32,
}

impl TubeBody {
    /// Distance along the unit ray o + t·d to the tube's glass, if it is hit.
    pub fn hit(&self, o: Vec3A, d: Vec3A) -> Option<f32> {
        let w = o - self.centre;
        let dp = d - self.axis * self.axis.dot(d);
        let wp = w - self.axis * self.axis.dot(w);
        let a = dp.length_squared();
        if a < 1.0e-12 {
            return None;
        }
        let b = 2.0 * wp.dot(dp);
        let c = wp.length_squared() - self.radius * self.radius;
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)]
            .into_iter()
            .find(|&t| t > 0.0 && self.axis.dot(w + d * t).abs() <= 0.5 * self.length)
    }
}

/// Centre of the tube: x = cart − travel/2, at its lamp's distance_mm above the sample.
fn tube_centre(rig: &RigSpec, world: &WorldSnapshot, height_mm: f64) -> Vec3A {
    let travel = rig.cart.as_ref().map_or(0.0, |c| c.travel_mm);
    Vec3A::new((world.cart_mm - 0.5 * travel) as f32, 0.0, height_mm as f32)
}

/// Every lit lamp of the rig (output > 0) in the sample frame, with its as-built intensity and
/// colour, plus the ids in the world's
/// lamp table that the rig does not have.
pub fn lit_lamps(
    rig: &RigSpec,
    as_built: &AsBuilt,
    world: &WorldSnapshot,
    angles: RigAngles,
    to_sample: ToSample,
) -> (Vec<Light>, Vec<String>) {
    let mut lights = Vec::new();
    for lamp in &rig.lamps {
        let output = world.lamps.get(&lamp.id).copied().unwrap_or(0.0);
        if output <= 0.0 {
            continue;
        }
        let built = as_built.lamp(&lamp.id);
        let strength = (output * lamp.power * built.intensity) as f32;
        let tint = Vec3A::new(
            built.rgb[0] as f32,
            built.rgb[1] as f32,
            built.rgb[2] as f32,
        );
        let (rgb, emitter) = match lamp.kind {
            LampKind::Halogen => {
                let world_pos =
                    spherical(angles.light_arc_deg, lamp.elevation_deg, lamp.distance_mm);
                let centre = to_sample.point(world_pos);
                let facing = (-centre).normalize_or(-Vec3A::Z);
                let u = facing.any_orthonormal_vector();
                let v = facing.cross(u);
                let intensity = strength * REFERENCE_DISTANCE_MM * REFERENCE_DISTANCE_MM;
                (
                    HALOGEN_RGB,
                    Emitter::Halogen {
                        centre,
                        u,
                        v,
                        intensity,
                    },
                )
            }
            LampKind::Tube => {
                let centre = to_sample.point(tube_centre(rig, world, lamp.distance_mm));
                let axis = to_sample.dir(Vec3A::Y);
                let length = lamp.length_mm as f32;
                let start = centre - axis * (0.5 * length);
                // Infinite Lambertian line at height h gives E = π·per_mm / (2h) below it.
                let per_mm = strength * 2.0 * TUBE_REFERENCE_HEIGHT_MM / std::f32::consts::PI;
                (
                    TUBE_RGB,
                    Emitter::Tube {
                        start,
                        axis,
                        length,
                        per_mm,
                    },
                )
            }
            LampKind::Backlight => (
                BACKLIGHT_RGB,
                Emitter::Backlight {
                    radiance: strength * std::f32::consts::FRAC_1_PI,
                },
            ),
        };
        lights.push(Light {
            id: lamp.id.clone(),
            kind: lamp.kind,
            output: output as f32,
            rgb: rgb * tint,
            emitter,
        });
    }
    let unknown = world
        .lamps
        .keys()
        .filter(|id| rig.lamp(id).is_none())
        .cloned()
        .collect();
    (lights, unknown)
}

/// The tube bodies of the rig in the sample frame.
pub fn tube_bodies(rig: &RigSpec, world: &WorldSnapshot, to_sample: ToSample) -> Vec<TubeBody> {
    rig.lamps
        .iter()
        .filter(|l| l.kind == LampKind::Tube)
        .map(|l| TubeBody {
            centre: to_sample.point(tube_centre(rig, world, l.distance_mm)),
            axis: to_sample.dir(Vec3A::Y),
            length: l.length_mm as f32,
            radius: l.radius_mm as f32,
        })
        .collect()
}
