//! Starting runs on the daemon's rig: a script of the library, a stored run resumed, and the
//! single capture (a generated two-step plan through the same executor path, so its frames
//! are durable and indexed like any run's).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::error::{ApiError, ViolationItem};
use super::frame_index::{self, FrameInfo};
use super::runs::{ActiveRun, LaunchSpec, Reservation};
use super::scripts::{self, EstimateInfo, Library, ViolationInfo};
use super::state::AppState;
use super::stored_runs;
use crate::executor::Start;
use crate::script::ScriptSource;
use crate::session::{self, Prepared, SessionError};
use crate::storage::{RunStatus, RunStore, StorageError};

/// `POST /api/runs` (and `POST /api/queue`).
#[derive(Debug, Clone, Deserialize, Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StartRun {
    /// Script name (`quickstart` or `quickstart.rhai`).
    pub script: String,
    /// Script parameters (as `--set`): numbers, strings, booleans or lists of those.
    #[serde(default)]
    #[schema(value_type = Option<Object>)]
    pub set: Option<BTreeMap<String, serde_json::Value>>,
    /// Must be the daemon's seed (`serve --seed`) if given: the simulated sensor noise is
    /// seeded once, when the daemon opens the rig.
    #[serde(default)]
    pub seed: Option<u64>,
}

/// A run that started.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Started {
    pub run_id: String,
    pub script: String,
    pub estimate: EstimateInfo,
    /// Warnings of the dry run (errors would have refused the run).
    pub warnings: Vec<ViolationInfo>,
}

/// `POST /api/capture`.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CaptureRequest {
    /// Camera ids (default: every camera).
    #[serde(default)]
    pub cameras: Option<Vec<String>>,
    /// Exposure time in seconds.
    pub exposure_s: f64,
    /// Analogue gain (linear, default 1).
    #[serde(default)]
    pub gain: Option<f64>,
}

/// The frames of a single capture.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct CaptureResult {
    /// The run that holds the frames (script `capture.rhai`).
    pub run_id: String,
    pub frames: Vec<FrameInfo>,
}

/// 409 while the e-stop is latched.
fn refuse_if_latched(app: &AppState) -> Result<(), ApiError> {
    if app.estop.is_latched() {
        return Err(
            ApiError::conflict("the e-stop is latched: runs and captures are refused")
                .hint("make the rig safe, then `POST /api/estop/reset`"),
        );
    }
    Ok(())
}

/// Maps a failed `prepare` / `create_run`: the script's fault is a 422 saying where.
/// Script errors and plan violations also come as a list of `{line, col, message}`.
fn session_error(script: &str, e: SessionError) -> ApiError {
    match e {
        SessionError::Script(e) => {
            let (line, col) = e.position().unzip();
            let item = ViolationItem {
                line,
                col,
                message: e.to_string(),
            };
            ApiError::unprocessable(e.to_string())
                .hint(format!(
                    "fix the script; `POST /api/scripts/{script}/validate` shows the dry run"
                ))
                .violations(vec![item])
        }
        SessionError::Invalid(ref violations, _) => {
            let items = violations
                .iter()
                .filter(|v| v.severity == crate::validate::Severity::Error)
                .map(|v| ViolationItem {
                    line: Some(v.at.line),
                    col: Some(v.at.col),
                    message: v.message.clone(),
                })
                .collect();
            ApiError::unprocessable(e.to_string())
                .hint(format!(
                    "fix the errors above; `POST /api/scripts/{script}/validate` shows the dry run"
                ))
                .violations(items)
        }
        e => ApiError::internal(format!("cannot create the run: {e}")),
    }
}

/// Builds, validates and estimates the plan and creates its run directory (blocking work on
/// the blocking pool).
async fn prepare_run(
    app: &AppState,
    source: ScriptSource,
    set: Vec<(String, String)>,
) -> Result<(Prepared, RunStore), ApiError> {
    let rig = app.rig_source.clone();
    let root = app.runs_dir();
    let seed = app.seed;
    let name = source.name.clone();
    stagehand_devices::realtime::spawn_blocking(move || {
        let prepared = session::prepare(source, &set, rig)?;
        let store = session::create_run(&prepared, &root, seed)?;
        Ok::<_, SessionError>((prepared, store))
    })
    .await
    .map_err(|e| ApiError::internal(format!("preparing the run stopped: {e}")))?
    .map_err(|e| session_error(name.trim_end_matches(".rhai"), e))
}

/// Launches a prepared plan on the daemon's rig.
fn launch_new(
    app: &AppState,
    reservation: Reservation,
    prepared: Prepared,
    store: RunStore,
    start: Start,
) -> Result<(Arc<ActiveRun>, Started), ApiError> {
    if let Err(e) = reservation.check() {
        // Stopped between creating the run directory and starting: say so in its index.
        let message = format!("not started: {}", e.error);
        if let Err(se) = store.set_status(RunStatus::Aborted, Some(&message)) {
            tracing::warn!(run = store.run_id(), "cannot record the run's status: {se}");
        }
        return Err(e);
    }
    let started = Started {
        run_id: store.run_id().to_string(),
        script: prepared.script.name.clone(),
        estimate: EstimateInfo::of(&prepared.plan, &prepared.estimate),
        warnings: prepared.warnings.iter().map(ViolationInfo::of).collect(),
    };
    let spec = LaunchSpec {
        run_id: started.run_id.clone(),
        dir: store.dir().to_path_buf(),
        script: started.script.clone(),
        total_steps: prepared.plan.steps.len(),
        steps_done: 0,
        frames_written: 0,
        estimated_rig_time_s: prepared.estimate.rig_time_s,
    };
    let rig = app.rig.clone();
    let active = reservation.launch(spec, move |wiring| {
        session::run_from(prepared, store, rig, wiring, start)
    })?;
    Ok((active, started))
}

/// Starts a script of the library.
pub async fn start_script(app: &AppState, req: StartRun) -> Result<Started, ApiError> {
    start_script_run(app, req).await.map(|(_, s)| s)
}

/// The script and `--set` overrides of a start request, checked (seed, script name, values).
pub fn checked_request(
    app: &AppState,
    req: &StartRun,
) -> Result<(ScriptSource, Vec<(String, String)>), ApiError> {
    if let Some(seed) = req.seed
        && seed != app.seed
    {
        return Err(ApiError::unprocessable(format!(
            "seed {seed}: this daemon's simulated sensor noise is seeded with {}",
            app.seed
        ))
        .hint("leave `seed` out, or restart the daemon with `--seed`"));
    }
    let (_, source) = Library::of(app).read(&req.script)?;
    let set = scripts::overrides(req.set.as_ref())?;
    Ok((source, set))
}

/// Starts a script of the library; also the run, to follow it to its end (the run queue).
pub async fn start_script_run(
    app: &AppState,
    req: StartRun,
) -> Result<(Arc<ActiveRun>, Started), ApiError> {
    refuse_if_latched(app)?;
    let (source, set) = checked_request(app, &req)?;
    let reservation = app.runs.reserve(app)?;
    reservation.settle().await?;
    let (prepared, store) = prepare_run(app, source, set).await?;
    launch_new(app, reservation, prepared, store, Start::Establish)
}

/// The directory of a stored run: 400 for a bad id, 404 if there is none.
pub fn run_dir(app: &AppState, run_id: &str) -> Result<PathBuf, ApiError> {
    scripts::check_run_id(run_id)?;
    let dir = app.runs_dir().join(run_id);
    // Not followed: a symlink in the runs directory is not a run.
    let is_dir = std::fs::symlink_metadata(&dir).is_ok_and(|m| m.is_dir());
    if !is_dir {
        return Err(
            ApiError::not_found(format!("no run {run_id}")).hint("`GET /api/runs` lists the runs")
        );
    }
    Ok(dir)
}

/// Resumes a stored run that stopped (aborted, failed, or interrupted by a crash) on the
/// daemon's rig: the steps not yet durable run, nothing is captured twice.
pub async fn resume_stored(app: &AppState, run_id: &str) -> Result<Arc<ActiveRun>, ApiError> {
    refuse_if_latched(app)?;
    let dir = run_dir(app, run_id)?;
    let reservation = app.runs.reserve(app)?;
    reservation.settle().await?;
    let refused = |why: String| {
        ApiError::conflict(format!("run {run_id} cannot be resumed: {why}"))
            .hint("`GET /api/runs/{id}` shows its status")
    };
    let opened = {
        let dir = dir.clone();
        stagehand_devices::realtime::spawn_blocking(move || {
            let stored = stored_runs::read(&dir);
            session::reopen(&dir).map(|r| {
                let eta = remaining_rig_time_s(&r);
                (r, stored, eta)
            })
        })
        .await
        .map_err(|e| ApiError::internal(format!("reopening the run stopped: {e}")))?
    };
    let (reopened, stored, remaining_s) = opened.map_err(|e| match e {
        SessionError::Storage(StorageError::RunInUse { .. }) => {
            refused("another process is writing it".into())
        }
        e => refused(e.to_string()),
    })?;
    match reopened.store.status() {
        Ok((RunStatus::Done, _)) => {
            return Err(
                ApiError::conflict(format!("run {run_id} is done; nothing to resume"))
                    .hint("start the script again for a new run"),
            );
        }
        Ok(_) => {}
        Err(e) => return Err(refused(e.to_string())),
    }
    if reopened.rig.text != app.rig_source.text {
        return Err(refused(format!(
            "it was recorded on rig `{}` as described then; this daemon owns rig `{}` ({})",
            reopened.manifest.rig_name, app.rig_source.spec.rig.name, app.rig_source.origin
        )));
    }
    if reopened.manifest.seed != app.seed {
        tracing::warn!(
            run = run_id,
            "resuming with sensor-noise seed {} (the run was started with {})",
            app.seed,
            reopened.manifest.seed
        );
    }
    let spec = LaunchSpec {
        run_id: run_id.to_string(),
        dir,
        script: reopened.manifest.script_name.clone(),
        total_steps: reopened.plan.steps.len(),
        steps_done: stored.steps_done,
        frames_written: stored.frames,
        estimated_rig_time_s: remaining_s,
    };
    let rig = app.rig.clone();
    reservation.launch(spec, move |wiring| {
        session::resume_on(reopened, rig, wiring)
    })
}

/// The estimated rig time of the steps a resumed run still has to do (from its first step not
/// yet durable, as the executor estimates it), so a resume answers a real ETA.
fn remaining_rig_time_s(r: &session::Reopened) -> f64 {
    use crate::estimate::{estimate_from, state_before};
    let done = match r.store.done_steps() {
        Ok(done) => done,
        Err(e) => {
            tracing::warn!("cannot read the run's done steps for its ETA: {e}");
            Default::default()
        }
    };
    let first = (0..r.plan.steps.len())
        .find(|i| !done.contains(i))
        .unwrap_or(r.plan.steps.len());
    let start = state_before(&r.plan, &r.rig.spec, first);
    estimate_from(&r.plan, &r.rig.spec, first, &start).rig_time_s
}

/// A Rhai script of one capture with the rig as it is (run in place: nothing moves or
/// switches). Camera ids come from the rig file; JSON string quoting is valid Rhai.
fn capture_script(cameras: &[String], exposure_s: f64, gain: f64) -> String {
    let q = |s: &str| serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into());
    let items: Vec<String> = cameras.iter().map(|s| q(s)).collect();
    format!(
        "// generated by POST /api/capture: one capture with the rig as it is\ncapture({exposure_s:?}, #{{cameras: [{}], gain: {gain:?}, label: \"capture\"}});\n",
        items.join(", ")
    )
}

/// One capture with the rig as it is: returns when the frames are durable.
pub async fn capture(app: &AppState, req: CaptureRequest) -> Result<CaptureResult, ApiError> {
    refuse_if_latched(app)?;
    let all: Vec<String> = app.rig.cameras.keys().cloned().collect();
    let cameras = match req.cameras {
        None => all.clone(),
        Some(list) => {
            if list.is_empty() {
                return Err(ApiError::unprocessable("cameras: the list is empty")
                    .hint("leave `cameras` out to capture with every camera"));
            }
            let mut out: Vec<String> = Vec::new();
            for id in list {
                if !all.contains(&id) {
                    return Err(ApiError::not_found(format!("no camera {id:?}"))
                        .hint(format!("this rig's cameras: {}", all.join(", "))));
                }
                if !out.contains(&id) {
                    out.push(id);
                }
            }
            out
        }
    };
    if all.is_empty() {
        return Err(ApiError::unprocessable("this rig has no cameras"));
    }
    let gain = req.gain.unwrap_or(1.0);
    let reservation = app.runs.reserve(app)?;
    reservation.settle().await?;
    let text = capture_script(&cameras, req.exposure_s, gain);
    let source = ScriptSource {
        name: "capture.rhai".into(),
        text,
    };
    let (prepared, store) = prepare_run(app, source, Vec::new()).await.map_err(|e| {
        if e.status == StatusCode::UNPROCESSABLE_ENTITY {
            e.hint("check exposure_s and gain against the cameras' limits (`GET /api/status`)")
        } else {
            e
        }
    })?;
    let step = prepared.plan.steps.len().saturating_sub(1);
    let (active, started) = launch_new(app, reservation, prepared, store, Start::InPlace)?;
    let outcome = active.wait_finished().await;
    let run_id = started.run_id;
    match outcome.status {
        RunStatus::Done => {}
        RunStatus::Aborted => {
            return Err(
                ApiError::conflict(format!("the capture was aborted (run {run_id})"))
                    .hint("an abort or the e-stop stopped it; try again when the rig is ready"),
            );
        }
        _ => {
            return Err(ApiError::new(
                StatusCode::BAD_GATEWAY,
                format!(
                    "the capture failed (run {run_id}): {}",
                    outcome.message.unwrap_or_default()
                ),
            )
            .hint("`GET /api/status` shows the rig; the run's message says which device"));
        }
    }
    let dir = active.dir.clone();
    let id = run_id.clone();
    let frames = stagehand_devices::realtime::spawn_blocking(move || {
        frame_index::frames_of_step(&dir, &id, step)
    })
    .await
    .map_err(|e| ApiError::internal(format!("listing the frames stopped: {e}")))?
    .map_err(|e| ApiError::internal(format!("cannot list the frames: {e}")))?;
    Ok(CaptureResult { run_id, frames })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_capture_script_is_one_capture_and_validates() {
        let text = capture_script(&["cam1".into()], 0.01, 1.0);
        assert_eq!(
            text.lines().filter(|l| !l.starts_with("//")).count(),
            1,
            "{text}"
        );
        assert!(text.contains(r#"cameras: ["cam1"]"#), "{text}");
        let rig = crate::rig::RigSource::load(None).expect("built-in rig");
        let source = ScriptSource {
            name: "capture.rhai".into(),
            text,
        };
        let dry = scripts::dry_run(&source, &[], &rig);
        assert!(dry.ok, "{}", dry.report);
        assert_eq!(dry.estimate.map(|e| e.raw_frames), Some(1));
    }
}
