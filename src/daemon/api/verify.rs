//! `GET /api/runs/{id}/verify`: the same check as `stagehand verify` (files against the index,
//! the index against the plan, no stray or temp files), on the blocking pool.

use axum::extract::State;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiResult};
use crate::daemon::frame_index;
use crate::daemon::state::AppState;
use crate::storage::verify::{VerifyReport, verify_run};

/// Checks a run's files and index: every file the index records is present, of its size and
/// SHA-256, and decodable; every done capture step has exactly the frames its plan step asks
/// for; nothing else is in the run directory. Problems are in the answer (`ok` false), with
/// the steps to retake and the command that does it; a run being written shows its in-flight
/// step as orphan files.
#[utoipa::path(get, path = "/api/runs/{id}/verify", tag = "runs",
    params(("id" = String, Path, description = "Run id")),
    responses(
        (status = 200, description = "The report (`ok` says whether anything is wrong)", body = VerifyReport),
        (status = 400, description = "Bad run id", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 500, description = "The run's manifest is unreadable", body = crate::daemon::error::ErrorBody)))]
async fn verify(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> ApiResult<ApiJson<VerifyReport>> {
    let runs_dir = app.runs_dir();
    let report = stagehand_devices::realtime::spawn_blocking(move || {
        let dir = frame_index::run_dir(&runs_dir, &id)?;
        verify_run(&dir).map_err(|e| {
            ApiError::internal(format!("run {id}: {e}"))
                .hint("the run directory is damaged beyond what verify can check")
        })
    })
    .await
    .map_err(|e| ApiError::internal(format!("verify worker failed: {e}")))??;
    Ok(ApiJson(report))
}

/// The verify route.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(verify))
}
