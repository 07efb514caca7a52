//! Runs: start a script, list and inspect runs, pause / resume / abort, answer prompts, and
//! the single capture.

use std::collections::BTreeMap;

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiQuery, ApiResult};
use crate::daemon::events::EventKind;
use crate::daemon::operator::PromptInfo;
use crate::daemon::run_start::{self, CaptureRequest, CaptureResult, StartRun, Started};
use crate::daemon::runs::{ActiveRun, RunState};
use crate::daemon::state::AppState;
use crate::daemon::stored_runs::StoredStatus;
use crate::daemon::stored_runs::{self, StoredRun};
use crate::executor::Answer;

/// One run as listed.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RunSummary {
    #[serde(flatten)]
    pub run: StoredRun,
    /// True for the run executing now (its `status` is then its live state: `running`,
    /// `paused`, `prompt` or `stopping`).
    pub active: bool,
    /// True when `POST /api/runs/{id}/resume` would continue it (stopped before its end).
    pub resumable: bool,
}

/// The manifest's essentials.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ManifestInfo {
    pub format_version: u32,
    pub software_version: String,
    pub script_name: String,
    pub plan_hash: String,
    #[schema(value_type = Object)]
    pub params: BTreeMap<String, serde_json::Value>,
    pub rig_name: String,
    pub seed: u64,
    pub simulated: bool,
}

/// One run in detail.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RunDetail {
    #[serde(flatten)]
    pub summary: RunSummary,
    /// `null` when the run directory is unreadable.
    pub manifest: Option<ManifestInfo>,
    /// Live state while the run is active.
    pub live: Option<RunState>,
}

/// `run` with the live state folded in.
fn summarise(run: StoredRun, active: Option<&RunState>) -> RunSummary {
    let mut run = run;
    run.message = run
        .message
        .map(|m| crate::daemon::runs::for_api(&m, &run.run_id));
    let live = active.filter(|a| a.run_id == run.run_id);
    if let Some(l) = live {
        run.status = l.state.into();
        run.ended_unix_s = None;
        run.duration_s = Some((crate::executor::wall_now() - run.created_unix_s).max(0.0));
    } else if run.status == StoredStatus::Running {
        // The index says running but nothing executes it: the daemon stopped mid-run.
        run.status = StoredStatus::Interrupted;
    }
    let resumable = live.is_none()
        && matches!(
            run.status,
            StoredStatus::Aborted | StoredStatus::Failed | StoredStatus::Interrupted
        );
    RunSummary {
        run,
        active: live.is_some(),
        resumable,
    }
}

/// Parameters of `GET /api/runs`.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct RunsQuery {
    /// At most this many runs, the newest (default: all).
    pub limit: Option<usize>,
}

/// The runs in the data directory, newest first (by creation), each with its start, end,
/// wall-clock duration and status; `limit` keeps the newest few. A broken run directory is
/// listed with status `unreadable` and its `error`.
#[utoipa::path(get, path = "/api/runs", tag = "runs",
    params(RunsQuery),
    responses(
        (status = 200, body = Vec<RunSummary>),
        (status = 400, description = "Bad query", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
    ))]
async fn list_runs(
    State(app): State<AppState>,
    ApiQuery(q): ApiQuery<RunsQuery>,
) -> ApiResult<ApiJson<Vec<RunSummary>>> {
    let root = app.runs_dir();
    let runs = stagehand_devices::realtime::spawn_blocking(move || stored_runs::list(&root))
        .await
        .map_err(|e| ApiError::internal(format!("listing runs stopped: {e}")))?
        .map_err(|e| ApiError::internal(e.to_string()))?;
    let live = app.runs.snapshot();
    Ok(ApiJson(
        runs.into_iter()
            .take(q.limit.unwrap_or(usize::MAX))
            .map(|r| summarise(r, live.as_ref()))
            .collect(),
    ))
}

/// One run: status, progress, its manifest's essentials and, while active, its live state.
#[utoipa::path(get, path = "/api/runs/{id}", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    responses(
        (status = 200, body = RunDetail),
        (status = 400, description = "Bad run id", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
    ))]
async fn get_run(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> ApiResult<ApiJson<RunDetail>> {
    let dir = run_start::run_dir(&app, &id)?;
    let run = stagehand_devices::realtime::spawn_blocking(move || stored_runs::read(&dir))
        .await
        .map_err(|e| ApiError::internal(format!("reading the run stopped: {e}")))?;
    let manifest = run.manifest.as_ref().map(|m| ManifestInfo {
        format_version: m.format_version,
        software_version: m.software_version.clone(),
        script_name: m.script_name.clone(),
        plan_hash: m.plan_hash.clone(),
        params: m.params.clone(),
        rig_name: m.rig_name.clone(),
        seed: m.seed,
        simulated: m.simulated,
    });
    let live = app.runs.snapshot().filter(|s| s.run_id == id);
    Ok(ApiJson(RunDetail {
        summary: summarise(run, live.as_ref()),
        manifest,
        live,
    }))
}

/// Starts a script on the rig. The dry run must be free of errors (422 with every error's
/// line and column otherwise); one run at a time (409).
#[utoipa::path(post, path = "/api/runs", tag = "runs",
    request_body = StartRun,
    responses(
        (status = 201, description = "Started", body = Started),
        (status = 400, description = "Bad script name or body", body = crate::daemon::error::ErrorBody),
        (status = 403, description = "Read-only token", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such script", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "A run is active, or the e-stop is latched", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "The script has errors (each with file:line:col), or bad `set`/`seed`", body = crate::daemon::error::ErrorBody),
    ))]
async fn start_run(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<StartRun>,
) -> ApiResult<(StatusCode, ApiJson<Started>)> {
    let started = run_start::start_script(&app, req).await?;
    Ok((StatusCode::CREATED, ApiJson(started)))
}

/// The active run if it is `id`: 404 for no such run, 409 if it is not the active one.
fn active_run(app: &AppState, id: &str, action: &str) -> ApiResult<std::sync::Arc<ActiveRun>> {
    if let Some(a) = app.runs.active().filter(|a| a.run_id == id) {
        return Ok(a);
    }
    run_start::run_dir(app, id)?;
    Err(
        ApiError::conflict(format!("run {id} is not running; cannot {action} it"))
            .hint("`GET /api/runs/{id}` shows its status; stopped runs can be resumed"),
    )
}

/// Pauses the active run at the next step boundary (the step under way finishes).
#[utoipa::path(post, path = "/api/runs/{id}/pause", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    responses(
        (status = 200, body = RunState),
        (status = 400, description = "Bad run id", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "Not running, already paused, or stopping", body = crate::daemon::error::ErrorBody),
    ))]
async fn pause_run(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> ApiResult<ApiJson<RunState>> {
    let run = active_run(&app, &id, "pause")?;
    run.pause()?;
    Ok(ApiJson(run.state()))
}

/// Continues a paused run, or resumes a stopped one (aborted, failed, interrupted) on the
/// daemon's rig: steps already durable are skipped, nothing is captured twice.
#[utoipa::path(post, path = "/api/runs/{id}/resume", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    responses(
        (status = 200, body = RunState),
        (status = 400, description = "Bad run id", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "Not paused, done, another run active, e-stop latched, or recorded on another rig", body = crate::daemon::error::ErrorBody),
    ))]
async fn resume_run(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> ApiResult<ApiJson<RunState>> {
    if let Some(run) = app.runs.active().filter(|a| a.run_id == id) {
        run.resume()?;
        return Ok(ApiJson(run.state()));
    }
    let run = run_start::resume_stored(&app, &id).await?;
    Ok(ApiJson(run.state()))
}

/// Aborts the active run: the rig goes to its safe state (lamps and laser off, axes stopped);
/// the run stays resumable. A pending prompt is answered `abort`.
#[utoipa::path(post, path = "/api/runs/{id}/abort", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    responses(
        (status = 200, body = RunState),
        (status = 400, description = "Bad run id", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "Not running", body = crate::daemon::error::ErrorBody),
    ))]
async fn abort_run(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> ApiResult<ApiJson<RunState>> {
    let run = active_run(&app, &id, "abort")?;
    run.abort();
    Ok(ApiJson(run.state()))
}

/// The operator's answer to a prompt.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum PromptAnswer {
    /// Done what the prompt asked; the run continues.
    Continue,
    /// Stop the run (resumable).
    Abort,
}

/// `POST /api/runs/{id}/prompt`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PromptReply {
    pub answer: PromptAnswer,
}

/// Answers the run's pending prompt.
#[utoipa::path(post, path = "/api/runs/{id}/prompt", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    request_body = PromptReply,
    responses(
        (status = 200, description = "The prompt answered", body = PromptInfo),
        (status = 400, description = "Bad run id or body", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "Not running, or no prompt waiting", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "`answer` is not continue or abort", body = crate::daemon::error::ErrorBody),
    ))]
async fn answer_prompt(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(reply): ApiJson<PromptReply>,
) -> ApiResult<ApiJson<PromptInfo>> {
    let run = active_run(&app, &id, "answer a prompt of")?;
    let answer = match reply.answer {
        PromptAnswer::Continue => Answer::Continue,
        PromptAnswer::Abort => Answer::Abort,
    };
    let info = run.answer(answer)?;
    let answered = match reply.answer {
        PromptAnswer::Continue => "continue",
        PromptAnswer::Abort => "abort",
    };
    app.hub.publish(
        EventKind::Prompt,
        serde_json::json!({"run_id": id, "step": info.step, "answered": answered}),
    );
    Ok(ApiJson(info))
}

/// One capture with the rig as it is (axes, lamps, laser), on the chosen cameras; returns
/// when the frames are on disk. Recorded as a run of its own (script `capture.rhai`).
#[utoipa::path(post, path = "/api/capture", tag = "runs",
    request_body = CaptureRequest,
    responses(
        (status = 200, body = CaptureResult),
        (status = 400, description = "Bad body", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such camera", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "A run is active, the e-stop is latched, or the capture was aborted", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "Exposure or gain outside the cameras' limits", body = crate::daemon::error::ErrorBody),
        (status = 502, description = "A device failed", body = crate::daemon::error::ErrorBody),
    ))]
async fn capture(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<CaptureRequest>,
) -> ApiResult<ApiJson<CaptureResult>> {
    Ok(ApiJson(run_start::capture(&app, req).await?))
}

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_runs, start_run))
        .routes(routes!(get_run))
        .routes(routes!(pause_run))
        .routes(routes!(resume_run))
        .routes(routes!(abort_run))
        .routes(routes!(answer_prompt))
        .routes(routes!(capture))
}
