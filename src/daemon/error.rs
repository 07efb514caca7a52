//! API errors: every failure is a status code and a JSON body that says what is wrong and what
//! to do, `{"error": "...", "hint": "..."}`. Bad input is always a 4xx.

use axum::Json;
use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::extract::{FromRequest, Request};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// The JSON body of every error response.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ErrorBody {
    /// What went wrong.
    pub error: String,
    /// What to do about it, when there is something to do.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hint: Option<String>,
    /// Every problem found when a script or its parameters failed validation (422), each at
    /// its line and column, so a client can mark them without parsing `error`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub violations: Vec<ViolationItem>,
}

/// One validation problem of a script or its parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ViolationItem {
    /// 1-based script line; `null` when the problem has no place in the script (a parameter).
    pub line: Option<u32>,
    /// 1-based column on that line; `null` like `line`.
    pub col: Option<u32>,
    /// What is wrong there.
    pub message: String,
}

/// An error answered to an API client.
#[derive(Debug, Clone)]
pub struct ApiError {
    /// The HTTP status.
    pub status: StatusCode,
    /// What went wrong (the body's `error`).
    pub error: String,
    /// What to do about it (the body's `hint`).
    pub hint: Option<String>,
    /// Validation problems (the body's `violations`).
    pub violations: Vec<ViolationItem>,
}

/// Result of a handler.
pub type ApiResult<T> = Result<T, ApiError>;

impl ApiError {
    /// An error with this status and message.
    pub fn new(status: StatusCode, error: impl Into<String>) -> Self {
        Self {
            status,
            error: error.into(),
            hint: None,
            violations: Vec::new(),
        }
    }

    /// Adds the validation problems behind a 422.
    pub fn violations(mut self, violations: Vec<ViolationItem>) -> Self {
        self.violations = violations;
        self
    }

    /// Adds what the client should do.
    pub fn hint(mut self, hint: impl Into<String>) -> Self {
        self.hint = Some(hint.into());
        self
    }

    /// 400: the request itself is malformed.
    pub fn bad_request(error: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, error)
    }

    /// 404: no such thing.
    pub fn not_found(error: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, error)
    }

    /// The request is valid but the rig is not in a state that allows it (a run is active,
    /// the e-stop is latched, the laser is not armed…).
    pub fn conflict(error: impl Into<String>) -> Self {
        Self::new(StatusCode::CONFLICT, error)
    }

    /// 422: well-formed, but the values are not acceptable.
    pub fn unprocessable(error: impl Into<String>) -> Self {
        Self::new(StatusCode::UNPROCESSABLE_ENTITY, error)
    }

    /// A device failed while doing what was asked (not the client's fault, but not a bug of
    /// the daemon either): 502, naming the device.
    pub fn device(e: &stagehand_devices::DeviceError) -> Self {
        Self::new(StatusCode::BAD_GATEWAY, for_daemon(&e.to_string()))
            .hint("check the device named above; `GET /api/status` shows the rig's state")
    }

    /// 500: the daemon's own failure.
    pub fn internal(error: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, error)
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}", self.status.as_u16(), self.error)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.error,
            hint: self.hint,
            violations: self.violations,
        };
        (self.status, Json(body)).into_response()
    }
}

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> Self {
        let status = match r {
            JsonRejection::MissingJsonContentType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            JsonRejection::BytesRejection(ref b) if b.status() == StatusCode::PAYLOAD_TOO_LARGE => {
                StatusCode::PAYLOAD_TOO_LARGE
            }
            JsonRejection::JsonDataError(_) => StatusCode::UNPROCESSABLE_ENTITY,
            _ => StatusCode::BAD_REQUEST,
        };
        ApiError::new(status, format!("request body: {}", r.body_text())).hint(
            "send a JSON body with `Content-Type: application/json` as /openapi.json describes",
        )
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        ApiError::bad_request(format!("path: {}", r.body_text()))
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> Self {
        ApiError::bad_request(format!("query string: {}", r.body_text()))
            .hint("see /openapi.json for the parameters this endpoint takes")
    }
}

/// A JSON request body that must be a JSON object, or a JSON response. As an extractor it
/// rejects with an [`ApiError`] (a JSON message instead of plain text), and it refuses any
/// body that is not an object: serde reads a struct from a sequence too, so without this
/// `[true]` would pass for `{"confirm": true}`.
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiJson<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for ApiJson<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        // axum checks the content type, the size limit and the syntax.
        let Json(value) = Json::<serde_json::Value>::from_request(req, state).await?;
        object_value(value).map(ApiJson)
    }
}

/// Reads `T` from a request body that must be a JSON object: 422 for any other JSON value
/// (an array, a number…) and for an object of the wrong shape.
pub fn object_value<T: DeserializeOwned>(value: serde_json::Value) -> ApiResult<T> {
    let hint = "send a JSON object (`{...}`) as /openapi.json describes";
    if !value.is_object() {
        let kind = match value {
            serde_json::Value::Array(_) => "an array",
            serde_json::Value::String(_) => "a string",
            serde_json::Value::Number(_) => "a number",
            serde_json::Value::Bool(_) => "a boolean",
            serde_json::Value::Null => "null",
            serde_json::Value::Object(_) => "an object",
        };
        return Err(ApiError::unprocessable(format!(
            "request body: expected a JSON object, got {kind}"
        ))
        .hint(hint));
    }
    serde_json::from_value(value)
        .map_err(|e| ApiError::unprocessable(format!("request body: {e}")).hint(hint))
}

/// Reads `T` from raw body bytes that must hold a JSON object (for handlers that read the
/// body themselves): 400 for malformed JSON, 422 as [`object_value`].
pub fn object_body<T: DeserializeOwned>(bytes: &[u8]) -> ApiResult<T> {
    let value: serde_json::Value = serde_json::from_slice(bytes).map_err(|e| {
        ApiError::bad_request(format!("request body: {e}"))
            .hint("send a JSON object as /openapi.json describes")
    })?;
    object_value(value)
}

impl<T: Serialize> IntoResponse for ApiJson<T> {
    fn into_response(self) -> Response {
        Json(self.0).into_response()
    }
}

/// A device's message as the daemon answers it: the `stagehand devices` it may suggest is a
/// command for the daemon's host (it lists and checks the ports), not for the API client.
pub fn for_daemon(message: &str) -> String {
    message.replace(
        "`stagehand devices`",
        "`stagehand devices` on the daemon's host (`GET /api/status` shows the rig)",
    )
}

/// `axum::extract::Path` with an [`ApiError`] rejection.
#[derive(Debug, axum::extract::FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

/// `axum::extract::Query` with an [`ApiError`] rejection.
#[derive(Debug, axum::extract::FromRequestParts)]
#[from_request(via(axum::extract::Query), rejection(ApiError))]
pub struct ApiQuery<T>(pub T);

/// Middleware: an error response that is not JSON yet (axum's own 405, a body-limit 413 from
/// a raw-body extractor, …) gets the same `{"error", "hint"}` body as every other error, so a
/// client can always parse what went wrong.
pub async fn json_errors(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let response = next.run(req).await;
    let status = response.status();
    let is_json = response
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 4096)
        .await
        .map(|b| String::from_utf8_lossy(&b).trim().to_string())
        .unwrap_or_default();
    let error = if text.is_empty() {
        status
            .canonical_reason()
            .unwrap_or("request refused")
            .to_string()
    } else {
        text
    };
    let mut e = ApiError::new(status, format!("{method} {path}: {error}"));
    e = match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            e.hint("/openapi.json lists the methods each route takes")
        }
        StatusCode::PAYLOAD_TOO_LARGE => e.hint(format!(
            "request bodies are limited to {} bytes",
            super::MAX_BODY_BYTES
        )),
        _ => e,
    };
    let mut out = e.into_response();
    // Keep headers such as `Allow` and `WWW-Authenticate`.
    for (name, value) in parts.headers.iter() {
        if name != axum::http::header::CONTENT_TYPE && name != axum::http::header::CONTENT_LENGTH {
            out.headers_mut().insert(name.clone(), value.clone());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    struct Arm {
        #[serde(default)]
        confirm: bool,
    }

    #[test]
    fn only_an_object_is_read_as_a_struct() {
        for body in ["[true]", "[]", "true", "1", "\"x\"", "null"] {
            let e = object_body::<Arm>(body.as_bytes()).expect_err(body);
            assert_eq!(e.status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
            assert!(e.error.contains("JSON object"), "{body}: {}", e.error);
        }
        assert!(object_body::<Arm>(br#"{"confirm": true}"#).is_ok_and(|a| a.confirm));
        assert!(object_body::<Arm>(b"{}").is_ok_and(|a| !a.confirm));
        let e = object_body::<Arm>(b"{").expect_err("malformed");
        assert_eq!(e.status, StatusCode::BAD_REQUEST);
        let e = object_body::<Arm>(br#"{"confirm": "yes"}"#).expect_err("wrong type");
        assert_eq!(e.status, StatusCode::UNPROCESSABLE_ENTITY);
    }

    #[test]
    fn device_messages_name_the_host_for_cli_commands() {
        let m = for_daemon("cannot open port (see `stagehand devices`)");
        assert!(m.contains("on the daemon's host"), "{m}");
        assert!(m.contains("GET /api/status"), "{m}");
        let run = crate::daemon::runs::for_api(
            "aborted before step 3; resumable with `stagehand resume`",
            "r1",
        );
        assert_eq!(
            run,
            "aborted before step 3; resumable with `POST /api/runs/r1/resume` (or Resume on the dashboard)"
        );
    }
}
