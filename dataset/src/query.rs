//! The typed queries on an index, shared by the writer ([`crate::RunStore`]) and the reader
//! ([`crate::RunReader`]): the one place that reads rows of `runs`, `steps`, `frames` and
//! `ground_truth` and turns them into Rust values. Queries adapt to the schema version, so
//! indexes of older datasets read the same (no `sample_shift` column before version 3: 0; no
//! `ground_truth` table before version 2: none).

use std::collections::BTreeSet;
use std::path::Path;

use rusqlite::types::Value;
use rusqlite::{Connection, OptionalExtension, Row};
use serde::Serialize;
use stagehand_devices::fixture_pose::FixturePose;

use crate::error::{Result, StorageError};
use crate::frame_meta::{FrameKind, FrameMeta};
use crate::index::{
    RunStatus, StoredFrame, StoredGroundTruth, get_usize, sql_err, to_i64, to_u64, to_usize,
};

/// An open index and what is needed to read it.
pub(crate) struct Ctx<'a> {
    /// The connection (read-only for readers).
    pub conn: &'a Connection,
    /// The `index.sqlite` file, for errors.
    pub path: &'a Path,
    /// Its schema version (`PRAGMA user_version`), already checked to be supported.
    pub version: i32,
}

/// The `runs` row of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunRow {
    /// The run id (the run directory's name).
    pub run_id: String,
    /// Where the run stands.
    pub status: RunStatus,
    /// Why it failed or stopped, when it did.
    pub message: Option<String>,
    /// Unix time (seconds) the run was created.
    pub created_unix_s: f64,
    /// Unix time (seconds) its row last changed: a status change or a step commit.
    pub updated_unix_s: f64,
}

/// The step journal in numbers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JournalSummary {
    /// Steps of the plan (one journal row each).
    pub steps_total: usize,
    /// Steps marked done.
    pub steps_done: usize,
    /// Rig time in seconds at the end of the last done step (`None` before the first).
    pub rig_time_s: Option<f64>,
    /// Wall-clock Unix time of the last step commit (`None` before the first).
    pub last_step_unix_s: Option<f64>,
}

/// One row of the step journal.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JournalStep {
    /// Plan step index.
    pub step: usize,
    /// The action kind the plan had when the run was created (`capture`, `move`, …).
    pub kind: String,
    /// True when the step's frames are durable and indexed.
    pub done: bool,
}

/// What a recorded file is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordedKind {
    /// A raw frame: 16-bit RGB PNG.
    Raw,
    /// An HDR frame: f32 RGB OpenEXR.
    Hdr,
    /// A ground-truth image: f32 named-channel OpenEXR.
    GroundTruth,
}

/// A file the index records (a frame or a ground-truth image), as checking files needs it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordedFile {
    /// Row id of the frame (for ground truth: of the frame it belongs to).
    pub frame_id: i64,
    /// Plan step.
    pub step: usize,
    /// Path relative to the run directory (`frames/…`).
    pub path: String,
    /// Hex SHA-256 of the file as written.
    pub sha256: String,
    /// File size in bytes as written.
    pub size_bytes: u64,
    /// What kind of file.
    pub kind: RecordedKind,
}

/// Filters and paging of a frame listing; `None` means any, and all filters must match.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameQuery {
    /// Frames of this camera.
    pub camera: Option<String>,
    /// Frames during which this lamp was on.
    pub lamp: Option<String>,
    /// Frames of this plan step.
    pub step: Option<usize>,
    /// Raw or HDR frames.
    pub kind: Option<FrameKind>,
    /// Frames with this label.
    pub label: Option<String>,
    /// Frames inside this block: a prefix of whole block names (`view 3` matches
    /// `view 3/light 1`, not `view 30`).
    pub block: Option<String>,
    /// At most this many frames (all when `None`).
    pub limit: Option<u64>,
    /// Frames to skip first.
    pub offset: u64,
}

/// One page of a frame listing.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePage {
    /// Frames matching the filters (all pages).
    pub total: u64,
    /// This page, ordered by step, then frame id.
    pub frames: Vec<StoredFrame>,
}

/// The frame columns in the order [`frame_from_row`] reads them.
fn frame_columns(version: i32) -> String {
    let shift = if version >= 3 {
        "frames.sample_shift"
    } else {
        "0"
    };
    let pose = if version >= 4 {
        "frames.fixture_pose"
    } else {
        "NULL"
    };
    format!(
        "frames.id, frames.path, frames.sha256, frames.size_bytes, frames.step, frames.block, \
         frames.label, frames.camera, frames.kind, frames.exposure_index, frames.exposure_s, \
         frames.exposures_s, frames.gain, frames.trigger_id, frames.axes_deg, frames.lamps_on, \
         frames.laser_armed, frames.laser_on, frames.laser_colour_nm, frames.laser_tilt_deg, \
         frames.laser_mount_deg, frames.fixture, frames.cart_mm, frames.rig_time_s, \
         frames.wall_time_unix_s, frames.width, frames.height, frames.bit_depth, \
         frames.saturated_samples, frames.notes, {shift}, {pose}"
    )
}

/// A text column that must decode (as JSON, or as a frame kind).
fn decode_failure(
    column: usize,
    e: impl std::error::Error + Send + Sync + 'static,
) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(column, rusqlite::types::Type::Text, Box::new(e))
}

/// A JSON text column decoded into `T`.
fn json<T: serde::de::DeserializeOwned>(r: &Row<'_>, column: usize) -> rusqlite::Result<T> {
    let text: String = r.get(column)?;
    serde_json::from_str(&text).map_err(|e| decode_failure(column, e))
}

/// An optional non-negative integer column.
fn opt_unsigned<T: TryFrom<i64>>(r: &Row<'_>, column: usize) -> rusqlite::Result<Option<T>> {
    r.get::<_, Option<i64>>(column)?
        .map(|v| T::try_from(v).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(column, v)))
        .transpose()
}

/// An unknown `frames.kind` text.
#[derive(Debug, thiserror::Error)]
#[error("unknown frame kind {0:?}")]
struct UnknownKind(String);

/// A frame row read with [`frame_columns`].
fn frame_from_row(r: &Row<'_>) -> rusqlite::Result<StoredFrame> {
    let kind: String = r.get(8)?;
    let meta = FrameMeta {
        step: get_usize(r, 4)?,
        block: r.get(5)?,
        label: r.get(6)?,
        camera: r.get(7)?,
        kind: FrameKind::parse(&kind).ok_or_else(|| decode_failure(8, UnknownKind(kind)))?,
        exposure_index: opt_unsigned(r, 9)?,
        exposure_s: r.get(10)?,
        exposures_s: json(r, 11)?,
        gain: r.get(12)?,
        trigger_id: opt_unsigned(r, 13)?,
        axes_deg: json(r, 14)?,
        lamps_on: json(r, 15)?,
        laser_armed: r.get(16)?,
        laser_on: r.get(17)?,
        laser_colour_nm: r.get(18)?,
        laser_tilt_deg: r.get(19)?,
        laser_mount_deg: r.get(20)?,
        fixture: r.get(21)?,
        fixture_pose: match r.get::<_, Option<String>>(31)? {
            None => FixturePose::default(),
            Some(text) => serde_json::from_str(&text).map_err(|e| decode_failure(31, e))?,
        },
        cart_mm: r.get(22)?,
        rig_time_s: r.get(23)?,
        wall_time_unix_s: r.get(24)?,
        width: r.get(25)?,
        height: r.get(26)?,
        bit_depth: r.get(27)?,
        saturated_samples: to_u64(28, r.get(28)?)?,
        notes: json(r, 29)?,
        sample_shift: r.get(30)?,
    };
    Ok(StoredFrame {
        id: r.get(0)?,
        path: r.get(1)?,
        sha256: r.get(2)?,
        size_bytes: to_u64(3, r.get(3)?)?,
        meta,
    })
}

/// The WHERE clause and parameters of `query`'s filters.
fn where_clause(query: &FrameQuery) -> (String, Vec<Value>) {
    let mut clauses = Vec::new();
    let mut params = Vec::new();
    let mut text = |column: &str, value: Option<&str>| {
        if let Some(v) = value {
            params.push(Value::Text(v.to_string()));
            clauses.push(format!("frames.{column} = ?{}", params.len()));
        }
    };
    text("camera", query.camera.as_deref());
    text("kind", query.kind.map(FrameKind::as_str));
    text("label", query.label.as_deref());
    if let Some(block) = &query.block {
        params.push(Value::Text(block.trim_end_matches('/').to_string()));
        let n = params.len();
        clauses.push(format!(
            "(frames.block = ?{n} OR substr(frames.block, 1, length(?{n}) + 1) = ?{n} || '/')"
        ));
    }
    if let Some(lamp) = &query.lamp {
        params.push(Value::Text(lamp.clone()));
        clauses.push(format!(
            "EXISTS (SELECT 1 FROM json_each(frames.lamps_on) AS j WHERE j.value = ?{})",
            params.len()
        ));
    }
    if let Some(step) = query.step {
        params.push(Value::Integer(to_i64(step)));
        clauses.push(format!("frames.step = ?{}", params.len()));
    }
    let sql = if clauses.is_empty() {
        String::new()
    } else {
        format!(" WHERE {}", clauses.join(" AND "))
    };
    (sql, params)
}

impl Ctx<'_> {
    fn err(&self, what: &'static str) -> impl Fn(rusqlite::Error) -> StorageError + '_ {
        sql_err(self.path, what)
    }

    /// Frames selected by `tail` (`WHERE … ORDER BY …`, parameters `params`).
    fn select_frames(
        &self,
        tail: &str,
        params: &[Value],
        what: &'static str,
    ) -> Result<Vec<StoredFrame>> {
        let sql = format!("SELECT {} FROM frames{tail}", frame_columns(self.version));
        let mut stmt = self.conn.prepare_cached(&sql).map_err(self.err(what))?;
        let rows = stmt
            .query_map(rusqlite::params_from_iter(params), frame_from_row)
            .map_err(self.err(what))?;
        rows.collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.err(what))
    }

    /// The `runs` row.
    pub(crate) fn run(&self) -> Result<RunRow> {
        let row: Option<(String, String, Option<String>, f64, f64)> = self
            .conn
            .query_row(
                "SELECT id, status, message, created_unix_s, updated_unix_s FROM runs",
                [],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)),
            )
            .optional()
            .map_err(self.err("read the run row"))?;
        let Some((run_id, status, message, created_unix_s, updated_unix_s)) = row else {
            return Err(StorageError::CorruptIndex {
                path: self.path.to_path_buf(),
                reason: "the runs table is empty".into(),
            });
        };
        let status = RunStatus::parse(&status).ok_or_else(|| StorageError::CorruptIndex {
            path: self.path.to_path_buf(),
            reason: format!("unknown run status {status:?}"),
        })?;
        Ok(RunRow {
            run_id,
            status,
            message,
            created_unix_s,
            updated_unix_s,
        })
    }

    /// The journal in numbers.
    pub(crate) fn journal(&self) -> Result<JournalSummary> {
        let (total, done, rig_time_s, last_step_unix_s): (i64, i64, Option<f64>, Option<f64>) =
            self.conn
                .query_row(
                    "SELECT COUNT(*), COALESCE(SUM(status = 'done'), 0),
                            MAX(CASE WHEN status = 'done' THEN rig_time_end_s END),
                            MAX(wall_time_unix_s) FROM steps",
                    [],
                    |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
                )
                .map_err(self.err("summarise the journal"))?;
        let count = |n: i64| usize::try_from(n).unwrap_or(0);
        Ok(JournalSummary {
            steps_total: count(total),
            steps_done: count(done),
            rig_time_s,
            last_step_unix_s,
        })
    }

    /// Every journal row, by step.
    pub(crate) fn steps(&self) -> Result<Vec<JournalStep>> {
        let mut stmt = self
            .conn
            .prepare_cached("SELECT idx, kind, status FROM steps ORDER BY idx")
            .map_err(self.err("read the journal"))?;
        let rows = stmt
            .query_map([], |r| {
                Ok(JournalStep {
                    step: get_usize(r, 0)?,
                    kind: r.get(1)?,
                    done: r.get::<_, String>(2)? == "done",
                })
            })
            .map_err(self.err("read the journal"))?;
        rows.collect::<rusqlite::Result<_>>()
            .map_err(self.err("read the journal"))
    }

    /// Indices of the steps marked done.
    pub(crate) fn done_steps(&self) -> Result<BTreeSet<usize>> {
        let mut stmt = self
            .conn
            .prepare_cached("SELECT idx FROM steps WHERE status = 'done' ORDER BY idx")
            .map_err(self.err("query done steps"))?;
        let rows = stmt
            .query_map([], |row| get_usize(row, 0))
            .map_err(self.err("query done steps"))?;
        rows.collect::<rusqlite::Result<_>>()
            .map_err(self.err("read done steps"))
    }

    /// Number of frame rows.
    pub(crate) fn frame_count(&self) -> Result<u64> {
        let n: i64 = self
            .conn
            .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
            .map_err(self.err("count frames"))?;
        Ok(u64::try_from(n).unwrap_or(0))
    }

    /// Frames of one step or all, ordered by step and path (the writer's order).
    pub(crate) fn frames_by_path(&self, step: Option<usize>) -> Result<Vec<StoredFrame>> {
        self.select_frames(
            " WHERE ?1 IS NULL OR frames.step = ?1 ORDER BY frames.step, frames.path",
            &[step.map_or(Value::Null, |s| Value::Integer(to_i64(s)))],
            "query frames",
        )
    }

    /// One page of the frames matching `query`, ordered by step then id, with the total.
    pub(crate) fn frames(&self, query: &FrameQuery) -> Result<FramePage> {
        let (clause, mut params) = where_clause(query);
        let total: i64 = self
            .conn
            .query_row(
                &format!("SELECT count(*) FROM frames{clause}"),
                rusqlite::params_from_iter(params.iter()),
                |r| r.get(0),
            )
            .map_err(self.err("count frames"))?;
        let clamp = |v: u64| i64::try_from(v).unwrap_or(i64::MAX);
        params.push(Value::Integer(query.limit.map_or(-1, clamp)));
        params.push(Value::Integer(clamp(query.offset)));
        let n = params.len();
        let frames = self.select_frames(
            &format!(
                "{clause} ORDER BY frames.step, frames.id LIMIT ?{} OFFSET ?{n}",
                n - 1
            ),
            &params,
            "list frames",
        )?;
        Ok(FramePage {
            total: u64::try_from(total).unwrap_or(0),
            frames,
        })
    }

    /// The frame with row id `id`.
    pub(crate) fn frame(&self, id: i64) -> Result<Option<StoredFrame>> {
        Ok(self
            .select_frames(
                " WHERE frames.id = ?1",
                &[Value::Integer(id)],
                "look up a frame",
            )?
            .pop())
    }

    /// The frames of `step`, by id (capture order).
    pub(crate) fn frames_of_step(&self, step: usize) -> Result<Vec<StoredFrame>> {
        self.select_frames(
            " WHERE frames.step = ?1 ORDER BY frames.id",
            &[Value::Integer(to_i64(step))],
            "list the frames of a step",
        )
    }

    /// The newest frame of `camera` by capture wall time.
    pub(crate) fn latest_frame(&self, camera: &str) -> Result<Option<StoredFrame>> {
        Ok(self
            .select_frames(
                " WHERE frames.camera = ?1
                  ORDER BY frames.wall_time_unix_s DESC, frames.id DESC LIMIT 1",
                &[Value::Text(camera.to_string())],
                "find the latest frame of a camera",
            )?
            .pop())
    }

    /// Ground-truth rows of one step or all, ordered by path (none before schema 2).
    pub(crate) fn ground_truth(&self, step: Option<usize>) -> Result<Vec<StoredGroundTruth>> {
        if self.version < 2 {
            return Ok(Vec::new());
        }
        let what = "query ground truth";
        let mut stmt = self
            .conn
            .prepare_cached(
                "SELECT frames.path, g.kind, g.path, g.sha256, g.size_bytes, g.channels,
                        g.frame_id, g.step
                 FROM ground_truth AS g JOIN frames ON frames.id = g.frame_id
                 WHERE ?1 IS NULL OR g.step = ?1 ORDER BY g.path",
            )
            .map_err(self.err(what))?;
        let rows = stmt
            .query_map([step.map(to_i64)], |r| {
                Ok(StoredGroundTruth {
                    frame_path: r.get(0)?,
                    kind: r.get(1)?,
                    path: r.get(2)?,
                    sha256: r.get(3)?,
                    size_bytes: to_u64(4, r.get(4)?)?,
                    channels: json(r, 5)?,
                    frame_id: r.get(6)?,
                    step: to_usize(7, r.get(7)?)?,
                })
            })
            .map_err(self.err(what))?;
        rows.collect::<rusqlite::Result<_>>()
            .map_err(self.err(what))
    }

    /// Every file the index records: frames by id, then ground truth by id. Reads only the
    /// columns that locate and check a file, so a damaged metadata column does not hide them.
    pub(crate) fn recorded_files(&self) -> Result<Vec<RecordedFile>> {
        let what = "list recorded files";
        // The last column says what the file is: 1 HDR, 0 raw, NULL ground truth.
        let frames = "SELECT id, step, path, sha256, size_bytes, kind = 'hdr' FROM frames \
                      ORDER BY id";
        let truth = "SELECT frame_id, step, path, sha256, size_bytes, NULL FROM ground_truth \
                     ORDER BY id";
        let tables = if self.version < 2 { 1 } else { 2 };
        let mut out = Vec::new();
        for sql in [frames, truth].into_iter().take(tables) {
            let mut stmt = self.conn.prepare_cached(sql).map_err(self.err(what))?;
            let rows = stmt
                .query_map([], |r| {
                    Ok(RecordedFile {
                        frame_id: r.get(0)?,
                        step: lenient_usize(r.get(1)?),
                        path: r.get(2)?,
                        sha256: r.get(3)?,
                        size_bytes: u64::try_from(r.get::<_, i64>(4)?).unwrap_or(u64::MAX),
                        kind: match r.get::<_, Option<bool>>(5)? {
                            Some(true) => RecordedKind::Hdr,
                            Some(false) => RecordedKind::Raw,
                            None => RecordedKind::GroundTruth,
                        },
                    })
                })
                .map_err(self.err(what))?;
            for row in rows {
                out.push(row.map_err(self.err(what))?);
            }
        }
        Ok(out)
    }
}

/// A stored integer as an index (negative values, which no writer produces, map far away so
/// checks report them instead of failing the read).
fn lenient_usize(v: i64) -> usize {
    usize::try_from(v).unwrap_or(usize::MAX)
}
