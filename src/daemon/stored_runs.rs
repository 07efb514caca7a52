//! The run directories under `<data>/runs/`, read without taking their write lock (a run
//! being written is read too): the manifest and a read-only look at the SQLite index. A broken
//! directory is reported as `unreadable` with the reason, never as a server error.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::storage::Manifest;
use crate::storage::layout::{INDEX, MANIFEST};

/// What a run directory says about its run.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct StoredRun {
    pub run_id: String,
    /// Script file name (`""` when unreadable).
    pub script: String,
    /// `done`, `failed`, `aborted`, `running` (as the index says) or `unreadable`.
    pub status: String,
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
            status: "unreadable".into(),
            message: None,
            created_unix_s: modified_unix_s(dir),
            ended_unix_s: None,
            duration_s: None,
            steps_done: 0,
            steps_total: 0,
            frames: 0,
            rig_time_s: 0.0,
            error: Some(error),
            manifest: None,
        },
    }
}

fn read_inner(dir: &Path, run_id: &str) -> Result<StoredRun, String> {
    let manifest_path = dir.join(MANIFEST);
    let bytes = std::fs::read(&manifest_path)
        .map_err(|e| format!("cannot read {}: {e}", manifest_path.display()))?;
    let manifest: Manifest = serde_json::from_slice(&bytes)
        .map_err(|e| format!("{} is not a run manifest: {e}", manifest_path.display()))?;
    let index = dir.join(INDEX);
    let sql = |e: rusqlite::Error| format!("index {}: {e}", index.display());
    // Read-only and leaving no `-shm`/`-wal` files behind in a finished run.
    let conn = crate::daemon::frame_index::open_index(dir, run_id).map_err(|e| e.to_string())?;
    let (status, message, updated_unix_s): (String, Option<String>, f64) = conn
        .query_row(
            "SELECT status, message, updated_unix_s FROM runs",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )
        .map_err(sql)?;
    let (steps_total, steps_done, rig_time_s, last_step_unix_s): (
        i64,
        i64,
        Option<f64>,
        Option<f64>,
    ) = conn
        .query_row(
            "SELECT COUNT(*), COALESCE(SUM(status = 'done'), 0),
                    MAX(CASE WHEN status = 'done' THEN rig_time_end_s END),
                    MAX(wall_time_unix_s) FROM steps",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
        )
        .map_err(sql)?;
    // A run still `running` in its index either runs now (the caller knows) or was
    // interrupted: then it ended with its last durable step.
    let ended_unix_s = if status == "running" {
        last_step_unix_s
    } else {
        Some(updated_unix_s)
    };
    let frames: i64 = conn
        .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
        .map_err(sql)?;
    let count = |n: i64| usize::try_from(n).unwrap_or(0);
    Ok(StoredRun {
        run_id: run_id.to_string(),
        script: manifest.script_name.clone(),
        status,
        message,
        created_unix_s: manifest.created_unix_s,
        ended_unix_s,
        duration_s: ended_unix_s.map(|end| (end - manifest.created_unix_s).max(0.0)),
        steps_done: count(steps_done),
        steps_total: count(steps_total),
        frames: count(frames),
        rig_time_s: rig_time_s.unwrap_or(0.0),
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

/// The run directories under `root` whose names are valid run ids.
pub fn dirs(root: &Path) -> Result<Vec<PathBuf>, String> {
    let read = match std::fs::read_dir(root) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(format!("cannot list {}: {e}", root.display())),
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
pub fn list(root: &Path) -> Result<Vec<StoredRun>, String> {
    let mut runs: Vec<StoredRun> = dirs(root)?.iter().map(|d| read(d)).collect();
    runs.sort_by(|a, b| {
        b.created_unix_s
            .total_cmp(&a.created_unix_s)
            .then_with(|| b.run_id.cmp(&a.run_id))
    });
    Ok(runs)
}
