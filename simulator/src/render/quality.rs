//! Quality presets: how many samples per pixel and per light the renderer spends.

use super::error::RenderError;

/// The rig's `sim.quality` preset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// 1 sample per pixel, halogen lamps as point lights: fast frames for scripting.
    Preview,
    /// 4 stratified samples per pixel, lamps as 10 mm disks.
    Standard,
    /// 16 stratified samples per pixel, more light samples.
    Reference,
}

impl Quality {
    /// Parses the rig's preset name.
    pub fn parse(name: &str) -> Result<Quality, RenderError> {
        match name {
            "preview" => Ok(Quality::Preview),
            "standard" => Ok(Quality::Standard),
            "reference" => Ok(Quality::Reference),
            other => Err(RenderError::UnknownQuality(other.to_string())),
        }
    }

    /// The preset's name as written in rig files.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Preview => "preview",
            Quality::Standard => "standard",
            Quality::Reference => "reference",
        }
    }

    /// Side of the square grid of stratified sub-pixel samples.
    pub fn grid_side(self) -> u32 {
        match self {
            Quality::Preview => 1,
            Quality::Standard => 2,
            Quality::Reference => 4,
        }
    }

    /// Samples per pixel.
    pub fn spp(self) -> u32 {
        self.grid_side() * self.grid_side()
    }

    /// Points on a halogen lamp's disk per pixel, spread over the pixel's sub-samples
    /// (1 means a point light at the disk centre).
    pub fn halogen_samples(self) -> u32 {
        match self {
            Quality::Preview => 1,
            Quality::Standard => 4,
            Quality::Reference => 16,
        }
    }

    /// Spacing of the relief grid and material texels in mm: preview trades detail finer
    /// than two camera pixels for speed.
    pub fn relief_mm(self) -> f32 {
        match self {
            Quality::Preview => 0.2,
            Quality::Standard | Quality::Reference => 0.1,
        }
    }

    /// Points along the reflectometer tube per pixel, spread over the pixel's sub-samples.
    pub fn tube_samples(self) -> u32 {
        match self {
            Quality::Preview => 16,
            Quality::Standard => 32,
            Quality::Reference => 64,
        }
    }
}
