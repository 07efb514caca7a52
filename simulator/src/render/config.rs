//! The simulated rig's settings: the rig file's `[sim]` table, which the device layer carries
//! as raw TOML ([`SimTable`]) and the simulator reads and checks here: the sample on the stage
//! (a built-in scene from [`FIXTURES`] or a scene file), its size, the renderer's quality
//! preset and knob overrides, and whether ground truth is written. [`check_rig`] reports a
//! problem at file:line:col like every other rig-file error; [`SimSpec::of`] reads the table of
//! a rig already checked or built in code. It sits in `render` because the renderer reads it
//! (`Renderer::new`) and it reads the renderer's presets and knobs: one module, no cycle.

use serde::{Deserialize, Serialize};
use stagehand_devices::rig::span::{Problem, Seg, key, locate};
use stagehand_devices::rig::{RigError, RigSpec, SimTable};

use super::RenderError;
use super::quality::{Knobs, Quality, SimKnobs};
pub use crate::scene_file::builtin::FIXTURES;

/// Simulation settings (`[sim]`): the sample on the stage and the renderer's quality.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
    /// The fixture on the stage at power-on: a built-in scene ([`FIXTURES`]) or the path of a
    /// scene file ending in `.toml`.
    #[serde(default = "default_sample")]
    pub sample: String,
    /// Edge length of the square sample.
    #[serde(default = "default_sample_size")]
    pub sample_size_mm: f64,
    /// Renderer quality preset: preview, standard, reference ([`Quality`]).
    #[serde(default = "default_quality")]
    pub quality: String,
    /// Single accuracy knobs overriding the preset (`[sim.knobs]`).
    #[serde(default)]
    pub knobs: SimKnobs,
    /// Write ground truth (depth, normals, noise-free radiance, material parameters) beside
    /// every frame: `true`, or the kinds wanted (`["depth"]`).
    #[serde(default)]
    pub ground_truth: GroundTruthPlanes,
    /// Draw an "as built" rig (`[sim.as_built]`): cameras, responses and lamps off nominal,
    /// recorded in `as_built.json` beside each run for evaluation.
    #[serde(default)]
    pub as_built: Option<crate::as_built::AsBuiltSpec>,
    /// What the simulated cameras deliver: `"render"` (the World rendered, the default) or
    /// `"pattern"` (a test pattern that changes with every trigger, made without rendering, as
    /// Micro-Manager's DemoCamera does): for measuring the frame pipeline at the rig's full
    /// rate, where rendering would be the bottleneck.
    #[serde(default)]
    pub frames: FrameSource,
}

/// What a simulated camera's frame shows (`sim.frames`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameSource {
    /// The World rendered as the camera sees it.
    #[default]
    Render,
    /// [`crate::sim_devices::test_pattern`]: no rendering, no ground truth.
    Pattern,
}

/// The kinds of ground-truth plane, in the order they are written.
pub const GROUND_TRUTH_KINDS: [&str; 4] = ["depth", "normal", "radiance", "material"];

/// Which ground-truth planes the simulated cameras write beside every frame (`sim.ground_truth`):
/// `true` (all of [`GROUND_TRUTH_KINDS`]), `false` (none), or a list of kinds. The noise-free
/// radiance is a second render of every frame; the geometric planes (depth, normals,
/// material) only change when the scene moves, so a laser sweep evaluated for depth asks for
/// `["depth"]` and pays for one per sweep.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum GroundTruthPlanes {
    /// Every kind, or none.
    All(bool),
    /// These kinds.
    Only(Vec<String>),
}

impl Default for GroundTruthPlanes {
    fn default() -> Self {
        GroundTruthPlanes::All(false)
    }
}

impl GroundTruthPlanes {
    /// Whether kind `kind` is written.
    pub fn wants(&self, kind: &str) -> bool {
        match self {
            GroundTruthPlanes::All(all) => *all,
            GroundTruthPlanes::Only(kinds) => kinds.iter().any(|k| k == kind),
        }
    }

    /// Whether any plane is written.
    pub fn any(&self) -> bool {
        GROUND_TRUTH_KINDS.iter().any(|k| self.wants(k))
    }

    /// Whether only planes that depend on the scene's geometry are written (no radiance):
    /// they stay the same while only the light changes.
    pub fn geometry_only(&self) -> bool {
        !self.wants("radiance")
    }
}

fn default_sample() -> String {
    "bumps".into()
}
fn default_sample_size() -> f64 {
    80.0
}
fn default_quality() -> String {
    Quality::Preview.name().into()
}

impl Default for SimSpec {
    fn default() -> Self {
        Self {
            sample: default_sample(),
            sample_size_mm: default_sample_size(),
            quality: default_quality(),
            knobs: SimKnobs::default(),
            ground_truth: GroundTruthPlanes::default(),
            as_built: None,
            frames: FrameSource::default(),
        }
    }
}

/// A rig's `[sim]` table that does not read as [`SimSpec`] (a rig built in code; a rig file
/// gets a [`RigError`] at file:line:col from [`check_rig`] instead).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("the rig's [sim] table: {0}")]
pub struct SimError(pub String);

impl SimSpec {
    /// The settings in `rig`'s `[sim]` table, defaults for the keys it leaves out (types are
    /// checked, values by [`SimSpec::check`]).
    pub fn of(rig: &RigSpec) -> Result<SimSpec, SimError> {
        toml::Value::Table(rig.sim.0.clone())
            .try_into()
            .map_err(|e: toml::de::Error| SimError(e.message().trim().replace('\n', " ")))
    }

    /// The sample on `rig`'s stage at power-on (the default sample if its `[sim]` table does
    /// not read, which a rig loaded through [`check_rig`] cannot have).
    pub fn sample_of(rig: &RigSpec) -> String {
        Self::of(rig).map_or_else(|_| default_sample(), |s| s.sample)
    }

    /// Writes these settings into `rig`'s `[sim]` table (rigs built or varied in code).
    pub fn store(&self, rig: &mut RigSpec) -> Result<(), SimError> {
        let table = toml::Table::try_from(self).map_err(|e| SimError(e.to_string()))?;
        rig.sim = SimTable(table);
        Ok(())
    }

    /// Changes `rig`'s `[sim]` settings with `change` (tests and tools that vary the sample,
    /// the quality or a knob).
    pub fn edit(rig: &mut RigSpec, change: impl FnOnce(&mut SimSpec)) -> Result<(), SimError> {
        let mut sim = Self::of(rig)?;
        change(&mut sim);
        sim.store(rig)
    }

    /// The renderer's knobs these settings ask for: the quality preset with `[sim.knobs]`
    /// applied, validated.
    pub fn render_knobs(&self) -> Result<Knobs, RenderError> {
        Quality::parse(&self.quality)?.knobs().with(&self.knobs)
    }

    /// What the types cannot say: a sample the renderer can build, a known preset, a positive
    /// size, knobs in range. Returns the value to blame and a sentence.
    pub fn check(&self) -> Result<(), Problem> {
        if !names_sample(&self.sample) {
            return Err((
                key("sim", "sample"),
                format!(
                    "sim.sample `{}` is unknown; use one of {} or the path of a scene file ending in .toml",
                    self.sample,
                    FIXTURES.join(", ")
                ),
            ));
        }
        if let GroundTruthPlanes::Only(kinds) = &self.ground_truth
            && let Some(bad) = kinds
                .iter()
                .find(|k| !GROUND_TRUTH_KINDS.contains(&k.as_str()))
        {
            return Err((
                key("sim", "ground_truth"),
                format!(
                    "sim.ground_truth names `{bad}`; use true, false or a list of {}",
                    GROUND_TRUTH_KINDS.join(", ")
                ),
            ));
        }
        if self.frames == FrameSource::Pattern && self.ground_truth.any() {
            return Err((
                key("sim", "frames"),
                "sim.frames = \"pattern\" renders nothing, so it has no ground truth; set sim.ground_truth = false or sim.frames = \"render\"".into(),
            ));
        }
        if Quality::parse(&self.quality).is_err() {
            return Err((
                key("sim", "quality"),
                format!(
                    "sim.quality `{}` is unknown; use {}",
                    self.quality,
                    Quality::names()
                ),
            ));
        }
        if !(self.sample_size_mm.is_finite() && self.sample_size_mm > 0.0) {
            return Err((
                key("sim", "sample_size_mm"),
                "sim.sample_size_mm must be positive".into(),
            ));
        }
        match self.render_knobs() {
            Err(e @ RenderError::InvalidKnob { knob, .. }) => Err((
                vec![Seg::Key("sim"), Seg::Key("knobs"), Seg::Key(knob)],
                e.to_string(),
            )),
            Err(e) => Err((key("sim", "knobs"), e.to_string())),
            Ok(_) => Ok(()),
        }
    }
}

/// Whether `name` can name the sample on the stage: a built-in scene from [`FIXTURES`] or the
/// path of a scene file ending in `.toml` (whether it exists is checked when the renderer
/// builds the sample).
pub fn names_sample(name: &str) -> bool {
    FIXTURES.contains(&name) || name.ends_with(".toml")
}

/// Reads and checks the `[sim]` table of the rig file `text` (named `origin` in errors): an
/// unknown key, a wrong type or an impossible value is a [`RigError`] at its file:line:col.
/// Every rig a run or the daemon loads goes through here after
/// [`stagehand_devices::rig::parse_rig`].
pub fn check_rig(text: &str, origin: &str) -> Result<SimSpec, RigError> {
    /// The rig file as the simulator sees it: only `[sim]`.
    #[derive(Deserialize)]
    struct Document {
        #[serde(default)]
        sim: SimSpec,
    }
    let doc: Document = toml::from_str(text).map_err(|e| {
        RigError::at(
            text,
            origin,
            e.span().map_or(0, |s| s.start),
            e.message().trim().replace('\n', " "),
        )
    })?;
    doc.sim.check().map_err(|(path, message)| {
        RigError::at(text, origin, locate(text, &path).unwrap_or(0), message)
    })?;
    Ok(doc.sim)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};

    fn err(text: &str) -> (usize, usize, String) {
        match check_rig(text, "x.toml") {
            Err(RigError::Invalid {
                line, col, message, ..
            }) => (line, col, message),
            other => panic!("expected an error, got {other:?}"),
        }
    }

    fn line_of(text: &str, needle: &str) -> usize {
        text.lines().position(|l| l.contains(needle)).expect("line") + 1
    }

    #[test]
    fn builtin_rig_reads_as_its_table() {
        let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
        let checked = check_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("sim");
        assert_eq!(SimSpec::of(&rig), Ok(checked));
    }

    #[test]
    fn sim_sample_names_a_builtin_scene_or_a_toml_path() {
        let with = |sample: &str| {
            BUILTIN_LIGHTSTAGE.replacen("sample = \"bumps\"", &format!("sample = \"{sample}\""), 1)
        };
        assert!(check_rig(&with("marble"), "x.toml").is_ok());
        assert!(check_rig(&with("scenes/mine.toml"), "x.toml").is_ok());
        let text = with("teapot");
        let (l, _, m) = err(&text);
        assert_eq!(l, line_of(&text, "teapot"));
        assert!(m.contains("teapot") && m.contains(".toml"), "{m}");
        assert!(names_sample("cavity") && names_sample("a/b.toml"));
        assert!(!names_sample("teapot") && !names_sample("b.tom"));
    }

    #[test]
    fn unknown_quality_unknown_key_and_bad_knob_are_placed() {
        let text = BUILTIN_LIGHTSTAGE.replacen("quality = \"preview\"", "quality = \"ultra\"", 1);
        let (l, c, m) = err(&text);
        assert_eq!((l, c), (line_of(&text, "ultra"), 11));
        assert!(
            m.contains("sim.quality `ultra` is unknown; use preview, standard or reference"),
            "{m}"
        );
        let text = BUILTIN_LIGHTSTAGE.replacen("[sim]\n", "[sim]\nqualty = \"standard\"\n", 1);
        let (l, c, m) = err(&text);
        assert_eq!((l, c), (line_of(&text, "qualty"), 1));
        assert!(m.contains("unknown field `qualty`"), "{m}");
        let text = format!("{BUILTIN_LIGHTSTAGE}\n[sim.knobs]\nspp_side = 100\n");
        let (l, _, m) = err(&text);
        assert_eq!(l, line_of(&text, "spp_side = 100"));
        assert!(m.contains("spp_side") && m.contains("1 to 64"), "{m}");
    }

    #[test]
    fn ground_truth_is_all_none_or_the_kinds_named() {
        let with = |value: &str| {
            BUILTIN_LIGHTSTAGE.replacen("[sim]\n", &format!("[sim]\nground_truth = {value}\n"), 1)
        };
        let all = check_rig(&with("true"), "x.toml")
            .expect("all")
            .ground_truth;
        assert!(all.any() && all.wants("radiance") && !all.geometry_only());
        let none = check_rig(&with("false"), "x.toml")
            .expect("none")
            .ground_truth;
        assert!(!none.any());
        let depth = check_rig(&with("[\"depth\"]"), "x.toml")
            .expect("depth")
            .ground_truth;
        assert!(depth.any() && depth.wants("depth") && !depth.wants("normal"));
        assert!(depth.geometry_only());
        let text = with("[\"depth\", \"albedo\"]");
        let (l, _, m) = err(&text);
        assert_eq!(l, line_of(&text, "albedo"));
        assert!(
            m.contains("`albedo`") && m.contains("depth, normal, radiance, material"),
            "{m}"
        );
    }

    #[test]
    fn the_frame_source_is_render_or_pattern_and_a_pattern_has_no_ground_truth() {
        let with =
            |lines: &str| BUILTIN_LIGHTSTAGE.replacen("[sim]\n", &format!("[sim]\n{lines}\n"), 1);
        assert_eq!(
            check_rig(&with("frames = \"pattern\""), "x.toml").map(|s| s.frames),
            Ok(FrameSource::Pattern)
        );
        assert_eq!(
            check_rig(BUILTIN_LIGHTSTAGE, "x.toml").map(|s| s.frames),
            Ok(FrameSource::Render)
        );
        let text = with("frames = \"noise\"");
        let (l, _, m) = err(&text);
        assert_eq!(l, line_of(&text, "noise"));
        assert!(m.contains("render") && m.contains("pattern"), "{m}");
        let text = with("frames = \"pattern\"\nground_truth = true");
        let (l, _, m) = err(&text);
        assert_eq!(l, line_of(&text, "frames ="));
        assert!(m.contains("no ground truth"), "{m}");
    }

    #[test]
    fn edit_round_trips_through_the_table() {
        let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
        SimSpec::edit(&mut rig, |s| {
            s.quality = "standard".into();
            s.knobs.bounces = Some(0);
        })
        .expect("edit");
        let sim = SimSpec::of(&rig).expect("sim");
        assert_eq!(
            (sim.quality.as_str(), sim.knobs.bounces),
            ("standard", Some(0))
        );
        assert_eq!(sim.sample, "bumps");
    }
}
