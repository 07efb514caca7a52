//! Runs started over the API: one at a time, on the daemon's rig, with prompts answered over
//! the API and progress published on the event hub.
//!
//! A run executes on its own task. Its executor events go to a broadcast channel read by a
//! dedicated forwarding task, which folds them into the run's live state (for
//! `GET /api/status`) and republishes them on the hub as `run` events, plus `frame` events when
//! a step becomes durable. The executor never waits for the forwarder: a forwarder that falls
//! behind loses events and says so with a `warning` event.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use stagehand_devices::clock::RigClock;
use tokio::sync::{broadcast, watch};
use utoipa::ToSchema;

use super::error::ApiError;
use super::operator::{ApiOperator, PromptInfo, PromptSlot};
use super::state::AppState;
use crate::daemon::events::EventKind;
use crate::executor::{Answer, Control, Event, RunControl, RunError, Summary};
use crate::session::{DEFAULT_RESERVE_BYTES, SessionError, Wiring};
use crate::storage::RunStatus;

/// Executor events buffered for the forwarder before it starts losing them.
const EVENT_CAPACITY: usize = 4096;
/// How long a run start waits for a manual device command in flight to end.
const MANUAL_WAIT: Duration = Duration::from_secs(10);
/// How long a finished run waits for its forwarder to publish the last events.
const FORWARDER_DRAIN: Duration = Duration::from_secs(5);

/// What an active run is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LiveState {
    /// Steps are executing.
    Running,
    /// No new step starts; the current one finishes.
    Paused,
    /// Waiting for the operator to answer a prompt.
    Prompt,
    /// Aborting to the safe state.
    Stopping,
}

/// What the active run is doing, for `GET /api/status`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RunState {
    pub run_id: String,
    /// Script file name.
    pub script: String,
    /// What the run is doing now.
    pub state: LiveState,
    /// The step executing or last executed (none before the first).
    pub step: Option<usize>,
    pub total_steps: usize,
    /// Steps durable (including those of earlier sessions of a resumed run).
    pub steps_done: usize,
    /// Frame files written (including earlier sessions of a resumed run).
    pub frames_written: usize,
    /// Rig time this session has taken so far.
    pub rig_time_s: f64,
    /// Rig time the plan estimate gave this session.
    pub estimated_rig_time_s: f64,
    /// Estimated rig time left (the estimate scaled by how the run tracked it so far).
    pub eta_s: f64,
    /// `steps_done / total_steps`, 0..1.
    pub progress: f64,
    /// The prompt waiting for an answer (`POST /api/runs/{id}/prompt`).
    pub prompt: Option<PromptInfo>,
    /// Why the run paused itself (the interlock opened), and what to do before resuming.
    pub pause_reason: Option<String>,
    /// Wall-clock Unix time when this session started.
    pub started_unix_s: f64,
}

/// How a run ended.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// `done`, `aborted` or `failed`.
    pub status: RunStatus,
    pub message: Option<String>,
    /// The executor's summary when it got that far.
    pub summary: Option<Summary>,
}

/// Progress folded from the executor's events.
struct Progress {
    total_steps: usize,
    steps_done: usize,
    frames_written: usize,
    step: Option<usize>,
    estimated_rig_time_s: f64,
    /// The executor's last ETA and the rig time it was given at.
    eta: Option<(f64, f64)>,
    /// Status and message of the `run_finished` event.
    finished: Option<(RunStatus, Option<String>)>,
}

/// The run being executed.
pub struct ActiveRun {
    pub run_id: String,
    /// The run directory.
    pub dir: PathBuf,
    pub script: String,
    control: RunControl,
    prompt: Arc<PromptSlot>,
    clock: RigClock,
    rig_start_s: f64,
    started_unix_s: f64,
    progress: Mutex<Progress>,
    finished: watch::Sender<Option<Outcome>>,
}

impl ActiveRun {
    fn progress(&self) -> MutexGuard<'_, Progress> {
        self.progress.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The run's live state.
    pub fn state(&self) -> RunState {
        let p = self.progress();
        let prompt = self.prompt.pending();
        let state = match self.control.current() {
            Control::Abort => LiveState::Stopping,
            _ if prompt.is_some() => LiveState::Prompt,
            Control::Pause => LiveState::Paused,
            Control::Run => LiveState::Running,
        };
        let now = self.clock.now_s();
        let elapsed = (now - self.rig_start_s).max(0.0);
        let eta_s = match p.eta {
            Some((eta, at)) => eta - (now - at),
            None => p.estimated_rig_time_s - elapsed,
        }
        .max(0.0);
        RunState {
            run_id: self.run_id.clone(),
            script: self.script.clone(),
            state,
            step: p.step,
            total_steps: p.total_steps,
            steps_done: p.steps_done,
            frames_written: p.frames_written,
            rig_time_s: elapsed,
            estimated_rig_time_s: p.estimated_rig_time_s,
            eta_s,
            progress: if p.total_steps == 0 {
                0.0
            } else {
                (p.steps_done as f64 / p.total_steps as f64).clamp(0.0, 1.0)
            },
            prompt,
            pause_reason: self.control.pause_reason(),
            started_unix_s: self.started_unix_s,
        }
    }

    fn stopping(&self) -> ApiError {
        ApiError::conflict(format!("run {} is stopping (aborted)", self.run_id))
            .hint("wait for it to stop; `POST /api/runs/{id}/resume` continues it afterwards")
    }

    /// Pauses at the next step boundary. 409 if already paused or stopping.
    pub fn pause(&self) -> Result<(), ApiError> {
        match self.control.current() {
            Control::Abort => Err(self.stopping()),
            Control::Pause => Err(ApiError::conflict(format!(
                "run {} is already paused",
                self.run_id
            ))
            .hint("`POST /api/runs/{id}/resume` continues it")),
            Control::Run => {
                self.control.pause();
                Ok(())
            }
        }
    }

    /// Continues a paused run. 409 if it is not paused.
    pub fn resume(&self) -> Result<(), ApiError> {
        match self.control.current() {
            Control::Abort => Err(self.stopping()),
            Control::Run => Err(
                ApiError::conflict(format!("run {} is not paused", self.run_id))
                    .hint("`POST /api/runs/{id}/pause` pauses it at the next step boundary"),
            ),
            Control::Pause => {
                self.control.resume();
                Ok(())
            }
        }
    }

    /// Aborts to the safe state (also ends a pending prompt); returns at once.
    pub fn abort(&self) {
        self.control.abort();
        self.prompt.answer(Answer::Abort);
    }

    /// Answers the pending prompt. 409 if none is pending.
    pub fn answer(&self, answer: Answer) -> Result<PromptInfo, ApiError> {
        if self.control.current() == Control::Abort {
            return Err(self.stopping());
        }
        self.prompt.answer(answer).ok_or_else(|| {
            ApiError::conflict(format!("run {} has no prompt waiting", self.run_id))
                .hint("prompts arrive as `prompt` events and in `GET /api/status` (run.prompt)")
        })
    }

    /// Waits until the run has ended and returns how.
    pub async fn wait_finished(&self) -> Outcome {
        let mut rx = self.finished.subscribe();
        match rx.wait_for(|o| o.is_some()).await {
            Ok(o) => o.clone().unwrap_or_else(lost_outcome),
            Err(_) => lost_outcome(),
        }
    }

    /// Folds one executor event into the live state (the executor records the metrics).
    fn fold(&self, event: &Event) {
        let mut p = self.progress();
        match event {
            Event::RunStarted {
                total_steps,
                steps_to_do,
                estimated_rig_time_s,
            } => {
                p.total_steps = *total_steps;
                p.steps_done = total_steps.saturating_sub(*steps_to_do);
                p.estimated_rig_time_s = *estimated_rig_time_s;
            }
            Event::StepStarted { step, .. } => p.step = Some(*step),
            Event::StepFinished { eta_s, .. } => p.eta = Some((*eta_s, self.clock.now_s())),
            Event::StepDurable { files, .. } => {
                p.steps_done += 1;
                p.frames_written += files;
            }
            Event::RunFinished {
                status, message, ..
            } => {
                p.finished = Some((*status, message.clone()));
            }
            Event::Prompt { .. }
            | Event::DeviceFault { .. }
            | Event::Recovered { .. }
            | Event::Paused { .. }
            | Event::Resumed { .. }
            | Event::Warning { .. } => {}
        }
    }
}

fn lost_outcome() -> Outcome {
    Outcome {
        status: RunStatus::Failed,
        message: Some("the run's task went away without a result".into()),
        summary: None,
    }
}

/// What the run slot holds.
enum Slot {
    Idle,
    /// A run is being prepared (script, run directory); `cancelled` by an abort meanwhile.
    Starting {
        cancelled: bool,
    },
    Active(Arc<ActiveRun>),
}

/// The daemon's one active run (if any) and what it is doing.
pub struct RunManager {
    slot: Mutex<Slot>,
    /// True while no run is active or starting.
    idle: watch::Sender<bool>,
}

impl Default for RunManager {
    fn default() -> Self {
        Self {
            slot: Mutex::new(Slot::Idle),
            idle: watch::channel(true).0,
        }
    }
}

impl RunManager {
    fn slot(&self) -> MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// True while a run is executing or starting (manual device commands are refused then).
    pub fn is_active(&self) -> bool {
        !matches!(*self.slot(), Slot::Idle)
    }

    /// The executing run, if any.
    pub fn active(&self) -> Option<Arc<ActiveRun>> {
        match &*self.slot() {
            Slot::Active(a) => Some(a.clone()),
            _ => None,
        }
    }

    /// The active run, if any.
    pub fn snapshot(&self) -> Option<RunState> {
        self.active().map(|a| a.state())
    }

    /// Aborts the active run (e-stop, shutdown), or the one being started; returns at once.
    pub fn abort(&self) {
        let mut slot = self.slot();
        match &mut *slot {
            Slot::Idle => {}
            Slot::Starting { cancelled } => *cancelled = true,
            Slot::Active(a) => a.abort(),
        }
    }

    /// Waits until no run is active (after [`RunManager::abort`]).
    pub async fn wait_idle(&self) {
        let mut rx = self.idle.subscribe();
        let _ = rx.wait_for(|idle| *idle).await;
    }

    /// Claims the run slot for a run about to start: 409 if a run is active or starting.
    /// Dropping the reservation without launching frees the slot.
    pub fn reserve(&self, app: &AppState) -> Result<Reservation, ApiError> {
        let mut slot = self.slot();
        match &*slot {
            Slot::Idle => {
                *slot = Slot::Starting { cancelled: false };
                self.idle.send_replace(false);
                Ok(Reservation {
                    app: app.clone(),
                    launched: false,
                })
            }
            Slot::Starting { .. } => Err(ApiError::conflict("another run is starting")
                .hint("wait for it; `GET /api/status` shows the active run")),
            Slot::Active(a) => Err(ApiError::conflict(format!(
                "run {} is active; one run at a time",
                a.run_id
            ))
            .hint(format!(
                "wait for it, or `POST /api/runs/{}/abort` it first",
                a.run_id
            ))),
        }
    }

    fn release(&self, run_id: Option<&str>) {
        let mut slot = self.slot();
        let matches = match (&*slot, run_id) {
            (Slot::Starting { .. }, None) => true,
            (Slot::Active(a), Some(id)) => a.run_id == id,
            _ => false,
        };
        if matches {
            *slot = Slot::Idle;
            self.idle.send_replace(true);
            metrics::gauge!("stagehand_run_active").set(0.0);
        }
    }
}

/// The run slot, claimed by [`RunManager::reserve`].
pub struct Reservation {
    app: AppState,
    launched: bool,
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if !self.launched {
            self.app.runs.release(None);
        }
    }
}

/// What [`Reservation::launch`] needs to know about the run.
pub struct LaunchSpec {
    pub run_id: String,
    pub dir: PathBuf,
    pub script: String,
    pub total_steps: usize,
    /// Steps and frames already durable (a resumed run).
    pub steps_done: usize,
    pub frames_written: usize,
    pub estimated_rig_time_s: f64,
}

impl Reservation {
    /// Waits for a manual device command in flight to finish (none starts while the slot is
    /// claimed), then fails if the e-stop latched or an abort came while the run was prepared.
    pub async fn settle(&self) -> Result<(), ApiError> {
        match tokio::time::timeout(MANUAL_WAIT, self.app.manual.all()).await {
            Ok(guard) => drop(guard),
            Err(_) => {
                return Err(ApiError::conflict(
                    "a manual device command (a move, homing or a jog) is still in progress",
                )
                .hint("wait for it to end or stop the axis, then start the run again"));
            }
        }
        self.check()
    }

    /// Fails if the e-stop latched or an abort came while the run was being prepared.
    pub fn check(&self) -> Result<(), ApiError> {
        if self.app.estop.is_latched() {
            return Err(
                ApiError::conflict("the e-stop is latched: runs and captures are refused")
                    .hint("make the rig safe, then `POST /api/estop/reset`"),
            );
        }
        if matches!(*self.app.runs.slot(), Slot::Starting { cancelled: true }) {
            return Err(ApiError::conflict("aborted while the run was starting")
                .hint("start it again when the rig is ready"));
        }
        Ok(())
    }

    /// Starts the run: `body` gets the run's wiring and executes it on a task of its own.
    pub fn launch<F, Fut>(mut self, spec: LaunchSpec, body: F) -> Result<Arc<ActiveRun>, ApiError>
    where
        F: FnOnce(Wiring) -> Fut,
        Fut: std::future::Future<Output = Result<Summary, SessionError>> + Send + 'static,
    {
        self.check()?;
        let app = self.app.clone();
        let (events, rx) = broadcast::channel(EVENT_CAPACITY);
        let control = RunControl::new();
        let prompt = Arc::new(PromptSlot::default());
        let active = Arc::new(ActiveRun {
            run_id: spec.run_id.clone(),
            dir: spec.dir,
            script: spec.script,
            control: control.clone(),
            prompt: prompt.clone(),
            clock: app.rig.clock,
            rig_start_s: app.rig.clock.now_s(),
            started_unix_s: crate::executor::wall_now(),
            progress: Mutex::new(Progress {
                total_steps: spec.total_steps,
                steps_done: spec.steps_done,
                frames_written: spec.frames_written,
                step: None,
                estimated_rig_time_s: spec.estimated_rig_time_s,
                eta: None,
                finished: None,
            }),
            finished: watch::channel(None).0,
        });
        let operator = Arc::new(ApiOperator::new(app.clone(), spec.run_id.clone(), prompt));
        let wiring = Wiring {
            events,
            control,
            operator,
            reserve_bytes: DEFAULT_RESERVE_BYTES,
        };
        let run = body(wiring);
        {
            let mut slot = app.runs.slot();
            *slot = Slot::Active(active.clone());
        }
        self.launched = true;
        metrics::gauge!("stagehand_run_active").set(1.0);
        metrics::counter!("stagehand_runs_started_total").increment(1);
        tracing::info!(run = %active.run_id, "run started");
        let forwarder = tokio::spawn(forward(app.clone(), active.clone(), rx));
        let supervised = active.clone();
        // While the run drives it, the simulated rig renders ahead of its frames.
        render_ahead(&app, true);
        tokio::spawn(async move {
            // The run on a task of its own, so even a panic ends in a recorded outcome.
            let joined = tokio::spawn(run).await;
            render_ahead(&app, false);
            if tokio::time::timeout(FORWARDER_DRAIN, forwarder)
                .await
                .is_err()
            {
                tracing::warn!(run = %supervised.run_id, "the event forwarder did not drain");
            }
            let outcome = outcome_of(&supervised, joined);
            finish(&app, &supervised, outcome);
            // No frames are made until the next run: the memory kept for them goes back.
            stagehand_devices::realtime::spawn_blocking(stagehand_dataset::release_frame_memory);
        });
        Ok(active)
    }
}

/// Starts or stops the simulated rig's rendering ahead (`World::set_render_ahead`): the
/// cameras trace the world the rig settles into while it settles, as a real camera's frame
/// costs only its readout after the exposure. Without it frames still render, after their
/// exposures.
fn render_ahead(app: &AppState, on: bool) {
    if let Some(world) = &app.rig.world
        && let Err(e) = world.set_render_ahead(on)
    {
        tracing::warn!("simulated rig: cannot render ahead ({e}); frames render after exposure");
    }
}

/// How the run ended, from its result and its `run_finished` event.
fn outcome_of(
    active: &ActiveRun,
    joined: Result<Result<Summary, SessionError>, tokio::task::JoinError>,
) -> Outcome {
    let reported = active.progress().finished.clone();
    match joined {
        Ok(Ok(summary)) => Outcome {
            status: summary.status,
            message: reported.and_then(|(_, m)| m),
            summary: Some(summary),
        },
        Ok(Err(e)) => {
            let status = match (&reported, &e) {
                (Some((s, _)), _) => *s,
                (None, SessionError::Run(RunError::Aborted { .. })) => RunStatus::Aborted,
                (None, _) => RunStatus::Failed,
            };
            Outcome {
                status,
                message: Some(e.to_string()),
                summary: None,
            }
        }
        Err(e) => Outcome {
            status: RunStatus::Failed,
            message: Some(format!("the run's task failed: {e}")),
            summary: None,
        },
    }
}

/// Publishes how the run ended, frees the slot and wakes whoever waits for the outcome.
fn finish(app: &AppState, active: &Arc<ActiveRun>, mut outcome: Outcome) {
    let run_id = &active.run_id;
    outcome.message = outcome.message.map(|m| for_api(&m, run_id));
    if outcome.status != RunStatus::Done {
        let message = outcome.message.clone().unwrap_or_default();
        tracing::warn!(run = %run_id, status = %outcome.status, "run ended: {message}");
        app.hub.publish(
            EventKind::Warning,
            serde_json::json!({
                "run_id": run_id,
                "message": format!("run {run_id} {}: {message}", outcome.status),
            }),
        );
    }
    for v in outcome
        .summary
        .iter()
        .flat_map(|s| s.safety_violations.iter())
    {
        app.hub.publish(
            EventKind::Warning,
            serde_json::json!({"run_id": run_id, "message": format!("safety violation: {v}")}),
        );
    }
    app.runs.release(Some(run_id));
    active.finished.send_replace(Some(outcome));
}

/// Forwards one run's executor events to the hub until the run ends (every sender dropped).
async fn forward(app: AppState, active: Arc<ActiveRun>, mut rx: broadcast::Receiver<Event>) {
    use tokio::sync::broadcast::error::RecvError;
    loop {
        let event = match rx.recv().await {
            Ok(e) => e,
            Err(RecvError::Lagged(n)) => {
                metrics::counter!("stagehand_run_events_dropped_total").increment(n);
                tracing::warn!(run = %active.run_id, "the event forwarder fell {n} events behind");
                app.hub.publish(
                    EventKind::Warning,
                    serde_json::json!({
                        "run_id": active.run_id,
                        "message": format!("{n} progress events of run {} were dropped (the daemon is busy); the progress shown may skip", active.run_id),
                    }),
                );
                continue;
            }
            Err(RecvError::Closed) => return,
        };
        active.fold(&event);
        app.hub
            .publish(EventKind::Run, with_run_id(&event, &active.run_id));
        if let Event::Warning { message } = &event {
            app.hub.publish(
                EventKind::Warning,
                serde_json::json!({"run_id": active.run_id, "message": for_api(message, &active.run_id)}),
            );
        }
        if let Event::StepDurable { step, files } = event
            && files > 0
        {
            publish_frames(&app, &active, step).await;
        }
    }
}

/// `event` as JSON with `run_id` added, and its `message` worded for API clients.
fn with_run_id(event: &impl Serialize, run_id: &str) -> serde_json::Value {
    let mut value = serde_json::to_value(event)
        .unwrap_or_else(|e| serde_json::json!({"event": "unserialisable", "error": e.to_string()}));
    if let Some(map) = value.as_object_mut() {
        if let Some(serde_json::Value::String(m)) = map.get_mut("message") {
            *m = for_api(m, run_id);
        }
        map.insert("run_id".into(), run_id.into());
    }
    value
}

/// A message of the executor or the storage worded for the daemon's clients: where it tells
/// a CLI user to run `stagehand resume`, an API client or dashboard user is told how to
/// resume the run from there instead.
pub fn for_api(message: &str, run_id: &str) -> String {
    let endpoint = format!("`POST /api/runs/{run_id}/resume`");
    super::error::for_daemon(message)
        .replace(
            "run `stagehand resume`",
            &format!("resume it ({endpoint} or Resume on the dashboard)"),
        )
        .replace(
            "`stagehand resume` the run",
            &format!("resume the run ({endpoint} or Resume on the dashboard)"),
        )
        .replace(
            "`stagehand resume`",
            &format!("{endpoint} (or Resume on the dashboard)"),
        )
}

/// Publishes a `frame` event for each frame of a durable step.
async fn publish_frames(app: &AppState, active: &Arc<ActiveRun>, step: usize) {
    let dir = active.dir.clone();
    let run_id = active.run_id.clone();
    let frames = stagehand_devices::realtime::spawn_blocking(move || {
        crate::daemon::frame_index::frames_of_step(&dir, &run_id, step)
    })
    .await
    .map_err(|e| e.to_string())
    .and_then(|r| r.map_err(|e| e.to_string()));
    match frames {
        Ok(frames) => {
            for f in frames {
                app.hub
                    .publish(EventKind::Frame, with_run_id(&f, &active.run_id));
            }
        }
        Err(e) => {
            tracing::warn!(run = %active.run_id, step, "cannot list the step's frames: {e}");
            app.hub.publish(
                EventKind::Warning,
                serde_json::json!({
                    "run_id": active.run_id,
                    "message": format!("step {step}: frames written but not listed: {e}"),
                }),
            );
        }
    }
}
