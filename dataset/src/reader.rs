//! [`RunReader`]: a run opened read-only, for everything that reads a dataset without writing
//! it (the daemon's listings and frame downloads, `stagehand verify`, processing).
//!
//! Opening checks the index's schema version: versions 1 to [`SCHEMA_VERSION`] are read
//! (older ones as the writer would upgrade them, without changing the file), anything else is
//! [`StorageError::UnsupportedSchema`]. The reader never takes the run's write lock and never
//! blocks or disturbs a writer: while one has the index open, the reader sees its last
//! committed step, and it leaves no `-shm`/`-wal` files behind in a finished run.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rusqlite::Connection;

use crate::error::{Result, StorageError};
use crate::index::{SCHEMA_VERSION, StoredFrame, StoredGroundTruth, open_read_only, sql_err};
use crate::layout;
use crate::manifest::Manifest;
use crate::query::{Ctx, FramePage, FrameQuery, JournalStep, JournalSummary, RecordedFile, RunRow};

/// A run directory opened read-only, its index's schema version checked.
pub struct RunReader {
    dir: PathBuf,
    index: PathBuf,
    conn: Connection,
    version: i32,
}

impl std::fmt::Debug for RunReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunReader")
            .field("dir", &self.dir)
            .field("version", &self.version)
            .finish_non_exhaustive()
    }
}

impl RunReader {
    /// Opens the index of the run at `run_dir` read-only and checks its schema version.
    pub fn open(run_dir: &Path) -> Result<RunReader> {
        let index = run_dir.join(layout::INDEX);
        if !index.is_file() {
            return Err(StorageError::NotARun {
                path: run_dir.to_path_buf(),
                missing: layout::INDEX,
            });
        }
        let conn = open_read_only(run_dir).map_err(sql_err(&index, "open read-only"))?;
        let version: i32 = conn
            .query_row("PRAGMA user_version", [], |row| row.get(0))
            .map_err(sql_err(&index, "read the schema version"))?;
        if !(1..=SCHEMA_VERSION).contains(&version) {
            return Err(StorageError::UnsupportedSchema {
                path: run_dir.to_path_buf(),
                found: version,
                supported: SCHEMA_VERSION,
            });
        }
        Ok(RunReader {
            dir: run_dir.to_path_buf(),
            index,
            conn,
            version,
        })
    }

    fn ctx(&self) -> Ctx<'_> {
        Ctx {
            conn: &self.conn,
            path: &self.index,
            version: self.version,
        }
    }

    /// The run directory as given to [`RunReader::open`].
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The index's schema version (1 to [`SCHEMA_VERSION`]).
    pub fn schema_version(&self) -> i32 {
        self.version
    }

    /// The run's `manifest.json`.
    pub fn manifest(&self) -> Result<Manifest> {
        read_manifest(&self.dir)
    }

    /// The `runs` row: id, status and message, creation and last update times.
    pub fn run(&self) -> Result<RunRow> {
        self.ctx().run()
    }

    /// The step journal in numbers: steps, steps done, last rig time and commit time.
    pub fn journal(&self) -> Result<JournalSummary> {
        self.ctx().journal()
    }

    /// Every journal row (step, kind, done), by step.
    pub fn steps(&self) -> Result<Vec<JournalStep>> {
        self.ctx().steps()
    }

    /// Indices of the steps whose frames are durable and indexed.
    pub fn done_steps(&self) -> Result<BTreeSet<usize>> {
        self.ctx().done_steps()
    }

    /// Number of frames indexed (raw and HDR).
    pub fn frame_count(&self) -> Result<u64> {
        self.ctx().frame_count()
    }

    /// One page of the frames matching `query`, ordered by step then frame id, with the
    /// number of matches on all pages.
    pub fn frames(&self, query: &FrameQuery) -> Result<FramePage> {
        self.ctx().frames(query)
    }

    /// The frame with row id `frame_id`, if the run has it.
    pub fn frame(&self, frame_id: i64) -> Result<Option<StoredFrame>> {
        self.ctx().frame(frame_id)
    }

    /// The frames of plan step `step`, in capture order (by frame id).
    pub fn frames_of_step(&self, step: usize) -> Result<Vec<StoredFrame>> {
        self.ctx().frames_of_step(step)
    }

    /// The newest frame of `camera` (by capture wall time), if any.
    pub fn latest_frame(&self, camera: &str) -> Result<Option<StoredFrame>> {
        self.ctx().latest_frame(camera)
    }

    /// Ground-truth images of one step or (`None`) all, ordered by path.
    pub fn ground_truth(&self, step: Option<usize>) -> Result<Vec<StoredGroundTruth>> {
        self.ctx().ground_truth(step)
    }

    /// Every product processing wrote into the run, in key order (none before schema 4).
    pub fn products(&self) -> Result<Vec<crate::products::StoredProduct>> {
        if self.version < 4 {
            return Ok(Vec::new());
        }
        crate::products::list(&self.conn, &self.index)
    }

    /// Every file the index records (frames, then ground truth), with what checking it needs.
    pub fn recorded_files(&self) -> Result<Vec<RecordedFile>> {
        self.ctx().recorded_files()
    }
}

/// Reads and decodes the run's `manifest.json`; a directory without one is not a (complete)
/// run.
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    let path = dir.join(layout::MANIFEST);
    let bytes = match std::fs::read(&path) {
        Ok(bytes) => bytes,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(StorageError::NotARun {
                path: dir.to_path_buf(),
                missing: layout::MANIFEST,
            });
        }
        Err(e) => return Err(StorageError::io("read", path, e)),
    };
    serde_json::from_slice(&bytes).map_err(|source| StorageError::Json {
        op: "decode",
        path,
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame_meta::FrameKind;
    use crate::index::SCHEMA;
    use crate::layout::{FRAMES_DIR, INDEX, MANIFEST};

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

    /// A schema-1 index (no ground truth, no sample shift), as the first datasets have, is
    /// read as the writer would upgrade it; reading leaves no files behind and sees a writer's
    /// commits.
    #[test]
    fn reads_old_schemas_leaves_no_files_and_sees_a_writer_s_commits()
    -> std::result::Result<(), Box<dyn std::error::Error>> {
        let tmp = tempfile::tempdir()?;
        // Characters an SQLite URI would misread unless escaped.
        let run = tmp.path().join("data ?%#& x").join("r1");
        std::fs::create_dir_all(run.join(FRAMES_DIR))?;
        std::fs::write(run.join(MANIFEST), "{}")?;
        {
            let w = Connection::open(run.join(INDEX))?;
            w.pragma_update(None, "journal_mode", "WAL")?;
            w.execute_batch(SCHEMA)?;
            w.pragma_update(None, "user_version", 1)?;
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
        let reader = RunReader::open(&run)?;
        assert_eq!(reader.schema_version(), 1);
        let page = reader.frames(&FrameQuery::default())?;
        assert_eq!(page.total, 1);
        let f = &page.frames[0];
        assert_eq!(
            (f.meta.camera.as_str(), f.meta.lamps_on.clone()),
            ("cam1", vec!["lamp2".to_string()])
        );
        assert_eq!(f.meta.axes_deg.get("turntable"), Some(&90.0));
        assert_eq!(
            (f.id, f.meta.kind, f.meta.sample_shift),
            (1, FrameKind::Raw, 0)
        );
        assert_eq!(reader.frames_of_step(0)?.len(), 1);
        assert_eq!(
            reader.frame(1)?.map(|f| f.path),
            Some("frames/a.png".into())
        );
        assert_eq!(reader.frame(2)?, None);
        assert_eq!(reader.ground_truth(None)?, Vec::new());
        assert_eq!(reader.recorded_files()?.len(), 1);
        drop(reader);
        assert_eq!(listing()?, before, "a read left files in the run directory");

        // A writer holds the index open: its commits are visible.
        let w = Connection::open(run.join(INDEX))?;
        w.pragma_update(None, "journal_mode", "WAL")?;
        insert_frame(&w, "frames/b.png")?;
        assert!(run.join(format!("{INDEX}-wal")).exists());
        let reader = RunReader::open(&run)?;
        let lamp = FrameQuery {
            lamp: Some("lamp2".into()),
            camera: Some("cam1".into()),
            ..FrameQuery::default()
        };
        assert_eq!(reader.frames(&lamp)?.total, 2);
        let other = FrameQuery {
            lamp: Some("lamp1".into()),
            ..FrameQuery::default()
        };
        assert_eq!(reader.frames(&other)?.total, 0);
        let page = FrameQuery {
            limit: Some(1),
            offset: 1,
            ..FrameQuery::default()
        };
        let page = reader.frames(&page)?;
        assert_eq!((page.total, page.frames.len()), (2, 1));
        assert_eq!(page.frames[0].path, "frames/b.png");
        let latest = reader.latest_frame("cam1")?.ok_or("no latest frame")?;
        assert_eq!(latest.path, "frames/b.png");
        assert_eq!(reader.latest_frame("cam9")?, None);
        Ok(())
    }

    /// An index of an unknown schema version is refused with the run directory named.
    #[test]
    fn unknown_schema_versions_are_refused() -> std::result::Result<(), Box<dyn std::error::Error>>
    {
        let tmp = tempfile::tempdir()?;
        let run = tmp.path().join("r1");
        std::fs::create_dir_all(&run)?;
        for version in [0, SCHEMA_VERSION + 1] {
            let _ = std::fs::remove_file(run.join(INDEX));
            {
                let w = Connection::open(run.join(INDEX))?;
                w.execute_batch(SCHEMA)?;
                w.pragma_update(None, "user_version", version)?;
            }
            let err = RunReader::open(&run)
                .err()
                .ok_or("an unknown schema version was read")?;
            assert!(
                matches!(err, StorageError::UnsupportedSchema { found, .. } if found == version),
                "{err}"
            );
            assert!(
                err.to_string().contains(&run.display().to_string()),
                "{err}"
            );
        }
        assert!(matches!(
            RunReader::open(&tmp.path().join("none")),
            Err(StorageError::NotARun { .. })
        ));
        Ok(())
    }
}
