//! Frames of the daemon's runs as the API shows them, read from each run's SQLite index.
//!
//! Every read goes through the dataset's [`RunReader`] (read-only, schema version checked), so
//! listing frames never blocks or disturbs the writer of a run in progress (it sees the last
//! committed step). Paths are never taken from the client: a run is a direct child directory
//! of the runs directory whose name passes [`check_run_id`], and a frame file is found only
//! through its index row, canonicalised and checked to lie inside the run's `frames/`.

use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use serde::Serialize;
use utoipa::ToSchema;

use crate::storage::layout::{FRAMES_DIR, INDEX, MANIFEST};
use crate::storage::{FrameQuery, RunReader, StorageError, StoredFrame};

/// Longest run id accepted (run ids are `<stem>-<stamp>-<hash>[-n]`, far shorter).
pub const MAX_RUN_ID_LEN: usize = 200;
/// Most frames one query returns.
pub const MAX_LIMIT: u32 = 1000;
/// Frames a query returns when it does not say.
pub const DEFAULT_LIMIT: u32 = 100;

/// One frame as the API lists it: its index row (every per-frame fact, flattened) plus the
/// run it belongs to and where to download it.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct FrameInfo {
    pub run_id: String,
    /// The index row: `frame_id`, `path`, `sha256`, `size_bytes` and the frame's metadata.
    #[serde(flatten)]
    pub frame: StoredFrame,
    /// Where to download it (`?format=png|tiff|exr`; default: as stored).
    pub url: String,
    /// An 8-bit PNG preview (`?size=16..1024`).
    pub thumbnail_url: String,
}

impl FrameInfo {
    /// The API's view of index row `frame` of run `run_id`.
    pub fn new(run_id: &str, frame: StoredFrame) -> FrameInfo {
        let url = frame_url(run_id, frame.id);
        FrameInfo {
            run_id: run_id.to_string(),
            thumbnail_url: format!("{url}/thumbnail"),
            url,
            frame,
        }
    }
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
    /// The frames of a step could not be read from the index (500).
    #[error("run {run}: frames of step {step}: {reason}")]
    StepFrames {
        run: String,
        step: usize,
        reason: String,
    },
}

/// Why an index row's path is not a frame file of the run.
#[derive(Debug, thiserror::Error)]
pub enum FramePathError {
    /// Empty, absolute, with `..` or a NUL.
    #[error("the index path {0:?} is not a plain relative path")]
    NotPlain(String),
    /// The run's `frames/` directory cannot be resolved.
    #[error("the frames directory: {0}")]
    FramesDir(std::io::Error),
    /// The path cannot be resolved or its metadata read.
    #[error("{path}: {source}")]
    Unreadable {
        /// The index row's path.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// It resolves (through a symlink) outside `frames/`.
    #[error("{0} resolves outside the run's frames directory")]
    Outside(String),
    /// A directory or special file.
    #[error("{0} is not a regular file")]
    NotAFile(String),
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

/// Opens a run read-only through the dataset's reader (never blocks or disturbs a writer,
/// leaves no files behind, refuses an index schema it cannot read).
pub fn open_index(run_dir: &Path, run_id: &str) -> Result<RunReader, FrameIndexError> {
    RunReader::open(run_dir).map_err(index_err(run_id))
}

fn index_err(run_id: &str) -> impl Fn(StorageError) -> FrameIndexError + '_ {
    move |e| FrameIndexError::Index {
        run: run_id.to_string(),
        reason: e.to_string(),
    }
}

/// The download URL of a frame.
pub fn frame_url(run_id: &str, frame_id: i64) -> String {
    format!("/api/runs/{run_id}/frames/{frame_id}")
}

/// The frames of run `run_id` matching `filter`, one page of them, with the total count.
pub fn query(
    runs_dir: &Path,
    run_id: &str,
    filter: &FrameQuery,
) -> Result<FramePage, FrameIndexError> {
    let limit = filter.limit.unwrap_or(u64::from(DEFAULT_LIMIT));
    if limit > u64::from(MAX_LIMIT) {
        return Err(FrameIndexError::BadFilter(format!(
            "limit {limit} is above the maximum of {MAX_LIMIT}; page with `offset`"
        )));
    }
    if i64::try_from(filter.offset).is_err() {
        return Err(FrameIndexError::BadFilter("offset is too large".into()));
    }
    if filter.step.is_some_and(|step| i64::try_from(step).is_err()) {
        return Err(FrameIndexError::BadFilter("step is too large".into()));
    }
    let dir = run_dir(runs_dir, run_id)?;
    let page = open_index(&dir, run_id)?
        .frames(&FrameQuery {
            limit: Some(limit),
            ..filter.clone()
        })
        .map_err(index_err(run_id))?;
    Ok(FramePage {
        total: page.total,
        frames: page
            .frames
            .into_iter()
            .map(|f| FrameInfo::new(run_id, f))
            .collect(),
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
    let info = open_index(&dir, run_id)?
        .frame(frame_id)
        .map_err(index_err(run_id))?
        .map(|f| FrameInfo::new(run_id, f))
        .ok_or_else(|| FrameIndexError::UnknownFrame {
            run: run_id.to_string(),
            frame_id,
        })?;
    let file = frame_file(&dir, &info.frame.path).map_err(|reason| {
        tracing::warn!(run = run_id, frame_id, "frame file refused: {reason}");
        let gone = std::fs::symlink_metadata(dir.join(&info.frame.path))
            .is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound);
        if gone && crate::storage::layout::is_frame_path(&info.frame.path) {
            damaged(&dir, &info, "is missing".into())
        } else {
            FrameIndexError::FileUnavailable {
                run: run_id.to_string(),
                frame_id,
                reason: reason.to_string(),
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
        frame_id: info.frame.id,
        step: info.frame.meta.step,
        path: info.frame.path.clone(),
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
    let (bytes, found) = crate::storage::checksum::read_hashed(file, info.frame.size_bytes)
        .map_err(|e| {
            tracing::warn!(
                run = info.run_id,
                frame_id = info.frame.id,
                "cannot read {}: {e}",
                file.display()
            );
            if e.kind() == std::io::ErrorKind::NotFound {
                damaged(&run_dir, info, "is missing".into())
            } else {
                FrameIndexError::FileUnavailable {
                    run: info.run_id.clone(),
                    frame_id: info.frame.id,
                    reason: e.to_string(),
                }
            }
        })?;
    if found != info.frame.sha256 {
        tracing::warn!(
            run = info.run_id,
            frame_id = info.frame.id,
            path = info.frame.path,
            "frame file damaged"
        );
        return Err(damaged(
            &run_dir,
            info,
            format!(
                "does not match the SHA-256 recorded when it was written (recorded {}, the \
                 file's {} bytes hash to {found})",
                info.frame.sha256,
                bytes.len()
            ),
        ));
    }
    Ok(bytes)
}

/// Resolves an index row's `path` inside the canonical run directory `run_dir`: relative,
/// no `..`, and after resolving symlinks a regular file inside `<run>/frames/`.
pub fn frame_file(run_dir: &Path, rel: &str) -> Result<PathBuf, FramePathError> {
    let rel_path = Path::new(rel);
    let plain = rel_path
        .components()
        .all(|c| matches!(c, std::path::Component::Normal(_)));
    if rel.is_empty() || rel.contains('\0') || !plain {
        return Err(FramePathError::NotPlain(rel.to_string()));
    }
    let unreadable = |source| FramePathError::Unreadable {
        path: rel.to_string(),
        source,
    };
    let frames = run_dir
        .join(FRAMES_DIR)
        .canonicalize()
        .map_err(FramePathError::FramesDir)?;
    let file = run_dir.join(rel_path).canonicalize().map_err(unreadable)?;
    if !file.starts_with(&frames) {
        return Err(FramePathError::Outside(rel.to_string()));
    }
    let meta = std::fs::metadata(&file).map_err(unreadable)?;
    if !meta.is_file() {
        return Err(FramePathError::NotAFile(rel.to_string()));
    }
    Ok(file)
}

/// The frames of `step` in the run at `run_dir` (for `frame` events when the step is durable).
pub fn frames_of_step(
    run_dir: &Path,
    run_id: &str,
    step: usize,
) -> Result<Vec<FrameInfo>, FrameIndexError> {
    let frames = open_index(run_dir, run_id)?
        .frames_of_step(step)
        .map_err(|e| FrameIndexError::StepFrames {
            run: run_id.to_string(),
            step,
            reason: e.to_string(),
        })?;
    Ok(frames
        .into_iter()
        .map(|f| FrameInfo::new(run_id, f))
        .collect())
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
            && mtime + MTIME_SLACK_S < b.frame.meta.wall_time_unix_s
        {
            break;
        }
        let found = open_index(&dir, &run_id).and_then(|reader| {
            reader
                .latest_frame(camera)
                .map(|f| f.map(|f| FrameInfo::new(&run_id, f)))
                .map_err(index_err(&run_id))
        });
        match found {
            Ok(Some(f))
                if best.as_ref().is_none_or(|b| {
                    f.frame.meta.wall_time_unix_s > b.frame.meta.wall_time_unix_s
                }) =>
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
