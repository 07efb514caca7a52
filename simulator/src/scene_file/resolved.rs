//! A checked scene with its defaults filled in and its referenced files loaded: what the
//! renderer builds a [`crate::render::sample::Sample`] from.

use std::path::PathBuf;

use crate::render::quality::SimKnobs;
use glam::Vec3A;

use super::image::ImageMap;
use super::mesh::Mesh;
use crate::render::material::{Medium, Model};
use crate::render::quality::Quality;

/// Where a sample's scene came from, so datasets can record it verbatim.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneSource {
    /// The scene's `[scene] name`.
    pub name: String,
    /// The scene file on disk; `None` for a built-in scene.
    pub path: Option<PathBuf>,
    /// The scene file's full text.
    pub text: String,
}

/// A loaded scene.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name, path and text of the file.
    pub source: SceneSource,
    /// The `[scene] description`.
    pub description: String,
    /// Edge length in mm, if the scene sets one (else the rig's).
    pub size_mm: Option<f32>,
    /// The relief.
    pub shape: Shape,
    /// The scene's material; `None` keeps a procedural shape's built-in materials.
    pub material: Option<SceneMaterial>,
    /// `[render] quality`, if set.
    pub quality: Option<Quality>,
    /// `[render.knobs]`, if set.
    pub knobs: Option<SimKnobs>,
}

/// A relief with its parameters (defaults applied).
#[derive(Debug, Clone)]
pub enum Shape {
    /// z = 0 everywhere.
    Flat,
    /// Smooth bumps on a jittered 10 mm lattice.
    Bumps {
        /// Tallest possible bump in mm.
        max_height_mm: f32,
        /// Layout seed.
        seed: u64,
    },
    /// Five concentric square terraces.
    Steps {
        /// Rise of each terrace in mm.
        step_height_mm: f32,
    },
    /// Over-under woven strands with see-through gaps.
    Weave,
    /// Flat black and white squares.
    Checkerboard {
        /// Square edge in mm.
        square_mm: f32,
    },
    /// Flat 6×4 colour checker.
    ColorChecker,
    /// Two planes at 0 and `step_mm` (y > 0 raised).
    Planes {
        /// Height of the raised plane in mm.
        step_mm: f32,
    },
    /// A 16-bit greyscale height image over the footprint.
    HeightImage {
        /// Decoded heights in [0, 1].
        image: ImageMap,
        /// Height of full white in mm.
        height_scale_mm: f32,
    },
    /// An OBJ mesh rasterised top-down.
    Mesh {
        /// The triangles, in file units.
        mesh: Mesh,
        /// Millimetres per file unit.
        scale: f32,
    },
    /// Parallel V-grooves along y: ridges at `depth_mm`, groove bottoms at 0.
    Grooves {
        /// Ridge-to-ridge distance in mm.
        pitch_mm: f32,
        /// Groove depth in mm.
        depth_mm: f32,
    },
    /// A block `depth_mm` high with a spherical-cap bowl of opening radius `radius_mm`
    /// sunk into its centre down to z = 0.
    Bowl {
        /// Radius of the opening in mm.
        radius_mm: f32,
        /// Depth in mm (at most the radius).
        depth_mm: f32,
    },
}

impl Shape {
    /// The shape's name in scene files.
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Flat => "flat",
            Shape::Bumps { .. } => "bumps",
            Shape::Steps { .. } => "steps",
            Shape::Weave => "weave",
            Shape::Checkerboard { .. } => "checkerboard",
            Shape::ColorChecker => "colorchecker",
            Shape::Planes { .. } => "planes",
            Shape::HeightImage { .. } => "height_image",
            Shape::Mesh { .. } => "mesh",
            Shape::Grooves { .. } => "grooves",
            Shape::Bowl { .. } => "bowl",
        }
    }
}

/// A material parameter: one value for the whole sample or a map over its footprint.
#[derive(Debug, Clone)]
pub enum Param<T> {
    /// The same everywhere.
    Const(T),
    /// From an image (colour maps RGB, scalar maps greyscale).
    Map(ImageMap),
}

/// The scene's `[material]`, checked, with defaults and maps loaded.
#[derive(Debug, Clone)]
pub struct SceneMaterial {
    /// The specular model.
    pub model: Model,
    /// Diffuse albedo ρd.
    pub albedo: Param<Vec3A>,
    /// Specular albedo or F0.
    pub ks: Param<f32>,
    /// Roughness α (αx for ward_aniso; converted from the exponent for blinn_phong).
    pub alpha: Param<f32>,
    /// ward_aniso αy; `None` means equal to α.
    pub alpha_y: Option<f32>,
    /// Anisotropy tangent, radians from +x.
    pub tangent_rad: f32,
    /// Backlight transmittance.
    pub transmittance: Vec3A,
    /// The subsurface medium, if any.
    pub medium: Option<Medium>,
    /// Quasi-homogeneous entrance and exit functions, if any.
    pub meso: Option<Meso>,
}

/// How the quasi-homogeneous entrance and exit functions vary over the sample.
#[derive(Debug, Clone)]
pub enum Meso {
    /// From greyscale maps; a missing map means 1 everywhere.
    Maps {
        /// Entrance function map.
        entrance: Option<ImageMap>,
        /// Exit function map.
        exit: Option<ImageMap>,
    },
    /// 1 on the relief's highest points, 1 − contrast in its lowest.
    Relief {
        /// Depth of the dip, in [0, 1].
        contrast: f32,
    },
    /// Smooth value noise between 1 − contrast and 1 (entrance and exit independent).
    Noise {
        /// Depth of the dip, in [0, 1].
        contrast: f32,
        /// Feature size in mm.
        scale_mm: f32,
    },
}
