//! The per-texel material store of a spatially varying sample: every field of a
//! [`Material`] quantised into 16 bytes, on a square grid of texels over the footprint.

use std::f32::consts::PI;

use glam::Vec3A;
use rayon::prelude::*;

use crate::render::material::{Material, Model};

/// Models in the order of their stored index.
const MODELS: [Model; 5] = [
    Model::Lambert,
    Model::WardIso,
    Model::WardAniso,
    Model::BlinnPhong,
    Model::Ggx,
];

/// One quantised material: fractions in 8 bits, roughness in 16 bits (a Blinn–Phong
/// exponent of 1000 needs α to 10⁻⁴), the tangent modulo π (a Ward lobe is symmetric under
/// half-turns) in 256 steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Texel {
    alpha: u16,
    alpha_y: u16,
    albedo: [u8; 3],
    trans: [u8; 3],
    ks: u8,
    model: u8,
    tangent: u8,
    medium: u8,
    meso_in: u8,
    meso_out: u8,
}

/// A fraction in [0, 1] to 8 bits (clamped, rounded).
fn q8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// A fraction in [0, 1] to 16 bits (clamped, rounded).
fn q16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

impl Texel {
    /// Quantises `m`.
    pub(super) fn encode(m: &Material) -> Texel {
        let turn = m.tangent_rad.rem_euclid(PI) / PI;
        Texel {
            alpha: q16(m.alpha),
            alpha_y: q16(m.alpha_y),
            albedo: [q8(m.albedo.x), q8(m.albedo.y), q8(m.albedo.z)],
            trans: [
                q8(m.transmittance.x),
                q8(m.transmittance.y),
                q8(m.transmittance.z),
            ],
            ks: q8(m.ks),
            model: MODELS.iter().position(|&x| x == m.model).unwrap_or(0) as u8,
            tangent: ((turn * 256.0 + 0.5) as u32 % 256) as u8,
            medium: m.medium,
            meso_in: q8(m.meso_in),
            meso_out: q8(m.meso_out),
        }
    }

    /// The material this texel stores.
    pub(super) fn decode(&self) -> Material {
        let f = |v: u8| v as f32 * (1.0 / 255.0);
        let g = |v: u16| v as f32 * (1.0 / 65535.0);
        let rgb = |c: [u8; 3]| Vec3A::new(f(c[0]), f(c[1]), f(c[2]));
        Material {
            model: MODELS[self.model as usize % MODELS.len()],
            albedo: rgb(self.albedo),
            ks: f(self.ks),
            alpha: g(self.alpha),
            alpha_y: g(self.alpha_y),
            tangent_rad: self.tangent as f32 * (PI / 256.0),
            transmittance: rgb(self.trans),
            medium: self.medium,
            meso_in: f(self.meso_in),
            meso_out: f(self.meso_out),
        }
    }
}

/// Texels on an n×n grid over a square sample, looked up nearest-texel.
#[derive(Debug, Clone)]
pub(super) struct TexelMap {
    n: usize,
    cell: f32,
    half: f32,
    texels: Vec<Texel>,
}

impl TexelMap {
    /// Samples `material(x, y)` at the centres of an n×n grid over a sample `size` mm across.
    pub(super) fn build(
        n: usize,
        size: f32,
        material: impl Fn(f32, f32) -> Material + Sync,
    ) -> TexelMap {
        let n = n.max(1);
        let cell = size / n as f32;
        let origin = -0.5 * size;
        let texels = (0..n * n)
            .into_par_iter()
            .map(|k| {
                let x = origin + ((k % n) as f32 + 0.5) * cell;
                let y = origin + ((k / n) as f32 + 0.5) * cell;
                Texel::encode(&material(x, y))
            })
            .collect();
        TexelMap {
            n,
            cell,
            half: 0.5 * size,
            texels,
        }
    }

    /// The material of the texel containing (x, y) (edge texels extend outwards).
    pub(super) fn at(&self, x: f32, y: f32) -> Option<Material> {
        let last = self.n - 1;
        let index = |c: f32| (((c + self.half) / self.cell).max(0.0) as usize).min(last);
        self.texels
            .get(index(y) * self.n + index(x))
            .map(Texel::decode)
    }

    /// Largest ks over all texels.
    pub(super) fn max_ks(&self) -> f32 {
        self.texels.iter().map(|t| t.ks).max().unwrap_or(0) as f32 / 255.0
    }

    /// Largest transmittance (any channel) over all texels.
    pub(super) fn max_transmittance(&self) -> f32 {
        let max = self.texels.iter().flat_map(|t| t.trans).max().unwrap_or(0);
        max as f32 / 255.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::material::Model;

    #[test]
    fn a_texel_is_16_bytes() {
        assert_eq!(std::mem::size_of::<Texel>(), 16);
    }

    #[test]
    fn every_field_round_trips_within_its_quantum() {
        let m = Material {
            model: Model::WardAniso,
            albedo: Vec3A::new(0.1, 0.5, 0.9),
            ks: 0.3,
            alpha: 0.0447,
            alpha_y: 0.31,
            tangent_rad: 2.0,
            transmittance: Vec3A::new(0.0, 0.2, 0.85),
            medium: 2,
            meso_in: 0.4,
            meso_out: 1.0,
        };
        let d = Texel::encode(&m).decode();
        assert_eq!(d.model, Model::WardAniso);
        assert_eq!(d.medium, 2);
        assert!((d.albedo - m.albedo).abs().max_element() <= 0.5 / 255.0 + 1e-6);
        assert!((d.transmittance - m.transmittance).abs().max_element() <= 0.5 / 255.0 + 1e-6);
        assert!((d.ks - m.ks).abs() <= 0.5 / 255.0 + 1e-6);
        assert!((d.alpha - m.alpha).abs() <= 0.5 / 65535.0 + 1e-7);
        assert!((d.alpha_y - m.alpha_y).abs() <= 0.5 / 65535.0 + 1e-7);
        assert!((d.tangent_rad - m.tangent_rad).abs() <= PI / 512.0 + 1e-6);
        assert!((d.meso_in - 0.4).abs() <= 0.5 / 255.0 + 1e-6);
        assert_eq!(d.meso_out, 1.0);
        // The tangent is stored modulo a half-turn.
        let flipped = Material {
            tangent_rad: 2.0 - PI,
            ..m
        };
        assert_eq!(Texel::encode(&flipped).tangent, Texel::encode(&m).tangent);
    }
}
