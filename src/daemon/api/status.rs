//! Rig status, live events (SSE), the recent-event log and Prometheus metrics.

use std::convert::Infallible;
use std::time::Duration;

use axum::Extension;
use axum::extract::State;
use axum::http::{HeaderMap, header};
use axum::response::IntoResponse;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::Stream;
use serde::Serialize;
use tokio::sync::broadcast::error::RecvError;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::auth::Role;
use crate::daemon::device_state::{self, DevicesState};
use crate::daemon::error::ApiJson;
use crate::daemon::events::HubEvent;
use crate::daemon::runs::RunState;
use crate::daemon::state::AppState;

/// The rig the daemon owns.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RigInfo {
    pub name: String,
    /// A path or `builtin:<name>`.
    pub origin: String,
    /// True when every device is simulated (frames are rendered).
    pub simulated: bool,
    /// True when the real drivers talk to firmware emulators (`serve --emulate`).
    pub emulated: bool,
}

/// Everything a client needs to draw the rig (also sent as the SSE `resync` event).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Status {
    pub rig: RigInfo,
    /// True while the e-stop is latched: nothing moves or emits until it is reset.
    pub estop: bool,
    pub devices: DevicesState,
    /// The active run, if any.
    pub run: Option<RunState>,
    /// Number of event subscribers (SSE clients).
    pub subscribers: usize,
}

/// The current status.
pub fn status_of(app: &AppState) -> Status {
    Status {
        rig: RigInfo {
            name: app.rig_source.spec.rig.name.clone(),
            origin: app.rig_source.origin.clone(),
            simulated: !crate::rig::needs_real_time(&app.rig_source.spec),
            emulated: app.emulation.is_some(),
        },
        estop: app.estop.is_latched(),
        devices: device_state::snapshot(&app.rig),
        run: app.runs.snapshot(),
        subscribers: app.hub.subscribers(),
    }
}

/// Rig, devices, e-stop and the active run.
#[utoipa::path(get, path = "/api/status", tag = "status",
    responses((status = 200, body = Status), (status = 401, body = crate::daemon::error::ErrorBody)))]
async fn get_status(State(app): State<AppState>) -> ApiJson<Status> {
    ApiJson(status_of(&app))
}

/// The last 200 events, oldest first (the dashboard's event log on load).
#[utoipa::path(get, path = "/api/events/recent", tag = "status",
    responses((status = 200, body = Vec<HubEvent>)))]
async fn recent_events(State(app): State<AppState>) -> ApiJson<Vec<HubEvent>> {
    ApiJson(app.hub.recent())
}

/// Server-Sent Events: `device`, `run`, `frame`, `prompt`, `warning`, `estop`, `queue`, each
/// with an increasing `id`. A new stream starts with a `resync` event carrying the whole
/// status. A client reconnecting with `Last-Event-ID` (browsers' `EventSource` does) is
/// replayed the events it missed instead, while the daemon still holds them (the last 200),
/// else it gets a `resync`. A client that falls behind gets a `resync` instead of the events
/// it missed. When the daemon stops, a run it aborts sends its final `run` event before the
/// stream ends.
#[utoipa::path(get, path = "/api/events", tag = "status",
    params(("Last-Event-ID" = Option<u64>, Header, description = "The `id` of the last event received: the events after it are replayed")),
    responses((status = 200, description = "text/event-stream of events", content_type = "text/event-stream")))]
async fn events(
    State(app): State<AppState>,
    headers: HeaderMap,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let after = headers
        .get("last-event-id")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    let (mut rx, missed) = match after {
        Some(after) => app.hub.subscribe_after(after),
        None => (app.hub.subscribe(), None),
    };
    metrics::gauge!("stagehand_sse_clients").increment(1.0);
    let guard = ClientGuard;
    let stream = async_stream(move |tx| async move {
        let _guard = guard;
        let first = match missed {
            Some(missed) => missed.iter().map(sse_event).collect(),
            None => vec![resync(&app)],
        };
        for event in first {
            if tx.send(event).await.is_err() {
                return;
            }
        }
        loop {
            let received = tokio::select! {
                // Events already published go out before the stream ends at shutdown.
                biased;
                r = rx.recv() => r,
                // The client went away while nothing happened: end now, not at the next event.
                () = tx.closed() => return,
                () = app.hub.closed() => return,
            };
            let event = match received {
                Ok(e) => sse_event(&e),
                Err(RecvError::Lagged(n)) => {
                    metrics::counter!("stagehand_sse_resyncs_total").increment(1);
                    tracing::debug!("SSE client fell {n} events behind; resynchronising");
                    resync(&app)
                }
                Err(RecvError::Closed) => return,
            };
            if tx.send(event).await.is_err() {
                return;
            }
        }
    });
    Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
}

/// Decrements the SSE client gauge when a stream ends.
struct ClientGuard;

impl Drop for ClientGuard {
    fn drop(&mut self) {
        metrics::gauge!("stagehand_sse_clients").decrement(1.0);
    }
}

fn sse_event(e: &HubEvent) -> Event {
    Event::default()
        .event(e.kind.as_str())
        .id(e.seq.to_string())
        .data(serde_json::to_string(e).unwrap_or_default())
}

fn resync(app: &AppState) -> Event {
    Event::default()
        .event("resync")
        .data(serde_json::to_string(&status_of(app)).unwrap_or_default())
}

/// A stream fed by a task through a small channel: when the client stops reading, the channel
/// fills, the task's `send` waits, and the task's broadcast receiver lags (never the sender).
fn async_stream<F, Fut>(f: F) -> impl Stream<Item = Result<Event, Infallible>>
where
    F: FnOnce(tokio::sync::mpsc::Sender<Event>) -> Fut,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    tokio::spawn(f(tx));
    futures_util::StreamExt::map(tokio_stream::wrappers::ReceiverStream::new(rx), Ok)
}

/// Prometheus text: step timing, frames written, dropped frames, device errors, reconnects,
/// SSE clients.
#[utoipa::path(get, path = "/api/metrics", tag = "status",
    responses((status = 200, description = "Prometheus text exposition format", content_type = "text/plain")))]
async fn metrics_text(State(app): State<AppState>) -> impl IntoResponse {
    app.metrics.run_upkeep();
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        app.metrics.render(),
    )
}

/// The role of the token this request carries.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct WhoAmI {
    pub role: Role,
}

/// Which role the caller's token has (the dashboard disables controls for `read_only`).
#[utoipa::path(get, path = "/api/whoami", tag = "status",
    responses((status = 200, body = WhoAmI), (status = 401, body = crate::daemon::error::ErrorBody)))]
async fn whoami(role: Option<Extension<Role>>) -> ApiJson<WhoAmI> {
    // The auth middleware always sets the role on /api/ routes.
    let role = role.map(|Extension(r)| r).unwrap_or(Role::ReadOnly);
    ApiJson(WhoAmI { role })
}

/// `GET /api/health`: for load balancers and monitoring, without a token.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Health {
    /// `ok` while the daemon serves.
    pub status: String,
    /// The daemon's software version.
    pub version: String,
    /// Seconds since the daemon started.
    pub uptime_s: f64,
}

/// Whether the daemon is up: status, version and uptime. Needs no token and says nothing
/// else (no rig, run or device state).
#[utoipa::path(get, path = "/api/health", tag = "status", security(()),
    responses((status = 200, body = Health)))]
async fn health(State(app): State<AppState>) -> ApiJson<Health> {
    ApiJson(Health {
        status: "ok".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        uptime_s: app.started.elapsed().as_secs_f64(),
    })
}

/// The routes that need no token (outside the token check).
pub fn public_routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(health))
}

/// The status, event and metrics routes.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(whoami))
        .routes(routes!(get_status))
        .routes(routes!(recent_events))
        .routes(routes!(events))
        .routes(routes!(metrics_text))
}
