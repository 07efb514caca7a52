//! Checking a plan against a rig before anything moves (the second stage of the data flow in
//! ARCHITECTURE.md).
//!
//! [`validate`] is pure: it folds the plan over the power-on [`RigState`] (tracking arm state,
//! the fitted laser colour, lamps and the laser) and reports every problem with the step and
//! script position that caused it. Errors make the plan unrunnable; warnings point at
//! something that is probably not what the author meant.

use std::collections::{BTreeMap, BTreeSet};

use serde::Serialize;
use stagehand_devices::rig::{CameraSpec, RigSpec};

use crate::estimate::{MAX_WAIT_S, RigState};
use crate::plan::{Action, Plan, SourcePos, Step};
use stagehand_simulator::render::config::{FIXTURES, names_sample};

/// How bad a [`Violation`] is.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Severity {
    /// The plan cannot run as written.
    Error,
    /// The plan can run but probably does not do what was meant.
    Warning,
}

/// One problem of a plan against a rig.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Violation {
    /// Index of the step (position in `Plan::steps`).
    pub step: usize,
    /// Script position that created the step.
    pub at: SourcePos,
    /// Error or warning.
    pub severity: Severity,
    /// What is wrong and what to do about it.
    pub message: String,
}

/// Every problem of the plan against the rig, in step order. Nothing moves; this is pure.
pub fn validate(plan: &Plan, rig: &RigSpec) -> Vec<Violation> {
    let mut checker = Checker {
        rig,
        out: Vec::new(),
        laser_watchdog_warned: false,
    };
    let mut state = RigState::power_on(rig);
    // Where each lamp that is on was last switched on, where the laser was switched on, and
    // where the laser was armed (with whether it has been switched on since).
    let mut lamp_on_at: BTreeMap<String, (usize, SourcePos)> = BTreeMap::new();
    let mut laser_on_at: Option<(usize, SourcePos)> = None;
    let mut armed_at: Option<(usize, SourcePos, bool)> = None;

    for (i, step) in plan.steps.iter().enumerate() {
        let mut here = Here {
            checker: &mut checker,
            step: i,
            at: step.at,
        };
        if step.index != i {
            let msg = format!(
                "step {i} says it is step {}; steps must be numbered from 0 in order (regenerate the plan from its script)",
                step.index
            );
            here.error(msg);
        }
        here.check(step, &state);

        match &step.action {
            Action::LaserArm if rig.laser.is_some() && armed_at.is_none() => {
                armed_at = Some((i, step.at, false));
            }
            Action::LaserDisarm => {
                if let Some((s, at, false)) = armed_at {
                    checker.warning(s, at, never_fired_message());
                }
                armed_at = None;
            }
            Action::Laser { on: true, .. } => {
                if let Some(arm) = armed_at.as_mut() {
                    arm.2 = true;
                }
            }
            _ => {}
        }

        let before = state.clone();
        state.apply(&step.action, rig);
        for id in state.lamps_on.difference(&before.lamps_on) {
            lamp_on_at.insert(id.clone(), (i, step.at));
        }
        if state.laser_on && !before.laser_on {
            laser_on_at = Some((i, step.at));
        }
    }

    // What the plan leaves behind.
    let mut left_on: BTreeMap<usize, (SourcePos, Vec<&str>)> = BTreeMap::new();
    for id in &state.lamps_on {
        if let Some(&(s, at)) = lamp_on_at.get(id) {
            left_on
                .entry(s)
                .or_insert_with(|| (at, Vec::new()))
                .1
                .push(id);
        }
    }
    for (s, (at, ids)) in left_on {
        let (noun, verb) = if ids.len() == 1 {
            ("lamp", "is")
        } else {
            ("lamps", "are")
        };
        checker.warning(
            s,
            at,
            format!(
                "lamps: {noun} {} switched on here {verb} still on when the plan ends; the executor switches it off anyway, \
                 but switch it off at the end of the script to say so",
                ids.join(", ")
            ),
        );
    }
    if state.laser_on
        && let Some((s, at)) = laser_on_at
    {
        checker.warning(
            s,
            at,
            "laser: the laser switched on here is still on when the plan ends; the executor switches it off anyway, \
             but switch it off or disarm it at the end of the script"
                .into(),
        );
    }
    if let Some((s, at, false)) = armed_at {
        checker.warning(s, at, never_fired_message());
    }

    let mut out = checker.out;
    out.sort_by_key(|v| v.step);
    out
}

fn never_fired_message() -> String {
    "laser_arm: the laser is armed here but never switched on before it is disarmed or the plan ends; \
     remove the arm or add a laser step that switches it on"
        .into()
}

/// Collects violations.
struct Checker<'a> {
    rig: &'a RigSpec,
    out: Vec<Violation>,
    /// The laser's missing watchdog was reported (once per plan).
    laser_watchdog_warned: bool,
}

impl Checker<'_> {
    fn warning(&mut self, step: usize, at: SourcePos, message: String) {
        self.out.push(Violation {
            step,
            at,
            severity: Severity::Warning,
            message,
        });
    }
}

/// The checks of one step.
struct Here<'c, 'a> {
    checker: &'c mut Checker<'a>,
    step: usize,
    at: SourcePos,
}

/// "a, b, c", or `none` when empty.
fn list<'s>(ids: impl IntoIterator<Item = &'s str>, none: &str) -> String {
    let ids: Vec<&str> = ids.into_iter().collect();
    if ids.is_empty() {
        none.to_string()
    } else {
        ids.join(", ")
    }
}

impl<'a> Here<'_, 'a> {
    fn push(&mut self, severity: Severity, message: String) {
        self.checker.out.push(Violation {
            step: self.step,
            at: self.at,
            severity,
            message,
        });
    }

    fn error(&mut self, message: String) {
        self.push(Severity::Error, message);
    }

    fn warning(&mut self, message: String) {
        self.push(Severity::Warning, message);
    }

    fn rig(&self) -> &'a RigSpec {
        self.checker.rig
    }

    fn known_axes(&self) -> String {
        list(self.rig().axes.iter().map(|a| a.id.as_str()), "no axes")
    }

    fn check(&mut self, step: &Step, state: &RigState) {
        match &step.action {
            Action::Home { axes } => self.home(axes),
            Action::Move { targets } => self.move_axes(targets),
            Action::Lamps { states } => self.lamps(states),
            Action::LaserArm | Action::LaserDisarm => {
                self.needs_laser(step.action.kind());
            }
            Action::Laser { on, colour_nm } => self.laser(*on, *colour_nm, state),
            Action::Capture {
                exposures_s,
                cameras,
                gain,
                hdr,
                min_interval_s,
                ..
            } => {
                self.capture(exposures_s, cameras, *gain, *hdr, *min_interval_s, state);
            }
            Action::CartTo { position_mm } => self.cart_to(*position_mm),
            Action::Prompt {
                fixture,
                laser_mount_deg,
                laser_fit_nm,
                ..
            } => {
                self.prompt(fixture.as_deref(), *laser_mount_deg, *laser_fit_nm, state);
            }
            Action::Wait { seconds } => {
                let s = *seconds;
                if !(s.is_finite() && s >= 0.0) {
                    self.error(format!(
                        "wait: {s} s is not a duration; wait a number of seconds ≥ 0"
                    ));
                } else if s > MAX_WAIT_S {
                    self.error(format!(
                        "wait: {s} s is longer than 24 h ({MAX_WAIT_S} s); shorten the wait or split the run into several plans"
                    ));
                }
            }
        }
    }

    fn unknown_axis(&mut self, call: &str, id: &str) {
        let known = self.known_axes();
        self.error(format!("{call}: unknown axis `{id}`; the rig has {known}"));
    }

    fn home(&mut self, axes: &[String]) {
        if axes.is_empty() {
            let known = self.known_axes();
            self.error(format!(
                "home: no axes named; name at least one of: {known}"
            ));
        }
        for id in axes {
            if self.rig().axis(id).is_none() {
                self.unknown_axis("home", id);
            }
        }
    }

    fn move_axes(&mut self, targets: &BTreeMap<String, f64>) {
        if targets.is_empty() {
            let known = self.known_axes();
            self.error(format!(
                "move_to: no axes named; give a target for at least one of: {known}"
            ));
        }
        for (id, &target) in targets {
            let Some(axis) = self.rig().axis(id) else {
                self.unknown_axis("move_to", id);
                continue;
            };
            let (min, max) = (axis.min_deg, axis.max_deg);
            if !target.is_finite() {
                self.error(format!(
                    "move_to: {id} target {target}° is not a number; give an angle in degrees"
                ));
            } else if !(min..=max).contains(&target) {
                self.error(format!(
                    "move_to: {id} target {target}° is outside the soft limits [{min}°, {max}°]; \
                     choose a target inside the limits or widen them in the rig file"
                ));
            }
        }
    }

    fn lamps(&mut self, states: &BTreeMap<String, bool>) {
        for id in states.keys() {
            if self.rig().lamp(id).is_none() {
                let known = list(self.rig().lamps.iter().map(|l| l.id.as_str()), "no lamps");
                self.error(format!("lamps: unknown lamp `{id}`; the rig has {known}"));
            }
        }
    }

    /// Reports a laser step on a rig without a laser; true if the rig has one.
    fn needs_laser(&mut self, call: &str) -> bool {
        if self.rig().laser.is_some() {
            return true;
        }
        let name = self.rig().rig.name.clone();
        self.error(format!(
            "{call}: the rig `{name}` has no laser; remove the laser steps or run on a rig with a [laser] table"
        ));
        false
    }

    fn laser(&mut self, on: bool, colour_nm: u32, state: &RigState) {
        if !self.needs_laser("laser") || !on {
            return;
        }
        if !state.laser_armed {
            self.error(
                "laser: the laser is switched on but not armed; add laser_arm before this step"
                    .into(),
            );
        }
        let Some(laser) = &self.rig().laser else {
            return;
        };
        if let Some(stagehand_devices::rig::LaserWatchdog::None(why)) = self.rig().laser_watchdog()
            && !self.checker.laser_watchdog_warned
        {
            self.checker.laser_watchdog_warned = true;
            self.warning(format!(
                "laser `{}` has no watchdog: {why}; stop the run with stagehand (abort, e-stop), not by killing it",
                laser.id
            ));
        }
        let Some(laser) = &self.rig().laser else {
            return;
        };
        if !laser.colours_nm.contains(&colour_nm) {
            let colours = list_nm(&laser.colours_nm);
            self.error(format!(
                "laser: {colour_nm} nm is not one of the rig's laser colours ({colours}); use one of them"
            ));
        } else if colour_nm != state.laser_fitted_nm {
            let fitted = state.laser_fitted_nm;
            self.error(format!(
                "laser: {colour_nm} nm is not fitted ({fitted} nm is); add a prompt that fits it \
                 (laser_fit_nm = {colour_nm}) before this step"
            ));
        }
    }

    fn capture(
        &mut self,
        exposures_s: &[f64],
        cameras: &[String],
        gain: f64,
        hdr: bool,
        min_interval_s: f64,
        state: &RigState,
    ) {
        let rig = self.checker.rig;
        let all_cameras = list(rig.cameras.iter().map(|c| c.id.as_str()), "no cameras");
        if exposures_s.is_empty() {
            self.error(
                "capture: no exposures given; give at least one exposure time in seconds".into(),
            );
        }
        if cameras.is_empty() {
            self.error(format!(
                "capture: no cameras listed; list at least one of: {all_cameras}"
            ));
        }
        let mut seen = BTreeSet::new();
        let mut known: Vec<&CameraSpec> = Vec::new();
        for id in cameras {
            if !seen.insert(id.as_str()) {
                self.error(format!(
                    "capture: camera `{id}` is listed twice; list each camera once"
                ));
                continue;
            }
            match rig.camera(id) {
                Some(c) => known.push(c),
                None => self.error(format!(
                    "capture: unknown camera `{id}`; the rig has {all_cameras}"
                )),
            }
        }
        for &e in exposures_s {
            if !(e.is_finite() && e > 0.0) {
                self.error(format!(
                    "capture: exposure {e} s is not a positive time; give exposures in seconds > 0"
                ));
                continue;
            }
            // Group the cameras that cannot take this exposure by their range.
            let mut by_range: Vec<((f64, f64), Vec<&str>)> = Vec::new();
            for c in known
                .iter()
                .filter(|c| !(c.min_exposure_s..=c.max_exposure_s).contains(&e))
            {
                let range = (c.min_exposure_s, c.max_exposure_s);
                match by_range.iter_mut().find(|(r, _)| *r == range) {
                    Some((_, ids)) => ids.push(&c.id),
                    None => by_range.push((range, vec![&c.id])),
                }
            }
            for ((min, max), ids) in by_range {
                let (noun, ids) = camera_noun(&ids);
                self.error(format!(
                    "capture: exposure {e} s is outside the exposure range [{min} s, {max} s] of {noun} {ids}; \
                     choose an exposure inside the range or leave {} out of this capture",
                    if noun == "camera" { "that camera" } else { "those cameras" }
                ));
            }
        }
        if !(gain.is_finite() && gain >= 1.0) {
            self.error(format!(
                "capture: gain {gain} must be at least 1 (unity gain)"
            ));
        } else {
            let mut by_max: Vec<(f64, Vec<&str>)> = Vec::new();
            for c in known.iter().filter(|c| gain > c.max_gain) {
                match by_max.iter_mut().find(|(m, _)| *m == c.max_gain) {
                    Some((_, ids)) => ids.push(&c.id),
                    None => by_max.push((c.max_gain, vec![&c.id])),
                }
            }
            for (max, ids) in by_max {
                let (noun, ids) = camera_noun(&ids);
                self.error(format!(
                    "capture: gain {gain} is above the maximum gain {max} of {noun} {ids}; lower the gain or lengthen the exposure"
                ));
            }
        }
        if !(min_interval_s.is_finite() && min_interval_s >= 0.0) {
            self.error(format!(
                "capture: min_interval_s {min_interval_s} must be 0 or more seconds; use 0 for no pacing"
            ));
        } else if min_interval_s > MAX_WAIT_S {
            self.error(format!(
                "capture: min_interval_s {min_interval_s} s is longer than 24 h; pace captures at most 24 h apart"
            ));
        }
        if hdr && exposures_s.len() == 1 {
            self.warning(
                "capture: hdr is requested with a single exposure, so no HDR frame is merged; \
                 give a bracket of several exposures or drop hdr"
                    .into(),
            );
        }
        if state.lamps_on.is_empty() && !state.laser_on {
            self.warning(
                "capture: no lamp is on and the laser is off, so the frames will be dark; \
                 switch a lamp or the laser on first (ignore this for dark frames on purpose)"
                    .into(),
            );
        }
    }

    fn cart_to(&mut self, position_mm: f64) {
        let Some(cart) = &self.rig().cart else {
            let name = self.rig().rig.name.clone();
            self.error(format!(
                "cart_to: the rig `{name}` has no reflectometer cart; remove the step or run on a rig with a [cart] table"
            ));
            return;
        };
        let travel = cart.travel_mm;
        if !position_mm.is_finite() {
            self.error(format!("cart_to: position {position_mm} mm is not a number; give millimetres from the - end stop"));
        } else if !(0.0..=travel).contains(&position_mm) {
            self.error(format!(
                "cart_to: position {position_mm} mm is outside the cart's travel [0 mm, {travel} mm]; \
                 choose a position between the end stops"
            ));
        }
    }

    fn prompt(
        &mut self,
        fixture: Option<&str>,
        mount_deg: Option<f64>,
        fit_nm: Option<u32>,
        state: &RigState,
    ) {
        if let Some(f) = fixture
            && !names_sample(f)
        {
            self.error(format!(
                "prompt: fixture `{f}` is unknown; use one of: {} or the path of a scene file ending in .toml",
                FIXTURES.join(", ")
            ));
        }
        if let Some(m) = mount_deg
            && self.needs_laser("prompt (laser_mount_deg)")
            && !(m.is_finite() && (0.0..=90.0).contains(&m))
        {
            self.error(format!(
                "prompt: laser_mount_deg {m}° is outside [0°, 90°]; mount the laser between the sample plane (0°) and the zenith (90°)"
            ));
        }
        if let Some(nm) = fit_nm
            && self.needs_laser("prompt (laser_fit_nm)")
        {
            let colours = self
                .rig()
                .laser
                .as_ref()
                .map(|l| l.colours_nm.clone())
                .unwrap_or_default();
            if !colours.contains(&nm) {
                self.error(format!(
                    "prompt: laser_fit_nm {nm} nm is not one of the rig's laser colours ({}); fit one of them",
                    list_nm(&colours)
                ));
            } else if state.laser_on && nm != state.laser_fitted_nm {
                self.warning(format!(
                    "prompt: the operator is asked to fit the {nm} nm laser while the laser is on; switch it off before this prompt"
                ));
            }
        }
    }
}

/// "camera cam1" or "cameras cam1, cam2".
fn camera_noun(ids: &[&str]) -> (&'static str, String) {
    (
        if ids.len() == 1 { "camera" } else { "cameras" },
        ids.join(", "),
    )
}

/// "650, 532, 473 nm".
fn list_nm(colours: &[u32]) -> String {
    let s: Vec<String> = colours.iter().map(u32::to_string).collect();
    format!("{} nm", s.join(", "))
}

#[cfg(test)]
mod tests;
