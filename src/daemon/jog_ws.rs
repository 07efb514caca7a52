//! Hold-to-jog over a WebSocket (`GET /api/ws/jog`): the dashboard's jog buttons move an axis
//! while they are held, and a dead-man timer stops it when the client goes quiet, so a lost
//! connection or a frozen browser can never leave an axis running.
//!
//! Protocol (JSON text messages). Client → daemon:
//! - `{"axis": "turntable", "direction": 1 | -1, "speed": 0..1}` starts moving toward the soft
//!   limit in that direction (`speed` defaults to 1, full speed; below 1 the axis crawls in
//!   short steps of `speed × cruise speed × 0.5 s`). Repeating it for the same axis and
//!   direction counts as a keepalive.
//! - `{"hold": true}` keepalive; send one every 200 ms while the button is held.
//! - `{"stop": true}` stops.
//!
//! If no message arrives for 500 ms, or the socket closes, the axis stops (dead man).
//! Daemon → client: `{"axis", "position_deg", "moving", "homed", "estimated"}` every 100 ms
//! while moving (positions mid-move are estimated from the motion profile) and once stopped;
//! `{"stopped": "<reason>", "axis", "position_deg"}` when a jog ends (`stop`, `deadman`,
//! `limit`, `estop`, `error`); `{"error", "hint"}` when a message is refused (the same
//! refusals as the HTTP commands: e-stop latched, a run active, another manual command, an
//! axis not homed, an unknown axis).

use std::time::Duration;

use axum::extract::State;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_devices::DeviceResult;
use stagehand_devices::axis::AxisHandle;
use stagehand_devices::motion::Trapezoid;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::auth::Role;
use super::error::ApiError;
use super::manual;
use super::state::AppState;

/// The dead-man time: the axis stops when no message came for this long.
pub const DEADMAN: Duration = Duration::from_millis(500);
/// How often position updates are sent while moving.
const UPDATE_EVERY: Duration = Duration::from_millis(100);
/// Duration of one crawl step at cruise speed when `speed` < 1.
const CRAWL_STEP_S: f64 = 0.5;
/// How many times ending a jog sends a stop before giving up on the leg.
const STOP_TRIES: usize = 10;
/// What a client may send.
const MESSAGE_HINT: &str =
    r#"send {"axis", "direction": 1|-1, "speed"?}, {"hold": true} or {"stop": true}"#;
/// Largest accepted message (they are tiny).
const MAX_MESSAGE_BYTES: usize = 4096;

/// A client message.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClientMessage {
    axis: Option<String>,
    direction: Option<i32>,
    speed: Option<f64>,
    #[serde(default)]
    hold: bool,
    #[serde(default)]
    stop: bool,
}

/// A position update.
#[derive(Debug, Serialize)]
struct Update<'a> {
    axis: &'a str,
    position_deg: f64,
    moving: bool,
    homed: bool,
    /// True when the position is estimated from the motion profile (mid-move).
    estimated: bool,
}

/// Hold-to-jog WebSocket; needs the operator token (browsers pass it as `?access_token=`).
/// See the module documentation for the message protocol: `{"axis", "direction": ±1,
/// "speed"?}` starts, `{"hold": true}` every 200 ms keeps moving, `{"stop": true}` stops, and
/// 500 ms without a message (or closing the socket) stops the axis.
#[utoipa::path(get, path = "/api/ws/jog", tag = "devices",
    params(("access_token" = Option<String>, Query, description = "The operator token, for clients that cannot send headers")),
    responses(
        (status = 101, description = "Switching Protocols: the jog WebSocket (see the description for its messages)"),
        (status = 400, body = crate::daemon::error::ErrorBody, description = "Not a WebSocket upgrade request"),
        (status = 401, body = crate::daemon::error::ErrorBody, description = "No valid token"),
        (status = 403, body = crate::daemon::error::ErrorBody, description = "Read-only token")))]
pub async fn ws_jog(
    State(app): State<AppState>,
    role: Option<axum::Extension<Role>>,
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Response {
    if role.map(|r| r.0) != Some(Role::Operator) {
        return ApiError::new(StatusCode::FORBIDDEN, "jogging needs the operator token")
            .hint("connect with the operator token (`?access_token=` from a browser)")
            .into_response();
    }
    let ws = match ws {
        Ok(ws) => ws,
        Err(e) => {
            return ApiError::bad_request(format!("not a WebSocket upgrade: {e}"))
                .hint("connect with a WebSocket client")
                .into_response();
        }
    };
    metrics::counter!("stagehand_jog_sessions_total").increment(1);
    ws.max_message_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| session(app, socket))
}

/// One jog in progress.
struct Jog {
    axis: AxisHandle,
    direction: f64,
    speed: f64,
    /// The current leg's move request.
    leg: JoinHandle<DeviceResult<f64>>,
    /// Its motion profile and start, for position estimates.
    profile: Trapezoid,
    started: Instant,
    /// Held for the whole jog: no other manual command meanwhile.
    _guard: manual::ManualGuard,
}

/// Why a jog ended.
enum End {
    Stop,
    Deadman,
    Limit,
    EStop,
    Closed,
    Error(String),
}

impl End {
    fn name(&self) -> &'static str {
        match self {
            End::Stop => "stop",
            End::Deadman => "deadman",
            End::Limit => "limit",
            End::EStop => "estop",
            End::Closed => "closed",
            End::Error(_) => "error",
        }
    }
}

async fn session(app: AppState, socket: WebSocket) {
    let mut s = Session {
        app: &app,
        socket,
        jog: None,
    };
    let mut last_message = Instant::now();
    let mut ticker = tokio::time::interval(UPDATE_EVERY);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let deadline = last_message + DEADMAN;
        let jogging = s.jog.is_some();
        tokio::select! {
            msg = s.socket.recv() => {
                let text = match msg {
                    None | Some(Err(_)) | Some(Ok(Message::Close(_))) => {
                        if let Some(j) = s.jog.take() {
                            finish(j, End::Closed).await;
                        }
                        return;
                    }
                    Some(Ok(Message::Text(t))) => t,
                    Some(Ok(Message::Binary(_))) => {
                        s.refuse("binary messages are not understood", "send JSON text")
                            .await;
                        continue;
                    }
                    Some(Ok(_)) => continue,
                };
                last_message = Instant::now();
                s.on_text(text.as_str()).await;
            }
            () = tokio::time::sleep_until(deadline), if jogging => {
                if let Some(j) = &s.jog {
                    tracing::info!(
                        "jog of `{}`: no message for {} ms; stopping (dead man)",
                        j.axis.id(),
                        DEADMAN.as_millis()
                    );
                }
                s.end(End::Deadman).await;
            }
            _ = ticker.tick(), if jogging => s.on_tick().await,
        }
    }
}

/// One connection: the socket and its jog in progress.
struct Session<'a> {
    app: &'a AppState,
    socket: WebSocket,
    jog: Option<Jog>,
}

impl<'a> Session<'a> {
    /// A client message: start, keep, or stop a jog.
    async fn on_text(&mut self, text: &str) {
        let m: ClientMessage = match serde_json::from_str(text) {
            Ok(m) => m,
            Err(e) => {
                let hint = MESSAGE_HINT;
                self.refuse(&format!("bad message: {e}"), hint).await;
                return;
            }
        };
        if m.stop {
            self.end(End::Stop).await;
            return;
        }
        let Some(axis_id) = &m.axis else {
            if !m.hold {
                self.refuse(
                    "a message needs `axis` and `direction`, `hold` or `stop`",
                    "see the description of GET /api/ws/jog in /openapi.json",
                )
                .await;
            }
            return;
        };
        if let Some(j) = &self.jog
            && j.axis.id() == axis_id
            && m.direction.map(f64::from) == Some(j.direction)
            && m.speed.is_none_or(|s| s == j.speed)
        {
            return; // the same jog, held
        }
        self.end(End::Stop).await;
        match start(self.app, axis_id, m.direction, m.speed) {
            Ok(j) => self.jog = Some(j),
            Err(e) => {
                let hint = e.hint.unwrap_or_default();
                self.refuse(&e.error, &hint).await;
            }
        }
    }

    /// Every [`UPDATE_EVERY`] while jogging: notice the e-stop, chain crawl steps, report the
    /// (estimated) position.
    async fn on_tick(&mut self) {
        let app = self.app;
        let Some(j) = self.jog.as_mut() else { return };
        if app.estop.is_latched() {
            self.end(End::EStop).await;
            return;
        }
        if j.leg.is_finished() {
            match next_leg(app, j).await {
                Ok(true) => {}
                Ok(false) => return self.end(End::Limit).await,
                Err(e) => return self.end(End::Error(e.to_string())).await,
            }
        }
        let Some(j) = self.jog.as_ref() else { return };
        let update = Update {
            axis: j.axis.id(),
            position_deg: j.profile.position_at(j.started.elapsed().as_secs_f64()),
            moving: true,
            homed: j.axis.status().homed,
            estimated: true,
        };
        let text = serde_json::to_string(&update);
        if let Ok(text) = text {
            let _ = self.socket.send(Message::Text(text.into())).await;
        }
    }

    /// Ends the jog in progress, if any, and tells the client where the axis stopped.
    async fn end(&mut self, why: End) {
        if let Some(j) = self.jog.take() {
            let v = finish(j, why).await;
            self.reply(&v).await;
        }
    }

    async fn refuse(&mut self, error: &str, hint: &str) {
        self.reply(&json!({"error": error, "hint": hint})).await;
    }

    /// Sends a JSON message; a failed send is a closed socket, noticed by the next receive.
    async fn reply(&mut self, v: &impl Serialize) {
        if let Ok(text) = serde_json::to_string(v) {
            let _ = self.socket.send(Message::Text(text.into())).await;
        }
    }
}

/// Checks the refusals and starts the first leg.
fn start(
    app: &AppState,
    axis_id: &str,
    direction: Option<i32>,
    speed: Option<f64>,
) -> Result<Jog, ApiError> {
    let axis = app.rig.axes.get(axis_id).cloned().ok_or_else(|| {
        let known: Vec<&str> = app.rig.axes.keys().map(String::as_str).collect();
        ApiError::not_found(format!("no axis `{axis_id}`; this rig's axes: {known:?}"))
    })?;
    let direction = match direction {
        Some(1) => 1.0,
        Some(-1) => -1.0,
        _ => {
            return Err(ApiError::bad_request("`direction` must be 1 or -1")
                .hint("1 moves toward the upper soft limit, -1 toward the lower"));
        }
    };
    let speed = speed.unwrap_or(1.0);
    if !(speed.is_finite() && speed > 0.0 && speed <= 1.0) {
        return Err(
            ApiError::unprocessable(format!("`speed` {speed} is outside (0, 1]"))
                .hint("1 is the axis's cruise speed; omit it for full speed"),
        );
    }
    let guard = manual::try_lock(app, &[manual::axis_key(axis_id)])?;
    if !axis.status().homed {
        return Err(ApiError::conflict(format!("{axis_id}: not homed"))
            .hint(format!("home it first: `POST /api/axes/{axis_id}/home`")));
    }
    let from = axis.status().position_deg;
    let Some(target) = leg_target(&axis, from, direction, speed) else {
        return Err(ApiError::unprocessable(format!(
            "{axis_id}: already at its soft limit in that direction ({from:.3}°)"
        ))
        .hint("jog the other way"));
    };
    tracing::info!("jog of `{axis_id}` toward {target:.3}° (speed {speed})");
    let (leg, profile) = spawn_leg(&axis, from, target);
    Ok(Jog {
        axis,
        direction,
        speed,
        leg,
        profile,
        started: Instant::now(),
        _guard: guard,
    })
}

/// Where the next leg goes: the soft limit at full speed, a crawl step below it; `None` at
/// the limit.
fn leg_target(axis: &AxisHandle, from: f64, direction: f64, speed: f64) -> Option<f64> {
    let spec = axis.spec();
    let limit = if direction > 0.0 {
        spec.max_deg
    } else {
        spec.min_deg
    };
    let target = if speed >= 1.0 {
        limit
    } else {
        let step = speed * spec.speed_deg_s * CRAWL_STEP_S;
        let t = from + direction * step;
        if direction > 0.0 {
            t.min(limit)
        } else {
            t.max(limit)
        }
    };
    // Within a microstep of the limit counts as there.
    ((target - from).abs() * spec.steps_per_deg >= 1.0).then_some(target)
}

fn spawn_leg(
    axis: &AxisHandle,
    from: f64,
    target: f64,
) -> (JoinHandle<DeviceResult<f64>>, Trapezoid) {
    let a = axis.clone();
    let leg = tokio::spawn(async move { a.move_to(target).await });
    (leg, Trapezoid::plan(from, target, axis.spec().kinematics()))
}

/// Why a jog's leg failed.
#[derive(Debug, thiserror::Error)]
enum LegError {
    /// The task moving the axis panicked or was cancelled.
    #[error("the jog task failed: {0}")]
    Task(tokio::task::JoinError),
    /// The axis refused or failed the move (worded as the API words it).
    #[error("{}", manual::device_error(.0).error)]
    Device(stagehand_devices::DeviceError),
}

/// The current leg ended: start the next crawl step (`Ok(true)`), or report the limit reached
/// (`Ok(false)`) or the failure.
async fn next_leg(app: &AppState, j: &mut Jog) -> Result<bool, LegError> {
    let r = (&mut j.leg).await.map_err(LegError::Task)?;
    let from = r.map_err(LegError::Device)?;
    if app.estop.is_latched() || app.runs.is_active() {
        return Ok(false);
    }
    let Some(target) = leg_target(&j.axis, from, j.direction, j.speed) else {
        return Ok(false);
    };
    let (leg, profile) = spawn_leg(&j.axis, from, target);
    j.leg = leg;
    j.profile = profile;
    j.started = Instant::now();
    Ok(true)
}

/// Ends a jog: stops the axis (interrupting the leg in flight), waits for the leg to wind
/// down, releases the manual lock, and says where the axis stopped. The stop is repeated if
/// the leg's move reached the axis only after the first stop.
async fn finish(mut j: Jog, why: End) -> serde_json::Value {
    for _ in 0..STOP_TRIES {
        if j.leg.is_finished() {
            break;
        }
        if let Err(e) = j.axis.stop().await {
            tracing::error!("jog: stopping `{}`: {e}", j.axis.id());
        }
        let _ = tokio::time::timeout(Duration::from_millis(200), &mut j.leg).await;
    }
    let s = j.axis.status();
    tracing::info!(
        "jog of `{}` ended ({}) at {:.3}°",
        j.axis.id(),
        why.name(),
        s.position_deg
    );
    let mut v = json!({
        "stopped": why.name(),
        "axis": j.axis.id(),
        "position_deg": s.position_deg,
        "moving": s.moving,
        "homed": s.homed,
    });
    if let End::Error(e) = why {
        v["error"] = json!(e);
    }
    v
}
