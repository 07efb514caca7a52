//! The run directories under `<data>/runs/`, read without taking their write lock (a run
//! being written is read too): the manifest and the dataset's read-only [`RunReader`]
//! (`crate::storage::RunReader`). A broken
//! directory is reported as `unreadable` with the reason, never as a server error.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::daemon::frame_index::FrameIndexError;
use crate::daemon::runs::LiveState;
use crate::storage::{Manifest, RunStatus, StorageError, read_manifest};

/// A run's status as the run list shows it: what its index says, `unreadable`, or, for the
/// active run, its [`LiveState`], and `interrupted` for a run the index says is running but
/// nothing executes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StoredStatus {
    /// Executing (the index says so; the live state says more).
    Running,
    /// Every step is done.
    Done,
    /// Stopped by an error.
    Failed,
    /// Stopped by the operator.
    Aborted,
    /// The index says running but nothing executes it: the daemon stopped mid-run.
    Interrupted,
    /// The run directory could not be read.
    Unreadable,
    /// The active run is paused.
    Paused,
    /// The active run waits at a prompt.
    Prompt,
    /// The active run is stopping.
    Stopping,
}

impl StoredStatus {
    /// The serde spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            StoredStatus::Running => "running",
            StoredStatus::Done => "done",
            StoredStatus::Failed => "failed",
            StoredStatus::Aborted => "aborted",
            StoredStatus::Interrupted => "interrupted",
            StoredStatus::Unreadable => "unreadable",
            StoredStatus::Paused => "paused",
            StoredStatus::Prompt => "prompt",
            StoredStatus::Stopping => "stopping",
        }
    }
}

impl std::fmt::Display for StoredStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl From<RunStatus> for StoredStatus {
    fn from(s: RunStatus) -> Self {
        match s {
            RunStatus::Running => StoredStatus::Running,
            RunStatus::Done => StoredStatus::Done,
            RunStatus::Failed => StoredStatus::Failed,
            RunStatus::Aborted => StoredStatus::Aborted,
        }
    }
}

impl From<LiveState> for StoredStatus {
    fn from(s: LiveState) -> Self {
        match s {
            LiveState::Running => StoredStatus::Running,
            LiveState::Paused => StoredStatus::Paused,
            LiveState::Prompt => StoredStatus::Prompt,
            LiveState::Stopping => StoredStatus::Stopping,
        }
    }
}

/// What a run directory says about its run.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct StoredRun {
    pub run_id: String,
    /// Script file name (`""` when unreadable).
    pub script: String,
    /// `done`, `failed`, `aborted`, `running` (as the index says) or `unreadable`; in the run
    /// list, the live state of the active run and `interrupted` for one nothing executes.
    pub status: StoredStatus,
    /// The index's status message (why a run failed or stopped).
    pub message: Option<String>,
    /// Wall-clock Unix time the run was created (its start).
    pub created_unix_s: f64,
    /// Wall-clock Unix time it ended: when its status was last recorded for a stopped run, the
    /// last durable step for one the daemon was interrupted in; `null` while it runs.
    pub ended_unix_s: Option<f64>,
    /// Wall-clock seconds from start to end (to now while it runs; pauses and the time between
    /// the sessions of a resumed run count), `null` when unknown.
    pub duration_s: Option<f64>,
    pub steps_done: usize,
    pub steps_total: usize,
    /// Frames indexed (raw and HDR).
    pub frames: usize,
    /// Rig time at the end of the last durable step.
    pub rig_time_s: f64,
    /// Why the directory could not be read (status `unreadable`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The manifest (`None` when unreadable).
    #[serde(skip)]
    pub manifest: Option<Manifest>,
}

/// Reads one run directory; never fails (an unreadable one says why).
pub fn read(dir: &Path) -> StoredRun {
    let run_id = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    match read_inner(dir, &run_id) {
        Ok(run) => run,
        Err(error) => StoredRun {
            run_id,
            script: String::new(),
            status: StoredStatus::Unreadable,
            message: None,
            created_unix_s: modified_unix_s(dir),
            ended_unix_s: None,
            duration_s: None,
            steps_done: 0,
            steps_total: 0,
            frames: 0,
            rig_time_s: 0.0,
            error: Some(error.to_string()),
            manifest: None,
        },
    }
}

/// Why a run directory could not be read.
#[derive(Debug, thiserror::Error)]
enum ReadError {
    /// The manifest or the index cannot be read.
    #[error(transparent)]
    Storage(#[from] StorageError),
    /// The index cannot be opened.
    #[error(transparent)]
    Index(#[from] FrameIndexError),
}

fn read_inner(dir: &Path, run_id: &str) -> Result<StoredRun, ReadError> {
    let manifest = read_manifest(dir)?;
    // Read-only, schema version checked, leaving no `-shm`/`-wal` files behind.
    let reader = crate::daemon::frame_index::open_index(dir, run_id)?;
    let run = reader.run()?;
    let journal = reader.journal()?;
    // A run still `running` in its index either runs now (the caller knows) or was
    // interrupted: then it ended with its last durable step.
    let ended_unix_s = if run.status == RunStatus::Running {
        journal.last_step_unix_s
    } else {
        Some(run.updated_unix_s)
    };
    let frames = reader.frame_count()?;
    Ok(StoredRun {
        run_id: run_id.to_string(),
        script: manifest.script_name.clone(),
        status: run.status.into(),
        message: run.message,
        created_unix_s: manifest.created_unix_s,
        ended_unix_s,
        duration_s: ended_unix_s.map(|end| (end - manifest.created_unix_s).max(0.0)),
        steps_done: journal.steps_done,
        steps_total: journal.steps_total,
        frames: usize::try_from(frames).unwrap_or(usize::MAX),
        rig_time_s: journal.rig_time_s.unwrap_or(0.0),
        error: None,
        manifest: Some(manifest),
    })
}

fn modified_unix_s(dir: &Path) -> f64 {
    std::fs::metadata(dir)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// The runs directory cannot be listed.
#[derive(Debug, thiserror::Error)]
#[error("cannot list {}: {source}", root.display())]
pub struct ListError {
    /// The runs directory.
    pub root: PathBuf,
    /// Why.
    pub source: std::io::Error,
}

/// The run directories under `root` whose names are valid run ids.
pub fn dirs(root: &Path) -> Result<Vec<PathBuf>, ListError> {
    let read = match std::fs::read_dir(root) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(ListError {
                root: root.to_path_buf(),
                source,
            });
        }
    };
    Ok(read
        .filter_map(|e| e.ok())
        // `file_type` does not follow symlinks: a link to elsewhere is not a run here.
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter(|e| {
            e.file_name()
                .to_str()
                .is_some_and(|n| super::scripts::check_run_id(n).is_ok())
        })
        .map(|e| e.path())
        .collect())
}

/// Every run under `root`, newest first.
pub fn list(root: &Path) -> Result<Vec<StoredRun>, ListError> {
    let mut runs: Vec<StoredRun> = dirs(root)?.iter().map(|d| read(d)).collect();
    runs.sort_by(|a, b| {
        b.created_unix_s
            .total_cmp(&a.created_unix_s)
            .then_with(|| b.run_id.cmp(&a.run_id))
    });
    Ok(runs)
}
