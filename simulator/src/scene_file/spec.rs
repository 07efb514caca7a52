//! The scene file schema as written in TOML. Every table rejects unknown keys; values are
//! range-checked by [`super::load`], which also resolves names and loads referenced files.

use crate::render::quality::SimKnobs;
use serde::Deserialize;

/// A whole scene file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// Name and purpose.
    pub scene: SceneInfo,
    /// The sample's size and relief.
    pub sample: SampleSpec,
    /// Reflectance; without it a procedural shape keeps its built-in materials.
    #[serde(default)]
    pub material: Option<MaterialSpec>,
    /// Quality preset and knobs frames of this scene are rendered with.
    #[serde(default)]
    pub render: Option<RenderSpec>,
}

/// `[scene]`: what this sample is.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneInfo {
    /// Short name, recorded with datasets.
    pub name: String,
    /// One or two sentences on what the scene is for.
    #[serde(default)]
    pub description: String,
}

/// `[sample]`: the square sample's edge length, relief shape and the shape's parameters.
/// Parameters that do not belong to the chosen shape are rejected.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleSpec {
    /// Edge length in mm; the rig's `sim.sample_size_mm` when absent.
    pub size_mm: Option<f64>,
    /// flat, bumps, steps, weave, checkerboard, colorchecker, planes, height_image, mesh,
    /// grooves or bowl.
    pub shape: String,
    /// bumps: tallest bump in mm (default 3).
    pub max_height_mm: Option<f64>,
    /// bumps: layout seed.
    pub seed: Option<i64>,
    /// steps: rise of each terrace in mm (default 1.5).
    pub step_height_mm: Option<f64>,
    /// checkerboard: square edge in mm (default 10).
    pub square_mm: Option<f64>,
    /// planes: height of the raised plane in mm (default 20).
    pub step_mm: Option<f64>,
    /// height_image: a 16-bit greyscale PNG; mesh: a Wavefront OBJ. Relative to the scene file.
    pub path: Option<String>,
    /// height_image: height of full white in mm.
    pub height_scale_mm: Option<f64>,
    /// mesh: millimetres per OBJ unit (default 1).
    pub scale: Option<f64>,
    /// grooves: groove pitch in mm (default 10).
    pub pitch_mm: Option<f64>,
    /// grooves, bowl: depth in mm.
    pub depth_mm: Option<f64>,
    /// bowl: radius of the opening in mm.
    pub radius_mm: Option<f64>,
}

/// `[material]`: one reflectance model for the whole sample, each parameter a constant or a
/// PNG map over the sample's footprint.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// lambert, ward, ward_aniso, blinn_phong or ggx.
    pub model: String,
    /// Diffuse albedo ρd, linear RGB in [0, 1].
    pub albedo: Option<[f64; 3]>,
    /// Diffuse albedo map (8-bit sRGB or 16-bit linear PNG).
    pub albedo_map: Option<String>,
    /// Specular albedo ρs (Ward, Blinn–Phong) or F0 (GGX), in [0, 1].
    pub ks: Option<f64>,
    /// Greyscale map of `ks`.
    pub ks_map: Option<String>,
    /// Roughness α (Ward αx, GGX α), in (0, 1].
    pub alpha: Option<f64>,
    /// Greyscale map of `alpha`.
    pub alpha_map: Option<String>,
    /// ward_aniso: roughness across the tangent αy, in (0, 1].
    pub alpha_y: Option<f64>,
    /// ward_aniso: tangent direction in degrees from +x.
    pub tangent_deg: Option<f64>,
    /// blinn_phong: exponent n > 0 (α = √(2/(n+2))).
    pub exponent: Option<f64>,
    /// Fraction of the backlight passing through, linear RGB in [0, 1].
    pub transmittance: Option<[f64; 3]>,
    /// A homogeneous scattering medium under the surface (dipole).
    pub subsurface: Option<SubsurfaceSpec>,
    /// Quasi-homogeneous mesostructure modulating the medium's entrance and exit.
    pub meso: Option<MesoSpec>,
}

/// `[material.subsurface]`: dipole medium coefficients per RGB channel.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubsurfaceSpec {
    /// Absorption σa in 1/mm, ≥ 0.
    pub sigma_a: [f64; 3],
    /// Reduced scattering σ′s in 1/mm, > 0.
    pub sigma_s_prime: [f64; 3],
    /// Relative index of refraction η > 0.
    pub eta: f64,
}

/// `[material.meso]`: entrance and exit functions, from greyscale maps or procedural.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MesoSpec {
    /// Greyscale map of the entrance function (fraction in [0, 1]).
    pub entrance_map: Option<String>,
    /// Greyscale map of the exit function (fraction in [0, 1]).
    pub exit_map: Option<String>,
    /// `relief` (lower in the relief's hollows) or `noise` (value noise).
    pub procedural: Option<String>,
    /// Procedural: how far the functions dip below 1, in [0, 1] (default 0.5).
    pub contrast: Option<f64>,
    /// Procedural noise: feature size in mm (default 2).
    pub scale_mm: Option<f64>,
}

/// `[render]`: how frames of this scene are rendered, on top of the rig's `[sim]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSpec {
    /// preview, standard or reference; the rig's `sim.quality` when absent.
    pub quality: Option<String>,
    /// Single knobs overriding the preset, as in a rig's `[sim.knobs]`.
    #[serde(default)]
    pub knobs: Option<SimKnobs>,
}
