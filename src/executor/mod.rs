//! The executor: runs a plan's steps against a rig, in order, owning time and safety.
//!
//! - Nothing moves while a camera exposes: a capture completes (every frame collected) before
//!   the next step starts; frames are written on the writer thread while the next move runs.
//! - A step is done when its frames are durable: the writer commits the journal row only
//!   after the files are fsynced and renamed.
//! - Pause takes effect at the next step boundary; abort interrupts the step and puts the rig
//!   in its safe state (laser off and disarmed, lamps off, axes stopped, cameras disarmed).
//! - Trigger ids are derived from (step, exposure), so a resumed run reproduces exactly the
//!   frames an uninterrupted one would have captured.

mod capture;
mod control;
mod establish;
mod events;
mod telemetry;
mod writer;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::sync::broadcast;

pub use control::{Answer, AutoConfirm, Control, Operator, RunControl};

pub use events::Event;
pub use telemetry::describe_metrics;
pub use writer::WriterHandle;

use crate::estimate::{Estimate, RigState, estimate_from, state_before};
use crate::plan::{Action, Plan, SourcePos};
use crate::rig::Rig;
use crate::storage::{RunStatus, StepRecord};

/// Why a run stopped before its end.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{script}:{}:{}: step {step} ({kind}) failed: {source}", at.line, at.col)]
    Device {
        script: String,
        step: usize,
        kind: &'static str,
        at: SourcePos,
        source: Box<DeviceError>,
    },
    #[error(
        "writing step {step} failed: {message}; the run is resumable with `stagehand resume` once fixed"
    )]
    Storage { step: usize, message: String },
    #[error(
        "aborted before step {step}; the rig is in its safe state and the run is resumable with `stagehand resume`"
    )]
    Aborted { step: usize },
    #[error("{0}")]
    Other(String),
}

/// What a finished (or stopped) run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    /// How the run ended (`done`, `failed` or `aborted`).
    pub status: RunStatus,
    pub steps_done: usize,
    pub steps_total: usize,
    pub frames_written: usize,
    /// Rig clock at the end (a resumed run continues the clock of its earlier sessions).
    pub rig_time_s: f64,
    /// Rig time this session took, and what the plan estimate said it would take.
    pub session_rig_s: f64,
    pub estimated_rig_time_s: f64,
    pub safety_violations: Vec<String>,
}

/// How a run brings the rig into the state of its first step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Start {
    /// Home every axis and set up the state the plan has before its first pending step
    /// (runs and resumes); the rig ends in its safe state.
    #[default]
    Establish,
    /// Take the rig as it is (a single capture): every axis must be homed; nothing is homed,
    /// moved or switched first, and a run that completes leaves the rig as it was.
    InPlace,
}

/// Everything a run needs.
pub struct Execution {
    pub rig: Rig,
    pub plan: Arc<Plan>,
    pub script_name: String,
    pub events: broadcast::Sender<Event>,
    pub control: RunControl,
    pub operator: Arc<dyn Operator>,
    pub writer: WriterHandle,
    /// Steps already durable (non-empty when resuming).
    pub done: BTreeSet<usize>,
    pub start: Start,
}

/// State the executor tracks while it runs (for metadata, warm-up and pacing).
struct Live {
    state: RigState,
    lamp_on_since: BTreeMap<String, f64>,
    last_capture_s: Option<f64>,
}

impl Execution {
    /// Every safety violation the simulated world recorded so far (none on real hardware).
    fn world_violations(&self) -> Vec<String> {
        self.rig
            .world
            .as_ref()
            .map(|w| w.violations())
            .unwrap_or_default()
    }

    fn emit(&self, e: Event) {
        // No subscriber is fine: events are advisory.
        let _ = self.events.send(e);
    }

    /// Runs every step not yet done; always leaves the rig in its safe state and the dataset
    /// consistent (each step durable or not started).
    pub async fn run(self) -> Result<Summary, RunError> {
        let steps_total = self.plan.steps.len();
        let first = (0..steps_total)
            .find(|i| !self.done.contains(i))
            .unwrap_or(steps_total);
        let start_state = state_before(&self.plan, &self.rig.spec, first);
        let est: Estimate = estimate_from(&self.plan, &self.rig.spec, first, &start_state);
        let rig_start = self.rig.clock.now_s();
        // The simulated world may outlive the run (the daemon's rig): report only this run's.
        let violations_before = self.world_violations().len();
        self.emit(Event::RunStarted {
            total_steps: steps_total,
            steps_to_do: steps_total - self.done.len().min(steps_total),
            estimated_rig_time_s: est.rig_time_s,
        });
        let result = self.run_steps(first, &start_state, &est).await;
        // An in-place capture that completed leaves the rig as the operator set it up; every
        // other ending (and every ordinary run) goes to the safe state.
        let safe = if self.start == Start::InPlace && result.is_ok() {
            Ok(())
        } else {
            self.rig.safe_state().await
        };
        let (status, message) = match (&result, &safe) {
            (Ok(()), Ok(())) => (RunStatus::Done, None),
            (Ok(()), Err(e)) => (
                RunStatus::Failed,
                Some(format!("could not reach the safe state: {e}")),
            ),
            (Err(RunError::Aborted { .. }), _) => (
                RunStatus::Aborted,
                result.as_ref().err().map(|e| e.to_string()),
            ),
            (Err(e), _) => (RunStatus::Failed, Some(e.to_string())),
        };
        let finished = self.writer.finish(status, message.clone()).await;
        let violations: Vec<String> = self
            .world_violations()
            .into_iter()
            .skip(violations_before)
            .collect();
        let rig_time_s = self.rig.clock.now_s();
        let summary = Summary {
            status,
            steps_done: finished.as_ref().map(|f| f.steps_done).unwrap_or(0),
            steps_total,
            frames_written: finished.as_ref().map(|f| f.frames_written).unwrap_or(0),
            rig_time_s,
            session_rig_s: rig_time_s - rig_start,
            estimated_rig_time_s: est.rig_time_s,
            safety_violations: violations,
        };
        telemetry::run_finished(summary.status.as_str());
        self.emit(Event::RunFinished {
            status: summary.status,
            message: message.clone(),
            rig_time_s,
            elapsed_rig_s: rig_time_s - rig_start,
        });
        let writer_error = finished.err();
        match (result, writer_error) {
            (Err(e), _) => Err(e),
            (Ok(()), Some(e)) => Err(e),
            (Ok(()), None) => match safe {
                Ok(()) => Ok(summary),
                Err(e) => Err(RunError::Other(format!(
                    "run finished but the safe state failed: {e}"
                ))),
            },
        }
    }

    async fn run_steps(
        &self,
        first: usize,
        start_state: &RigState,
        est: &Estimate,
    ) -> Result<(), RunError> {
        if first >= self.plan.steps.len() {
            // Every step is durable already (resuming a finished run): nothing to move.
            return Ok(());
        }
        let mut live = Live {
            state: start_state.clone(),
            lamp_on_since: BTreeMap::new(),
            last_capture_s: None,
        };
        let establish_at = self
            .plan
            .steps
            .get(first)
            .map(|s| (s.index, s.at))
            .unwrap_or((first, SourcePos::default()));
        let established = match self.start {
            Start::Establish => establish::establish(&self.rig, &mut live, start_state).await,
            Start::InPlace => establish::adopt(&self.rig, &mut live).await,
        };
        established.map_err(|source| {
            telemetry::device_error(&source);
            RunError::Device {
                script: self.script_name.clone(),
                step: establish_at.0,
                kind: "establish",
                at: establish_at.1,
                source: Box::new(source),
            }
        })?;
        let rig_t0 = self.rig.clock.now_s();
        let est_t0 = if first == 0 {
            0.0
        } else {
            est.step_end_s.get(first - 1).copied().unwrap_or(0.0)
        };
        for step in self.plan.steps.iter().skip(first) {
            if self.done.contains(&step.index) {
                continue;
            }
            self.writer.check()?;
            if !self.control.wait_to_proceed(step.index, &self.events).await {
                return Err(RunError::Aborted { step: step.index });
            }
            self.emit(Event::StepStarted {
                step: step.index,
                kind: step.action.kind(),
                block: step.block.clone(),
            });
            let rig_start = self.rig.clock.now_s();
            let wall_start = wall_now();
            let wall_timer = std::time::Instant::now();
            let outcome = self.run_step_recovering(step, &mut live).await;
            let captures = outcome.map_err(|e| match e {
                StepFailure::Device(source) => RunError::Device {
                    script: self.script_name.clone(),
                    step: step.index,
                    kind: step.action.kind(),
                    at: step.at,
                    source: Box::new(source),
                },
                StepFailure::Aborted => RunError::Aborted { step: step.index },
            })?;
            let rig_end = self.rig.clock.now_s();
            let frames = captures.frames.len();
            let record = StepRecord {
                step: step.index,
                kind: step.action.kind().to_string(),
                block: step.block.clone(),
                rig_time_start_s: rig_start,
                rig_time_end_s: rig_end,
                wall_time_unix_s: wall_start,
            };
            // The step's own time (devices, capture), not the wait for the writer below.
            telemetry::step_done(step.action.kind(), wall_timer.elapsed().as_secs_f64());
            self.writer.submit(record, captures).await?;
            // ETA: remaining estimate, scaled by how the run has tracked the estimate so far.
            let est_end = est.step_end_s.get(step.index).copied().unwrap_or(0.0);
            let est_total = est.step_end_s.last().copied().unwrap_or(0.0);
            let ratio = if est_end - est_t0 > 1e-9 {
                (rig_end - rig_t0) / (est_end - est_t0)
            } else {
                1.0
            };
            let eta_s = ((est_total - est_end) * ratio.clamp(0.1, 10.0)).max(0.0);
            self.emit(Event::StepFinished {
                step: step.index,
                kind: step.action.kind(),
                frames,
                rig_time_s: rig_end,
                total_steps: self.plan.steps.len(),
                eta_s,
            });
        }
        Ok(())
    }

    /// Runs one step; when a device fails in a way a reconnect can cure (a lost port, garbage,
    /// a lost reply, an alarm, a stalled camera), pauses the run with a `DeviceFault` event,
    /// brings the rig back to the state before the step (reconnecting, re-homing every axis so
    /// no frame is taken at an unverified position) and runs the step again. The frames of a
    /// failed attempt are never written and trigger ids depend only on the step, so a retried
    /// step records exactly the frames an undisturbed one would have.
    async fn run_step_recovering(
        &self,
        step: &crate::plan::Step,
        live: &mut Live,
    ) -> Result<capture::StepFrames, StepFailure> {
        let before = live.state.clone();
        let mut faults = 0;
        loop {
            let outcome = tokio::select! {
                r = self.run_step(step, live) => r,
                () = self.control.aborted() => return Err(StepFailure::Aborted),
            };
            if let Err(StepFailure::Device(e)) = &outcome {
                telemetry::device_error(e);
            }
            if let Err(StepFailure::Device(
                e @ DeviceError {
                    kind: DeviceErrorKind::InterlockOpen,
                    ..
                },
            )) = &outcome
            {
                self.hold_for_interlock(step, live, &before, e).await?;
                continue;
            }
            let error = match outcome {
                Err(StepFailure::Device(e)) if e.is_recoverable() && faults < MAX_STEP_FAULTS => e,
                other => return other,
            };
            faults += 1;
            tracing::warn!("step {}: {error}; recovering", step.index);
            self.emit(Event::DeviceFault {
                step: step.index,
                device: error.device().to_string(),
                message: error.to_string(),
                attempt: faults,
            });
            tokio::select! {
                r = self.recover(live, &before, &error) => r?,
                () = self.control.aborted() => return Err(StepFailure::Aborted),
            }
            telemetry::reconnected(error.device());
            self.emit(Event::Recovered {
                step: step.index,
                device: error.device().to_string(),
            });
        }
    }

    /// The interlock opened during `step` (the laser went dark, or could not switch on): the
    /// step's frames are dropped, the run pauses with a warning until the operator resumes
    /// it, and the rig is then brought back to the state before the step so it is retaken
    /// whole. An interlock still open at the resume pauses again.
    async fn hold_for_interlock(
        &self,
        step: &crate::plan::Step,
        live: &mut Live,
        before: &RigState,
        error: &DeviceError,
    ) -> Result<(), StepFailure> {
        let mut error = error.clone();
        loop {
            let reason = format!(
                "step {}: {}: the laser interlock (the enclosure door switch) is open while the step needs the laser. The run is paused and the step's frames were discarded; close the enclosure door, then resume the run to retake the step",
                step.index,
                error.device()
            );
            tracing::warn!("{reason}");
            self.control.pause_because(reason.clone());
            self.emit(Event::Warning { message: reason });
            if !self.control.wait_to_proceed(step.index, &self.events).await {
                return Err(StepFailure::Aborted);
            }
            let recovered = tokio::select! {
                r = self.recover(live, before, &error) => r,
                () = self.control.aborted() => return Err(StepFailure::Aborted),
            };
            match recovered {
                Err(StepFailure::Device(
                    e @ DeviceError {
                        kind: DeviceErrorKind::InterlockOpen,
                        ..
                    },
                )) => error = e,
                other => return other,
            }
        }
    }

    /// Re-establishes `state` after `fault`, retrying with a growing pause while the device is
    /// still away (a port re-enumerating takes a moment). Gives up with the last error.
    async fn recover(
        &self,
        live: &mut Live,
        state: &RigState,
        fault: &DeviceError,
    ) -> Result<(), StepFailure> {
        let mut last = fault.clone();
        for attempt in 0..RECOVERY_ATTEMPTS {
            self.rig
                .clock
                .sleep_s(RECOVERY_PAUSE_S * f64::from(1u32 << attempt))
                .await;
            match establish::establish(&self.rig, live, state).await {
                Ok(()) => return Ok(()),
                Err(e) if e.is_recoverable() => {
                    telemetry::device_error(&e);
                    tracing::warn!("recovery attempt {}: {e}", attempt + 1);
                    last = e;
                }
                Err(e) => {
                    telemetry::device_error(&e);
                    return Err(StepFailure::Device(e));
                }
            }
        }
        Err(StepFailure::Device(last))
    }

    async fn run_step(
        &self,
        step: &crate::plan::Step,
        live: &mut Live,
    ) -> Result<capture::StepFrames, StepFailure> {
        let rig = &self.rig;
        let mut out = capture::StepFrames::default();
        match &step.action {
            Action::Home { axes } => {
                let handles = axes
                    .iter()
                    .map(|id| axis(rig, id))
                    .collect::<Result<Vec<_>, _>>()?;
                try_all(handles.iter().map(|h| h.home())).await?;
                for (id, h) in axes.iter().zip(&handles) {
                    live.state.axes_deg.insert(id.clone(), h.spec().home_deg);
                }
            }
            Action::Move { targets } => {
                let mut moves = Vec::new();
                for (id, deg) in targets {
                    moves.push((axis(rig, id)?, *deg));
                }
                try_all(moves.iter().map(|(h, deg)| h.move_to(*deg))).await?;
                for (id, deg) in targets {
                    live.state.axes_deg.insert(id.clone(), *deg);
                }
            }
            Action::Lamps { states } => establish::switch_lamps(rig, live, states).await?,
            Action::LaserArm => {
                laser(rig)?.arm().await?;
                live.state.laser_armed = true;
            }
            Action::LaserDisarm => {
                laser(rig)?.disarm().await?;
                live.state.laser_armed = false;
                live.state.laser_on = false;
            }
            Action::Laser { on, colour_nm } => {
                let l = laser(rig)?;
                if *on {
                    l.on(*colour_nm).await?
                } else {
                    l.off().await?
                }
                live.state.laser_on = *on;
            }
            Action::Capture { .. } => out = capture::capture(self, step, live).await?,
            Action::CartTo { position_mm } => {
                let cart = rig
                    .cart
                    .as_ref()
                    .ok_or_else(|| missing("cart", "this rig has no cart"))?;
                cart.move_to(*position_mm).await?;
                live.state.cart_mm = *position_mm;
            }
            Action::Prompt {
                message,
                fixture,
                placement,
                laser_mount_deg,
                laser_fit_nm,
            } => {
                // The operator reads the placement asked for, not only the script's words.
                let message = match placement {
                    Some(pose) => format!("{message} [placement: {}]", pose.describe()),
                    None => message.clone(),
                };
                self.emit(Event::Prompt {
                    step: step.index,
                    message: message.clone(),
                });
                if self.operator.confirm(step.index, &message).await == Answer::Abort {
                    return Err(StepFailure::Aborted);
                }
                if fixture.is_some() || placement.is_some() {
                    if let Some(f) = fixture {
                        live.state.fixture = f.clone();
                        live.state.fixture_pose = placement.unwrap_or_default();
                    } else if let Some(pose) = placement {
                        live.state.fixture_pose = *pose;
                    }
                    if let Some(w) = &rig.world {
                        w.place_fixture(&live.state.fixture, live.state.fixture_pose);
                    }
                }
                if laser_mount_deg.is_some() || laser_fit_nm.is_some() {
                    let l = laser(rig)?;
                    let colour = laser_fit_nm.unwrap_or(live.state.laser_fitted_nm);
                    let mount = laser_mount_deg.unwrap_or(live.state.laser_mount_deg);
                    l.fitted(colour, mount).await?;
                    live.state.laser_fitted_nm = colour;
                    live.state.laser_mount_deg = mount;
                }
            }
            Action::Wait { seconds } => rig.clock.sleep_s(*seconds).await,
        }
        Ok(out)
    }
}

/// Device faults a single step may recover from before the run stops (resumable).
const MAX_STEP_FAULTS: u32 = 3;
/// Attempts to re-establish the rig after a fault, and the first pause (doubling each time).
const RECOVERY_ATTEMPTS: u32 = 5;
const RECOVERY_PAUSE_S: f64 = 0.5;

/// A step that did not complete.
pub(crate) enum StepFailure {
    Device(DeviceError),
    Aborted,
}

impl From<DeviceError> for StepFailure {
    fn from(e: DeviceError) -> Self {
        StepFailure::Device(e)
    }
}

fn missing(device: &str, message: &str) -> DeviceError {
    DeviceError::new(
        device.to_string(),
        DeviceErrorKind::Other {
            message: message.to_string(),
        },
    )
}

fn axis<'a>(
    rig: &'a Rig,
    id: &str,
) -> Result<&'a stagehand_devices::axis::AxisHandle, DeviceError> {
    rig.axes
        .get(id)
        .ok_or_else(|| missing(id, "no such axis in this rig"))
}

fn laser(rig: &Rig) -> Result<&stagehand_devices::laser::LaserHandle, DeviceError> {
    rig.laser
        .as_ref()
        .ok_or_else(|| missing("laser", "this rig has no laser"))
}

/// Runs device requests concurrently and returns the first error, after all have finished
/// (so no request is left running unobserved).
pub(crate) async fn try_all<T, F>(
    futures: impl IntoIterator<Item = F>,
) -> Result<Vec<T>, DeviceError>
where
    F: std::future::Future<Output = Result<T, DeviceError>>,
{
    futures_util::future::join_all(futures)
        .await
        .into_iter()
        .collect()
}

pub(crate) fn wall_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}
