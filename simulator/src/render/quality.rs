//! Accuracy knobs and the presets that set them: how many samples per pixel and per light the
//! renderer spends, how many interreflection bounces it follows, how finely it resolves relief
//! and subsurface transport. Every knob trades render time for error; `stagehand sim tradeoff`
//! measures each one.

use serde::{Deserialize, Serialize};

use super::error::RenderError;

/// A named preset (`sim.quality` in rig and scene files).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// 1 sample per pixel, halogen lamps as point lights, per-vertex shadow maps: fast
    /// frames for scripting.
    Preview,
    /// 4 stratified samples per pixel, lamps as 10 mm disks, exact shadow rays.
    Standard,
    /// 16 stratified samples per pixel, more light, bounce and subsurface samples.
    Reference,
}

impl Quality {
    /// Every preset, fastest first.
    pub const ALL: [Quality; 3] = [Quality::Preview, Quality::Standard, Quality::Reference];

    /// The preset names for a sentence: `preview, standard or reference`.
    pub fn names() -> String {
        let names = Self::ALL.map(Quality::name);
        let (last, rest) = names.split_last().unwrap_or((&"", &[]));
        format!("{} or {last}", rest.join(", "))
    }

    /// Parses the preset name.
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

    /// The knob settings of this preset.
    pub fn knobs(self) -> Knobs {
        match self {
            Quality::Preview => Knobs {
                preset: self.name().into(),
                spp_side: 1,
                halogen_samples: 1,
                tube_samples: 16,
                bounces: 1,
                bounce_rays: 8,
                bounce_tolerance: 0.02,
                relief_mm: 0.2,
                shadow_maps: true,
                dipole_samples: 8,
                adaptive_threshold: 0.0,
            },
            Quality::Standard => Knobs {
                preset: self.name().into(),
                spp_side: 2,
                halogen_samples: 4,
                tube_samples: 32,
                bounces: 1,
                bounce_rays: 16,
                bounce_tolerance: 0.01,
                relief_mm: 0.1,
                shadow_maps: false,
                dipole_samples: 16,
                adaptive_threshold: 0.0,
            },
            Quality::Reference => Knobs {
                preset: self.name().into(),
                spp_side: 4,
                halogen_samples: 16,
                tube_samples: 64,
                bounces: 2,
                bounce_rays: 64,
                bounce_tolerance: 0.002,
                relief_mm: 0.1,
                shadow_maps: false,
                dipole_samples: 32,
                adaptive_threshold: 0.0,
            },
        }
    }
}

/// Overrides of the renderer's accuracy knobs (a rig's `[sim.knobs]`, a scene's
/// `[render.knobs]`); each unset knob keeps the preset's value. Each field is the [`Knobs`]
/// field of the same name; an unknown key or a wrong type is an error at file:line:col.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimKnobs {
    /// Side of the stratified sub-pixel grid (samples per pixel = side²).
    pub spp_side: Option<u32>,
    /// Points on each halogen lamp's disk per pixel (1 = point light).
    pub halogen_samples: Option<u32>,
    /// Points along the reflectometer tube per pixel.
    pub tube_samples: Option<u32>,
    /// Most interreflection bounces.
    pub bounces: Option<u32>,
    /// Hemisphere rays per relief texel per bounce.
    pub bounce_rays: Option<u32>,
    /// Relative bound below which a bounce is skipped.
    pub bounce_tolerance: Option<f32>,
    /// Relief grid and march step in mm.
    pub relief_mm: Option<f32>,
    /// Per-vertex shadow maps instead of exact shadow rays.
    pub shadow_maps: Option<bool>,
    /// Dipole kernel samples per mean free path.
    pub dipole_samples: Option<u32>,
    /// Adaptive sampling's contrast threshold (0 = every pixel at `spp_side`²).
    pub adaptive_threshold: Option<f32>,
}

/// Every accuracy knob of the renderer. Start from a preset ([`Quality::knobs`]) and
/// override single knobs in the rig's or scene's `[sim.knobs]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Knobs {
    /// The preset these knobs started from (recorded in frame notes).
    #[serde(default = "default_preset")]
    pub preset: String,
    /// Side of the stratified sub-pixel grid: samples per pixel = side².
    pub spp_side: u32,
    /// Points on a halogen lamp's 10 mm disk per pixel (1 = a point light at its centre).
    pub halogen_samples: u32,
    /// Points along the reflectometer tube per pixel.
    pub tube_samples: u32,
    /// Most interreflection bounces followed (the effect plan may need fewer).
    pub bounces: u32,
    /// Hemisphere rays per relief texel per bounce.
    pub bounce_rays: u32,
    /// A bounce is simulated only if its bound on added radiance, relative to direct light,
    /// exceeds this.
    pub bounce_tolerance: f32,
    /// Spacing of the relief grid and material texels in mm: the height-field march resolves
    /// relief at this step (cells are intersected exactly, so it is the only march step).
    pub relief_mm: f32,
    /// Shadows from per-vertex visibility maps toward each light position (interpolated,
    /// fast) instead of one exact shadow ray per light sample.
    pub shadow_maps: bool,
    /// Radial samples of the dipole kernel per mean free path (subsurface integration
    /// resolution).
    pub dipole_samples: u32,
    /// Adaptive sampling: 0 renders every pixel with `spp_side`² samples; above 0, every
    /// pixel first takes one sample at its centre, and only pixels differing from a
    /// 4-neighbour by more than this fraction of the frame's mean radiance (edges, shadow
    /// boundaries, texture) are rendered with `spp_side`², where aliasing error lives.
    #[serde(default)]
    pub adaptive_threshold: f32,
}

fn default_preset() -> String {
    "custom".into()
}

/// Largest value accepted for the sample-count knobs (bounds render time and memory).
pub const MAX_SAMPLES: u32 = 4096;

impl Knobs {
    /// These knobs with every knob set in `overrides` replaced, then validated. The preset
    /// name becomes `"<preset>+custom"` when anything changed.
    pub fn with(mut self, overrides: &SimKnobs) -> Result<Knobs, RenderError> {
        let before = self.clone();
        let SimKnobs {
            spp_side,
            halogen_samples,
            tube_samples,
            bounces,
            bounce_rays,
            bounce_tolerance,
            relief_mm,
            shadow_maps,
            dipole_samples,
            adaptive_threshold,
        } = overrides.clone();
        self.spp_side = spp_side.unwrap_or(self.spp_side);
        self.halogen_samples = halogen_samples.unwrap_or(self.halogen_samples);
        self.tube_samples = tube_samples.unwrap_or(self.tube_samples);
        self.bounces = bounces.unwrap_or(self.bounces);
        self.bounce_rays = bounce_rays.unwrap_or(self.bounce_rays);
        self.bounce_tolerance = bounce_tolerance.unwrap_or(self.bounce_tolerance);
        self.relief_mm = relief_mm.unwrap_or(self.relief_mm);
        self.shadow_maps = shadow_maps.unwrap_or(self.shadow_maps);
        self.dipole_samples = dipole_samples.unwrap_or(self.dipole_samples);
        self.adaptive_threshold = adaptive_threshold.unwrap_or(self.adaptive_threshold);
        if self != before && !self.preset.ends_with("+custom") {
            self.preset.push_str("+custom");
        }
        self.validate()?;
        Ok(self)
    }

    /// Samples per pixel.
    pub fn spp(&self) -> u32 {
        self.spp_side * self.spp_side
    }

    /// Checks every knob is in range; the error names the knob and the range.
    pub fn validate(&self) -> Result<(), RenderError> {
        let count = |name: &'static str, v: u32, lo: u32, hi: u32| {
            if (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(RenderError::InvalidKnob {
                    knob: name,
                    expected: format!("an integer from {lo} to {hi}"),
                    got: v.to_string(),
                })
            }
        };
        count("spp_side", self.spp_side, 1, 64)?;
        count("halogen_samples", self.halogen_samples, 1, MAX_SAMPLES)?;
        count("tube_samples", self.tube_samples, 1, MAX_SAMPLES)?;
        count("bounces", self.bounces, 0, 8)?;
        count("bounce_rays", self.bounce_rays, 1, MAX_SAMPLES)?;
        count("dipole_samples", self.dipole_samples, 1, 1024)?;
        if !(self.bounce_tolerance.is_finite() && (0.0..=1.0).contains(&self.bounce_tolerance)) {
            return Err(RenderError::InvalidKnob {
                knob: "bounce_tolerance",
                expected: "a fraction from 0 to 1".into(),
                got: self.bounce_tolerance.to_string(),
            });
        }
        if !(self.adaptive_threshold.is_finite() && (0.0..=1.0).contains(&self.adaptive_threshold))
        {
            return Err(RenderError::InvalidKnob {
                knob: "adaptive_threshold",
                expected: "a fraction of the mean radiance from 0 (off) to 1".into(),
                got: self.adaptive_threshold.to_string(),
            });
        }
        if !(self.relief_mm.is_finite() && (0.01..=5.0).contains(&self.relief_mm)) {
            return Err(RenderError::InvalidKnob {
                knob: "relief_mm",
                expected: "a spacing from 0.01 to 5 mm".into(),
                got: self.relief_mm.to_string(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_ordered() {
        let [p, s, r] =
            [Quality::Preview, Quality::Standard, Quality::Reference].map(Quality::knobs);
        for k in [&p, &s, &r] {
            k.validate().expect("preset knobs valid");
        }
        assert!(p.spp() < s.spp() && s.spp() < r.spp());
        assert!(p.halogen_samples < s.halogen_samples && s.halogen_samples < r.halogen_samples);
        assert!(r.bounces >= s.bounces && r.dipole_samples > s.dipole_samples);
    }

    #[test]
    fn out_of_range_knob_is_named() {
        let mut k = Quality::Standard.knobs();
        k.spp_side = 0;
        let e = k.validate().expect_err("0 spp rejected").to_string();
        assert!(e.contains("spp_side") && e.contains("1 to 64"), "{e}");
        for bad in [f32::NAN, -0.1, 2.0] {
            let mut k = Quality::Standard.knobs();
            k.adaptive_threshold = bad;
            let e = k.validate().expect_err("out of range").to_string();
            assert!(e.contains("adaptive_threshold"), "{e}");
        }
        let mut k = Quality::Standard.knobs();
        k.relief_mm = f32::NAN;
        assert!(
            k.validate()
                .expect_err("NaN")
                .to_string()
                .contains("relief_mm")
        );
    }

    #[test]
    fn overrides_replace_single_knobs() {
        let k = Quality::Preview
            .knobs()
            .with(&SimKnobs {
                bounces: Some(3),
                ..SimKnobs::default()
            })
            .expect("valid");
        assert_eq!(k.bounces, 3);
        assert_eq!(k.spp_side, 1);
        assert_eq!(k.preset, "preview+custom");
        let same = Quality::Preview
            .knobs()
            .with(&SimKnobs::default())
            .expect("valid");
        assert_eq!(same, Quality::Preview.knobs());
        let bad = SimKnobs {
            spp_side: Some(100),
            ..SimKnobs::default()
        };
        assert!(Quality::Preview.knobs().with(&bad).is_err());
    }
}
