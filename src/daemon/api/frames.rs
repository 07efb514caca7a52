//! Frames: query a run's frames by metadata, download them (PNG / TIFF / EXR, converted on the
//! fly), 8-bit thumbnails, and the latest frame of a camera across runs.
//!
//! Run and frame ids from the URL never become paths directly: see
//! [`crate::daemon::frame_index`] for the checks. Index reads and image conversion run on the
//! blocking pool, at most [`CONVERSIONS`] conversions at a time, so large downloads cannot
//! starve the runtime that drives a run.

use std::sync::OnceLock;

use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use tokio::sync::Semaphore;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::daemon::error::{ApiError, ApiJson, ApiPath, ApiQuery, ApiResult};
use crate::daemon::frame_index::{
    self, DEFAULT_LIMIT, FrameIndexError, FrameInfo, FramePage, MAX_LIMIT,
};
use crate::daemon::image_convert::{
    self, ConvertError, ImageFormat, THUMBNAIL_DEFAULT, THUMBNAIL_MAX, THUMBNAIL_MIN,
};
use crate::daemon::state::AppState;

/// Image conversions (decode + encode) running at once.
pub const CONVERSIONS: usize = 4;

fn conversions() -> &'static Semaphore {
    static SEM: OnceLock<Semaphore> = OnceLock::new();
    SEM.get_or_init(|| Semaphore::new(CONVERSIONS))
}

/// Image bytes in OpenAPI (`type: string, format: binary`); only its schema is used.
#[derive(ToSchema)]
#[schema(value_type = String, format = Binary)]
#[allow(dead_code)]
pub struct ImageBytes(Vec<u8>);

/// `raw` or `hdr`.
#[derive(Debug, Clone, Copy, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum KindParam {
    Raw,
    Hdr,
}

/// Download format; omitted: as stored (raw → png, hdr → exr).
#[derive(Debug, Clone, Copy, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum FormatParam {
    Png,
    Tiff,
    Exr,
}

/// Filters of `GET /api/runs/{id}/frames`; every given filter must match.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct FrameQuery {
    /// Camera id.
    pub camera: Option<String>,
    /// Frames during which this lamp was on.
    pub lamp: Option<String>,
    /// Plan step index.
    pub step: Option<usize>,
    pub kind: Option<KindParam>,
    /// Capture label.
    pub label: Option<String>,
    /// Enclosing script blocks joined with `/`: a prefix of whole block names (`view 3`
    /// matches `view 3` and `view 3/light 1`, not `view 30`).
    pub block: Option<String>,
    /// Page size, 0..=1000 (default 100).
    pub limit: Option<u32>,
    /// Frames to skip (default 0).
    pub offset: Option<u64>,
}

/// `?format=` of a frame download.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct DownloadQuery {
    /// `png` (raw frames only: HDR would clip), `tiff` (16-bit raw, 32-bit float HDR) or `exr`
    /// (32-bit float); default: the stored format.
    pub format: Option<FormatParam>,
}

/// `?size=` of a thumbnail.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ThumbnailQuery {
    /// Longer edge in pixels, 16..=1024 (default 256).
    pub size: Option<u32>,
}

impl From<FrameIndexError> for ApiError {
    fn from(e: FrameIndexError) -> Self {
        let msg = e.to_string();
        match e {
            FrameIndexError::BadRunId { .. } => ApiError::bad_request(msg)
                .hint("use a run id from `GET /api/runs` (letters, digits, `_`, `-`, `.`)"),
            FrameIndexError::UnknownRun(_) => {
                ApiError::not_found(msg).hint("`GET /api/runs` lists the runs")
            }
            FrameIndexError::UnknownFrame { .. } => ApiError::not_found(msg)
                .hint("`GET /api/runs/{id}/frames` lists the run's frames and their ids"),
            FrameIndexError::FileUnavailable { run, frame_id, .. } => {
                ApiError::not_found(format!("frame {frame_id} of run {run} is not available"))
                    .hint("the frame's file is missing or unsafe; check the run directory")
            }
            FrameIndexError::Damaged {
                run,
                run_dir,
                step,
                ..
            } => {
                let dir = run_dir.display();
                ApiError::internal(msg).hint(format!(
                    "`GET /api/runs/{run}/verify` (or `stagehand verify {dir}`) lists every \
                     damaged file of the run; `stagehand resume --retake {step} {dir}` captures \
                     step {step} again"
                ))
            }
            FrameIndexError::BadFilter(_) => ApiError::bad_request(msg)
                .hint(format!(
                    "limit is 0..={MAX_LIMIT} (default {DEFAULT_LIMIT}); offset and step are non-negative integers"
                )),
            FrameIndexError::Index { .. } | FrameIndexError::StepFrames { .. } => ApiError::internal(msg)
                .hint("the run's index.sqlite is unreadable; check the data directory"),
        }
    }
}

impl From<ConvertError> for ApiError {
    fn from(e: ConvertError) -> Self {
        match e {
            ConvertError::WouldClip(m) => ApiError::unprocessable(m).hint(
                "download HDR frames as `?format=exr` or `?format=tiff` (32-bit float), or use the thumbnail for a preview",
            ),
            other => ApiError::internal(other.to_string()),
        }
    }
}

/// Runs blocking work (SQLite, files, image codecs) off the runtime.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> ApiResult<T> + Send + 'static,
) -> ApiResult<T> {
    stagehand_devices::realtime::spawn_blocking(f)
        .await
        .map_err(|e| ApiError::internal(format!("frame worker failed: {e}")))?
}

/// Parses a frame id from the URL.
fn parse_frame_id(text: &str) -> ApiResult<i64> {
    text.parse::<i64>().map_err(|_| {
        ApiError::bad_request(format!(
            "frame id {:?} is not an integer",
            text.chars().take(40).collect::<String>()
        ))
        .hint("frame ids are the `frame_id` of `GET /api/runs/{id}/frames`")
    })
}

/// The frames of a run matching the filters, one page at a time, ordered by step.
#[utoipa::path(get, path = "/api/runs/{id}/frames", tag = "frames",
    params(("id" = String, Path, description = "Run id"), FrameQuery),
    responses(
        (status = 200, body = FramePage),
        (status = 400, description = "Bad run id or query", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run", body = crate::daemon::error::ErrorBody),
        (status = 500, description = "The run's index is unreadable", body = crate::daemon::error::ErrorBody)))]
async fn list_frames(
    State(app): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiQuery(q): ApiQuery<FrameQuery>,
) -> ApiResult<ApiJson<FramePage>> {
    let filter = crate::storage::FrameQuery {
        camera: q.camera,
        lamp: q.lamp,
        step: q.step,
        kind: q.kind.map(|k| match k {
            KindParam::Raw => crate::storage::FrameKind::Raw,
            KindParam::Hdr => crate::storage::FrameKind::Hdr,
        }),
        label: q.label,
        block: q.block,
        limit: q.limit.map(u64::from),
        offset: q.offset.unwrap_or(0),
    };
    let runs_dir = app.runs_dir();
    let page = blocking(move || Ok(frame_index::query(&runs_dir, &id, &filter)?)).await?;
    Ok(ApiJson(page))
}

/// A file name for `Content-Disposition`: run id and frame file stem (both plain).
fn download_name(info: &FrameInfo, ext: &str) -> String {
    let stem = std::path::Path::new(&info.frame.path)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("frame");
    let safe = |s: &str| crate::storage::layout::sanitize(s, "frame");
    format!("{}_{}.{ext}", safe(&info.run_id), safe(stem))
}

/// True when the request's `If-None-Match` lists `etag`.
fn not_modified(headers: &HeaderMap, etag: &str) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|t| {
            let t = t.trim();
            t == "*" || t == etag || t.strip_prefix("W/") == Some(etag)
        })
}

/// An image response (or 304 when the client has it already).
fn image_response(
    bytes: Vec<u8>,
    content_type: &'static str,
    disposition: String,
    etag: String,
) -> Response {
    let mut res = bytes.into_response();
    let h = res.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    if let Ok(v) = HeaderValue::from_str(&disposition) {
        h.insert(header::CONTENT_DISPOSITION, v);
    }
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    res
}

fn not_modified_response(etag: &str) -> Response {
    let mut res = StatusCode::NOT_MODIFIED.into_response();
    if let Ok(v) = HeaderValue::from_str(etag) {
        res.headers_mut().insert(header::ETAG, v);
    }
    res
}

/// One frame's image: as stored (raw: 16-bit RGB PNG of sensor DN; HDR: 32-bit float RGB
/// OpenEXR) or converted: raw → 16-bit RGB TIFF or 32-bit float EXR (same DN); HDR → 32-bit
/// float TIFF. HDR → PNG is refused with 422 (it would clip). Conversions carry the frame
/// metadata JSON (TIFF ImageDescription, EXR `stagehand` attribute).
#[utoipa::path(get, path = "/api/runs/{id}/frames/{frame_id}", tag = "frames",
    params(("id" = String, Path, description = "Run id"),
        ("frame_id" = i64, Path, description = "Frame id from the frame list"), DownloadQuery),
    responses(
        (status = 200, description = "The image", content(
            (ImageBytes = "image/png"), (ImageBytes = "image/tiff"), (ImageBytes = "image/x-exr"))),
        (status = 304, description = "Not modified (If-None-Match)"),
        (status = 400, description = "Bad run id, frame id or format", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run or frame", body = crate::daemon::error::ErrorBody),
        (status = 422, description = "PNG of an HDR frame (would clip)", body = crate::daemon::error::ErrorBody),
        (status = 500, description = "The stored frame is damaged (missing, or not the bytes its SHA-256 recorded)", body = crate::daemon::error::ErrorBody)))]
async fn download_frame(
    State(app): State<AppState>,
    ApiPath((id, frame_id)): ApiPath<(String, String)>,
    ApiQuery(q): ApiQuery<DownloadQuery>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let frame_id = parse_frame_id(&frame_id)?;
    let _permit = conversions()
        .acquire()
        .await
        .map_err(|_| ApiError::internal("the conversion limiter is closed"))?;
    blocking(move || {
        let (info, file) = frame_index::frame(&app.runs_dir(), &id, frame_id)?;
        let stored = ImageFormat::stored(info.frame.meta.kind);
        let format = match q.format {
            None => stored,
            Some(FormatParam::Png) => ImageFormat::Png,
            Some(FormatParam::Tiff) => ImageFormat::Tiff,
            Some(FormatParam::Exr) => ImageFormat::Exr,
        };
        let etag = format!("\"{}-{}\"", info.frame.sha256, format.extension());
        if not_modified(&headers, &etag) {
            return Ok(not_modified_response(&etag));
        }
        if stored == ImageFormat::Exr && format == ImageFormat::Png {
            // Refuse before reading the file.
            return Err(ConvertError::WouldClip(format!(
                "frame {frame_id} is an HDR frame (32-bit float radiance); a PNG would clip and quantise it"
            ))
            .into());
        }
        let bytes = frame_index::read_verified(&info, &file)?;
        let name = download_name(&info, format.extension());
        let out = image_convert::convert(info.frame.meta.kind, &name, bytes, format)?;
        Ok(image_response(
            out,
            format.content_type(),
            format!("attachment; filename=\"{name}\""),
            etag,
        ))
    })
    .await
}

/// An 8-bit sRGB PNG preview whose longer edge is `size` pixels (box-filtered, tone-mapped:
/// raw frames black-level subtracted and scaled by their 99.5th percentile, HDR frames
/// exposure-normalised and Reinhard-compressed; see `image_convert`).
#[utoipa::path(get, path = "/api/runs/{id}/frames/{frame_id}/thumbnail", tag = "frames",
    params(("id" = String, Path, description = "Run id"),
        ("frame_id" = i64, Path, description = "Frame id from the frame list"), ThumbnailQuery),
    responses(
        (status = 200, description = "8-bit PNG", content((ImageBytes = "image/png"))),
        (status = 304, description = "Not modified (If-None-Match)"),
        (status = 400, description = "Bad run id, frame id or size", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such run or frame", body = crate::daemon::error::ErrorBody),
        (status = 500, description = "The stored frame is damaged (missing, or not the bytes its SHA-256 recorded)", body = crate::daemon::error::ErrorBody)))]
async fn thumbnail(
    State(app): State<AppState>,
    ApiPath((id, frame_id)): ApiPath<(String, String)>,
    ApiQuery(q): ApiQuery<ThumbnailQuery>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let frame_id = parse_frame_id(&frame_id)?;
    let size = q.size.unwrap_or(THUMBNAIL_DEFAULT);
    if !(THUMBNAIL_MIN..=THUMBNAIL_MAX).contains(&size) {
        return Err(ApiError::bad_request(format!(
            "thumbnail size {size} is outside {THUMBNAIL_MIN}..={THUMBNAIL_MAX}"
        ))
        .hint("download the frame itself for full resolution"));
    }
    let _permit = conversions()
        .acquire()
        .await
        .map_err(|_| ApiError::internal("the conversion limiter is closed"))?;
    blocking(move || {
        let (info, file) = frame_index::frame(&app.runs_dir(), &id, frame_id)?;
        let etag = format!("\"{}-t{size}\"", info.frame.sha256);
        if not_modified(&headers, &etag) {
            return Ok(not_modified_response(&etag));
        }
        let bytes = frame_index::read_verified(&info, &file)?;
        let name = download_name(&info, "png");
        let decoded = image_convert::decode(info.frame.meta.kind, &name, &bytes)?;
        let png = image_convert::thumbnail(&decoded, size)?;
        Ok(image_response(
            png,
            "image/png",
            format!("inline; filename=\"thumb_{name}\""),
            etag,
        ))
    })
    .await
}

/// The newest frame of a camera in any run (by capture time).
#[utoipa::path(get, path = "/api/cameras/{id}/latest", tag = "frames",
    params(("id" = String, Path, description = "Camera id")),
    responses(
        (status = 200, body = FrameInfo),
        (status = 400, description = "Bad camera id", body = crate::daemon::error::ErrorBody),
        (status = 401, body = crate::daemon::error::ErrorBody),
        (status = 404, description = "No such camera, or the camera has no frame yet", body = crate::daemon::error::ErrorBody),
        (status = 500, description = "The runs directory is unreadable", body = crate::daemon::error::ErrorBody)))]
async fn latest_frame(
    State(app): State<AppState>,
    ApiPath(camera): ApiPath<String>,
) -> ApiResult<ApiJson<FrameInfo>> {
    if camera.is_empty() || camera.len() > 200 || camera.contains('\0') {
        return Err(
            ApiError::bad_request("camera id must be 1..=200 characters")
                .hint("`GET /api/status` lists the cameras"),
        );
    }
    if !app.rig.cameras.contains_key(&camera) {
        let known: Vec<&str> = app.rig.cameras.keys().map(String::as_str).collect();
        return Err(ApiError::not_found(format!(
            "no such camera `{camera}`; this rig's cameras: {known:?}"
        ))
        .hint("`GET /api/status` lists the devices"));
    }
    let runs_dir = app.runs_dir();
    let cam = camera.clone();
    let latest = blocking(move || Ok(frame_index::latest_for_camera(&runs_dir, &cam)?)).await?;
    latest.map(ApiJson).ok_or_else(|| {
        ApiError::not_found(format!("camera {camera} has no frame yet"))
            .hint("frames appear once a run or `POST /api/capture` captured with this camera")
    })
}

/// The frame routes.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_frames))
        .routes(routes!(download_frame))
        .routes(routes!(thumbnail))
        .routes(routes!(latest_frame))
}
