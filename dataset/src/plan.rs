//! What the dataset needs to know about a capture plan, without depending on the engine's
//! plan type: the engine's `Plan` implements [`RunPlan`], and the dataset stores it as
//! `plan.json`, journals one row per step and checks frames against its capture steps.

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::checksum::sha256_hex;

/// A plan the dataset can store and check a run against. Serialised with `serde_json` it is
/// the canonical `plan.json` whose SHA-256 is the manifest's `plan_hash`.
pub trait RunPlan: Serialize + DeserializeOwned {
    /// Number of steps; the journal has one row per step, keyed by position.
    fn step_count(&self) -> usize;
    /// Step `index` as the dataset sees it, or `None` past the end.
    fn step(&self, index: usize) -> Option<PlannedStep<'_>>;
}

/// One plan step as the journal records it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannedStep<'a> {
    /// The action kind (`home`, `move`, `capture`, …), stored in `steps.kind`.
    pub kind: &'a str,
    /// Enclosing block names joined with `/`.
    pub block: &'a str,
    /// Script line of the step.
    pub line: u32,
    /// Script column of the step.
    pub col: u32,
    /// What a capture step records; `None` for every other (frameless) step.
    pub capture: Option<PlannedCapture<'a>>,
}

/// The frames a capture step asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannedCapture<'a> {
    /// Camera ids.
    pub cameras: &'a [String],
    /// Exposures of the bracket (one raw frame per camera and exposure).
    pub exposures: usize,
    /// Whether an HDR merge is written per camera (when the bracket has more than one
    /// exposure).
    pub hdr: bool,
}

/// Hex SHA-256 of `plan`'s canonical JSON (what the manifest records as `plan_hash`); `None`
/// when it does not serialise.
pub fn plan_hash<P: RunPlan>(plan: &P) -> Option<String> {
    serde_json::to_vec(plan).ok().map(|json| sha256_hex(&json))
}

/// True when step `index` of `plan` is a capture.
pub(crate) fn is_capture<P: RunPlan>(plan: &P, index: usize) -> bool {
    plan.step(index).is_some_and(|s| s.capture.is_some())
}
