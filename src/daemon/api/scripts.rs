//! Scripts: the library (built-in and uploaded), uploads, and dry runs (validation and
//! estimate on the daemon's rig; nothing moves).

use std::collections::BTreeMap;

use axum::body::Body;
use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::IntoResponse;
use serde::Deserialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiResult, object_body};
use crate::daemon::scripts::{
    self, DryRun, Library, MAX_SCRIPT_BYTES, ScriptEntry, dry_run_async, too_large,
};
use crate::daemon::state::AppState;
use crate::script::ScriptSource;

/// Every script: built-in (read-only) and uploaded.
#[utoipa::path(get, path = "/api/scripts", tag = "scripts",
    responses(
        (status = 200, body = Vec<ScriptEntry>),
        (status = 401, body = crate::daemon::error::ErrorBody),
    ))]
async fn list_scripts(State(app): State<AppState>) -> ApiResult<ApiJson<Vec<ScriptEntry>>> {
    let lib = Library::of(&app);
    stagehand_devices::realtime::spawn_blocking(move || lib.list())
        .await
        .map_err(|e| ApiError::internal(format!("listing scripts stopped: {e}")))?
        .map(ApiJson)
}

/// The text of a script.
#[utoipa::path(get, path = "/api/scripts/{name}", tag = "scripts",
    params(("name" = String, Path, description = "Script name, with or without `.rhai`")),
    responses(
        (status = 200, body = String, content_type = "text/plain"),
        (status = 400, description = "Bad name", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such script", body = crate::daemon::error::ErrorBody),
    ))]
async fn get_script(
    State(app): State<AppState>,
    ApiPath(name): ApiPath<String>,
) -> ApiResult<impl IntoResponse> {
    let (_, source) = Library::of(&app).read(&name)?;
    Ok((
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        source.text,
    ))
}

/// Uploads (or replaces) a script and returns its dry run. A script with errors is stored
/// too (`ok` is false) so it can be fixed; runs refuse it.
#[utoipa::path(put, path = "/api/scripts/{name}", tag = "scripts",
    params(("name" = String, Path, description = "Script name, with or without `.rhai`")),
    request_body(content = String, content_type = "text/plain", description = "The Rhai script (UTF-8, at most 256 KiB)"),
    responses(
        (status = 200, description = "Stored; the dry run", body = DryRun),
        (status = 400, description = "Bad name or not UTF-8", body = crate::daemon::error::ErrorBody),
        (status = 403, description = "Read-only token", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "A built-in script has this name", body = crate::daemon::error::ErrorBody),
        (status = 413, description = "Larger than 256 KiB", body = crate::daemon::error::ErrorBody),
    ))]
async fn put_script(
    State(app): State<AppState>,
    ApiPath(name): ApiPath<String>,
    body: Body,
) -> ApiResult<ApiJson<DryRun>> {
    scripts::script_stem(&name)?;
    let bytes = read_limited(body, MAX_SCRIPT_BYTES).await?;
    let text = String::from_utf8(bytes).map_err(|e| {
        ApiError::bad_request(format!(
            "the script is not UTF-8 text (invalid byte at offset {})",
            e.utf8_error().valid_up_to()
        ))
        .hint("save the script as UTF-8 and send it as `Content-Type: text/plain`")
    })?;
    let lib = Library::of(&app);
    let (source, _replaced) =
        stagehand_devices::realtime::spawn_blocking(move || lib.write(&name, &text))
            .await
            .map_err(|e| ApiError::internal(format!("storing the script stopped: {e}")))??;
    let dry = dry_run_async(source, Vec::new(), app.rig_source.clone()).await?;
    Ok(ApiJson(dry))
}

/// Deletes an uploaded script (built-in scripts cannot be deleted: 409).
#[utoipa::path(delete, path = "/api/scripts/{name}", tag = "scripts",
    params(("name" = String, Path, description = "Script name, with or without `.rhai`")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "Bad name", body = crate::daemon::error::ErrorBody),
        (status = 403, description = "Read-only token", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such uploaded script", body = crate::daemon::error::ErrorBody),
        (status = 409, description = "A built-in script", body = crate::daemon::error::ErrorBody),
    ))]
async fn delete_script(
    State(app): State<AppState>,
    ApiPath(name): ApiPath<String>,
) -> ApiResult<StatusCode> {
    let lib = Library::of(&app);
    stagehand_devices::realtime::spawn_blocking(move || lib.remove(&name))
        .await
        .map_err(|e| ApiError::internal(format!("deleting the script stopped: {e}")))??;
    Ok(StatusCode::NO_CONTENT)
}

/// Reads a request body of at most `limit` bytes: 413 beyond (without reading the rest).
async fn read_limited(body: Body, limit: usize) -> ApiResult<Vec<u8>> {
    use futures_util::StreamExt;
    let mut stream = body.into_data_stream();
    let mut out = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk
            .map_err(|e| ApiError::bad_request(format!("cannot read the request body: {e}")))?;
        if out.len() + chunk.len() > limit {
            return Err(too_large(out.len() + chunk.len()));
        }
        out.extend_from_slice(&chunk);
    }
    Ok(out)
}

/// Parameters of a dry run.
#[derive(Debug, Clone, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ValidateParams {
    /// Script parameters (as `--set`): numbers, strings, booleans or lists of those.
    #[serde(default)]
    #[schema(value_type = Option<Object>)]
    pub set: Option<BTreeMap<String, serde_json::Value>>,
}

/// Dry run of a stored script: plan, estimate and every violation with its line and column.
/// A script with errors is a 200 with `ok: false`.
#[utoipa::path(post, path = "/api/scripts/{name}/validate", tag = "scripts",
    params(("name" = String, Path, description = "Script name, with or without `.rhai`")),
    request_body(content = ValidateParams, description = "Optional; `{}` for the defaults"),
    responses(
        (status = 200, body = DryRun),
        (status = 400, description = "Bad name or body", body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such script", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "Bad `set` values", body = crate::daemon::error::ErrorBody),
    ))]
async fn validate_script(
    State(app): State<AppState>,
    ApiPath(name): ApiPath<String>,
    body: Body,
) -> ApiResult<ApiJson<DryRun>> {
    let bytes = read_limited(body, crate::daemon::MAX_BODY_BYTES).await?;
    let params: ValidateParams = if bytes.iter().all(u8::is_ascii_whitespace) {
        ValidateParams::default()
    } else {
        object_body(&bytes).map_err(|e| e.hint(r#"send `{}` or `{"set": {"name": value}}`"#))?
    };
    let (_, source) = Library::of(&app).read(&name)?;
    let set = scripts::overrides(params.set.as_ref())?;
    Ok(ApiJson(
        dry_run_async(source, set, app.rig_source.clone()).await?,
    ))
}

/// A script sent inline for a dry run (not stored).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ValidateText {
    /// Name to report errors under (default `script`).
    #[serde(default)]
    pub name: Option<String>,
    /// The Rhai script.
    pub text: String,
    #[serde(default)]
    #[schema(value_type = Option<Object>)]
    pub set: Option<BTreeMap<String, serde_json::Value>>,
}

/// Dry run of a script sent inline (nothing is stored).
#[utoipa::path(post, path = "/api/validate", tag = "scripts",
    request_body = ValidateText,
    responses(
        (status = 200, body = DryRun),
        (status = 400, description = "Bad name or body", body = crate::daemon::error::ErrorBody),
        (status = 413, description = "Larger than 256 KiB", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "Bad `set` values or body fields", body = crate::daemon::error::ErrorBody),
    ))]
async fn validate_text(
    State(app): State<AppState>,
    ApiJson(req): ApiJson<ValidateText>,
) -> ApiResult<ApiJson<DryRun>> {
    let stem = match &req.name {
        Some(n) => scripts::script_stem(n)?,
        None => "script".to_string(),
    };
    if req.text.len() > MAX_SCRIPT_BYTES {
        return Err(too_large(req.text.len()));
    }
    let set = scripts::overrides(req.set.as_ref())?;
    let source = ScriptSource {
        name: format!("{stem}.rhai"),
        text: req.text,
    };
    Ok(ApiJson(
        dry_run_async(source, set, app.rig_source.clone()).await?,
    ))
}

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_scripts))
        .routes(routes!(get_script, put_script, delete_script))
        .routes(routes!(validate_script))
        .routes(routes!(validate_text))
}
