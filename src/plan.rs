//! The Plan: what a capture script asks for, as data. Numbered steps with absolute targets,
//! grouped in named blocks, each remembering the script position that created it.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use stagehand_devices::fixture_pose::FixturePose;

/// A complete, serialisable capture plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// File name of the script that produced the plan.
    pub script: String,
    /// Every script parameter with the value used (defaults and `--set` overrides).
    pub params: BTreeMap<String, serde_json::Value>,
    pub steps: Vec<Step>,
}

/// Line and column (1-based) in the script.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct SourcePos {
    pub line: u32,
    pub col: u32,
}

/// One step of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// Position in `Plan::steps`, from 0.
    pub index: usize,
    /// Names of the enclosing blocks joined with `/` ("" at top level).
    pub block: String,
    /// Where in the script the step was created.
    pub at: SourcePos,
    pub action: Action,
}

/// What a step does. Targets are absolute, so a step can be re-run after a crash.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Action {
    /// Home the named axes (all at once).
    Home { axes: Vec<String> },
    /// Move the named axes to absolute angles in degrees (all at once).
    Move { targets: BTreeMap<String, f64> },
    /// Switch lamps by id; lamps not named keep their state.
    Lamps { states: BTreeMap<String, bool> },
    /// Arm the laser: it may be switched on from now on.
    LaserArm,
    /// Switch the laser off and disarm it.
    LaserDisarm,
    /// Switch the laser on with the fitted colour (`colour_nm` must match it) or off.
    Laser { on: bool, colour_nm: u32 },
    /// Fire the trigger once per exposure; every listed camera returns one frame per trigger.
    /// With `hdr` and more than one exposure, the bracket is also merged to an HDR frame.
    Capture {
        exposures_s: Vec<f64>,
        cameras: Vec<String>,
        gain: f64,
        hdr: bool,
        /// Free-form label stored with the frames (e.g. "sweep 12").
        label: String,
        /// Minimum time between this capture's first trigger and the previous capture's
        /// first trigger (paces laser sweeps at the camera's recording rate).
        min_interval_s: f64,
    },
    /// Drive the reflectometer cart to a position estimate in millimetres from the - end stop.
    CartTo { position_mm: f64 },
    /// Pause until an operator confirms. What the operator is asked to change is recorded and,
    /// on the simulated rig, applied to the world.
    Prompt {
        message: String,
        /// Fixture the operator places on the stage (sample, checkerboard, colorchecker, planes).
        fixture: Option<String>,
        /// How the operator places it (tilted, turned, shifted); flat and centred when a
        /// fixture is named without one.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        placement: Option<FixturePose>,
        /// Elevation on the light arc where the operator mounts the laser unit.
        laser_mount_deg: Option<f64>,
        /// Laser colour the operator fits.
        laser_fit_nm: Option<u32>,
    },
    /// Wait a fixed time (e.g. thermal settling).
    Wait { seconds: f64 },
}

impl Action {
    /// Every name [`Action::kind`] returns (the JSON `kind` field), for reading events back.
    pub const KINDS: [&'static str; 10] = [
        "home",
        "move",
        "lamps",
        "laser_arm",
        "laser_disarm",
        "laser",
        "capture",
        "cart_to",
        "prompt",
        "wait",
    ];

    /// The step kind's name (one of [`Action::KINDS`]).
    pub fn kind(&self) -> &'static str {
        match self {
            Action::Home { .. } => "home",
            Action::Move { .. } => "move",
            Action::Lamps { .. } => "lamps",
            Action::LaserArm => "laser_arm",
            Action::LaserDisarm => "laser_disarm",
            Action::Laser { .. } => "laser",
            Action::Capture { .. } => "capture",
            Action::CartTo { .. } => "cart_to",
            Action::Prompt { .. } => "prompt",
            Action::Wait { .. } => "wait",
        }
    }
}

/// The dataset stores the plan as `plan.json`, journals its steps and checks a run's frames
/// against its capture steps.
impl stagehand_dataset::RunPlan for Plan {
    fn step_count(&self) -> usize {
        self.steps.len()
    }

    fn step(&self, index: usize) -> Option<stagehand_dataset::PlannedStep<'_>> {
        let step = self.steps.get(index)?;
        let capture = match &step.action {
            Action::Capture {
                exposures_s,
                cameras,
                hdr,
                ..
            } => Some(stagehand_dataset::PlannedCapture {
                cameras,
                exposures: exposures_s.len(),
                hdr: *hdr,
            }),
            _ => None,
        };
        Some(stagehand_dataset::PlannedStep {
            kind: step.action.kind(),
            block: &step.block,
            line: step.at.line,
            col: step.at.col,
            capture,
        })
    }
}

impl Plan {
    /// SHA-256 of the plan's canonical JSON, hex encoded. Stored with the run; a resumed run
    /// refuses a plan whose hash differs.
    pub fn hash(&self) -> String {
        let json = serde_json::to_vec(self).unwrap_or_default();
        let digest = Sha256::digest(&json);
        digest.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// Raw frames the plan will produce (one per camera per exposure).
    pub fn raw_frames(&self) -> usize {
        self.steps
            .iter()
            .map(|s| match &s.action {
                Action::Capture {
                    exposures_s,
                    cameras,
                    ..
                } => exposures_s.len() * cameras.len(),
                _ => 0,
            })
            .sum()
    }

    /// HDR frames the plan will produce (one per camera per bracketed HDR capture).
    pub fn hdr_frames(&self) -> usize {
        self.steps
            .iter()
            .map(|s| match &s.action {
                Action::Capture {
                    exposures_s,
                    cameras,
                    hdr: true,
                    ..
                } if exposures_s.len() > 1 => cameras.len(),
                _ => 0,
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `kind()`, the serde tag and [`Action::KINDS`] name every action alike.
    #[test]
    fn every_kind_is_listed_and_is_the_serde_tag() {
        let actions = [
            Action::Home { axes: vec![] },
            Action::Move {
                targets: BTreeMap::new(),
            },
            Action::Lamps {
                states: BTreeMap::new(),
            },
            Action::LaserArm,
            Action::LaserDisarm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::Capture {
                exposures_s: vec![0.01],
                cameras: vec![],
                gain: 1.0,
                hdr: false,
                label: String::new(),
                min_interval_s: 0.0,
            },
            Action::CartTo { position_mm: 0.0 },
            Action::Prompt {
                message: String::new(),
                fixture: None,
                placement: None,
                laser_mount_deg: None,
                laser_fit_nm: None,
            },
            Action::Wait { seconds: 0.0 },
        ];
        assert_eq!(actions.len(), Action::KINDS.len());
        for (a, listed) in actions.iter().zip(Action::KINDS) {
            assert_eq!(a.kind(), listed);
            let json = serde_json::to_value(a).expect("serialises");
            assert_eq!(json["kind"], a.kind());
        }
    }
}
