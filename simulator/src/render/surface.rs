//! What the light-transport passes (subsurface, interreflection) need of a sample: its extent,
//! relief, materials and subsurface media, behind one trait so the passes can be tested on
//! synthetic surfaces as well as run on built [`Sample`]s.

use glam::Vec3A;

use super::heightfield::HeightGrid;
use super::material::{Material, Medium};
use super::sample::Sample;

/// A square sample, `size_mm` on a side and centred on the origin, seen from above.
pub trait Surface: Sync {
    /// Fixture name (for the notes).
    fn name(&self) -> &str;
    /// Edge length in mm.
    fn size_mm(&self) -> f32;
    /// The relief, `None` when exactly flat (z = 0).
    fn grid(&self) -> Option<&HeightGrid>;
    /// The material at (x, y).
    fn material_at(&self, x: f32, y: f32) -> Material;
    /// The subsurface media that materials reference (`Material::medium` = index + 1).
    fn media(&self) -> &[Medium];

    /// Surface point and shading normal at (x, y).
    fn point(&self, x: f32, y: f32) -> (Vec3A, Vec3A) {
        match self.grid() {
            Some(g) => (Vec3A::new(x, y, g.height_at(x, y)), g.normal_at(x, y)),
            None => (Vec3A::new(x, y, 0.0), Vec3A::Z),
        }
    }
}

impl Surface for Sample {
    fn name(&self) -> &str {
        &self.name
    }
    fn size_mm(&self) -> f32 {
        self.size_mm
    }
    fn grid(&self) -> Option<&HeightGrid> {
        self.grid.as_ref()
    }
    fn material_at(&self, x: f32, y: f32) -> Material {
        Sample::material_at(self, x, y)
    }
    fn media(&self) -> &[Medium] {
        &self.media
    }
}
