//! The run queue over HTTP: submit runs ahead of time, list, remove and reorder them, and
//! start the queue again after an e-stop or a failed run paused it (see `daemon::queue`).

use axum::extract::State;
use axum::http::StatusCode;
use serde::Deserialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiResult, ErrorBody};
use crate::daemon::queue::{self, QueueItem, QueueState};
use crate::daemon::run_start::StartRun;
use crate::daemon::state::AppState;

/// The queue: whether it runs, the run it started, the runs waiting and the last ones done.
#[utoipa::path(get, path = "/api/queue", tag = "queue",
    responses((status = 200, body = QueueState)))]
async fn get_queue(State(app): State<AppState>) -> ApiJson<QueueState> {
    ApiJson(app.queue.state())
}

/// Queues a run (the body of `POST /api/runs`). It starts when the rig is idle and the runs
/// before it have ended; the dry run must pass now (422 with every violation otherwise).
#[utoipa::path(post, path = "/api/queue", tag = "queue",
    request_body = StartRun,
    responses(
        (status = 201, body = QueueItem, description = "Queued"),
        (status = 400, body = ErrorBody, description = "Bad script name or body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such script"),
        (status = 422, body = ErrorBody, description = "The script has errors (with `violations`), or bad `set`/`seed`")))]
async fn submit(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<StartRun>,
) -> ApiResult<(StatusCode, ApiJson<QueueItem>)> {
    queue::check_submission(&app, &req).await?;
    let item = app.queue.submit(req);
    let message = format!("queued item {} ({})", item.item_id, item.request.script);
    queue::publish(&app, "submitted", message);
    Ok((StatusCode::CREATED, ApiJson(item)))
}

/// Removes a queued run (one not started yet).
#[utoipa::path(delete, path = "/api/queue/{item}", tag = "queue",
    params(("item" = u64, Path, description = "Queue item id")),
    responses(
        (status = 200, body = QueueItem, description = "Removed"),
        (status = 400, body = ErrorBody, description = "Not an item id"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such queued item")))]
async fn remove(
    State(app): State<AppState>,
    ApiPath(item): ApiPath<u64>,
) -> ApiResult<ApiJson<QueueItem>> {
    let removed = app.queue.remove(item)?;
    let message = format!(
        "removed item {item} ({}) from the queue",
        removed.request.script
    );
    queue::publish(&app, "removed", message);
    Ok(ApiJson(removed))
}

/// `POST /api/queue/{item}/move`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MoveItem {
    /// The new place in the queue: 0 starts next.
    pub position: usize,
}

/// Moves a queued run to another place in the queue.
#[utoipa::path(post, path = "/api/queue/{item}/move", tag = "queue",
    params(("item" = u64, Path, description = "Queue item id")),
    request_body = MoveItem,
    responses(
        (status = 200, body = QueueState, description = "The queue after the move"),
        (status = 400, body = ErrorBody, description = "Not an item id, or a malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such queued item"),
        (status = 422, body = ErrorBody, description = "Position past the end of the queue")))]
async fn move_item(
    State(app): State<AppState>,
    ApiPath(item): ApiPath<u64>,
    ApiJson(req): ApiJson<MoveItem>,
) -> ApiResult<ApiJson<QueueState>> {
    app.queue.move_to(item, req.position)?;
    let message = format!("moved queued item {item} to position {}", req.position);
    queue::publish(&app, "moved", message);
    Ok(ApiJson(app.queue.state()))
}

/// Lets the queue start its runs again (after an e-stop, a failed or aborted run, or a stop).
#[utoipa::path(post, path = "/api/queue/start", tag = "queue",
    responses(
        (status = 200, body = QueueState),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 409, body = ErrorBody, description = "The e-stop is latched")))]
async fn start(State(app): State<AppState>) -> ApiResult<ApiJson<QueueState>> {
    if app.estop.is_latched() {
        return Err(
            ApiError::conflict("the e-stop is latched: the queue cannot start runs")
                .hint("make the rig safe, `POST /api/estop/reset`, then start the queue"),
        );
    }
    app.queue.start();
    queue::publish(&app, "started", "the queue was started".into());
    Ok(ApiJson(app.queue.state()))
}

/// Pauses the queue: the run under way goes on, no further one starts until
/// `POST /api/queue/start`.
#[utoipa::path(post, path = "/api/queue/stop", tag = "queue",
    responses(
        (status = 200, body = QueueState),
        (status = 403, body = ErrorBody, description = "Read-only token")))]
async fn stop(State(app): State<AppState>) -> ApiJson<QueueState> {
    app.queue
        .pause("stopped over the API (`POST /api/queue/stop`)");
    queue::publish(&app, "stopped", "the queue was stopped".into());
    ApiJson(app.queue.state())
}

/// The queue routes.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(get_queue, submit))
        .routes(routes!(remove))
        .routes(routes!(move_item))
        .routes(routes!(start))
        .routes(routes!(stop))
}
