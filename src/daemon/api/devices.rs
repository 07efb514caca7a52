//! Manual device control: axes (move, jog, home, stop), lamps, the laser (arm, on, off), the
//! laser interlock, and the e-stop. Every command answers the new state of what it touched.
//!
//! Commands that move or emit are refused (409) while the e-stop is latched or a run is
//! active, and run one at a time per device (commands on different devices do not wait for
//! each other). Stopping never is: axis stop,
//! laser off and disarm, and the e-stop always work. Switching lamps off is allowed with the
//! e-stop latched (it is the safe direction) but not during a run, whose frames it would spoil.

use axum::body::Bytes;
use axum::extract::State;
use serde::{Deserialize, Serialize, de::DeserializeOwned};
use stagehand_devices::axis::AxisHandle;
use stagehand_devices::interlock::InterlockSource;
use stagehand_devices::laser::LaserHandle;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::device_state::{self, AxisState, LampState, LaserState};
use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiResult, ErrorBody, object_body};
use crate::daemon::estop::{self, EStopReport};
use crate::daemon::jog_ws;
use crate::daemon::manual::{self, device_error};
use crate::daemon::state::AppState;

/// `POST /api/axes/{id}/move`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MoveRequest {
    /// Absolute target angle in degrees, within the axis's soft limits.
    pub target_deg: f64,
}

/// `POST /api/axes/{id}/jog`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JogRequest {
    /// Relative move from the current position, in degrees (negative: backwards).
    pub delta_deg: f64,
}

/// `POST /api/lamps/{id}`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LampRequest {
    pub on: bool,
}

/// `POST /api/laser/arm`: arming allows emission, so it must be confirmed.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ArmRequest {
    /// Must be `true`: the operator confirms that eyes are protected and the beam path clear.
    #[serde(default)]
    pub confirm: bool,
}

/// `POST /api/laser/on` (the body may be omitted).
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LaserOnRequest {
    /// Colour to emit; defaults to the fitted module (another colour is refused).
    #[serde(default)]
    pub colour_nm: Option<u32>,
}

/// `POST /api/interlock`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct InterlockRequest {
    /// True closes the simulated door switch, false opens it (the laser goes off at once).
    pub closed: bool,
}

/// The laser interlock (the enclosure's door switch).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct InterlockState {
    /// The laser may emit only while this is true.
    pub closed: bool,
    /// `simulated` (simulated and emulated rigs: settable with `POST /api/interlock`) or
    /// `not fitted` (a real rig without interlock wiring: reads as closed).
    pub source: String,
    /// True when `POST /api/interlock` may change it.
    pub settable: bool,
}

/// Path of the axis routes.
#[derive(Debug, Deserialize)]
struct IdPath {
    id: String,
}

fn axis<'a>(app: &'a AppState, id: &str) -> ApiResult<&'a AxisHandle> {
    app.rig.axes.get(id).ok_or_else(|| {
        let known: Vec<&str> = app.rig.axes.keys().map(String::as_str).collect();
        ApiError::not_found(format!("no axis `{id}`; this rig's axes: {known:?}"))
            .hint("`GET /api/status` lists the devices")
    })
}

fn laser(app: &AppState) -> ApiResult<&LaserHandle> {
    app.rig.laser.as_ref().ok_or_else(|| {
        ApiError::not_found(format!("the rig `{}` has no laser", app.rig.spec.rig.name))
    })
}

fn laser_state(app: &AppState) -> ApiResult<ApiJson<LaserState>> {
    device_state::laser_state(&app.rig)
        .map(ApiJson)
        .ok_or_else(|| ApiError::not_found("the rig has no laser"))
}

fn finite(name: &str, v: f64) -> ApiResult<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ApiError::unprocessable(format!(
            "{name} must be a finite number"
        )))
    }
}

/// Parses an optional JSON object body (empty → default).
fn optional_body<T: DeserializeOwned + Default>(body: &Bytes) -> ApiResult<T> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok(T::default());
    }
    object_body(body)
}

/// Counts a manual command by kind and outcome.
fn count<T>(kind: &'static str, r: ApiResult<T>) -> ApiResult<T> {
    metrics::counter!("stagehand_manual_commands_total", "kind" => kind, "outcome" => manual::outcome(&r))
        .increment(1);
    r
}

/// Moves an axis to an absolute angle and answers when it has arrived (and settled).
#[utoipa::path(post, path = "/api/axes/{id}/move", tag = "devices",
    params(("id" = String, Path, description = "Axis id, e.g. `turntable`")),
    request_body = MoveRequest,
    responses(
        (status = 200, body = AxisState, description = "Arrived"),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such axis"),
        (status = 409, body = ErrorBody, description = "Not homed, e-stop latched, a run active, busy, or interrupted by a stop"),
        (status = 422, body = ErrorBody, description = "Target outside the soft limits or not finite"),
        (status = 502, body = ErrorBody, description = "The axis failed")))]
async fn move_axis(
    State(app): State<AppState>,
    ApiPath(IdPath { id }): ApiPath<IdPath>,
    ApiJson(req): ApiJson<MoveRequest>,
) -> ApiResult<ApiJson<AxisState>> {
    count("move", move_to(&app, &id, req.target_deg).await)
}

/// Moves an axis by `delta_deg` from where it is now (a relative move).
#[utoipa::path(post, path = "/api/axes/{id}/jog", tag = "devices",
    params(("id" = String, Path, description = "Axis id")),
    request_body = JogRequest,
    responses(
        (status = 200, body = AxisState, description = "Arrived"),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such axis"),
        (status = 409, body = ErrorBody, description = "Not homed, e-stop latched, a run active, busy, or interrupted"),
        (status = 422, body = ErrorBody, description = "The resulting target is outside the soft limits"),
        (status = 502, body = ErrorBody, description = "The axis failed")))]
async fn jog_axis(
    State(app): State<AppState>,
    ApiPath(IdPath { id }): ApiPath<IdPath>,
    ApiJson(req): ApiJson<JogRequest>,
) -> ApiResult<ApiJson<AxisState>> {
    let r = async {
        let delta = finite("delta_deg", req.delta_deg)?;
        let from = axis(&app, &id)?.status().position_deg;
        move_to(&app, &id, from + delta).await
    };
    count("jog", r.await)
}

async fn move_to(app: &AppState, id: &str, target_deg: f64) -> ApiResult<ApiJson<AxisState>> {
    let a = axis(app, id)?;
    let target = finite("target_deg", target_deg)?;
    let _guard = manual::lock(app, &[manual::axis_key(id)], true).await?;
    manual::guarded(app, a, a.move_to(target)).await?;
    Ok(ApiJson(device_state::axis_state(a)))
}

/// `POST /api/axes/move`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MultiMoveRequest {
    /// Absolute target angle in degrees per axis id, e.g. `{"turntable": 90, "light_arc": 30}`.
    #[schema(value_type = Object)]
    pub targets: std::collections::BTreeMap<String, f64>,
}

/// Moves several axes at once, concurrently, and answers when all have arrived. The checks of
/// the single-axis move apply to each; nothing moves unless every axis and target is valid.
#[utoipa::path(post, path = "/api/axes/move", tag = "devices",
    request_body = MultiMoveRequest,
    responses(
        (status = 200, body = Vec<AxisState>, description = "Every axis arrived (in id order)"),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such axis"),
        (status = 409, body = ErrorBody, description = "An axis not homed, e-stop latched, a run active, busy, or interrupted by a stop"),
        (status = 422, body = ErrorBody, description = "No targets, or a target outside the soft limits or not finite"),
        (status = 502, body = ErrorBody, description = "An axis failed")))]
async fn move_axes(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<MultiMoveRequest>,
) -> ApiResult<ApiJson<Vec<AxisState>>> {
    let r = async {
        if req.targets.is_empty() {
            return Err(ApiError::unprocessable("targets: no axis given")
                .hint(r#"e.g. {"targets": {"turntable": 90, "light_arc": 30}}"#));
        }
        let mut moves = Vec::with_capacity(req.targets.len());
        for (id, &target) in &req.targets {
            let a = axis(&app, id)?;
            let target = finite(&format!("targets.{id}"), target)?;
            let spec = a.spec();
            if !(spec.min_deg..=spec.max_deg).contains(&target) {
                return Err(ApiError::unprocessable(format!(
                    "targets.{id}: {target}° is outside the soft limits [{}, {}]°",
                    spec.min_deg, spec.max_deg
                ))
                .hint("nothing moved; choose targets inside every axis's limits"));
            }
            if !a.status().homed {
                return Err(
                    ApiError::conflict(format!("{id}: not homed; nothing moved"))
                        .hint(format!("home it first: `POST /api/axes/{id}/home`")),
                );
            }
            moves.push((a, target));
        }
        let keys: Vec<String> = req.targets.keys().map(|id| manual::axis_key(id)).collect();
        let _guard = manual::lock(&app, &keys, true).await?;
        let results = futures_util::future::join_all(
            moves
                .iter()
                .map(|(a, target)| manual::guarded(&app, a, a.move_to(*target))),
        )
        .await;
        for r in results {
            r?;
        }
        Ok(ApiJson(
            moves
                .iter()
                .map(|(a, _)| device_state::axis_state(a))
                .collect(),
        ))
    };
    count("move_many", r.await)
}

/// Homes an axis (drives to its home switch; the position then reads 0°).
#[utoipa::path(post, path = "/api/axes/{id}/home", tag = "devices",
    params(("id" = String, Path, description = "Axis id")),
    responses(
        (status = 200, body = AxisState, description = "Homed"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such axis"),
        (status = 409, body = ErrorBody, description = "E-stop latched, a run active, busy, or interrupted"),
        (status = 502, body = ErrorBody, description = "The axis failed")))]
async fn home_axis(
    State(app): State<AppState>,
    ApiPath(IdPath { id }): ApiPath<IdPath>,
) -> ApiResult<ApiJson<AxisState>> {
    let r = async {
        let a = axis(&app, &id)?;
        let _guard = manual::lock(&app, &[manual::axis_key(&id)], true).await?;
        manual::guarded(&app, a, a.home()).await?;
        Ok(ApiJson(device_state::axis_state(a)))
    };
    count("home", r.await)
}

/// Stops an axis at once, interrupting a move or homing in progress. Always allowed (also
/// during a run, which then fails its step, and with the e-stop latched).
#[utoipa::path(post, path = "/api/axes/{id}/stop", tag = "devices",
    params(("id" = String, Path, description = "Axis id")),
    responses(
        (status = 200, body = AxisState, description = "Stopped"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such axis"),
        (status = 502, body = ErrorBody, description = "The axis failed")))]
async fn stop_axis(
    State(app): State<AppState>,
    ApiPath(IdPath { id }): ApiPath<IdPath>,
) -> ApiResult<ApiJson<AxisState>> {
    let r = async {
        let a = axis(&app, &id)?;
        a.stop().await.map_err(|e| device_error(&e))?;
        Ok(ApiJson(device_state::axis_state(a)))
    };
    count("stop", r.await)
}

/// Switches one lamp on or off.
#[utoipa::path(post, path = "/api/lamps/{id}", tag = "devices",
    params(("id" = String, Path, description = "Lamp id, e.g. `lamp1`")),
    request_body = LampRequest,
    responses(
        (status = 200, body = LampState, description = "Switched"),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "No such lamp"),
        (status = 409, body = ErrorBody, description = "E-stop latched (switching on), a run active, or busy"),
        (status = 502, body = ErrorBody, description = "The switch bank failed")))]
async fn set_lamp(
    State(app): State<AppState>,
    ApiPath(IdPath { id }): ApiPath<IdPath>,
    ApiJson(req): ApiJson<LampRequest>,
) -> ApiResult<ApiJson<LampState>> {
    let r = async {
        let wiring = app.rig.lamps.get(&id).ok_or_else(|| {
            let known: Vec<&str> = app.rig.lamps.keys().map(String::as_str).collect();
            ApiError::not_found(format!("no lamp `{id}`; this rig's lamps: {known:?}"))
                .hint("`GET /api/status` lists the devices")
        })?;
        let bank = app.rig.banks.get(&wiring.bank).ok_or_else(|| {
            ApiError::internal(format!("lamp `{id}`: no switch bank `{}`", wiring.bank))
        })?;
        let _guard = manual::lock(&app, &[manual::lamp_key(&id)], req.on).await?;
        bank.set_many(&[(wiring.channel, req.on)])
            .await
            .map_err(|e| device_error(&e))?;
        device_state::lamp_state(&app.rig, &id)
            .map(ApiJson)
            .ok_or_else(|| ApiError::not_found(format!("no lamp `{id}`")))
    };
    count("lamp", r.await)
}

/// Switches every lamp off. Allowed with the e-stop latched.
#[utoipa::path(post, path = "/api/lamps/off", tag = "devices",
    responses(
        (status = 200, body = Vec<LampState>, description = "Every lamp's state"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 409, body = ErrorBody, description = "A run is active, or busy"),
        (status = 502, body = ErrorBody, description = "A switch bank failed")))]
async fn lamps_off(State(app): State<AppState>) -> ApiResult<ApiJson<Vec<LampState>>> {
    let r = async {
        let keys: Vec<String> = app
            .rig
            .lamps
            .keys()
            .map(|id| manual::lamp_key(id))
            .collect();
        let _guard = manual::lock(&app, &keys, false).await?;
        let mut by_bank: std::collections::BTreeMap<&str, Vec<(u32, bool)>> = Default::default();
        for w in app.rig.lamps.values() {
            by_bank
                .entry(w.bank.as_str())
                .or_default()
                .push((w.channel, false));
        }
        let mut first_error = None;
        for (bank, changes) in by_bank {
            if let Some(b) = app.rig.banks.get(bank)
                && let Err(e) = b.set_many(&changes).await
            {
                first_error.get_or_insert(e);
            }
        }
        if let Some(e) = first_error {
            return Err(device_error(&e));
        }
        Ok(ApiJson(device_state::snapshot(&app.rig).lamps))
    };
    count("lamps_off", r.await)
}

/// Arms the laser (allows emission). Needs `{"confirm": true}`.
#[utoipa::path(post, path = "/api/laser/arm", tag = "devices",
    request_body = ArmRequest,
    responses(
        (status = 200, body = LaserState, description = "Armed"),
        (status = 400, body = ErrorBody, description = "Not confirmed"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "The rig has no laser"),
        (status = 409, body = ErrorBody, description = "E-stop latched, a run active, or busy"),
        (status = 502, body = ErrorBody, description = "The laser failed")))]
async fn laser_arm(State(app): State<AppState>, body: Bytes) -> ApiResult<ApiJson<LaserState>> {
    let r =
        async {
            let l = laser(&app)?;
            let req: ArmRequest = optional_body(&body)?;
            if !req.confirm {
                return Err(ApiError::bad_request("arming the laser must be confirmed").hint(
                "send {\"confirm\": true} once eyes are protected and the beam path is clear",
            ));
            }
            let _guard = manual::lock(&app, &[manual::LASER_KEY.into()], true).await?;
            l.arm().await.map_err(|e| device_error(&e))?;
            laser_state(&app)
        };
    count("laser_arm", r.await)
}

/// Switches the laser off and disarms it. Always allowed.
#[utoipa::path(post, path = "/api/laser/disarm", tag = "devices",
    responses(
        (status = 200, body = LaserState, description = "Off and disarmed"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "The rig has no laser"),
        (status = 502, body = ErrorBody, description = "The laser failed")))]
async fn laser_disarm(State(app): State<AppState>) -> ApiResult<ApiJson<LaserState>> {
    let r = async {
        laser(&app)?.disarm().await.map_err(|e| device_error(&e))?;
        laser_state(&app)
    };
    count("laser_disarm", r.await)
}

/// Switches the laser's emission on: it must be armed and the interlock closed. The body may
/// be omitted (the fitted colour).
#[utoipa::path(post, path = "/api/laser/on", tag = "devices",
    request_body(content = Option<LaserOnRequest>, description = "Optional"),
    responses(
        (status = 200, body = LaserState, description = "Emitting"),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "The rig has no laser"),
        (status = 409, body = ErrorBody, description = "Not armed, interlock open, e-stop latched, a run active, or busy"),
        (status = 422, body = ErrorBody, description = "Colour not fitted"),
        (status = 502, body = ErrorBody, description = "The laser failed")))]
async fn laser_on(State(app): State<AppState>, body: Bytes) -> ApiResult<ApiJson<LaserState>> {
    let r = async {
        let l = laser(&app)?;
        let req: LaserOnRequest = optional_body(&body)?;
        let colour = req.colour_nm.unwrap_or(l.status().fitted_nm);
        let _guard = manual::lock(&app, &[manual::LASER_KEY.into()], true).await?;
        l.on(colour).await.map_err(|e| device_error(&e))?;
        laser_state(&app)
    };
    count("laser_on", r.await)
}

/// Switches the laser's emission off (it stays armed). Always allowed.
#[utoipa::path(post, path = "/api/laser/off", tag = "devices",
    responses(
        (status = 200, body = LaserState, description = "Off"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 404, body = ErrorBody, description = "The rig has no laser"),
        (status = 502, body = ErrorBody, description = "The laser failed")))]
async fn laser_off(State(app): State<AppState>) -> ApiResult<ApiJson<LaserState>> {
    let r = async {
        laser(&app)?.off().await.map_err(|e| device_error(&e))?;
        laser_state(&app)
    };
    count("laser_off", r.await)
}

fn interlock_state(app: &AppState) -> InterlockState {
    let i = &app.rig.interlock;
    InterlockState {
        closed: i.is_closed(),
        source: i.source().as_str().to_string(),
        settable: i.source() == InterlockSource::Simulated,
    }
}

/// The laser interlock (door switch): the laser emits only while it is closed.
#[utoipa::path(get, path = "/api/interlock", tag = "devices",
    responses((status = 200, body = InterlockState)))]
async fn get_interlock(State(app): State<AppState>) -> ApiJson<InterlockState> {
    ApiJson(interlock_state(&app))
}

/// Opens or closes the simulated door switch (simulated and emulated rigs only). Opening it
/// switches an emitting laser off at once; runs are covered too.
#[utoipa::path(post, path = "/api/interlock", tag = "devices",
    request_body = InterlockRequest,
    responses(
        (status = 200, body = InterlockState),
        (status = 400, body = ErrorBody, description = "Malformed body"),
        (status = 403, body = ErrorBody, description = "Read-only token"),
        (status = 409, body = ErrorBody, description = "A real rig: the interlock is the door switch")))]
async fn set_interlock(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<InterlockRequest>,
) -> ApiResult<ApiJson<InterlockState>> {
    app.rig.interlock.set_closed(req.closed).map_err(|e| {
        ApiError::conflict(e.to_string())
            .hint("only simulated and emulated rigs have a software door switch")
    })?;
    tracing::info!(
        "interlock {} over the API",
        if req.closed { "closed" } else { "opened" }
    );
    Ok(ApiJson(interlock_state(&app)))
}

/// Emergency stop: latches (motion and emission refused until reset), aborts any run, and at
/// once disarms the laser, switches every output off and stops every axis. Answers how long
/// that took and what failed.
#[utoipa::path(post, path = "/api/estop", tag = "devices",
    responses(
        (status = 200, body = EStopReport),
        (status = 403, body = ErrorBody, description = "Read-only token")))]
async fn post_estop(State(app): State<AppState>) -> ApiJson<EStopReport> {
    ApiJson(estop::trigger(&app).await)
}

/// Clears the e-stop latch; devices stay as they are (off, stopped, disarmed).
#[utoipa::path(post, path = "/api/estop/reset", tag = "devices",
    responses(
        (status = 200, body = EStopReport),
        (status = 403, body = ErrorBody, description = "Read-only token")))]
async fn post_estop_reset(State(app): State<AppState>) -> ApiJson<EStopReport> {
    ApiJson(estop::reset(&app))
}

/// Device control routes, including the jog WebSocket.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(move_axes))
        .routes(routes!(move_axis))
        .routes(routes!(jog_axis))
        .routes(routes!(home_axis))
        .routes(routes!(stop_axis))
        .routes(routes!(set_lamp))
        .routes(routes!(lamps_off))
        .routes(routes!(laser_arm))
        .routes(routes!(laser_disarm))
        .routes(routes!(laser_on))
        .routes(routes!(laser_off))
        .routes(routes!(get_interlock, set_interlock))
        .routes(routes!(post_estop))
        .routes(routes!(post_estop_reset))
        .routes(routes!(jog_ws::ws_jog))
}
