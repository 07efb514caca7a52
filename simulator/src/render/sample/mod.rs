//! Samples on the turntable, built from scene files (see [`crate::scene_file`]): their relief
//! (a height field, or exactly flat), their materials (any [`Material`], quantised per texel
//! where they vary) and the subsurface media beneath them.
//!
//! One concept per file: `procedural` (the bumps, steps and weave fixtures), `charts`
//! (checkerboard and colour checker), `relief` (height grids of every shape), `painted`
//! (scene materials at a point), `texel` (the quantised store), `noise` and `knobs` (a
//! scene's `[render]` settings).

mod charts;
mod knobs;
mod noise;
mod painted;
mod procedural;
mod relief;
mod texel;

use crate::render::quality::SimKnobs;

pub use super::material::{Material, Medium};
pub use crate::scene_file::builtin::FIXTURES;
pub use charts::{colorchecker_patch, colorchecker_patch_centre, srgb_to_linear};
pub use knobs::scene_knobs;
pub use procedural::BUMPS_SEED;

use super::error::RenderError;
use super::heightfield::HeightGrid;
use super::quality::{Knobs, Quality};
use crate::scene_file::{Scene, SceneSource, Shape, resolve_fixture};
use charts::{checkerboard, colorchecker};
use procedural::{FLAT, PLANE, Procedural, Relief};
use texel::TexelMap;

/// Finest relief and texel spacing, in mm (about one pixel of the light stage cameras).
const TEXEL_MM: f32 = 0.1;
/// Most cells per side, to bound memory and build time for large samples.
const MAX_CELLS: usize = 1024;
/// Material of shapes without built-in materials when the scene has no `[material]`.
const DEFAULT: Material = Material::grey(0.5);

/// Which shape the sample's relief has (the scene's `[sample] shape`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// z = 0, grey Lambert 0.5 with a weak Ward lobe.
    Flat,
    /// Smooth coloured bumps up to 3 mm.
    Bumps,
    /// Concentric square terraces.
    Steps,
    /// Over-under woven straw strands with see-through gaps.
    Weave,
    /// Flat 10 mm black and white squares.
    Checkerboard,
    /// Flat 6×4 colour checker.
    ColorChecker,
    /// Two matte white planes at 0 and 20 mm (y > 0 raised), for laser-plane calibration.
    Planes,
    /// A 16-bit greyscale height image.
    HeightImage,
    /// A Wavefront OBJ mesh seen from above.
    Mesh,
    /// Parallel V-grooves.
    Grooves,
    /// A spherical bowl sunk into a block.
    Bowl,
}

impl Kind {
    fn of(shape: &Shape) -> Kind {
        match shape {
            Shape::Flat => Kind::Flat,
            Shape::Bumps { .. } => Kind::Bumps,
            Shape::Steps { .. } => Kind::Steps,
            Shape::Weave => Kind::Weave,
            Shape::Checkerboard { .. } => Kind::Checkerboard,
            Shape::ColorChecker => Kind::ColorChecker,
            Shape::Planes { .. } => Kind::Planes,
            Shape::HeightImage { .. } => Kind::HeightImage,
            Shape::Mesh { .. } => Kind::Mesh,
            Shape::Grooves { .. } => Kind::Grooves,
            Shape::Bowl { .. } => Kind::Bowl,
        }
    }
}

/// How [`Sample::material_at`] finds a point's material.
#[derive(Debug)]
enum Surface {
    /// One exact material everywhere.
    Uniform(Material),
    /// The analytic checkerboard with squares of this edge in mm.
    Checkerboard(f32),
    /// The analytic colour checker.
    ColorChecker,
    /// Quantised per-texel materials.
    Texels(TexelMap),
}

/// A built sample: square, `size_mm` on a side, centred on the turntable.
#[derive(Debug)]
pub struct Sample {
    /// The fixture name it was built for (a built-in scene's name or a scene file's path);
    /// unique per scene, so caches key on it.
    pub name: String,
    /// Which shape its relief has.
    pub kind: Kind,
    /// Edge length in mm.
    pub size_mm: f32,
    /// The relief; `None` for exactly flat samples (z = 0 everywhere, no shadow rays ever).
    pub grid: Option<HeightGrid>,
    surface: Surface,
    /// Subsurface media; a material's `medium` is an index into this plus one.
    pub media: Vec<Medium>,
    /// Largest specular albedo ρs (or F0) anywhere on the sample.
    pub max_ks: f32,
    /// Largest transmittance (any channel) anywhere on the sample.
    pub max_transmittance: f32,
    /// The scene's `[render] quality`, if it sets one.
    pub quality: Option<Quality>,
    /// The scene's `[render.knobs]`, if it sets any.
    pub knobs: Option<SimKnobs>,
    /// The knobs frames of this sample are rendered with, resolved by the renderer from the
    /// rig and the scene's `[render]`; `None` means the renderer's own.
    pub render_knobs: Option<Knobs>,
    /// The scene file it was built from, for datasets to record.
    pub source: SceneSource,
}

impl Sample {
    /// Builds the fixture `name` (a built-in scene or the path of a scene file ending in
    /// `.toml`), `size_mm` across unless the scene sets its size, with relief and materials
    /// sampled every `step_mm` (at least 0.1 mm).
    pub fn build(name: &str, size_mm: f32, step_mm: f32) -> Result<Sample, RenderError> {
        let scene =
            resolve_fixture(name)?.ok_or_else(|| RenderError::UnknownFixture(name.to_string()))?;
        Ok(Sample::from_scene(name, scene, size_mm, step_mm))
    }

    /// Builds a loaded scene as fixture `name`; `size_mm` applies when the scene sets no size.
    pub fn from_scene(name: &str, scene: Scene, size_mm: f32, step_mm: f32) -> Sample {
        let size = scene.size_mm.unwrap_or(size_mm);
        let n = cells(size, step_mm);
        let procedural = match scene.shape {
            Shape::Bumps {
                max_height_mm,
                seed,
            } => Some(Relief::Bumps {
                max_height_mm,
                seed,
            }),
            Shape::Steps { step_height_mm } => Some(Relief::Steps { step_height_mm }),
            Shape::Weave => Some(Relief::Weave),
            _ => None,
        }
        .map(|relief| Procedural::new(relief, size));
        let grid = relief::grid(&scene.shape, n, size, procedural.as_ref());
        let surface = match (&scene.material, &procedural, &scene.shape) {
            (Some(m), _, _) if painted::is_uniform(m) => {
                Surface::Uniform(painted::paint(m, size, 0.0, 0.0, 1.0))
            }
            (Some(m), _, _) => {
                let top = grid.as_ref().map_or(0.0, HeightGrid::zmax);
                let relief = |x, y| match &grid {
                    Some(g) if top > 0.0 => g.height_at(x, y) / top,
                    _ => 1.0,
                };
                Surface::Texels(TexelMap::build(n, size, |x, y| {
                    painted::paint(m, size, x, y, relief(x, y))
                }))
            }
            (None, Some(model), _) => {
                Surface::Texels(TexelMap::build(n, size, |x, y| model.material(x, y)))
            }
            (None, None, Shape::Flat) => Surface::Uniform(FLAT),
            (None, None, Shape::Planes { .. }) => Surface::Uniform(PLANE),
            (None, None, Shape::Checkerboard { square_mm }) => Surface::Checkerboard(*square_mm),
            (None, None, Shape::ColorChecker) => Surface::ColorChecker,
            (None, None, _) => Surface::Uniform(DEFAULT),
        };
        let (max_ks, max_transmittance) = match &surface {
            Surface::Uniform(m) => (
                if m.has_specular() { m.ks } else { 0.0 },
                m.transmittance.max_element(),
            ),
            Surface::Checkerboard(_) | Surface::ColorChecker => (0.0, 0.0),
            Surface::Texels(t) => (t.max_ks(), t.max_transmittance()),
        };
        Sample {
            name: name.to_string(),
            kind: Kind::of(&scene.shape),
            size_mm: size,
            grid,
            surface,
            media: scene.material.and_then(|m| m.medium).into_iter().collect(),
            max_ks,
            max_transmittance,
            quality: scene.quality,
            knobs: scene.knobs,
            render_knobs: None,
            source: scene.source,
        }
    }

    /// Whether (x, y) lies on the sample's square footprint.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let h = 0.5 * self.size_mm;
        x.abs() <= h && y.abs() <= h
    }

    /// The material at (x, y) on the sample.
    pub fn material_at(&self, x: f32, y: f32) -> Material {
        match &self.surface {
            Surface::Uniform(m) => *m,
            Surface::Checkerboard(square) => checkerboard(*square, x, y),
            Surface::ColorChecker => colorchecker(self.size_mm, x, y),
            Surface::Texels(t) => t.at(x, y).unwrap_or(FLAT),
        }
    }

    /// Surface height at (x, y).
    pub fn height_at(&self, x: f32, y: f32) -> f32 {
        self.grid.as_ref().map_or(0.0, |g| g.height_at(x, y))
    }
}

/// Cells per side for a sample of `size` mm sampled every `step` mm.
fn cells(size: f32, step: f32) -> usize {
    ((size / step.max(TEXEL_MM)).ceil() as usize).clamp(16, MAX_CELLS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_fixture_builds_and_unknown_does_not() {
        for name in FIXTURES {
            if let Err(e) = Sample::build(name, 80.0, 0.2) {
                panic!("{name}: {e}");
            }
        }
        let e = Sample::build("teapot", 80.0, 0.2).expect_err("unknown");
        assert!(matches!(e, RenderError::UnknownFixture(_)), "{e}");
    }

    #[test]
    fn reliefs_have_the_documented_shape() {
        let flat = Sample::build("flat", 80.0, 0.1).expect("flat");
        assert!(flat.grid.is_none());
        let bumps = Sample::build("bumps", 80.0, 0.1).expect("bumps");
        let g = bumps.grid.as_ref().expect("grid");
        assert!(g.zmax() > 1.0 && g.zmax() < 6.0, "bumps zmax {}", g.zmax());
        assert_eq!(g.edge_max(), 0.0, "bumps meet the turntable at height 0");
        let planes = Sample::build("planes", 80.0, 0.2).expect("planes");
        assert_eq!(planes.height_at(0.0, 20.0), 20.0);
        assert_eq!(planes.height_at(0.0, -20.0), 0.0);
        let weave = Sample::build("weave", 80.0, 0.2).expect("weave");
        assert!(weave.max_transmittance > 0.5);
        let steps = Sample::build("steps", 80.0, 0.2).expect("steps");
        assert_eq!(steps.height_at(0.0, 0.0), 7.5);
        assert_eq!(steps.height_at(39.0, 0.0), 1.5);
    }
}
