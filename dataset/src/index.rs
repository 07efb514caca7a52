//! The SQLite index of a run (`index.sqlite`): the run row, the step journal and one row per
//! frame with every per-frame fact. WAL mode, `synchronous=FULL` (a commit is durable when it
//! returns, which the durability invariant relies on).
//!
//! JSON columns (`manifest`, `axes_deg`, `lamps_on`, `exposures_s`, `notes`) are queried with
//! SQLite's built-in JSON functions, e.g. all frames of lamp `lamp3` seen by camera `cam5`:
//! ```sql
//! SELECT frames.path FROM frames, json_each(frames.lamps_on) j
//!  WHERE camera='cam5' AND j.value='lamp3';
//! ```
//! `json_each` has columns of its own named `path`, `id`, `key`, `value`, `type`, `atom`,
//! `parent` and `fullkey`, so `path` and `id` must be qualified (`frames.path`) in such a join;
//! the unqualified `SELECT path …` is rejected by SQLite as ambiguous. The view `frame_lamps`
//! (every frame column plus `lamp`, one row per lamp that was on) avoids the join:
//! `SELECT path FROM frame_lamps WHERE camera='cam5' AND lamp='lamp3'`.
//! Frames with the turntable at 90°: `WHERE json_extract(axes_deg, '$.turntable') = 90`.
//! The simulator's effect plan of a frame (and why) is in its notes:
//! `SELECT path, json_extract(notes, '$.effects.shadows.on'),
//! json_extract(notes, '$.effects.shadows.why') FROM frames`.
//! Ground-truth images (simulated rigs with `sim.ground_truth = true`) are rows of
//! `ground_truth`, one per image, keyed to their frame:
//! `SELECT g.kind, g.path FROM ground_truth g JOIN frames f ON f.id = g.frame_id
//!  WHERE f.camera = 'cam1' AND f.step = 3`.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use rusqlite::{Connection, OpenFlags, OptionalExtension, Transaction, params};
use serde::{Deserialize, Serialize};

use crate::error::{Result, StorageError};
use crate::frame_meta::FrameMeta;
use crate::manifest::Manifest;
use crate::plan::RunPlan;

/// Schema version, stored in `PRAGMA user_version`. Versions 1 (no `ground_truth` table),
/// 2 (no `frames.sample_shift`) and 3 (no `frames.fixture_pose`, no `products` table) are
/// upgraded in place when [`crate::RunStore::open`] opens the run; [`crate::RunReader`] reads
/// them without changing the file.
pub const SCHEMA_VERSION: i32 = 4;

/// What schema version 4 added to version 3: how each frame's fixture was placed (JSON of a
/// `FixturePose`, NULL for flat and centred), and the products that processing wrote into the
/// run directory.
pub const PRODUCTS_SCHEMA: &str = "
ALTER TABLE frames ADD COLUMN fixture_pose TEXT;
CREATE TABLE IF NOT EXISTS products (
    id              INTEGER PRIMARY KEY,
    kind            TEXT NOT NULL,            -- hdr, rectified, btf
    key             TEXT NOT NULL UNIQUE,     -- what the product is of (kind/step/camera...)
    path            TEXT NOT NULL UNIQUE,     -- relative to the run directory
    inputs          TEXT NOT NULL,            -- JSON array of input frame paths
    calibrations    TEXT NOT NULL,            -- JSON array of calibration ids
    software        TEXT NOT NULL,            -- e.g. stagehand 0.1.0
    parameters      TEXT NOT NULL,            -- JSON
    sha256          TEXT NOT NULL,            -- of the file's bytes (a directory: of its manifest)
    size_bytes      INTEGER NOT NULL,
    created_unix_s  REAL NOT NULL
) STRICT;
";

/// What schema version 3 added to version 2: the left shift of each raw frame's samples in its
/// PNG (MSB alignment, see [`crate::png16`]). Rows of older datasets get 0: their PNGs hold
/// the DN unshifted.
pub const SAMPLE_SHIFT_SCHEMA: &str =
    "ALTER TABLE frames ADD COLUMN sample_shift INTEGER NOT NULL DEFAULT 0;";

/// What schema version 2 added to version 1: the ground-truth images written beside frames.
/// One row per image; deleting a frame row deletes its ground truth rows.
pub const GROUND_TRUTH_SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS ground_truth (
    id          INTEGER PRIMARY KEY,
    frame_id    INTEGER NOT NULL REFERENCES frames(id) ON DELETE CASCADE,
    step        INTEGER NOT NULL REFERENCES steps(idx),
    camera      TEXT NOT NULL,
    kind        TEXT NOT NULL,            -- depth, normal, radiance, material
    path        TEXT NOT NULL UNIQUE,     -- relative to the run directory
    sha256      TEXT NOT NULL,            -- of the file's bytes, hex
    size_bytes  INTEGER NOT NULL,
    channels    TEXT NOT NULL             -- JSON array of channel names in sample order
) STRICT;
CREATE INDEX IF NOT EXISTS ground_truth_frame ON ground_truth(frame_id);
";

/// The schema. Every table is `STRICT`, so a wrongly typed value is an error, not a surprise.
pub const SCHEMA: &str = "
CREATE TABLE runs (
    id              TEXT PRIMARY KEY,
    status          TEXT NOT NULL CHECK (status IN ('running', 'done', 'failed', 'aborted')),
    message         TEXT,
    manifest        TEXT NOT NULL,            -- Manifest as JSON
    created_unix_s  REAL NOT NULL,
    updated_unix_s  REAL NOT NULL
) STRICT;
CREATE TABLE steps (
    idx               INTEGER PRIMARY KEY,    -- Plan step index
    kind              TEXT NOT NULL,          -- the step's action kind
    block             TEXT NOT NULL,
    script_line       INTEGER NOT NULL,
    script_col        INTEGER NOT NULL,
    status            TEXT NOT NULL DEFAULT 'pending' CHECK (status IN ('pending', 'done')),
    rig_time_start_s  REAL,
    rig_time_end_s    REAL,
    wall_time_unix_s  REAL                    -- when the step committed
) STRICT;
CREATE TABLE frames (
    id                 INTEGER PRIMARY KEY,
    step               INTEGER NOT NULL REFERENCES steps(idx),
    path               TEXT NOT NULL UNIQUE,  -- relative to the run directory
    sha256             TEXT NOT NULL,         -- of the file's bytes, hex
    size_bytes         INTEGER NOT NULL,
    camera             TEXT NOT NULL,
    kind               TEXT NOT NULL CHECK (kind IN ('raw', 'hdr')),
    label              TEXT NOT NULL,
    block              TEXT NOT NULL,
    exposure_index     INTEGER,
    exposure_s         REAL NOT NULL,
    exposures_s        TEXT NOT NULL,         -- JSON array
    gain               REAL NOT NULL,
    trigger_id         INTEGER,
    axes_deg           TEXT NOT NULL,         -- JSON object axis -> degrees
    lamps_on           TEXT NOT NULL,         -- JSON array of lamp ids
    laser_armed        INTEGER NOT NULL,
    laser_on           INTEGER NOT NULL,
    laser_colour_nm    INTEGER NOT NULL,
    laser_tilt_deg     REAL,
    laser_mount_deg    REAL,
    fixture            TEXT NOT NULL,
    cart_mm            REAL,
    rig_time_s         REAL NOT NULL,
    wall_time_unix_s   REAL NOT NULL,
    width              INTEGER NOT NULL,
    height             INTEGER NOT NULL,
    bit_depth          INTEGER NOT NULL,
    saturated_samples  INTEGER NOT NULL,
    notes              TEXT NOT NULL          -- JSON
) STRICT;
CREATE INDEX frames_camera ON frames(camera);
CREATE INDEX frames_step ON frames(step);
CREATE VIEW frame_lamps AS
    SELECT frames.*, j.value AS lamp FROM frames, json_each(frames.lamps_on) AS j;
";

/// State of a run, stored as text (`running`, `done`, `failed`, `aborted`) in `runs.status`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunStatus {
    /// Created or resumed, steps are executing (or the process died while they were).
    Running,
    /// Every step is done.
    Done,
    /// Stopped by an error.
    Failed,
    /// Stopped by the operator.
    Aborted,
}

impl RunStatus {
    /// The text stored in SQLite.
    pub fn as_str(self) -> &'static str {
        match self {
            RunStatus::Running => "running",
            RunStatus::Done => "done",
            RunStatus::Failed => "failed",
            RunStatus::Aborted => "aborted",
        }
    }

    /// Parses [`RunStatus::as_str`] output.
    pub fn parse(text: &str) -> Option<RunStatus> {
        match text {
            "running" => Some(RunStatus::Running),
            "done" => Some(RunStatus::Done),
            "failed" => Some(RunStatus::Failed),
            "aborted" => Some(RunStatus::Aborted),
            _ => None,
        }
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The journal entry of a finished step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    /// Plan step index.
    pub step: usize,
    /// Action kind ([`crate::plan::PlannedStep::kind`]).
    pub kind: String,
    /// Enclosing block names joined with `/`.
    pub block: String,
    /// Rig time in seconds when the step started.
    pub rig_time_start_s: f64,
    /// Rig time in seconds when the step ended.
    pub rig_time_end_s: f64,
    /// Wall-clock Unix time in seconds when the step ended.
    pub wall_time_unix_s: f64,
}

/// A frame row of the index: where the file is, its checksum, and every per-frame fact.
/// Serialises flat (`frame_id`, `path`, `sha256`, `size_bytes`, then the [`FrameMeta`]
/// fields), which is how the daemon's API shows a frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
pub struct StoredFrame {
    /// Row id (`frames.id`); stable while the run exists.
    #[serde(rename = "frame_id")]
    pub id: i64,
    /// Path relative to the run directory (`frames/…`).
    pub path: String,
    /// Hex SHA-256 of the file.
    pub sha256: String,
    /// File size in bytes.
    pub size_bytes: u64,
    /// Every per-frame fact.
    #[serde(flatten)]
    pub meta: FrameMeta,
}

/// A ground-truth row of the index: one image written beside a frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StoredGroundTruth {
    /// Row id of the frame it belongs to.
    pub frame_id: i64,
    /// Plan step of that frame.
    pub step: usize,
    /// Path of the frame it belongs to (`frames/…`).
    pub frame_path: String,
    /// Plane kind (`depth`, `normal`, `radiance`, `material`).
    pub kind: String,
    /// Path relative to the run directory (`frames/…`).
    pub path: String,
    /// Hex SHA-256 of the file.
    pub sha256: String,
    /// File size in bytes.
    pub size_bytes: u64,
    /// Channel names in sample order.
    pub channels: Vec<String>,
}

/// A frame row about to be inserted.
pub(crate) struct NewFrameRow<'a> {
    pub path: String,
    pub sha256: String,
    pub size_bytes: u64,
    pub meta: &'a FrameMeta,
    /// Ground-truth images written beside the frame.
    pub ground_truth: Vec<NewGroundTruthRow>,
}

/// A ground-truth row about to be inserted.
pub(crate) struct NewGroundTruthRow {
    pub kind: String,
    pub path: String,
    pub sha256: String,
    pub size_bytes: u64,
    pub channels: Vec<String>,
}

/// Current Unix time in seconds (0 if the clock is before 1970).
pub(crate) fn now_unix_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// The index database of one run.
pub(crate) struct Index {
    conn: Connection,
    path: PathBuf,
}

impl Index {
    fn err(&self, what: &'static str) -> impl Fn(rusqlite::Error) -> StorageError + '_ {
        sql_err(&self.path, what)
    }

    fn json_err(&self, column: &str) -> impl Fn(serde_json::Error) -> StorageError + '_ {
        let path = self.path.join(column);
        move |source| StorageError::Json {
            op: "encode/decode",
            path: path.clone(),
            source,
        }
    }

    /// Opens (or, with `create`, creates) the database and sets the durability pragmas.
    fn connect(path: &Path, create: bool) -> Result<Index> {
        let mut flags = OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        if create {
            flags |= OpenFlags::SQLITE_OPEN_CREATE;
        }
        let sqlite = |what| sql_err(path, what);
        let conn = Connection::open_with_flags(path, flags).map_err(sqlite("open"))?;
        conn.busy_timeout(std::time::Duration::from_secs(10))
            .map_err(sqlite("set busy timeout"))?;
        let mode: String = conn
            .pragma_update_and_check(None, "journal_mode", "WAL", |row| row.get(0))
            .map_err(sqlite("enable WAL"))?;
        if !mode.eq_ignore_ascii_case("wal") {
            tracing::warn!(path = %path.display(), mode, "SQLite refused WAL mode");
        }
        conn.execute_batch("PRAGMA synchronous = FULL; PRAGMA foreign_keys = ON;")
            .map_err(sqlite("set pragmas"))?;
        Ok(Index {
            conn,
            path: path.to_path_buf(),
        })
    }

    /// Creates a new index with the run row (status running) and one pending row per step.
    pub(crate) fn create<P: RunPlan>(path: &Path, manifest: &Manifest, plan: &P) -> Result<Index> {
        let mut index = Index::connect(path, true)?;
        let manifest_json =
            serde_json::to_string(manifest).map_err(index.json_err("runs.manifest"))?;
        let now = now_unix_s();
        let path = index.path.clone();
        let sqlite = |what| sql_err(&path, what);
        let tx = index
            .conn
            .transaction()
            .map_err(sqlite("begin transaction"))?;
        tx.execute_batch(SCHEMA).map_err(sqlite("create schema"))?;
        tx.execute_batch(GROUND_TRUTH_SCHEMA)
            .map_err(sqlite("create ground truth table"))?;
        tx.execute_batch(&format!("{SAMPLE_SHIFT_SCHEMA} {PRODUCTS_SCHEMA}"))
            .map_err(sqlite("add the sample shift column and the products table"))?;
        tx.pragma_update(None, "user_version", SCHEMA_VERSION)
            .map_err(sqlite("set schema version"))?;
        tx.execute(
            "INSERT INTO runs (id, status, message, manifest, created_unix_s, updated_unix_s)
             VALUES (?1, 'running', NULL, ?2, ?3, ?4)",
            params![manifest.run_id, manifest_json, manifest.created_unix_s, now],
        )
        .map_err(sqlite("insert run row"))?;
        {
            let mut insert = tx
                .prepare(
                    "INSERT INTO steps (idx, kind, block, script_line, script_col)
                     VALUES (?1, ?2, ?3, ?4, ?5)",
                )
                .map_err(sqlite("prepare step insert"))?;
            for (i, step) in (0..plan.step_count()).filter_map(|i| Some((i, plan.step(i)?))) {
                // The journal is keyed by position in the plan, which is what resume iterates.
                insert
                    .execute(params![
                        to_i64(i),
                        step.kind,
                        step.block,
                        step.line,
                        step.col
                    ])
                    .map_err(sqlite("insert step rows"))?;
            }
        }
        tx.commit().map_err(sqlite("commit run creation"))?;
        Ok(index)
    }

    /// Opens the index of an existing run and checks its schema version.
    pub(crate) fn open(path: &Path) -> Result<Index> {
        let index = Index::connect(path, false)?;
        let version: i32 = index
            .conn
            .query_row("PRAGMA user_version", [], |row| row.get(0))
            .map_err(index.err("read schema version"))?;
        if (1..SCHEMA_VERSION).contains(&version) {
            let ground_truth = if version < 2 { GROUND_TRUTH_SCHEMA } else { "" };
            let sample_shift = if version < 3 { SAMPLE_SHIFT_SCHEMA } else { "" };
            index
                .conn
                .execute_batch(&format!(
                    "BEGIN; {ground_truth} {sample_shift} {PRODUCTS_SCHEMA} \
                     PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
                ))
                .map_err(index.err("upgrade the schema to version 4"))?;
            return Ok(index);
        }
        if version != SCHEMA_VERSION {
            return Err(StorageError::CorruptIndex {
                path: index.path.clone(),
                reason: format!("schema version {version}, this build reads {SCHEMA_VERSION}"),
            });
        }
        Ok(index)
    }

    /// The run id recorded in the `runs` table.
    pub(crate) fn run_id(&self) -> Result<String> {
        self.conn
            .query_row("SELECT id FROM runs", [], |row| row.get(0))
            .optional()
            .map_err(self.err("read run row"))?
            .ok_or_else(|| StorageError::CorruptIndex {
                path: self.path.clone(),
                reason: "the runs table is empty".into(),
            })
    }

    /// The reader's view of this index (the writer's connection sees its own commits).
    fn read(&self) -> crate::query::Ctx<'_> {
        crate::query::Ctx {
            conn: &self.conn,
            path: &self.path,
            version: SCHEMA_VERSION,
        }
    }

    /// Indices of the steps marked done.
    pub(crate) fn done_steps(&self) -> Result<std::collections::BTreeSet<usize>> {
        self.read().done_steps()
    }

    /// Latest rig time reached by a committed step (0 if none).
    pub(crate) fn last_rig_time_s(&self) -> Result<f64> {
        Ok(self.read().journal()?.rig_time_s.unwrap_or(0.0))
    }

    /// Sets the run status and message.
    pub(crate) fn set_status(&self, status: RunStatus, message: Option<&str>) -> Result<()> {
        self.conn
            .execute(
                "UPDATE runs SET status = ?1, message = ?2, updated_unix_s = ?3",
                params![status.as_str(), message, now_unix_s()],
            )
            .map_err(self.err("update run status"))?;
        Ok(())
    }

    /// The run status and message.
    pub(crate) fn status(&self) -> Result<(RunStatus, Option<String>)> {
        let run = self.read().run()?;
        Ok((run.status, run.message))
    }

    /// Commits several steps in ONE transaction (one fsync): for each, replaces its frame rows
    /// and marks it done. Either every step of the batch commits or none does.
    pub(crate) fn commit_steps(
        &mut self,
        batch: &[(&StepRecord, &[NewFrameRow<'_>])],
    ) -> Result<()> {
        let path = self.path.clone();
        let sqlite = |what| sql_err(&path, what);
        let mut encoded_batch = Vec::with_capacity(batch.len());
        for (_, rows) in batch {
            let mut encoded = Vec::with_capacity(rows.len());
            for row in rows.iter() {
                let m = row.meta;
                let json = |v: serde_json::Result<String>| v.map_err(self.json_err("frames"));
                encoded.push((
                    json(serde_json::to_string(&m.exposures_s))?,
                    json(serde_json::to_string(&m.axes_deg))?,
                    json(serde_json::to_string(&m.lamps_on))?,
                    json(serde_json::to_string(&m.notes))?,
                    match m.fixture_pose.is_flat_centred() {
                        true => None,
                        false => Some(json(serde_json::to_string(&m.fixture_pose))?),
                    },
                ));
            }
            encoded_batch.push(encoded);
        }
        let tx: Transaction<'_> = self
            .conn
            .transaction()
            .map_err(sqlite("begin step commit"))?;
        for ((record, rows), encoded) in batch.iter().zip(&encoded_batch) {
            let (record, rows) = (*record, *rows);
            let step = to_i64(record.step);
            let kind: Option<String> = tx
                .prepare_cached("SELECT kind FROM steps WHERE idx = ?1")
                .and_then(|mut q| q.query_row([step], |row| row.get(0)))
                .optional()
                .map_err(sqlite("read step row"))?;
            match kind {
                None => {
                    return Err(StorageError::InvalidCommit {
                        step: record.step,
                        run: self.path.clone(),
                        reason: "the plan has no such step".into(),
                    });
                }
                Some(kind) if kind != record.kind => {
                    tracing::warn!(
                        step = record.step,
                        planned = kind,
                        recorded = record.kind,
                        "step kind differs from the plan"
                    );
                }
                Some(_) => {}
            }
            delete_step_rows(&tx, step).map_err(sqlite("delete old frame rows"))?;
            {
                let mut insert = tx
                    .prepare_cached(
                        "INSERT OR REPLACE INTO frames (
                            step, path, sha256, size_bytes, camera, kind, label, block,
                            exposure_index, exposure_s, exposures_s, gain, trigger_id, axes_deg,
                            lamps_on, laser_armed, laser_on, laser_colour_nm, laser_tilt_deg,
                            laser_mount_deg, fixture, cart_mm, rig_time_s, wall_time_unix_s, width,
                            height, bit_depth, saturated_samples, notes, sample_shift, fixture_pose)
                         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15,
                            ?16, ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, ?25, ?26, ?27, ?28, ?29,
                            ?30, ?31)",
                    )
                    .map_err(sqlite("prepare frame insert"))?;
                for (row, (exposures, axes, lamps, notes, pose)) in rows.iter().zip(encoded.iter())
                {
                    let m = row.meta;
                    let too_big = |what: &str| StorageError::InvalidFrame {
                        name: row.path.clone(),
                        reason: format!("{what} does not fit in SQLite's 63-bit integers"),
                    };
                    let trigger = m
                        .trigger_id
                        .map(|t| i64::try_from(t).map_err(|_| too_big("trigger id")))
                        .transpose()?;
                    let saturated = i64::try_from(m.saturated_samples)
                        .map_err(|_| too_big("saturated_samples"))?;
                    let size = i64::try_from(row.size_bytes).map_err(|_| too_big("file size"))?;
                    insert
                        .execute(params![
                            step,
                            row.path,
                            row.sha256,
                            size,
                            m.camera,
                            m.kind.as_str(),
                            m.label,
                            m.block,
                            m.exposure_index.map(to_i64),
                            m.exposure_s,
                            exposures,
                            m.gain,
                            trigger,
                            axes,
                            lamps,
                            m.laser_armed,
                            m.laser_on,
                            m.laser_colour_nm,
                            m.laser_tilt_deg,
                            m.laser_mount_deg,
                            m.fixture,
                            m.cart_mm,
                            m.rig_time_s,
                            m.wall_time_unix_s,
                            m.width,
                            m.height,
                            m.bit_depth,
                            saturated,
                            notes,
                            m.sample_shift,
                            pose,
                        ])
                        .map_err(sqlite("insert frame row"))?;
                    let frame_id = tx.last_insert_rowid();
                    for g in &row.ground_truth {
                        let size = i64::try_from(g.size_bytes).map_err(|_| too_big("file size"))?;
                        let channels = serde_json::to_string(&g.channels).map_err(|source| {
                            StorageError::Json {
                                op: "encode",
                                path: path.join("ground_truth"),
                                source,
                            }
                        })?;
                        tx.prepare_cached(
                            "INSERT INTO ground_truth (frame_id, step, camera, kind, path, sha256,
                                size_bytes, channels)
                             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                        )
                        .and_then(|mut q| {
                            q.execute(params![
                                frame_id, step, m.camera, g.kind, g.path, g.sha256, size, channels
                            ])
                        })
                        .map_err(sqlite("insert ground truth row"))?;
                    }
                }
            }
            tx.prepare_cached(
                "UPDATE steps SET status = 'done', kind = ?2, block = ?3, rig_time_start_s = ?4,
                    rig_time_end_s = ?5, wall_time_unix_s = ?6 WHERE idx = ?1",
            )
            .and_then(|mut q| {
                q.execute(params![
                    step,
                    record.kind,
                    record.block,
                    record.rig_time_start_s,
                    record.rig_time_end_s,
                    record.wall_time_unix_s
                ])
            })
            .map_err(sqlite("mark step done"))?;
        }
        tx.execute("UPDATE runs SET updated_unix_s = ?1", [now_unix_s()])
            .map_err(sqlite("touch run row"))?;
        tx.commit().map_err(sqlite("commit steps"))
    }

    /// Makes `steps` pending again in ONE transaction: deletes their frame and ground-truth
    /// rows and clears their journal times. Returns the paths of the deleted rows' files
    /// (relative to the run directory), which the caller removes after the commit.
    pub(crate) fn reset_steps(&mut self, steps: &[usize]) -> Result<Vec<String>> {
        let path = self.path.clone();
        let sqlite = |what| sql_err(&path, what);
        let tx = self.conn.transaction().map_err(sqlite("begin retake"))?;
        let mut files = Vec::new();
        for &step in steps {
            let step = to_i64(step);
            for sql in [
                "SELECT path FROM ground_truth WHERE step = ?1",
                "SELECT path FROM frames WHERE step = ?1",
            ] {
                let mut q = tx
                    .prepare_cached(sql)
                    .map_err(sqlite("list retaken files"))?;
                let rows = q
                    .query_map([step], |r| r.get::<_, String>(0))
                    .map_err(sqlite("list retaken files"))?;
                for row in rows {
                    files.push(row.map_err(sqlite("list retaken files"))?);
                }
            }
            delete_step_rows(&tx, step).map_err(sqlite("delete retaken frame rows"))?;
            tx.prepare_cached(
                "UPDATE steps SET status = 'pending', rig_time_start_s = NULL,
                    rig_time_end_s = NULL, wall_time_unix_s = NULL WHERE idx = ?1",
            )
            .and_then(|mut q| q.execute([step]))
            .map_err(sqlite("mark retaken step pending"))?;
        }
        tx.execute("UPDATE runs SET updated_unix_s = ?1", [now_unix_s()])
            .map_err(sqlite("touch run row"))?;
        tx.commit().map_err(sqlite("commit retake"))?;
        Ok(files)
    }

    /// Frame rows, of one step or all, ordered by step and path.
    pub(crate) fn frames(&self, step: Option<usize>) -> Result<Vec<StoredFrame>> {
        self.read().frames_by_path(step)
    }

    /// Ground-truth rows, of one step or all, ordered by path.
    pub(crate) fn ground_truth(&self, step: Option<usize>) -> Result<Vec<StoredGroundTruth>> {
        self.read().ground_truth(step)
    }

    /// The underlying connection: for the products table (`products.rs`) and tests.
    pub(crate) fn conn(&self) -> &Connection {
        &self.conn
    }
}

/// Deletes the frame rows of `step` and the ground-truth rows beside them.
fn delete_step_rows(tx: &Transaction<'_>, step: i64) -> rusqlite::Result<()> {
    tx.prepare_cached("DELETE FROM ground_truth WHERE step = ?1")?
        .execute([step])?;
    tx.prepare_cached("DELETE FROM frames WHERE step = ?1")?
        .execute([step])?;
    Ok(())
}

/// Opens the index of the run at `run_dir` read-only, for readers that must not take the
/// run's write lock (the daemon's listings, `stagehand verify`). While a writer has the index
/// open its `-wal` file exists and this is an ordinary WAL reader (it sees the last committed
/// step). When there is no `-wal` (no writer since the last clean close) the file is opened
/// `immutable`, because a read-only WAL reader would otherwise leave `-shm`/`-wal` files
/// behind in the run directory.
pub(crate) fn open_read_only(run_dir: &Path) -> rusqlite::Result<Connection> {
    let path = run_dir.join(crate::layout::INDEX);
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let quiescent = !run_dir
        .join(format!("{}-wal", crate::layout::INDEX))
        .exists();
    let conn = if quiescent {
        Connection::open_with_flags(
            format!("file:{}?immutable=1", uri_path(&path)),
            flags | OpenFlags::SQLITE_OPEN_URI,
        )
    } else {
        Connection::open_with_flags(&path, flags)
    }?;
    conn.busy_timeout(std::time::Duration::from_secs(5))?;
    conn.execute_batch("PRAGMA query_only = ON;")?;
    Ok(conn)
}

/// A file path percent-encoded for an SQLite `file:` URI.
fn uri_path(path: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let mut out = String::new();
    for &b in path.as_os_str().as_bytes() {
        if b.is_ascii_alphanumeric() || b"/-_.~".contains(&b) {
            out.push(char::from(b));
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Converts a count or index to SQLite's integer (saturating: no plan or image gets near 2⁶³).
pub(crate) fn to_i64(v: usize) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// Maps a rusqlite error to a [`StorageError::Sqlite`] naming the database and the operation.
pub(crate) fn sql_err<'a>(
    path: &'a Path,
    what: &'static str,
) -> impl Fn(rusqlite::Error) -> StorageError + 'a {
    move |source| StorageError::Sqlite {
        path: path.to_path_buf(),
        what,
        source,
    }
}

/// A non-negative integer column as `u64`.
pub(crate) fn to_u64(column: usize, v: i64) -> rusqlite::Result<u64> {
    u64::try_from(v).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(column, v))
}

/// A non-negative integer column as `usize`.
pub(crate) fn to_usize(column: usize, v: i64) -> rusqlite::Result<usize> {
    usize::try_from(v).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(column, v))
}

/// Reads a non-negative integer column as `usize`.
pub(crate) fn get_usize(row: &rusqlite::Row<'_>, column: usize) -> rusqlite::Result<usize> {
    to_usize(column, row.get(column)?)
}
