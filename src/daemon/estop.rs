//! The emergency stop. `POST /api/estop` latches first (every motion and emission is refused
//! from then on), aborts any run, and puts every device in its safe state concurrently (laser
//! disarmed, every switched output off, every axis stopped and marked for re-homing, since a
//! stepper stopped abruptly may have lost steps); it never waits for a run or for
//! the manual-command lock, so it finishes within one device round trip. Every camera is
//! disarmed beside it, without holding up the report: a camera answers after the frame it is
//! reading out, and cameras neither move nor emit. Motion and emission
//! stay refused until `POST /api/estop/reset`.

use std::time::{Duration, Instant};

use futures_util::future::join_all;
use serde::Serialize;
use tokio::sync::watch;
use utoipa::ToSchema;

use super::device_state::{self, DevicesState};
use super::state::AppState;
use crate::daemon::events::EventKind;

/// How long the follow-up sweep waits for an aborted run to wind down before it puts the rig
/// in its safe state once more (a step that was mid-request when the e-stop came).
const FOLLOW_UP_WAIT: Duration = Duration::from_secs(10);

/// Latched e-stop state; a watch channel so a manual move in flight can stop itself the
/// moment the latch is set.
#[derive(Debug)]
pub struct EStop {
    latched: watch::Sender<bool>,
}

impl Default for EStop {
    fn default() -> Self {
        Self {
            latched: watch::channel(false).0,
        }
    }
}

impl EStop {
    /// True while the e-stop is latched: motion and emission are refused.
    pub fn is_latched(&self) -> bool {
        *self.latched.borrow()
    }

    /// Sets the latch (refuses new motion and emission from now on).
    pub fn latch(&self) {
        self.latched.send_replace(true);
    }

    /// Clears the latch.
    pub fn reset(&self) {
        self.latched.send_replace(false);
    }

    /// A receiver that sees the latch change (wait with `wait_for(|l| *l)`).
    pub fn subscribe(&self) -> watch::Receiver<bool> {
        self.latched.subscribe()
    }
}

/// What an e-stop (or its reset) did.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct EStopReport {
    /// True while latched.
    pub active: bool,
    /// Time from the request to every device having answered, in milliseconds (0 for a reset).
    pub elapsed_ms: f64,
    /// The run that was aborted, if one was active.
    pub aborted_run: Option<String>,
    /// Devices that failed to reach their safe state (each message names the device).
    pub errors: Vec<String>,
    /// Every device as it is after the e-stop (switch banks read back from the hardware,
    /// axes marked for re-homing); `null` for a reset.
    pub devices: Option<DevicesState>,
}

/// Triggers the e-stop: latch, abort the run, then laser disarm, every bank off and every axis
/// stopped, all at once; every device is tried even if others fail. Publishes an `estop`
/// event and records `stagehand_estop_seconds`. Disarms every camera in the background.
pub async fn trigger(app: &AppState) -> EStopReport {
    let t0 = Instant::now();
    app.estop.latch();
    let aborted_run = app.runs.snapshot().map(|r| r.run_id);
    app.runs.abort();
    spawn_disarm_cameras(app);
    let errors = safe_state(app).await;
    let elapsed = t0.elapsed().as_secs_f64();
    // The banks' states as the hardware reports them, so the snapshot below cannot show a
    // lamp on that the board switched off (or off that it kept on).
    for e in join_all(app.rig.banks.values().map(|b| b.read())).await {
        if let Err(e) = e {
            tracing::error!("e-stop: reading a switch bank back: {e}");
        }
    }
    metrics::histogram!("stagehand_estop_seconds").record(elapsed);
    metrics::counter!("stagehand_estops_total").increment(1);
    for e in &errors {
        tracing::error!("e-stop: {e}");
    }
    let report = EStopReport {
        active: true,
        elapsed_ms: elapsed * 1e3,
        aborted_run,
        errors,
        devices: Some(device_state::snapshot(&app.rig)),
    };
    tracing::warn!(
        "E-STOP: latched; devices safe in {:.1} ms ({} errors)",
        report.elapsed_ms,
        report.errors.len()
    );
    app.hub.publish(EventKind::Estop, &report);
    if report.aborted_run.is_some() {
        spawn_follow_up(app.clone());
    }
    report
}

/// Clears the latch and publishes `{active: false}`.
pub fn reset(app: &AppState) -> EStopReport {
    app.estop.reset();
    tracing::info!("e-stop reset");
    let report = EStopReport {
        active: false,
        elapsed_ms: 0.0,
        aborted_run: None,
        errors: Vec::new(),
        devices: None,
    };
    app.hub.publish(EventKind::Estop, &report);
    report
}

/// Laser disarmed, every switched output off, every axis stopped, concurrently. Returns the
/// failures.
async fn safe_state(app: &AppState) -> Vec<String> {
    let rig = &app.rig;
    let laser = async {
        match &rig.laser {
            Some(l) => l.disarm().await.err().into_iter().collect::<Vec<_>>(),
            None => Vec::new(),
        }
    };
    let banks = join_all(rig.banks.values().map(|b| b.all_off()));
    let axes = join_all(rig.axes.values().map(|a| a.emergency_stop()));
    let (laser, banks, axes) = tokio::join!(laser, banks, axes);
    laser
        .into_iter()
        .chain(banks.into_iter().filter_map(Result::err))
        .chain(axes.into_iter().filter_map(Result::err))
        .map(|e| e.to_string())
        .collect()
}

/// Disarms every camera concurrently, logging failures: a capture arms them before its pacing
/// wait, so an armed camera must not outlive the e-stop even if the run's own end is slow.
fn spawn_disarm_cameras(app: &AppState) {
    let cameras: Vec<_> = app.rig.cameras.values().cloned().collect();
    tokio::spawn(async move {
        for r in join_all(cameras.iter().map(|c| c.set_armed(false))).await {
            if let Err(e) = r {
                tracing::error!("e-stop: {e}");
            }
        }
    });
}

/// After aborting a run: once it has wound down (or after [`FOLLOW_UP_WAIT`]), put the rig in
/// its safe state again if the e-stop is still latched, in case a step of the run was mid
/// request when the e-stop came and switched something on after the first sweep.
fn spawn_follow_up(app: AppState) {
    tokio::spawn(async move {
        let _ = tokio::time::timeout(FOLLOW_UP_WAIT, app.runs.wait_idle()).await;
        if app.estop.is_latched() {
            for e in safe_state(&app).await {
                tracing::error!("e-stop follow-up: {e}");
            }
        }
    });
}
