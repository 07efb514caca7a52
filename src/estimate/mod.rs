//! Costing a plan before anything moves: rig time, frames, bytes and per-device usage, and the
//! rig state the plan implies before each step (used by resume and the ETA).
//!
//! # The timing model
//!
//! The executor and the simulated devices follow exactly this model; the estimate is a pure
//! fold over the steps on a rig clock that starts at 0 s.
//!
//! - **Start.** A run starts by homing every axis from the power-on state (every axis at 0°),
//!   which costs the longest settling time. [`estimate_from`] also costs re-establishing the
//!   given [`RigState`]: homing, then moving axes (in parallel) and the cart to where the
//!   state has them. Lamps that are on in the start state count as switched on at that time
//!   (the executor switches them on when it re-establishes the state), so their warm-up is
//!   waited for again.
//! - **Home{axes}.** All named axes home in parallel; each takes
//!   `|position| / homing_speed_deg_s + settle_s` (it settles even if it was already at 0°);
//!   the step takes the longest. Every homed axis ends at 0°.
//! - **Move{targets}.** All named axes move in parallel; each takes
//!   [`motion::move_duration_s`]`(from, to, kinematics, backlash_deg)` plus `settle_s` if it
//!   moved at all; the step takes the longest. A move in the negative direction overshoots by
//!   `backlash_deg` and comes back, so it travels `|Δ| + 2·backlash_deg`.
//! - **Lamps.** Switching is instant. A lamp switched from off to on records its switch-on
//!   time (for warm-up); switching a lamp to the state it is already in does nothing.
//! - **Capture.** First wait until every lamp that is on has been on for at least its
//!   `warmup_s`, and until `min_interval_s` has passed since the previous capture's first
//!   trigger. Then, for each exposure `e` in order, fire one trigger and wait the longest
//!   `e + 1/fps` over the listed cameras before the next trigger. The capture's first trigger
//!   is the reference for the next capture's `min_interval_s`.
//! - **LaserArm, LaserDisarm, Laser** take 0 s. **CartTo** takes `|Δmm| / speed_mm_s`.
//!   **Prompt** takes 0 s of rig time (operator time is unknown; prompts are counted, and
//!   lamp warm-up is not assumed to elapse during a prompt). **Wait** takes its seconds.
//! - **Bytes** are an uncompressed upper bound: `width·height·3·2` per raw frame (16-bit
//!   RGB) and `width·height·3·4` per HDR frame (32-bit float RGB).
//!
//! # Plans that do not validate
//!
//! The estimate never fails and never produces NaN or a negative number. Values that
//! [`crate::validate::validate`] rejects are costed at the nearest meaningful value: unknown
//! devices and non-finite values are skipped, axis targets are clamped to the soft limits, cart
//! targets to the cart's travel, waits, exposures and capture intervals to [0 s, 24 h].
//!
//! # Per-device usage
//!
//! Every device of the rig gets a row in [`Estimate::per_device`], keyed by its id:
//! axes (busy time, moves and homes as operations, degrees travelled), lamps (on time,
//! switch operations), the laser (on time, on/off switches), cameras (frames, busy time
//! = Σ exposure + readout), the cart (busy time, moves, millimetres travelled) and the trigger
//! (fires as operations).

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};
use stagehand_devices::fixture_pose::FixturePose;
use stagehand_devices::motion;
use stagehand_devices::rig::RigSpec;
use stagehand_simulator::render::config::SimSpec;

use crate::plan::{Action, Plan};

/// Longest wait, exposure or capture interval the planner accepts (24 h).
pub const MAX_WAIT_S: f64 = 24.0 * 3600.0;

/// Bytes per pixel of a raw frame as stored (16-bit RGB).
pub const RAW_BYTES_PER_PIXEL: u64 = 3 * 2;

/// Bytes per pixel of an HDR frame as stored (32-bit float RGB).
pub const HDR_BYTES_PER_PIXEL: u64 = 3 * 4;

/// What a plan costs: counts, bytes, rig time and how each device is used.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Estimate {
    /// Number of steps estimated (all of them, or those from the starting step on).
    pub steps: usize,
    /// Number of capture steps.
    pub captures: usize,
    /// Raw frames (one per listed camera per exposure).
    pub raw_frames: usize,
    /// HDR frames (one per listed camera per HDR capture with more than one exposure).
    pub hdr_frames: usize,
    /// Uncompressed upper bound of the frame data in bytes.
    pub bytes: u64,
    /// Estimated rig time in seconds, excluding the operator's time at prompts.
    pub rig_time_s: f64,
    /// Number of prompts (each waits for an operator for an unknown time).
    pub prompts: usize,
    /// Usage of every device of the rig, keyed by device id.
    pub per_device: BTreeMap<String, DeviceUsage>,
    /// Cumulative rig time at the end of each step, indexed by step index (one entry per step
    /// of the plan; steps before the starting step of [`estimate_from`] are 0).
    pub step_end_s: Vec<f64>,
}

/// What kind of device a [`DeviceUsage`] row describes (decides its units).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// A rotary axis; travel in degrees.
    #[default]
    Axis,
    /// A switched lamp.
    Lamp,
    /// The line laser.
    Laser,
    /// A camera.
    Camera,
    /// The reflectometer cart; travel in millimetres.
    Cart,
    /// The trigger source; operations are fires.
    Trigger,
}

/// How much a plan uses one device.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct DeviceUsage {
    /// Which kind of device this is.
    pub kind: DeviceKind,
    /// Time the device is busy: moving and settling (axes, cart) or exposing and reading out
    /// (cameras).
    pub busy_s: f64,
    /// Moves and homes (axes, cart), switches between on and off (lamps, laser) or trigger
    /// fires (trigger).
    pub operations: usize,
    /// Distance travelled: degrees for axes, millimetres for the cart.
    pub travel: f64,
    /// Time switched on (lamps, laser).
    pub on_s: f64,
    /// Frames returned (cameras).
    pub frames: usize,
}

/// The state of the rig at a step boundary, as the plan implies it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigState {
    /// Position of every axis of the rig, in degrees.
    pub axes_deg: BTreeMap<String, f64>,
    /// Ids of the lamps that are on.
    pub lamps_on: BTreeSet<String>,
    /// Whether the laser is armed (it may be switched on).
    pub laser_armed: bool,
    /// Whether the laser is emitting.
    pub laser_on: bool,
    /// Wavelength of the fitted laser (0 on a rig without a laser).
    pub laser_fitted_nm: u32,
    /// Elevation on the light arc where the laser unit is mounted (0 on a rig without a laser).
    pub laser_mount_deg: f64,
    /// Position of the reflectometer cart from the - end stop (0 on a rig without a cart).
    pub cart_mm: f64,
    /// What lies on the stage: the rig's `sim.sample` or the fixture an operator placed.
    pub fixture: String,
    /// How the fixture was placed (flat and centred unless a prompt said otherwise).
    #[serde(default)]
    pub fixture_pose: FixturePose,
}

impl RigState {
    /// The state a run starts from once every axis is homed: axes at their home angle
    /// (`home_deg`, default 0°), lamps off, laser disarmed and off with the rig's fitted
    /// colour and mount elevation, cart at 0 mm, the rig's sample on the stage.
    pub fn power_on(rig: &RigSpec) -> Self {
        Self {
            axes_deg: rig
                .axes
                .iter()
                .map(|a| (a.id.clone(), a.home_deg))
                .collect(),
            lamps_on: BTreeSet::new(),
            laser_armed: false,
            laser_on: false,
            laser_fitted_nm: rig.laser.as_ref().map_or(0, |l| l.fitted_nm),
            laser_mount_deg: rig.laser.as_ref().map_or(0.0, |l| l.mount_elevation_deg),
            cart_mm: 0.0,
            fixture: SimSpec::sample_of(rig),
            fixture_pose: FixturePose::default(),
        }
    }

    /// Applies one step's action. Devices the rig does not have and non-finite values are
    /// ignored; axis targets are clamped to the soft limits and cart targets to the travel
    /// (a plan that validates is applied exactly).
    pub fn apply(&mut self, action: &Action, rig: &RigSpec) {
        match action {
            Action::Home { axes } => {
                for id in axes {
                    if let Some(axis) = rig.axis(id) {
                        // Where homing leaves it: next to the switch (`home_deg`, default 0°).
                        self.axes_deg.insert(id.clone(), axis.home_deg);
                    }
                }
            }
            Action::Move { targets } => {
                for (id, &target) in targets {
                    if let Some(axis) = rig.axis(id)
                        && target.is_finite()
                    {
                        self.axes_deg
                            .insert(id.clone(), clamp_to(target, axis.min_deg, axis.max_deg));
                    }
                }
            }
            Action::Lamps { states } => {
                for (id, &on) in states {
                    if rig.lamp(id).is_none() {
                        continue;
                    }
                    if on {
                        self.lamps_on.insert(id.clone());
                    } else {
                        self.lamps_on.remove(id);
                    }
                }
            }
            Action::LaserArm => {
                if rig.laser.is_some() {
                    self.laser_armed = true;
                }
            }
            Action::LaserDisarm => {
                self.laser_armed = false;
                self.laser_on = false;
            }
            Action::Laser { on, .. } => {
                if rig.laser.is_some() {
                    self.laser_on = *on;
                }
            }
            Action::CartTo { position_mm } => {
                if let Some(cart) = &rig.cart
                    && position_mm.is_finite()
                {
                    self.cart_mm = clamp_to(*position_mm, 0.0, cart.travel_mm);
                }
            }
            Action::Prompt {
                fixture,
                placement,
                laser_mount_deg,
                laser_fit_nm,
                ..
            } => {
                if let Some(fixture) = fixture {
                    self.fixture = fixture.clone();
                    self.fixture_pose = placement.unwrap_or_default();
                } else if let Some(pose) = placement {
                    self.fixture_pose = *pose;
                }
                if let Some(laser) = &rig.laser {
                    if let Some(mount) = laser_mount_deg
                        && mount.is_finite()
                    {
                        self.laser_mount_deg = mount.clamp(0.0, 90.0);
                    }
                    if let Some(nm) = laser_fit_nm
                        && laser.colours_nm.contains(nm)
                    {
                        self.laser_fitted_nm = *nm;
                    }
                }
            }
            Action::Capture { .. } | Action::Wait { .. } => {}
        }
    }

    /// This state with every value made usable on `rig`: an axis position for every axis of
    /// the rig (missing or non-finite positions become 0°, others are clamped to the soft
    /// limits), unknown lamps dropped, the cart clamped to its travel.
    fn sanitised(&self, rig: &RigSpec) -> Self {
        let mut state = self.clone();
        state.axes_deg = rig
            .axes
            .iter()
            .map(|a| {
                let pos = self.axes_deg.get(&a.id).copied().filter(|p| p.is_finite());
                (
                    a.id.clone(),
                    pos.map_or(0.0, |p| clamp_to(p, a.min_deg, a.max_deg)),
                )
            })
            .collect();
        state.lamps_on.retain(|id| rig.lamp(id).is_some());
        state.laser_on &= rig.laser.is_some();
        state.laser_armed &= rig.laser.is_some();
        state.cart_mm = match &rig.cart {
            Some(cart) if self.cart_mm.is_finite() => clamp_to(self.cart_mm, 0.0, cart.travel_mm),
            _ => 0.0,
        };
        state
    }
}

/// The rig state the plan implies just before step `index`: every earlier step applied to the
/// power-on state. An `index` past the end gives the state after the last step.
pub fn state_before(plan: &Plan, rig: &RigSpec, index: usize) -> RigState {
    let mut state = RigState::power_on(rig);
    for step in plan.steps.iter().take(index) {
        state.apply(&step.action, rig);
    }
    state
}

/// Costs the whole plan from the power-on state.
pub fn estimate(plan: &Plan, rig: &RigSpec) -> Estimate {
    estimate_from(plan, rig, 0, &RigState::power_on(rig))
}

/// Costs the plan from step `from` on, starting in the rig state `start` (see the module doc
/// for how a start state is treated). A `from` past the end gives an empty estimate.
pub fn estimate_from(plan: &Plan, rig: &RigSpec, from: usize, start: &RigState) -> Estimate {
    // Nothing to run, nothing to establish.
    let establish = from < plan.steps.len();
    let mut run = Run::new(rig, start, establish);
    let mut step_end_s = vec![0.0; plan.steps.len()];
    let mut steps = 0;
    for (i, step) in plan.steps.iter().enumerate().skip(from) {
        run.step(&step.action);
        step_end_s[i] = run.now;
        steps += 1;
    }
    run.finish();
    Estimate {
        steps,
        captures: run.captures,
        raw_frames: run.raw_frames,
        hdr_frames: run.hdr_frames,
        bytes: run.bytes,
        rig_time_s: run.now,
        prompts: run.prompts,
        per_device: run.usage,
        step_end_s,
    }
}

/// Time the executor takes to establish `state` before the first step it runs: home every
/// axis from the power-on position (0°, so only the settling time), then move the axes and
/// the cart to where the state has them, all axes in parallel. Lamps come on at its end.
fn establish_s(rig: &RigSpec, state: &RigState) -> f64 {
    let homing = rig
        .axes
        .iter()
        .map(|a| nonneg(a.settle_s))
        .fold(0.0, f64::max);
    let moves = rig
        .axes
        .iter()
        .filter_map(|a| state.axes_deg.get(&a.id).map(|deg| (a, *deg)))
        .filter(|(_, deg)| deg.is_finite() && *deg != 0.0)
        .map(|(a, deg)| nonneg(stagehand_devices::axis::planned_move_s(a, 0.0, deg)))
        .fold(0.0, f64::max);
    let cart = rig
        .cart
        .as_ref()
        .map(|c| travel_time(state.cart_mm.abs(), c.speed_mm_s))
        .unwrap_or(0.0);
    homing + moves + cart
}

/// `x` if it is a finite positive number, else 0.
fn nonneg(x: f64) -> f64 {
    if x.is_finite() && x > 0.0 { x } else { 0.0 }
}

/// `x` clamped to `[lo, hi]`, tolerating a malformed range (returns `lo`).
fn clamp_to(x: f64, lo: f64, hi: f64) -> f64 {
    if lo <= hi { x.clamp(lo, hi) } else { lo }
}

/// `distance / speed` as a duration, 0 for anything that is not a finite positive time.
fn travel_time(distance: f64, speed: f64) -> f64 {
    if distance > 0.0 && speed > 0.0 {
        nonneg(distance / speed)
    } else {
        0.0
    }
}

/// The estimate's running state.
struct Run<'a> {
    rig: &'a RigSpec,
    state: RigState,
    now: f64,
    lamp_on_since: BTreeMap<String, f64>,
    laser_on_since: Option<f64>,
    last_first_trigger: Option<f64>,
    captures: usize,
    raw_frames: usize,
    hdr_frames: usize,
    bytes: u64,
    prompts: usize,
    usage: BTreeMap<String, DeviceUsage>,
}

impl<'a> Run<'a> {
    fn new(rig: &'a RigSpec, start: &RigState, establish: bool) -> Self {
        let state = start.sanitised(rig);
        let mut usage = BTreeMap::new();
        let mut add = |id: &str, kind| {
            usage.insert(
                id.to_string(),
                DeviceUsage {
                    kind,
                    ..DeviceUsage::default()
                },
            );
        };
        for a in &rig.axes {
            add(&a.id, DeviceKind::Axis);
        }
        for l in &rig.lamps {
            add(&l.id, DeviceKind::Lamp);
        }
        if let Some(l) = &rig.laser {
            add(&l.id, DeviceKind::Laser);
        }
        for c in &rig.cameras {
            add(&c.id, DeviceKind::Camera);
        }
        if let Some(c) = &rig.cart {
            add(&c.id, DeviceKind::Cart);
        }
        if let Some(t) = &rig.trigger {
            add(&t.id, DeviceKind::Trigger);
        }
        let now = if establish {
            establish_s(rig, &state)
        } else {
            0.0
        };
        let lamp_on_since = state.lamps_on.iter().map(|id| (id.clone(), now)).collect();
        let laser_on_since = state.laser_on.then_some(now);
        Self {
            rig,
            state,
            now,
            lamp_on_since,
            laser_on_since,
            last_first_trigger: None,
            captures: 0,
            raw_frames: 0,
            hdr_frames: 0,
            bytes: 0,
            prompts: 0,
            usage,
        }
    }

    fn usage(&mut self, id: &str) -> Option<&mut DeviceUsage> {
        self.usage.get_mut(id)
    }

    fn step(&mut self, action: &Action) {
        let rig = self.rig;
        let duration = match action {
            Action::Home { axes } => self.home(axes),
            Action::Move { targets } => self.move_axes(targets),
            Action::Capture {
                exposures_s,
                cameras,
                hdr,
                min_interval_s,
                ..
            } => self.capture(exposures_s, cameras, *hdr, *min_interval_s),
            Action::CartTo { position_mm } => self.cart_to(*position_mm),
            Action::Prompt { .. } => {
                self.prompts += 1;
                0.0
            }
            Action::Wait { seconds } => nonneg(*seconds).min(MAX_WAIT_S),
            Action::Lamps { .. }
            | Action::LaserArm
            | Action::LaserDisarm
            | Action::Laser { .. } => 0.0,
        };
        // Switching happens at the start of the step (all switching steps take 0 s).
        let before = self.state.clone();
        self.state.apply(action, rig);
        self.account_switches(&before);
        self.now += nonneg(duration);
    }

    /// Records lamp and laser switches between `before` and the current state, at `now`.
    fn account_switches(&mut self, before: &RigState) {
        let now = self.now;
        let switched_on: Vec<String> = self
            .state
            .lamps_on
            .difference(&before.lamps_on)
            .cloned()
            .collect();
        let switched_off: Vec<String> = before
            .lamps_on
            .difference(&self.state.lamps_on)
            .cloned()
            .collect();
        for id in switched_on {
            self.lamp_on_since.insert(id.clone(), now);
            if let Some(u) = self.usage(&id) {
                u.operations += 1;
            }
        }
        for id in switched_off {
            let since = self.lamp_on_since.remove(&id).unwrap_or(now);
            if let Some(u) = self.usage(&id) {
                u.operations += 1;
                u.on_s += nonneg(now - since);
            }
        }
        if before.laser_on != self.state.laser_on {
            let since = self.laser_on_since.take();
            if self.state.laser_on {
                self.laser_on_since = Some(now);
            }
            if let Some(id) = self.rig.laser.as_ref().map(|l| l.id.clone())
                && let Some(u) = self.usage(&id)
            {
                u.operations += 1;
                if let Some(since) = since {
                    u.on_s += nonneg(now - since);
                }
            }
        }
    }

    fn home(&mut self, axes: &[String]) -> f64 {
        let unique: BTreeSet<&String> = axes.iter().collect();
        let mut longest: f64 = 0.0;
        for id in unique {
            let Some(axis) = self.rig.axis(id) else {
                continue;
            };
            let pos = self.state.axes_deg.get(id).copied().unwrap_or(0.0);
            let t = travel_time(pos.abs(), axis.homing_speed_deg_s) + nonneg(axis.settle_s);
            if let Some(u) = self.usage(id) {
                u.busy_s += t;
                u.operations += 1;
                u.travel += nonneg(pos.abs());
            }
            longest = longest.max(t);
        }
        longest
    }

    fn move_axes(&mut self, targets: &BTreeMap<String, f64>) -> f64 {
        let mut longest: f64 = 0.0;
        for (id, &target) in targets {
            let Some(axis) = self.rig.axis(id) else {
                continue;
            };
            if !target.is_finite() {
                continue;
            }
            let from = self.state.axes_deg.get(id).copied().unwrap_or(0.0);
            let to = clamp_to(target, axis.min_deg, axis.max_deg);
            let backlash = nonneg(axis.backlash_deg);
            let (t, travel) = if to == from {
                (0.0, 0.0)
            } else {
                let t = nonneg(motion::move_duration_s(
                    from,
                    to,
                    axis.kinematics(),
                    backlash,
                )) + nonneg(axis.settle_s);
                let overshoot = if to < from { 2.0 * backlash } else { 0.0 };
                (t, (to - from).abs() + overshoot)
            };
            if let Some(u) = self.usage(id) {
                u.busy_s += t;
                u.operations += 1;
                u.travel += travel;
            }
            longest = longest.max(t);
        }
        longest
    }

    fn capture(
        &mut self,
        exposures_s: &[f64],
        cameras: &[String],
        hdr: bool,
        min_interval_s: f64,
    ) -> f64 {
        let rig = self.rig;
        let start = self.now;
        // Lamp warm-up, then pacing against the previous capture's first trigger.
        let mut first_trigger = start;
        for id in &self.state.lamps_on {
            if let (Some(lamp), Some(&since)) = (rig.lamp(id), self.lamp_on_since.get(id)) {
                first_trigger = first_trigger.max(since + nonneg(lamp.warmup_s));
            }
        }
        if let Some(previous) = self.last_first_trigger {
            first_trigger = first_trigger.max(previous + nonneg(min_interval_s).min(MAX_WAIT_S));
        }
        self.last_first_trigger = Some(first_trigger);

        let exposures: Vec<f64> = exposures_s
            .iter()
            .map(|&e| nonneg(e).min(MAX_WAIT_S))
            .collect();
        let unique: BTreeSet<&String> = cameras.iter().collect();
        let known: Vec<_> = unique.iter().filter_map(|id| rig.camera(id)).collect();
        let mut t = first_trigger;
        for &e in &exposures {
            let step = known
                .iter()
                .map(|c| e + travel_time(1.0, c.fps))
                .fold(0.0, f64::max);
            t += step;
        }
        for cam in &known {
            let readout = travel_time(1.0, cam.fps);
            let busy: f64 = exposures.iter().map(|e| e + readout).sum();
            if let Some(u) = self.usage.get_mut(&cam.id) {
                u.frames += exposures.len();
                u.busy_s += busy;
            }
        }
        if let Some(trigger) = &rig.trigger
            && let Some(u) = self.usage.get_mut(&trigger.id)
        {
            u.operations += exposures.len();
        }

        let is_hdr = hdr && exposures_s.len() > 1;
        self.captures += 1;
        self.raw_frames += exposures_s.len() * cameras.len();
        if is_hdr {
            self.hdr_frames += cameras.len();
        }
        for id in cameras {
            if let Some(cam) = rig.camera(id) {
                let pixels = u64::from(cam.width) * u64::from(cam.height);
                let raw = pixels
                    .saturating_mul(RAW_BYTES_PER_PIXEL)
                    .saturating_mul(exposures_s.len() as u64);
                self.bytes = self.bytes.saturating_add(raw);
                if is_hdr {
                    self.bytes = self
                        .bytes
                        .saturating_add(pixels.saturating_mul(HDR_BYTES_PER_PIXEL));
                }
            }
        }
        nonneg(t - start)
    }

    fn cart_to(&mut self, position_mm: f64) -> f64 {
        let Some(cart) = &self.rig.cart else {
            return 0.0;
        };
        if !position_mm.is_finite() {
            return 0.0;
        }
        let to = clamp_to(position_mm, 0.0, cart.travel_mm);
        let distance = (to - self.state.cart_mm).abs();
        let t = travel_time(distance, cart.speed_mm_s);
        let id = cart.id.clone();
        if let Some(u) = self.usage(&id) {
            u.busy_s += t;
            u.operations += 1;
            u.travel += nonneg(distance);
        }
        t
    }

    /// Closes the on-time of whatever is still on at the end of the plan.
    fn finish(&mut self) {
        let now = self.now;
        let open: Vec<(String, f64)> = std::mem::take(&mut self.lamp_on_since)
            .into_iter()
            .collect();
        for (id, since) in open {
            if let Some(u) = self.usage(&id) {
                u.on_s += nonneg(now - since);
            }
        }
        if let Some(since) = self.laser_on_since.take()
            && let Some(id) = self.rig.laser.as_ref().map(|l| l.id.clone())
            && let Some(u) = self.usage(&id)
        {
            u.on_s += nonneg(now - since);
        }
    }
}

/// The built-in rigs for tests, with the numbers the tests compute by hand pinned to the
/// values of devices/rigs/*.toml when the tests were written (so a retuned rig file does not
/// silently change the arithmetic under test).
#[cfg(test)]
pub(crate) mod test_rigs {
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};

    fn pin_cameras(rig: &mut RigSpec) {
        for c in &mut rig.cameras {
            (c.width, c.height, c.fps) = (1024, 768, 15.0);
            (c.min_exposure_s, c.max_exposure_s, c.max_gain) = (0.00002, 4.0, 16.0);
        }
    }

    /// The built-in light stage.
    pub(crate) fn lightstage() -> RigSpec {
        let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").unwrap();
        let axes = [
            ("turntable", 30.0, 60.0, -180.0, 360.0, 0.05, 0.15, 40.0),
            ("light_arc", 20.0, 40.0, -180.0, 360.0, 0.1, 0.3, 30.0),
            ("laser_tilt", 10.0, 200.0, -30.0, 30.0, 0.02, 0.02, 10.0),
        ];
        assert_eq!(rig.axes.len(), axes.len());
        for (a, (id, v, acc, min, max, backlash, settle, homing)) in rig.axes.iter_mut().zip(axes) {
            assert_eq!(a.id, id);
            (a.speed_deg_s, a.accel_deg_s2, a.min_deg, a.max_deg) = (v, acc, min, max);
            (a.backlash_deg, a.settle_s, a.homing_speed_deg_s) = (backlash, settle, homing);
        }
        for l in &mut rig.lamps {
            l.warmup_s = 0.8;
        }
        pin_cameras(&mut rig);
        if let Some(l) = &mut rig.laser {
            (l.colours_nm, l.fitted_nm, l.mount_elevation_deg) = (vec![650, 532, 473], 650, 45.0);
        }
        stagehand_simulator::render::config::SimSpec::edit(&mut rig, |s| s.sample = "bumps".into())
            .unwrap();
        rig
    }

    /// The built-in reflectometer.
    pub(crate) fn reflectometer() -> RigSpec {
        let mut rig = parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").unwrap();
        if let Some(c) = &mut rig.cart {
            (c.speed_mm_s, c.travel_mm) = (12.0, 240.0);
        }
        pin_cameras(&mut rig);
        rig
    }
}

#[cfg(test)]
mod tests;
