//! Frames of the daemon's runs as the API shows them, read from each run's SQLite index.
//!
//! Every read opens the index read-only (`SQLITE_OPEN_READ_ONLY`, `query_only`), so listing
//! frames never blocks or disturbs the writer of a run in progress (WAL readers see the last
//! committed step). Paths are never taken from the client: a run is a direct child directory
//! of the runs directory whose name passes [`check_run_id`], and a frame file is found only
//! through its index row, canonicalised and checked to lie inside the run's `frames/`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use rusqlite::types::Value;
use rusqlite::{Connection, OptionalExtension, Row};
use serde::Serialize;
use utoipa::ToSchema;

use crate::storage::layout::{FRAMES_DIR, INDEX, MANIFEST};

/// Longest run id accepted (run ids are `<stem>-<stamp>-<hash>[-n]`, far shorter).
pub const MAX_RUN_ID_LEN: usize = 200;
/// Most frames one query returns.
pub const MAX_LIMIT: u32 = 1000;
/// Frames a query returns when it does not say.
pub const DEFAULT_LIMIT: u32 = 100;

/// One frame as the API lists it: every per-frame fact of the index row (except the
/// backend's free-form notes) plus where to download it.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct FrameInfo {
    pub run_id: String,
    /// Row id in the run's index; stable while the run exists.
    pub frame_id: i64,
    /// Plan step that captured the frame.
    pub step: usize,
    pub camera: String,
    /// `raw` (one exposure, 16-bit PNG) or `hdr` (merged bracket, 32-bit float EXR).
    pub kind: String,
    /// Free-form label of the capture.
    pub label: String,
    /// Enclosing script blocks joined with `/`.
    pub block: String,
    /// Index into the capture's exposure list (raw frames; null for HDR).
    pub exposure_index: Option<usize>,
    /// Exposure time in seconds (for HDR the longest of the bracket).
    pub exposure_s: f64,
    /// Every exposure of the bracket in seconds.
    pub exposures_s: Vec<f64>,
    /// Analogue gain (linear).
    pub gain: f64,
    /// Trigger id the frame answers (raw frames).
    pub trigger_id: Option<u64>,
    /// Ids of the lamps that were on.
    pub lamps_on: Vec<String>,
    /// Axis angles in degrees at capture time, by axis id.
    pub axes_deg: BTreeMap<String, f64>,
    pub laser_armed: bool,
    pub laser_on: bool,
    pub laser_colour_nm: u32,
    pub laser_tilt_deg: Option<f64>,
    pub laser_mount_deg: Option<f64>,
    /// Fixture on the stage.
    pub fixture: String,
    /// Reflectometer cart position in millimetres, if known.
    pub cart_mm: Option<f64>,
    /// Rig time in seconds at which the exposure started.
    pub rig_time_s: f64,
    /// Wall-clock Unix time in seconds of the capture.
    pub wall_time_unix_s: f64,
    pub width: u32,
    pub height: u32,
    /// Significant bits per sample (sensor bits for raw, 32 for HDR).
    pub bit_depth: u8,
    /// Samples at the sensor's maximum (raw) or saturated in every exposure (HDR).
    pub saturated_samples: u64,
    /// File path relative to the run directory (`frames/…`).
    pub path: String,
    pub size_bytes: u64,
    /// Hex SHA-256 of the file as stored.
    pub sha256: String,
    /// Where to download it (`?format=png|tiff|exr`; default: as stored).
    pub url: String,
    /// An 8-bit PNG preview (`?size=16..1024`).
    pub thumbnail_url: String,
}

/// Filters of a frame query; `None` means any. All filters must match.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameFilter {
    pub camera: Option<String>,
    /// Frames during which this lamp was on.
    pub lamp: Option<String>,
    pub step: Option<usize>,
    /// `raw` or `hdr`.
    pub kind: Option<String>,
    pub label: Option<String>,
    /// Enclosing blocks: a prefix of whole block names (see `where_clause`).
    pub block: Option<String>,
    /// At most [`MAX_LIMIT`]; [`DEFAULT_LIMIT`] when `None`.
    pub limit: Option<u32>,
    pub offset: Option<u64>,
}

/// One page of a frame query.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct FramePage {
    /// Frames matching the filters (all pages).
    pub total: u64,
    /// This page, ordered by step then frame id.
    pub frames: Vec<FrameInfo>,
}

/// Why a frame lookup failed; the API maps each to a status code.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameIndexError {
    /// The run id is not a plain directory name (400).
    #[error("run id {id:?} is not valid: {reason}")]
    BadRunId { id: String, reason: String },
    /// No such run (404).
    #[error("no run {0}")]
    UnknownRun(String),
    /// The run has no such frame (404).
    #[error("run {run} has no frame {frame_id}")]
    UnknownFrame { run: String, frame_id: i64 },
    /// The index row points at a file that is missing or outside the run (404; logged).
    #[error("frame {frame_id} of run {run} is not available: {reason}")]
    FileUnavailable {
        run: String,
        frame_id: i64,
        reason: String,
    },
    /// The frame's file is missing or no longer matches the SHA-256 recorded when it was
    /// written (500: the dataset is damaged; `stagehand verify` finds every such file and
    /// `stagehand resume --retake` captures the step again).
    #[error("frame {frame_id} of run {run} (step {step}) is damaged: {path} {reason}")]
    Damaged {
        run: String,
        /// The run directory, for the repair commands.
        run_dir: PathBuf,
        frame_id: i64,
        step: usize,
        /// The file, relative to the run directory.
        path: String,
        /// What is wrong with it ("is missing", "does not match …").
        reason: String,
    },
    /// A filter value is out of range (400).
    #[error("{0}")]
    BadFilter(String),
    /// The index could not be read (500: the dataset, not the request, is at fault).
    #[error("cannot read the index of run {run}: {reason}")]
    Index { run: String, reason: String },
}

/// Checks that `id` can only name a direct child of the runs directory: 1..=200 characters
/// of `[A-Za-z0-9_.-]`, not starting with a dot (so no `.`, `..`, hidden files, separators
/// or NUL).
pub fn check_run_id(id: &str) -> Result<(), FrameIndexError> {
    let bad = |reason: &str| FrameIndexError::BadRunId {
        id: id.chars().take(80).collect(),
        reason: reason.to_string(),
    };
    if id.is_empty() {
        return Err(bad("it is empty"));
    }
    if id.len() > MAX_RUN_ID_LEN {
        return Err(bad("it is longer than 200 characters"));
    }
    if id.starts_with('.') {
        return Err(bad("it starts with a dot"));
    }
    if let Some(c) = id
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.')))
    {
        return Err(bad(&format!(
            "it contains {c:?}; run ids use only letters, digits, `_`, `-` and `.`"
        )));
    }
    Ok(())
}

/// The canonical directory of run `run_id` under `runs_dir`: a real directory (not a
/// symlink) directly inside `runs_dir` that holds an index and a manifest.
pub fn run_dir(runs_dir: &Path, run_id: &str) -> Result<PathBuf, FrameIndexError> {
    check_run_id(run_id)?;
    let unknown = || FrameIndexError::UnknownRun(run_id.to_string());
    let dir = runs_dir.join(run_id);
    let meta = std::fs::symlink_metadata(&dir).map_err(|_| unknown())?;
    if !meta.is_dir() {
        return Err(unknown());
    }
    let canon_runs = runs_dir.canonicalize().map_err(|_| unknown())?;
    let canon = dir.canonicalize().map_err(|_| unknown())?;
    if canon.parent() != Some(canon_runs.as_path()) {
        tracing::warn!(
            run = run_id,
            "run directory resolves outside the runs directory"
        );
        return Err(unknown());
    }
    // The manifest is written last when a run is created: without it the index may not
    // have its tables yet.
    if !canon.join(INDEX).is_file() || !canon.join(MANIFEST).is_file() {
        return Err(unknown());
    }
    Ok(canon)
}

/// Opens a run's index read-only ([`crate::storage::index::open_read_only`]: never blocks or
/// disturbs a writer and leaves no files behind).
pub fn open_index(run_dir: &Path, run_id: &str) -> Result<Connection, FrameIndexError> {
    crate::storage::index::open_read_only(run_dir).map_err(index_err(run_id))
}

fn index_err(run_id: &str) -> impl Fn(rusqlite::Error) -> FrameIndexError + '_ {
    move |e| FrameIndexError::Index {
        run: run_id.to_string(),
        reason: e.to_string(),
    }
}

/// Columns read for a [`FrameInfo`], in the order [`frame_from_row`] expects.
const COLUMNS: &str = "frames.id, frames.step, frames.path, frames.sha256, frames.size_bytes, \
    frames.camera, frames.kind, frames.label, frames.block, frames.exposure_index, \
    frames.exposure_s, frames.exposures_s, frames.gain, frames.trigger_id, frames.axes_deg, \
    frames.lamps_on, frames.laser_armed, frames.laser_on, frames.laser_colour_nm, \
    frames.laser_tilt_deg, frames.laser_mount_deg, frames.fixture, frames.cart_mm, \
    frames.rig_time_s, frames.wall_time_unix_s, frames.width, frames.height, frames.bit_depth, \
    frames.saturated_samples";

/// A non-negative integer column.
fn unsigned<T: TryFrom<i64>>(row: &Row<'_>, column: usize) -> rusqlite::Result<T> {
    let v: i64 = row.get(column)?;
    T::try_from(v).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(column, v))
}

/// A JSON text column decoded into `T`.
fn json<T: serde::de::DeserializeOwned>(row: &Row<'_>, column: usize) -> rusqlite::Result<T> {
    let text: String = row.get(column)?;
    serde_json::from_str(&text).map_err(|e| {
        rusqlite::Error::FromSqlConversionFailure(column, rusqlite::types::Type::Text, Box::new(e))
    })
}

/// The download URL of a frame.
pub fn frame_url(run_id: &str, frame_id: i64) -> String {
    format!("/api/runs/{run_id}/frames/{frame_id}")
}

fn frame_from_row(run_id: &str, r: &Row<'_>) -> rusqlite::Result<FrameInfo> {
    let frame_id: i64 = r.get(0)?;
    let url = frame_url(run_id, frame_id);
    Ok(FrameInfo {
        run_id: run_id.to_string(),
        frame_id,
        step: unsigned(r, 1)?,
        path: r.get(2)?,
        sha256: r.get(3)?,
        size_bytes: unsigned(r, 4)?,
        camera: r.get(5)?,
        kind: r.get(6)?,
        label: r.get(7)?,
        block: r.get(8)?,
        exposure_index: match r.get::<_, Option<i64>>(9)? {
            Some(_) => Some(unsigned(r, 9)?),
            None => None,
        },
        exposure_s: r.get(10)?,
        exposures_s: json(r, 11)?,
        gain: r.get(12)?,
        trigger_id: match r.get::<_, Option<i64>>(13)? {
            Some(_) => Some(unsigned(r, 13)?),
            None => None,
        },
        axes_deg: json(r, 14)?,
        lamps_on: json(r, 15)?,
        laser_armed: r.get(16)?,
        laser_on: r.get(17)?,
        laser_colour_nm: unsigned(r, 18)?,
        laser_tilt_deg: r.get(19)?,
        laser_mount_deg: r.get(20)?,
        fixture: r.get(21)?,
        cart_mm: r.get(22)?,
        rig_time_s: r.get(23)?,
        wall_time_unix_s: r.get(24)?,
        width: unsigned(r, 25)?,
        height: unsigned(r, 26)?,
        bit_depth: unsigned(r, 27)?,
        saturated_samples: unsigned(r, 28)?,
        thumbnail_url: format!("{url}/thumbnail"),
        url,
    })
}

/// The WHERE clause and parameters of `filter`.
fn where_clause(filter: &FrameFilter) -> Result<(String, Vec<Value>), FrameIndexError> {
    let mut clauses = Vec::new();
    let mut params = Vec::new();
    let mut text = |column: &str, value: &Option<String>| {
        if let Some(v) = value {
            params.push(Value::Text(v.clone()));
            clauses.push(format!("frames.{column} = ?{}", params.len()));
        }
    };
    text("camera", &filter.camera);
    text("kind", &filter.kind);
    text("label", &filter.label);
    // A prefix of whole block names: `view 3` matches `view 3/light 1`, not `view 30`.
    if let Some(block) = &filter.block {
        params.push(Value::Text(block.trim_end_matches('/').to_string()));
        let n = params.len();
        clauses.push(format!(
            "(frames.block = ?{n} OR substr(frames.block, 1, length(?{n}) + 1) = ?{n} || '/')"
        ));
    }
    if let Some(lamp) = &filter.lamp {
        params.push(Value::Text(lamp.clone()));
        clauses.push(format!(
            "EXISTS (SELECT 1 FROM json_each(frames.lamps_on) AS j WHERE j.value = ?{})",
            params.len()
        ));
    }
    if let Some(step) = filter.step {
        let step = i64::try_from(step)
            .map_err(|_| FrameIndexError::BadFilter(format!("step {step} is too large")))?;
        params.push(Value::Integer(step));
        clauses.push(format!("frames.step = ?{}", params.len()));
    }
    let sql = if clauses.is_empty() {
        String::new()
    } else {
        format!(" WHERE {}", clauses.join(" AND "))
    };
    Ok((sql, params))
}

/// The frames of run `run_id` matching `filter`, one page of them, with the total count.
pub fn query(
    runs_dir: &Path,
    run_id: &str,
    filter: &FrameFilter,
) -> Result<FramePage, FrameIndexError> {
    let limit = filter.limit.unwrap_or(DEFAULT_LIMIT);
    if limit > MAX_LIMIT {
        return Err(FrameIndexError::BadFilter(format!(
            "limit {limit} is above the maximum of {MAX_LIMIT}; page with `offset`"
        )));
    }
    let offset = i64::try_from(filter.offset.unwrap_or(0))
        .map_err(|_| FrameIndexError::BadFilter("offset is too large".into()))?;
    let dir = run_dir(runs_dir, run_id)?;
    let conn = open_index(&dir, run_id)?;
    let err = index_err(run_id);
    let (clause, mut params) = where_clause(filter)?;
    let total: i64 = conn
        .query_row(
            &format!("SELECT count(*) FROM frames{clause}"),
            rusqlite::params_from_iter(params.iter()),
            |r| r.get(0),
        )
        .map_err(&err)?;
    params.push(Value::Integer(i64::from(limit)));
    params.push(Value::Integer(offset));
    let n = params.len();
    let sql = format!(
        "SELECT {COLUMNS} FROM frames{clause} ORDER BY frames.step, frames.id LIMIT ?{} OFFSET ?{n}",
        n - 1
    );
    let mut stmt = conn.prepare(&sql).map_err(&err)?;
    let frames = stmt
        .query_map(rusqlite::params_from_iter(params.iter()), |r| {
            frame_from_row(run_id, r)
        })
        .map_err(&err)?
        .collect::<rusqlite::Result<Vec<_>>>()
        .map_err(&err)?;
    Ok(FramePage {
        total: u64::try_from(total).unwrap_or(0),
        frames,
    })
}

/// One frame of a run and the canonical path of its file (checked to be a regular file
/// inside the run's `frames/` directory).
pub fn frame(
    runs_dir: &Path,
    run_id: &str,
    frame_id: i64,
) -> Result<(FrameInfo, PathBuf), FrameIndexError> {
    let dir = run_dir(runs_dir, run_id)?;
    let conn = open_index(&dir, run_id)?;
    let info = conn
        .query_row(
            &format!("SELECT {COLUMNS} FROM frames WHERE frames.id = ?1"),
            [frame_id],
            |r| frame_from_row(run_id, r),
        )
        .optional()
        .map_err(index_err(run_id))?
        .ok_or_else(|| FrameIndexError::UnknownFrame {
            run: run_id.to_string(),
            frame_id,
        })?;
    let file = frame_file(&dir, &info.path).map_err(|reason| {
        tracing::warn!(run = run_id, frame_id, "frame file refused: {reason}");
        let gone = std::fs::symlink_metadata(dir.join(&info.path))
            .is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound);
        if gone && crate::storage::layout::is_frame_path(&info.path) {
            damaged(&dir, &info, "is missing".into())
        } else {
            FrameIndexError::FileUnavailable {
                run: run_id.to_string(),
                frame_id,
                reason,
            }
        }
    })?;
    Ok((info, file))
}

/// A [`FrameIndexError::Damaged`] for the frame `info` of the run at `run_dir`.
fn damaged(run_dir: &Path, info: &FrameInfo, reason: String) -> FrameIndexError {
    FrameIndexError::Damaged {
        run: info.run_id.clone(),
        run_dir: run_dir.to_path_buf(),
        frame_id: info.frame_id,
        step: info.step,
        path: info.path.clone(),
        reason,
    }
}

/// Reads the file of frame `info` (resolved by [`frame`] to `file`) and checks it against the
/// SHA-256 its index row recorded, so a damaged file is never served or converted as if fine.
pub fn read_verified(info: &FrameInfo, file: &Path) -> Result<Vec<u8>, FrameIndexError> {
    // `file` is canonical and inside `<run>/frames/`.
    let run_dir = file
        .parent()
        .and_then(Path::parent)
        .unwrap_or(file)
        .to_path_buf();
    let (bytes, found) =
        crate::storage::checksum::read_hashed(file, info.size_bytes).map_err(|e| {
            tracing::warn!(
                run = info.run_id,
                frame_id = info.frame_id,
                "cannot read {}: {e}",
                file.display()
            );
            if e.kind() == std::io::ErrorKind::NotFound {
                damaged(&run_dir, info, "is missing".into())
            } else {
                FrameIndexError::FileUnavailable {
                    run: info.run_id.clone(),
                    frame_id: info.frame_id,
                    reason: e.to_string(),
                }
            }
        })?;
    if found != info.sha256 {
        tracing::warn!(
            run = info.run_id,
            frame_id = info.frame_id,
            path = info.path,
            "frame file damaged"
        );
        return Err(damaged(
            &run_dir,
            info,
            format!(
                "does not match the SHA-256 recorded when it was written (recorded {}, the \
                 file's {} bytes hash to {found})",
                info.sha256,
                bytes.len()
            ),
        ));
    }
    Ok(bytes)
}

/// Resolves an index row's `path` inside the canonical run directory `run_dir`: relative,
/// no `..`, and after resolving symlinks a regular file inside `<run>/frames/`.
pub fn frame_file(run_dir: &Path, rel: &str) -> Result<PathBuf, String> {
    let rel_path = Path::new(rel);
    let plain = rel_path
        .components()
        .all(|c| matches!(c, std::path::Component::Normal(_)));
    if rel.is_empty() || rel.contains('\0') || !plain {
        return Err(format!(
            "the index path {rel:?} is not a plain relative path"
        ));
    }
    let frames = run_dir
        .join(FRAMES_DIR)
        .canonicalize()
        .map_err(|e| format!("the frames directory: {e}"))?;
    let file = run_dir
        .join(rel_path)
        .canonicalize()
        .map_err(|e| format!("{rel}: {e}"))?;
    if !file.starts_with(&frames) {
        return Err(format!("{rel} resolves outside the run's frames directory"));
    }
    let meta = std::fs::metadata(&file).map_err(|e| format!("{rel}: {e}"))?;
    if !meta.is_file() {
        return Err(format!("{rel} is not a regular file"));
    }
    Ok(file)
}

/// The frames of `step` in the run at `run_dir` (for `frame` events when the step is durable).
pub fn frames_of_step(run_dir: &Path, run_id: &str, step: usize) -> Result<Vec<FrameInfo>, String> {
    let step = i64::try_from(step).map_err(|e| e.to_string())?;
    let conn = open_index(run_dir, run_id).map_err(|e| e.to_string())?;
    let err = |e: rusqlite::Error| format!("run {run_id}: frames of step {step}: {e}");
    let mut stmt = conn
        .prepare(&format!(
            "SELECT {COLUMNS} FROM frames WHERE frames.step = ?1 ORDER BY frames.id"
        ))
        .map_err(err)?;
    let frames = stmt
        .query_map([step], |r| frame_from_row(run_id, r))
        .map_err(err)?
        .collect::<rusqlite::Result<Vec<_>>>()
        .map_err(err)?;
    Ok(frames)
}

/// Unix time of the last modification of a run's index (the main file or its WAL): every
/// frame of the run was captured before it.
fn index_mtime(dir: &Path) -> Option<f64> {
    let mtime = |p: PathBuf| {
        std::fs::metadata(p)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
            .map(|d| d.as_secs_f64())
    };
    let main = mtime(dir.join(INDEX));
    let wal = mtime(dir.join(format!("{INDEX}-wal")));
    match (main, wal) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    }
}

/// Slack between a frame's wall time and its index's mtime (clock granularity).
const MTIME_SLACK_S: f64 = 2.0;

/// The newest frame (by capture wall time) of `camera` in any run under `runs_dir`, or
/// `None`. Runs are visited newest index first and the scan stops as soon as no older run
/// can hold a newer frame, so this stays cheap with many runs. Unreadable runs are skipped.
pub fn latest_for_camera(
    runs_dir: &Path,
    camera: &str,
) -> Result<Option<FrameInfo>, FrameIndexError> {
    let entries = match std::fs::read_dir(runs_dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => {
            return Err(FrameIndexError::Index {
                run: "*".into(),
                reason: format!("cannot list {}: {e}", runs_dir.display()),
            });
        }
    };
    let mut runs: Vec<(f64, String, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let name = entry.file_name().to_str()?.to_string();
            check_run_id(&name).ok()?;
            // Real directories only (a symlink planted in runs/ is ignored).
            if !entry.file_type().ok()?.is_dir() {
                return None;
            }
            let dir = entry.path();
            if !dir.join(MANIFEST).is_file() {
                return None;
            }
            Some((index_mtime(&dir)?, name, dir))
        })
        .collect();
    runs.sort_by(|a, b| b.0.total_cmp(&a.0).then_with(|| b.1.cmp(&a.1)));
    let mut best: Option<FrameInfo> = None;
    for (mtime, run_id, dir) in runs {
        if let Some(b) = &best
            && mtime + MTIME_SLACK_S < b.wall_time_unix_s
        {
            break;
        }
        let found = open_index(&dir, &run_id).and_then(|conn| {
            conn.query_row(
                &format!(
                    "SELECT {COLUMNS} FROM frames WHERE frames.camera = ?1
                     ORDER BY frames.wall_time_unix_s DESC, frames.id DESC LIMIT 1"
                ),
                [camera],
                |r| frame_from_row(&run_id, r),
            )
            .optional()
            .map_err(index_err(&run_id))
        });
        match found {
            Ok(Some(f))
                if best
                    .as_ref()
                    .is_none_or(|b| f.wall_time_unix_s > b.wall_time_unix_s) =>
            {
                best = Some(f)
            }
            Ok(_) => {}
            Err(e) => tracing::debug!("latest frame of {camera}: skipping run {run_id}: {e}"),
        }
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_ids_are_plain_names() {
        for ok in ["quickstart-20260101-000000-abcdef12", "a", "x.y_z-2"] {
            assert!(check_run_id(ok).is_ok(), "{ok}");
        }
        let long = "a".repeat(201);
        for bad in [
            "", ".", "..", ".hidden", "../etc", "a/b", "a\\b", "a\0b", "/abs", "a b", "ü", &long,
        ] {
            assert!(
                matches!(check_run_id(bad), Err(FrameIndexError::BadRunId { .. })),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn frame_paths_stay_inside_frames() -> Result<(), Box<dyn std::error::Error>> {
        let tmp = tempfile::tempdir()?;
        let run = tmp.path().join("run");
        std::fs::create_dir_all(run.join(FRAMES_DIR))?;
        std::fs::write(run.join("frames/a.png"), b"x")?;
        std::fs::write(run.join("secret.txt"), b"s")?;
        std::fs::write(tmp.path().join("outside.txt"), b"o")?;
        let run = run.canonicalize()?;
        assert!(frame_file(&run, "frames/a.png").is_ok());
        for bad in [
            "",
            "/etc/passwd",
            "../outside.txt",
            "frames/../secret.txt",
            "frames/../../outside.txt",
            "secret.txt",
            "frames",
            "frames/missing.png",
        ] {
            assert!(frame_file(&run, bad).is_err(), "{bad:?}");
        }
        std::os::unix::fs::symlink(tmp.path().join("outside.txt"), run.join("frames/link.png"))?;
        assert!(frame_file(&run, "frames/link.png").is_err());
        Ok(())
    }

    /// Inserts a frame row (step 0, camera `cam1`) into an index being written.
    fn insert_frame(conn: &Connection, path: &str) -> rusqlite::Result<usize> {
        conn.execute(
            "INSERT INTO frames (step, path, sha256, size_bytes, camera, kind, label, block,
                exposure_s, exposures_s, gain, axes_deg, lamps_on, laser_armed, laser_on,
                laser_colour_nm, fixture, rig_time_s, wall_time_unix_s, width, height,
                bit_depth, saturated_samples, notes)
             VALUES (0, ?1, 'ab', 1, 'cam1', 'raw', 'l', 'b', 0.01, '[0.01]', 1.0,
                '{\"turntable\":90.0}', '[\"lamp2\"]', 0, 0, 650, 'bumps', 1.0, 2.0, 4, 3,
                12, 0, '{}')",
            [path],
        )
    }

    #[test]
    fn reading_leaves_no_files_and_sees_a_writer_s_commits()
    -> Result<(), Box<dyn std::error::Error>> {
        let tmp = tempfile::tempdir()?;
        // Characters an SQLite URI would misread unless escaped.
        let runs = tmp.path().join("data ?%#& x").join("runs");
        let run = runs.join("r1");
        std::fs::create_dir_all(run.join(FRAMES_DIR))?;
        std::fs::write(run.join(MANIFEST), "{}")?;
        {
            let w = Connection::open(run.join(INDEX))?;
            w.pragma_update(None, "journal_mode", "WAL")?;
            w.execute_batch(crate::storage::index::SCHEMA)?;
            w.execute(
                "INSERT INTO steps (idx, kind, block, script_line, script_col)
                 VALUES (0, 'capture', 'b', 1, 1)",
                [],
            )?;
            insert_frame(&w, "frames/a.png")?;
        }
        let listing = || -> std::io::Result<Vec<String>> {
            let mut names: Vec<String> = std::fs::read_dir(&run)?
                .filter_map(|e| e.ok()?.file_name().into_string().ok())
                .collect();
            names.sort();
            Ok(names)
        };
        let before = listing()?;
        assert_eq!(before, vec!["frames", INDEX, MANIFEST]);
        let page = query(&runs, "r1", &FrameFilter::default())?;
        assert_eq!(page.total, 1);
        let f = &page.frames[0];
        assert_eq!(
            (f.camera.as_str(), f.lamps_on.clone()),
            ("cam1", vec!["lamp2".to_string()])
        );
        assert_eq!(f.axes_deg.get("turntable"), Some(&90.0));
        assert_eq!(f.url, "/api/runs/r1/frames/1");
        assert_eq!(frames_of_step(&run, "r1", 0)?.len(), 1);
        assert_eq!(listing()?, before, "a read left files in the run directory");

        // A writer holds the index open: its commits are visible.
        let w = Connection::open(run.join(INDEX))?;
        w.pragma_update(None, "journal_mode", "WAL")?;
        insert_frame(&w, "frames/b.png")?;
        assert!(run.join(format!("{INDEX}-wal")).exists());
        let lamp = FrameFilter {
            lamp: Some("lamp2".into()),
            camera: Some("cam1".into()),
            ..FrameFilter::default()
        };
        assert_eq!(query(&runs, "r1", &lamp)?.total, 2);
        let other = FrameFilter {
            lamp: Some("lamp1".into()),
            ..FrameFilter::default()
        };
        assert_eq!(query(&runs, "r1", &other)?.total, 0);
        let too_many = FrameFilter {
            limit: Some(MAX_LIMIT + 1),
            ..FrameFilter::default()
        };
        assert!(matches!(
            query(&runs, "r1", &too_many),
            Err(FrameIndexError::BadFilter(_))
        ));
        let latest = latest_for_camera(&runs, "cam1")?.ok_or("no latest frame")?;
        assert_eq!(latest.path, "frames/b.png");
        Ok(())
    }

    #[test]
    fn unknown_and_bad_runs() -> Result<(), Box<dyn std::error::Error>> {
        let tmp = tempfile::tempdir()?;
        let runs = tmp.path().join("runs");
        std::fs::create_dir_all(runs.join("empty"))?;
        std::fs::create_dir_all(tmp.path().join("elsewhere"))?;
        std::fs::write(tmp.path().join("elsewhere").join(INDEX), b"")?;
        std::fs::write(tmp.path().join("elsewhere").join(MANIFEST), b"{}")?;
        std::fs::create_dir_all(runs.join("no-manifest"))?;
        std::fs::write(runs.join("no-manifest").join(INDEX), b"")?;
        std::os::unix::fs::symlink(tmp.path().join("elsewhere"), runs.join("link"))?;
        assert!(matches!(
            run_dir(&runs, "nope"),
            Err(FrameIndexError::UnknownRun(_))
        ));
        assert!(matches!(
            run_dir(&runs, "empty"),
            Err(FrameIndexError::UnknownRun(_))
        ));
        assert!(matches!(
            run_dir(&runs, "no-manifest"),
            Err(FrameIndexError::UnknownRun(_))
        ));
        assert!(matches!(
            run_dir(&runs, "link"),
            Err(FrameIndexError::UnknownRun(_))
        ));
        assert!(matches!(
            run_dir(&runs, ".."),
            Err(FrameIndexError::BadRunId { .. })
        ));
        assert_eq!(latest_for_camera(&runs, "cam1")?, None);
        assert_eq!(latest_for_camera(&tmp.path().join("none"), "cam1")?, None);
        Ok(())
    }
}
