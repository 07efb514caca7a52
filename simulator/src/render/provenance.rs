//! What a dataset records about how its frames were simulated: the accuracy knobs frames of a
//! fixture are rendered with (the rig's `sim.quality` and `[sim.knobs]`, with the scene's
//! `[render]` settings applied) and the scene the fixture stands for, verbatim.

use std::path::PathBuf;

use super::quality::Knobs;
use super::{RenderError, Renderer};

/// How frames of one fixture are simulated.
#[derive(Debug, Clone, PartialEq)]
pub struct Provenance {
    /// The fixture name (or scene file path) as the rig or script gave it.
    pub fixture: String,
    /// The resolved knobs; `knobs.preset` names the preset they started from.
    pub knobs: Knobs,
    /// The scene's `[scene] name`.
    pub scene_name: String,
    /// The scene file on disk; `None` for a built-in scene.
    pub scene_path: Option<PathBuf>,
    /// The scene file's full text.
    pub scene_text: String,
    /// Edge length of the sample in mm.
    pub sample_size_mm: f32,
    /// Whether ground truth is written beside every frame (`sim.ground_truth`).
    pub ground_truth: bool,
}

impl Renderer {
    /// How frames of `fixture` are simulated (builds the sample, as the first frame would).
    pub fn provenance(&self, fixture: &str) -> Result<Provenance, RenderError> {
        let sample = self.sample(fixture)?;
        Ok(Provenance {
            fixture: fixture.to_string(),
            knobs: self.knobs_for(&sample).clone(),
            scene_name: sample.source.name.clone(),
            scene_path: sample.source.path.clone(),
            scene_text: sample.source.text.clone(),
            sample_size_mm: sample.size_mm,
            ground_truth: self.sim.ground_truth.any(),
        })
    }

    /// One line for dry runs: the preset, every resolved knob and the fixture, e.g.
    /// `preview (spp 1×1, halogen 1, tube 16, bounces 1×8 tol 0.02, relief 0.2 mm, shadow maps,
    /// dipole 8) on bumps`.
    pub fn summary_line(&self, fixture: &str) -> Result<String, RenderError> {
        let p = self.provenance(fixture)?;
        let k = &p.knobs;
        Ok(format!(
            "{} (spp {s}×{s}{}, halogen {}, tube {}, bounces {}×{} tol {}, relief {} mm, {}, dipole {}) on {}{}",
            k.preset,
            if k.adaptive_threshold > 0.0 {
                format!(
                    " where neighbours differ by > {}, else 1",
                    k.adaptive_threshold
                )
            } else {
                String::new()
            },
            k.halogen_samples,
            k.tube_samples,
            k.bounces,
            k.bounce_rays,
            k.bounce_tolerance,
            k.relief_mm,
            if k.shadow_maps {
                "shadow maps"
            } else {
                "shadow rays"
            },
            k.dipole_samples,
            p.fixture,
            if p.ground_truth {
                ", ground truth on"
            } else {
                ""
            },
            s = k.spp_side,
        ))
    }
}
