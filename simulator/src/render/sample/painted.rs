//! A scene file's `[material]` evaluated at a point: constants and maps combined into a
//! renderer [`Material`], with the quasi-homogeneous entrance and exit functions.

use glam::Vec3A;

use super::noise::texture;
use crate::render::material::Material;
use crate::scene_file::{Meso, Param, SceneMaterial};

/// Smallest roughness a map may give (a zero pixel would make the lobe a spike).
const MIN_MAP_ALPHA: f32 = 0.01;
/// Noise seeds of the entrance and exit functions.
const MESO_SEEDS: [u64; 2] = [0x3e50, 0x3e51];

/// Whether `m` is the same everywhere (no maps, no mesostructure), so one exact material
/// serves the whole sample.
pub(super) fn is_uniform(m: &SceneMaterial) -> bool {
    matches!(
        (&m.albedo, &m.ks, &m.alpha),
        (Param::Const(_), Param::Const(_), Param::Const(_))
    ) && m.meso.is_none()
}

/// The material at (x, y) on a sample `size` mm across whose relief there is `relief`, a
/// fraction of its highest point (0 at the turntable). Points under the medium refer to
/// the sample's first medium.
pub(super) fn paint(m: &SceneMaterial, size: f32, x: f32, y: f32, relief: f32) -> Material {
    let albedo = match &m.albedo {
        Param::Const(c) => *c,
        Param::Map(map) => Vec3A::from_array(map.at(x, y, size)),
    };
    let scalar = |p: &Param<f32>| match p {
        Param::Const(c) => *c,
        Param::Map(map) => map.scalar_at(x, y, size),
    };
    let alpha = match &m.alpha {
        Param::Const(c) => *c,
        Param::Map(map) => map.scalar_at(x, y, size).clamp(MIN_MAP_ALPHA, 1.0),
    };
    let (meso_in, meso_out) = match &m.meso {
        None => (1.0, 1.0),
        Some(Meso::Maps { entrance, exit }) => {
            let at = |map: &Option<crate::scene_file::image::ImageMap>| {
                map.as_ref().map_or(1.0, |map| map.scalar_at(x, y, size))
            };
            (at(entrance), at(exit))
        }
        Some(Meso::Relief { contrast }) => {
            let f = 1.0 - contrast * (1.0 - relief.clamp(0.0, 1.0));
            (f, f)
        }
        Some(Meso::Noise { contrast, scale_mm }) => {
            let f = |seed| 1.0 - contrast * (1.0 - texture(seed, x, y, *scale_mm).clamp(0.0, 1.0));
            (f(MESO_SEEDS[0]), f(MESO_SEEDS[1]))
        }
    };
    Material {
        model: m.model,
        albedo,
        ks: scalar(&m.ks),
        alpha,
        alpha_y: m.alpha_y.unwrap_or(alpha),
        tangent_rad: m.tangent_rad,
        transmittance: m.transmittance,
        medium: u8::from(m.medium.is_some()),
        meso_in,
        meso_out,
    }
}
