//! The rules of manual device commands, shared by the HTTP device endpoints and the jog
//! WebSocket: what is refused (e-stop latched, a run active), the per-device locks, how a
//! move is cut short by the e-stop, and how device errors become API errors.
//!
//! Commands on one device run one at a time; commands on different devices (a lamp switch
//! during a long turntable move) do not wait for each other. A run start waits for every
//! command in flight.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::http::StatusCode;
use stagehand_devices::axis::AxisHandle;
use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::sync::OwnedMutexGuard;

use super::error::{ApiError, ApiResult};
use super::state::AppState;

/// How long a manual command waits for the one before it on the same device (a lamp switch
/// behind another) before it is refused as busy.
const LOCK_WAIT: Duration = Duration::from_secs(1);

/// The lock key of an axis.
pub fn axis_key(id: &str) -> String {
    format!("axis {id}")
}

/// The lock key of a lamp.
pub fn lamp_key(id: &str) -> String {
    format!("lamp {id}")
}

/// The lock key of the laser.
pub const LASER_KEY: &str = "laser";

/// One lock per device (by key: [`axis_key`], [`lamp_key`], [`LASER_KEY`]), made on first use.
#[derive(Default)]
pub struct ManualLocks {
    locks: Mutex<BTreeMap<String, Arc<tokio::sync::Mutex<()>>>>,
}

/// The locks a manual command holds until it ends (dropping it releases them).
pub struct ManualGuard {
    _held: Vec<OwnedMutexGuard<()>>,
}

impl ManualLocks {
    fn mutex(&self, key: &str) -> Arc<tokio::sync::Mutex<()>> {
        let mut locks = self.locks.lock().unwrap_or_else(|p| p.into_inner());
        locks.entry(key.to_string()).or_default().clone()
    }

    /// Waits for the locks of `keys`, taken in key order (as every caller does, so two
    /// commands on overlapping devices never deadlock).
    async fn lock(&self, keys: &[String]) -> ManualGuard {
        let mut keys: Vec<&String> = keys.iter().collect();
        keys.sort();
        keys.dedup();
        let mut held = Vec::with_capacity(keys.len());
        for key in keys {
            held.push(self.mutex(key).lock_owned().await);
        }
        ManualGuard { _held: held }
    }

    /// Takes the locks of `keys` if they are all free.
    fn try_lock(&self, keys: &[String]) -> Option<ManualGuard> {
        let held = keys
            .iter()
            .map(|k| self.mutex(k).try_lock_owned().ok())
            .collect::<Option<Vec<_>>>()?;
        Some(ManualGuard { _held: held })
    }

    /// Waits until no manual command is in flight on any device, and holds them all (a run
    /// start: commands arriving meanwhile see the run and are refused).
    pub async fn all(&self) -> ManualGuard {
        let keys: Vec<String> = {
            let locks = self.locks.lock().unwrap_or_else(|p| p.into_inner());
            locks.keys().cloned().collect()
        };
        self.lock(&keys).await
    }
}

/// 409 when the e-stop is latched.
pub fn refuse_if_latched(app: &AppState) -> ApiResult<()> {
    if app.estop.is_latched() {
        return Err(
            ApiError::conflict("the e-stop is latched: motion and emission are refused")
                .hint("make the rig safe, then `POST /api/estop/reset`"),
        );
    }
    Ok(())
}

/// 409 when a run is active.
pub fn refuse_if_running(app: &AppState) -> ApiResult<()> {
    if app.runs.is_active() {
        let id = app
            .runs
            .snapshot()
            .map(|r| r.run_id)
            .unwrap_or_else(|| "?".into());
        return Err(ApiError::conflict(format!(
            "a run is active ({id}) and owns the rig, also while paused or prompting"
        ))
        .hint(format!(
            "wait for it to end, or `POST /api/runs/{id}/abort` (it stays resumable)"
        )));
    }
    Ok(())
}

/// Checks the refusals (`latch`: also refuse while the e-stop is latched, for commands that
/// move or emit) and takes the locks of the devices `keys` names, waiting at most
/// [`LOCK_WAIT`] for commands in flight on them.
pub async fn lock(app: &AppState, keys: &[String], latch: bool) -> ApiResult<ManualGuard> {
    let check = || -> ApiResult<()> {
        if latch {
            refuse_if_latched(app)?;
        }
        refuse_if_running(app)
    };
    check()?;
    let guard = tokio::time::timeout(LOCK_WAIT, app.manual.lock(keys))
        .await
        .map_err(|_| busy())?;
    // The rig may have changed while this command waited.
    check()?;
    Ok(guard)
}

/// Like [`lock`] without waiting (the jog WebSocket answers at once).
pub fn try_lock(app: &AppState, keys: &[String]) -> ApiResult<ManualGuard> {
    refuse_if_latched(app)?;
    refuse_if_running(app)?;
    app.manual.try_lock(keys).ok_or_else(busy)
}

fn busy() -> ApiError {
    ApiError::conflict("another manual command on this device is in progress (a move or homing)")
        .hint("wait for it to finish, or stop the axis with `POST /api/axes/{id}/stop`")
}

/// Runs an axis request (move, home) that the e-stop must be able to cut short: if the latch
/// is set while it runs, the axis is stopped at once and the result is a 409. Closes the gap
/// between this command's latch check and its request reaching the axis.
pub async fn guarded(
    app: &AppState,
    axis: &AxisHandle,
    request: impl Future<Output = Result<f64, DeviceError>>,
) -> ApiResult<f64> {
    let mut latch = app.estop.subscribe();
    let r = tokio::select! {
        r = request => r,
        // (The guard `wait_for` returns must not live across the stop below: it is not Send.)
        () = async { let _ = latch.wait_for(|l| *l).await; } => {
            let _ = axis.stop().await;
            return Err(estop_interrupted(axis));
        }
    };
    match r {
        Ok(p) => Ok(p),
        Err(_) if app.estop.is_latched() => Err(estop_interrupted(axis)),
        Err(e) => Err(device_error(&e)),
    }
}

fn estop_interrupted(axis: &AxisHandle) -> ApiError {
    ApiError::conflict(format!(
        "{}: interrupted by the e-stop at {:.3}°",
        axis.id(),
        axis.status().position_deg
    ))
    .hint("make the rig safe, then `POST /api/estop/reset`")
}

/// A device error as the API answers it: a request the device refuses as out of range is
/// 422, a state that must change first (not homed, not armed, interlock open, interrupted by
/// a stop) 409, a device failure 502.
pub fn device_error(e: &DeviceError) -> ApiError {
    let msg = e.to_string();
    let device = &e.device;
    match &e.kind {
        DeviceErrorKind::OutsideSoftLimits {
            min_deg, max_deg, ..
        } => ApiError::unprocessable(msg).hint(format!(
            "`{device}` moves within [{min_deg}, {max_deg}]°; choose a target inside the limits"
        )),
        DeviceErrorKind::LaserColour { fitted, .. } => ApiError::unprocessable(msg).hint(format!(
            "omit colour_nm to use the fitted module, or use one of {fitted:?} nm"
        )),
        DeviceErrorKind::NoSuchChannel { .. }
        | DeviceErrorKind::Rejected { .. }
        | DeviceErrorKind::Exposure { .. }
        | DeviceErrorKind::Gain { .. } => ApiError::unprocessable(msg),
        DeviceErrorKind::NotHomed => ApiError::conflict(msg)
            .hint(format!("home it first: `POST /api/axes/{device}/home`")),
        DeviceErrorKind::LaserNotArmed => ApiError::conflict(msg)
            .hint("arm it first: `POST /api/laser/arm` with {\"confirm\": true}"),
        DeviceErrorKind::InterlockOpen => ApiError::conflict(msg).hint(
            "close the enclosure door (simulated rigs: `POST /api/interlock` with {\"closed\": true})",
        ),
        DeviceErrorKind::Other { message } if message.contains("interrupted by stop") => {
            ApiError::conflict(msg).hint("a stop request interrupted it; send the command again")
        }
        _ => ApiError::device(e),
    }
}

/// The `outcome` label of `stagehand_manual_commands_total`: `ok`, `refused` (4xx) or
/// `device_error` (502).
pub fn outcome(r: &ApiResult<impl Sized>) -> &'static str {
    match r {
        Ok(_) => "ok",
        Err(e) if e.status == StatusCode::BAD_GATEWAY => "device_error",
        Err(_) => "refused",
    }
}
