//! [`RunStore`]: the one writer of a run directory.
//!
//! Crash-safety contract (the durability invariant in ARCHITECTURE.md):
//! - a step is done exactly when its `steps` row says so, and that row commits (in the same
//!   SQLite transaction as the step's frame rows) only after every frame file of the step is
//!   written, fsynced, renamed into place and the `frames/` directory fsynced;
//! - frame file names are deterministic ([`frame_file_name`]), so a file on disk without a
//!   committed row is an orphan of an interrupted step: resume re-runs that step, the rename
//!   atomically replaces the orphan and the commit replaces the step's rows, so nothing is
//!   duplicated;
//! - `manifest.json` is written last by [`RunStore::create`], so a directory without it is an
//!   interrupted creation, which [`RunStore::open`] refuses;
//! - [`RunStore::open`] deletes leftover temp files, and an advisory lock (`.lock`, `flock`)
//!   keeps a second process from writing the same run.

use std::collections::{BTreeSet, HashSet};
use std::ffi::CString;
use std::fs::{self, File, OpenOptions};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::atomic::{fsync_dir, remove_stale_temps, write_atomic, write_atomic_durable};
use crate::checksum::sha256_hex;
use crate::error::{Result, StorageError};

use crate::frame_meta::{FrameKind, FrameToWrite, frame_file_name};
use crate::frame_write::{
    FrameJob, RawCompression, WriteTimes, WrittenFrame, write_frame, writer_pool,
};
use crate::index::{
    Index, NewFrameRow, NewGroundTruthRow, RunStatus, StepRecord, StoredFrame, StoredGroundTruth,
};
use crate::layout;
use crate::manifest::Manifest;
use crate::plan::{RunPlan, is_capture, plan_hash};
use crate::png16::msb_shift;
use crate::reader::read_manifest;

/// How many `-N` suffixes `create` tries before giving up.
const MAX_NAME_TRIES: u32 = 1000;

/// A run directory open for writing. Owns the directory's lock and its index connection; use
/// it from one writer thread (it is `Send`, not `Sync`).
pub struct RunStore {
    dir: PathBuf,
    frames_dir: PathBuf,
    index: Index,
    manifest: Manifest,
    /// Held for the store's lifetime: the `flock` is released when the file closes.
    _lock: File,
}

impl std::fmt::Debug for RunStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunStore")
            .field("dir", &self.dir)
            .finish_non_exhaustive()
    }
}

impl RunStore {
    /// Creates `<root>/<run_id>/` (run id `"<script stem>-<UTC yyyymmdd-hhmmss>-<first 8 of
    /// plan hash>"`, with `-2`, `-3`, … appended if taken) and writes `plan.json`, the script
    /// copy, `rig.toml`, `scene.toml` (when the manifest has a `sim` block), `index.sqlite` (WAL; the run row with status running and one pending
    /// row per plan step) and finally `manifest.json`.
    ///
    /// Fills in `manifest.run_id` and `manifest.format_version`, and `manifest.plan_hash` when
    /// it is empty; a non-empty `plan_hash` that does not match `plan` is an error. On any
    /// error the half-made run directory is removed again.
    pub fn create<P: RunPlan>(root: &Path, mut manifest: Manifest, plan: &P) -> Result<RunStore> {
        let plan_json = serde_json::to_vec(plan).map_err(|source| StorageError::Json {
            op: "encode",
            path: root.join(layout::PLAN),
            source,
        })?;
        let plan_hash = sha256_hex(&plan_json);
        if manifest.plan_hash.is_empty() {
            manifest.plan_hash = plan_hash.clone();
        } else if manifest.plan_hash != plan_hash {
            return Err(StorageError::PlanHashMismatch {
                path: root.to_path_buf(),
                expected: manifest.plan_hash,
                found: plan_hash,
            });
        }
        manifest.format_version = Manifest::FORMAT_VERSION;

        fs::create_dir_all(root).map_err(|source| StorageError::CreateRoot {
            path: root.to_path_buf(),
            source,
        })?;
        let base = layout::run_id(&manifest.script_name, manifest.created_unix_s, &plan_hash);
        let mut claimed = None;
        for n in 1..=MAX_NAME_TRIES {
            let name = layout::candidate(&base, n);
            let dir = root.join(&name);
            match fs::create_dir(&dir) {
                Ok(()) => {
                    claimed = Some((name, dir));
                    break;
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(source) => {
                    return Err(if n == 1 {
                        // The root exists but we cannot create entries in it.
                        StorageError::CreateRoot {
                            path: root.to_path_buf(),
                            source,
                        }
                    } else {
                        StorageError::CreateRunDir { path: dir, source }
                    });
                }
            }
        }
        let Some((run_id, dir)) = claimed else {
            return Err(StorageError::NoFreeRunName {
                root: root.to_path_buf(),
                base,
                tries: MAX_NAME_TRIES,
            });
        };
        manifest.run_id = run_id;

        match RunStore::populate(&dir, manifest, plan, &plan_json) {
            Ok(store) => {
                fsync_dir(root)?;
                tracing::info!(dir = %dir.display(), steps = plan.step_count(), "created run");
                Ok(store)
            }
            Err(err) => {
                if let Err(rm) = fs::remove_dir_all(&dir) {
                    tracing::warn!(dir = %dir.display(), error = %rm, "could not remove half-created run directory");
                }
                Err(err)
            }
        }
    }

    /// Fills a freshly claimed run directory; `manifest.json` goes last.
    fn populate<P: RunPlan>(
        dir: &Path,
        manifest: Manifest,
        plan: &P,
        plan_json: &[u8],
    ) -> Result<RunStore> {
        let lock = lock_run(dir)?;
        let frames_dir = dir.join(layout::FRAMES_DIR);
        fs::create_dir(&frames_dir)
            .map_err(|e| StorageError::io("create directory", &frames_dir, e))?;
        write_atomic(dir, layout::PLAN, plan_json)?;
        write_atomic(
            dir,
            &layout::script_copy_name(&manifest.script_name),
            manifest.script_text.as_bytes(),
        )?;
        write_atomic(dir, layout::RIG, manifest.rig_toml.as_bytes())?;
        if let Some(sim) = &manifest.sim {
            write_atomic(dir, layout::SCENE, sim.scene_text.as_bytes())?;
            if let Some(truth) = &sim.as_built {
                let bytes =
                    serde_json::to_vec_pretty(truth).map_err(|source| StorageError::Json {
                        op: "encode",
                        path: dir.join(layout::AS_BUILT),
                        source,
                    })?;
                write_atomic(dir, layout::AS_BUILT, &bytes)?;
            }
        }
        let index = Index::create(&dir.join(layout::INDEX), &manifest, plan)?;
        fsync_dir(dir)?;
        let manifest_json =
            serde_json::to_vec_pretty(&manifest).map_err(|source| StorageError::Json {
                op: "encode",
                path: dir.join(layout::MANIFEST),
                source,
            })?;
        write_atomic_durable(dir, layout::MANIFEST, &manifest_json)?;
        Ok(RunStore {
            dir: dir.to_path_buf(),
            frames_dir,
            index,
            manifest,
            _lock: lock,
        })
    }

    /// Opens an existing run for resume: reads the manifest and plan, checks the plan against
    /// the manifest's plan hash, takes the run's write lock and removes stale temp files.
    pub fn open<P: RunPlan>(run_dir: &Path) -> Result<(RunStore, Manifest, P)> {
        let dir = run_dir.to_path_buf();
        if !dir.is_dir() {
            return Err(StorageError::NotARun {
                path: dir,
                missing: "the directory itself",
            });
        }
        let manifest = read_manifest(&dir)?;
        if manifest.format_version > Manifest::FORMAT_VERSION {
            return Err(StorageError::UnsupportedFormat {
                path: dir,
                found: manifest.format_version,
                supported: Manifest::FORMAT_VERSION,
            });
        }
        let lock = lock_run(&dir)?;

        // plan.json holds the exact canonical bytes the hash was taken over; hashing the bytes
        // (not a re-serialisation) keeps the check independent of float parsing precision.
        let plan_bytes = read_required(&dir, layout::PLAN)?;
        let found = sha256_hex(&plan_bytes);
        if found != manifest.plan_hash {
            return Err(StorageError::PlanHashMismatch {
                path: dir,
                expected: manifest.plan_hash,
                found,
            });
        }
        let plan: P = serde_json::from_slice(&plan_bytes).map_err(|source| StorageError::Json {
            op: "decode",
            path: dir.join(layout::PLAN),
            source,
        })?;
        if plan_hash(&plan).as_deref() != Some(manifest.plan_hash.as_str()) {
            tracing::warn!(
                dir = %dir.display(),
                "plan.json is intact but does not re-serialise to the same bytes (float parsing \
                 precision); enable serde_json's float_roundtrip feature"
            );
        }

        let index_path = dir.join(layout::INDEX);
        if !index_path.is_file() {
            return Err(StorageError::NotARun {
                path: dir,
                missing: layout::INDEX,
            });
        }
        let index = Index::open(&index_path)?;
        let indexed_id = index.run_id()?;
        if indexed_id != manifest.run_id {
            return Err(StorageError::CorruptIndex {
                path: index_path,
                reason: format!(
                    "it indexes run {indexed_id}, the manifest says {}",
                    manifest.run_id
                ),
            });
        }

        let frames_dir = dir.join(layout::FRAMES_DIR);
        remove_stale_temps(&dir)?;
        remove_stale_temps(&frames_dir)?;
        let store = RunStore {
            dir,
            frames_dir,
            index,
            manifest: manifest.clone(),
            _lock: lock,
        };
        tracing::info!(dir = %store.dir.display(), done = store.done_steps()?.len(), steps = plan.step_count(), "opened run for resume");
        Ok((store, manifest, plan))
    }

    /// The run directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The run id (the directory name).
    pub fn run_id(&self) -> &str {
        &self.manifest.run_id
    }

    /// The manifest as written to `manifest.json`.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Indices of the steps whose frames are durable and indexed.
    pub fn done_steps(&self) -> Result<BTreeSet<usize>> {
        self.index.done_steps()
    }

    /// Rig time (seconds) at the end of the last committed step — the largest `rig_time_end_s`
    /// of the done steps — or 0 if none, so a resumed run continues its rig clock.
    pub fn last_rig_time_s(&self) -> Result<f64> {
        self.index.last_rig_time_s()
    }

    /// Makes a step durable: writes every frame (temp → fsync → rename, then fsyncs `frames/`),
    /// then in ONE transaction replaces the step's frame rows and marks the step done.
    /// Idempotent: committing a step again rewrites the same files and leaves the same rows.
    ///
    /// Every frame must belong to `record.step`, carry pixels of its `kind` and size, and (raw)
    /// have an exposure index; no two frames may share a file name. Returns the written files.
    pub fn commit_step(
        &mut self,
        record: &StepRecord,
        frames: Vec<FrameToWrite>,
    ) -> Result<Vec<PathBuf>> {
        let written = self.commit_steps(vec![(record.clone(), frames)])?;
        tracing::debug!(step = record.step, frames = written.len(), "step committed");
        Ok(written)
    }

    /// Makes several steps durable at once: writes every frame of every step first, then marks
    /// them all done in ONE transaction. The writer uses it to journal a run of frameless steps
    /// (moves, lamp switches) with one fsync instead of one each. Returns the written files.
    pub fn commit_steps(
        &mut self,
        batch: Vec<(StepRecord, Vec<FrameToWrite>)>,
    ) -> Result<Vec<PathBuf>> {
        Ok(self
            .commit_steps_with(batch, RawCompression::Deflate, &|_| {})?
            .0)
    }

    /// [`RunStore::commit_steps`] with the raw frames' PNG compression given: the writer
    /// stores some uncompressed while it is behind the cameras. Calls `on_step_written(i)`
    /// once the files of the batch's `i`-th step are written and its frames' pixels freed
    /// (before they are indexed), so the writer can take in more frames while the rest of the
    /// batch is written. Also returns where the frame files' writing time went, so the writer
    /// can tell encoding from the disk.
    pub fn commit_steps_with(
        &mut self,
        mut batch: Vec<(StepRecord, Vec<FrameToWrite>)>,
        compression: RawCompression,
        on_step_written: &(dyn Fn(usize) + Sync),
    ) -> Result<(Vec<PathBuf>, WriteTimes)> {
        // Raw samples go MSB-aligned into their PNG; the shift is recorded with the frame.
        for f in batch.iter_mut().flat_map(|(_, frames)| frames.iter_mut()) {
            f.meta.sample_shift = match f.meta.kind {
                FrameKind::Raw => msb_shift(&frame_file_name(&f.meta), f.meta.bit_depth)?,
                FrameKind::Hdr => 0,
            };
        }
        let steps = batch
            .iter_mut()
            .map(|(record, frames)| (record.step, frames.as_mut_slice()))
            .collect();
        let written = self.write_steps(steps, compression, on_step_written)?;
        let rows: Vec<Vec<NewFrameRow<'_>>> = batch
            .iter()
            .zip(&written)
            .map(|((_, frames), files)| {
                files
                    .iter()
                    .map(|w| NewFrameRow {
                        path: w.rel_path.clone(),
                        sha256: w.sha256.clone(),
                        size_bytes: w.size_bytes,
                        meta: &frames[w.position].meta,
                        ground_truth: w
                            .ground_truth
                            .iter()
                            .map(|g| NewGroundTruthRow {
                                kind: g.kind.clone(),
                                path: g.rel_path.clone(),
                                sha256: g.sha256.clone(),
                                size_bytes: g.size_bytes,
                                channels: g.channels.clone(),
                            })
                            .collect(),
                    })
                    .collect()
            })
            .collect();
        let steps: Vec<(&StepRecord, &[NewFrameRow<'_>])> = batch
            .iter()
            .zip(&rows)
            .map(|((record, _), r)| (record, r.as_slice()))
            .collect();
        self.index.commit_steps(&steps)?;
        let times = written
            .iter()
            .flatten()
            .fold(WriteTimes::default(), |sum, w| WriteTimes {
                encode_s: sum.encode_s + w.times.encode_s,
                write_s: sum.write_s + w.times.write_s,
            });
        let paths = written
            .into_iter()
            .flatten()
            .flat_map(|w| std::iter::once(w.path).chain(w.ground_truth.into_iter().map(|g| g.path)))
            .collect();
        Ok((paths, times))
    }

    /// Validates, encodes and durably writes the frames of `step` (files only, no index rows):
    /// the first half of [`RunStore::commit_step`].
    #[cfg(test)]
    pub(crate) fn write_frames(
        &self,
        step: usize,
        frames: &[FrameToWrite],
    ) -> Result<Vec<WrittenFrame>> {
        let mut frames = frames.to_vec();
        let mut written =
            self.write_steps(vec![(step, &mut frames)], RawCompression::Deflate, &|_| {})?;
        Ok(written.pop().unwrap_or_default())
    }

    /// Validates the frames of every step, then encodes and writes them all at once on the
    /// writer's pool, and fsyncs `frames/` once: the files of a batch, per step. Each frame's
    /// pixels are taken (left empty) and freed once encoded; `on_step_written(i)` is called
    /// when the `i`-th step's files are all written.
    fn write_steps(
        &self,
        steps: Vec<(usize, &mut [FrameToWrite])>,
        compression: RawCompression,
        on_step_written: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<Vec<WrittenFrame>>> {
        for (step, frames) in &steps {
            self.validate_frames(*step, frames)?;
        }
        let frames_dir = &self.frames_dir;
        let remaining: Vec<AtomicUsize> = steps
            .iter()
            .map(|(_, frames)| AtomicUsize::new(frames.len()))
            .collect();
        let step_count = steps.len();
        let jobs: Vec<FrameJob<'_>> = steps
            .into_iter()
            .enumerate()
            .flat_map(|(s, (_, frames))| {
                frames
                    .iter_mut()
                    .enumerate()
                    .map(move |(p, f)| FrameJob::take(s, p, f))
            })
            .collect();
        for (s, left) in remaining.iter().enumerate() {
            if left.load(Ordering::Acquire) == 0 {
                on_step_written(s);
            }
        }
        // Files are fsynced one by one inside the jobs: the pool has more threads than cores,
        // so one thread's fsync does not leave its core idle while frames wait to be encoded.
        let write_all = || {
            jobs.into_par_iter()
                .enumerate()
                .map(|(i, job)| {
                    let s = job.step;
                    let file = write_frame(frames_dir, job, compression.for_frame(i))?;
                    if remaining[s].fetch_sub(1, Ordering::AcqRel) == 1 {
                        on_step_written(s);
                    }
                    Ok((s, file))
                })
                .collect::<Result<Vec<_>>>()
        };
        let files = match writer_pool() {
            Some(pool) => pool.install(write_all),
            None => write_all(),
        }?;
        fsync_dir(frames_dir)?;
        let mut written: Vec<Vec<WrittenFrame>> = (0..step_count).map(|_| Vec::new()).collect();
        for (s, file) in files {
            written[s].push(file);
        }
        Ok(written)
    }

    /// Refuses frames that are not of `step`, carry the wrong pixels, lack an exposure index
    /// or share a file name.
    fn validate_frames(&self, step: usize, frames: &[FrameToWrite]) -> Result<()> {
        let invalid = |reason: String| StorageError::InvalidCommit {
            step,
            run: self.dir.clone(),
            reason,
        };
        let mut names = HashSet::with_capacity(frames.len());
        for f in frames {
            let name = frame_file_name(&f.meta);
            if f.meta.step != step {
                return Err(invalid(format!(
                    "frame {name} belongs to step {}",
                    f.meta.step
                )));
            }
            if f.pixels.kind() != f.meta.kind {
                return Err(invalid(format!(
                    "frame {name} is {} but carries {} pixels",
                    f.meta.kind.as_str(),
                    f.pixels.kind().as_str()
                )));
            }
            if f.meta.kind == FrameKind::Raw && f.meta.exposure_index.is_none() {
                return Err(invalid(format!(
                    "raw frame of camera {} has no exposure index",
                    f.meta.camera
                )));
            }
            if !names.insert(name.clone()) {
                return Err(invalid(format!(
                    "two frames map to the file name {name} (same camera and exposure, or camera ids \
                     that differ only in characters unsafe for file names)"
                )));
            }
        }
        Ok(())
    }

    /// Prepares capture steps for `stagehand resume --retake` (after `stagehand verify` found
    /// their files damaged): in ONE transaction, deletes the frame and ground-truth rows of
    /// `steps` and marks them pending, together with every frameless step (moves, lamps,
    /// laser, prompts) between the first and the last of them, so the resumed run brings the
    /// rig into each retaken step's state exactly as the plan had it. Then removes the deleted
    /// rows' files (a file left behind is an orphan that the retake replaces). Captures that
    /// are not retaken stay done, with their frames.
    ///
    /// Every step must be a capture step of `plan`. Returns the steps made pending, in order.
    pub fn retake<P: RunPlan>(&mut self, plan: &P, steps: &[usize]) -> Result<Vec<usize>> {
        let is_capture = |i: usize| is_capture(plan, i);
        for &step in steps {
            let reason = match plan.step(step) {
                None => format!(
                    "the plan has steps 0..={}",
                    plan.step_count().saturating_sub(1)
                ),
                Some(s) if s.capture.is_none() => format!(
                    "it is a `{}` step, which records no frames; only capture steps are retaken",
                    s.kind
                ),
                Some(_) => continue,
            };
            return Err(StorageError::InvalidRetake {
                step,
                run: self.dir.clone(),
                reason,
            });
        }
        let (Some(&first), Some(&last)) = (steps.iter().min(), steps.iter().max()) else {
            return Ok(Vec::new());
        };
        let wanted: BTreeSet<usize> = steps.iter().copied().collect();
        // Skipped steps do not act on the rig: re-run the frameless ones between retakes so
        // each retaken capture finds the lamps, laser, axes and fixture of the original.
        let reset: Vec<usize> = (first..=last)
            .filter(|&i| wanted.contains(&i) || !is_capture(i))
            .collect();
        let files = self.index.reset_steps(&reset)?;
        for rel in files {
            let path = self.dir.join(&rel);
            match fs::remove_file(&path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => {
                    tracing::warn!(path = %path.display(), error = %e, "could not remove a retaken file; the retake replaces it");
                }
            }
        }
        fsync_dir(&self.frames_dir)?;
        tracing::info!(dir = %self.dir.display(), ?steps, pending = reset.len(), "steps reset for a retake");
        Ok(reset)
    }

    /// Sets the run status (and an optional message, e.g. the error that failed the run).
    pub fn set_status(&self, status: RunStatus, message: Option<&str>) -> Result<()> {
        self.index.set_status(status, message)
    }

    /// The run status and its message.
    pub fn status(&self) -> Result<(RunStatus, Option<String>)> {
        self.index.status()
    }

    /// Frame rows of the index, of one step or (with `None`) all, ordered by step and path.
    pub fn frames(&self, step: Option<usize>) -> Result<Vec<StoredFrame>> {
        self.index.frames(step)
    }

    /// Ground-truth rows of the index, of one step or (with `None`) all, ordered by path.
    pub fn ground_truth(&self, step: Option<usize>) -> Result<Vec<StoredGroundTruth>> {
        self.index.ground_truth(step)
    }

    /// Bytes available to this (unprivileged) process on the dataset's file system.
    pub fn available_bytes(&self) -> Result<u64> {
        available_bytes(&self.dir)
    }

    /// The index, for ad-hoc queries in tests.
    #[cfg(test)]
    pub(crate) fn index(&self) -> &Index {
        &self.index
    }
}

/// Reads a file the run layout requires, or says the directory is not a complete run.
fn read_required(dir: &Path, name: &'static str) -> Result<Vec<u8>> {
    let path = dir.join(name);
    match fs::read(&path) {
        Ok(bytes) => Ok(bytes),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(StorageError::NotARun {
            path: dir.to_path_buf(),
            missing: name,
        }),
        Err(e) => Err(StorageError::io("read", path, e)),
    }
}

/// Takes the run's exclusive advisory write lock (non-blocking).
pub(crate) fn lock_run(dir: &Path) -> Result<File> {
    let path = dir.join(layout::LOCK);
    let file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| StorageError::io("open lock file", &path, e))?;
    // Non-blocking exclusive `flock`, held while the file stays open.
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            return Err(StorageError::RunInUse {
                path: dir.to_path_buf(),
                lock: path,
            });
        }
        Err(std::fs::TryLockError::Error(err)) => return Err(StorageError::io("lock", path, err)),
    }
    Ok(file)
}

/// Bytes available to unprivileged users on the file system holding `path` (statvfs).
// The only unsafe in the crate: std has no statvfs.
#[allow(unsafe_code)]
fn available_bytes(path: &Path) -> Result<u64> {
    let c_path = CString::new(path.as_os_str().as_bytes()).map_err(|_| {
        StorageError::io(
            "query free space of",
            path,
            std::io::Error::new(std::io::ErrorKind::InvalidInput, "path contains a NUL byte"),
        )
    })?;
    // SAFETY: statvfs is plain old data, so all-zero is a valid value, and the call only
    // writes into it; c_path is a valid NUL-terminated string for the call's duration.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: see above.
    let rc = unsafe { libc::statvfs(c_path.as_ptr(), &mut st) };
    if rc != 0 {
        return Err(StorageError::io(
            "query free space of",
            path,
            std::io::Error::last_os_error(),
        ));
    }
    // The field types differ between platforms (u32 or u64); widen without a lossy cast.
    #[allow(clippy::unnecessary_cast, clippy::useless_conversion)]
    let (blocks, size) = (st.f_bavail as u64, st.f_frsize as u64);
    Ok(blocks.saturating_mul(size))
}
