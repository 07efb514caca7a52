//! Verification of a run directory: `stagehand verify RUN_DIR` and `GET /api/runs/{id}/verify`
//! both call [`verify_run`], so the CLI and the API report the same problems.
//!
//! Three checks, each problem naming the file (relative to the run directory), the frame and
//! the step, and what to do:
//! - **files against the index**: every file a `frames` or `ground_truth` row records is
//!   present, a regular file, of the recorded size, hashes to the recorded SHA-256 and decodes
//!   as the format it claims (16-bit PNG for raw frames, OpenEXR for HDR and ground truth);
//! - **index against the plan**: every capture step marked done has exactly the frames the plan
//!   asks for (cameras × exposures, plus one HDR merge per camera for an HDR bracket), no other
//!   step has frames, and the journal has one row per plan step of the plan's kind;
//! - **directory against the layout**: no leftover temp files and no files the run does not
//!   know (in the run directory or in `frames/`).
//!
//! Files are checked in parallel (rayon); each is read once, hashed chunk by chunk as it is
//! read ([`crate::checksum::read_hashed`]) and decoded from that one read, and its size is
//! compared before it is read, so a truncated file costs no hashing. Damaged, missing or unplanned frames of
//! a capture step are repaired by capturing the step again: the report lists those steps and
//! the exact `stagehand resume --retake` command. The index is opened read-only
//! ([`crate::RunReader`]): verifying never takes the run's write lock, so a run
//! being written can be verified too (its in-flight step shows as orphan files).

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::fs;
use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::atomic::is_temp_name;
use crate::checksum::{read_hashed, sha256_hex};
use crate::error::{Result, StorageError};
use crate::exr_hdr::decode_exr;
use crate::exr_planes::decode_exr_planes;
use crate::frame_meta::{hdr_file_name, raw_file_name};
use crate::layout;
use crate::manifest::Manifest;
use crate::plan::{RunPlan, is_capture};
use crate::png16::decode_png16;
use crate::query::{RecordedFile, RecordedKind};
use crate::reader::RunReader;

/// What kind of problem [`verify_run`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum ProblemKind {
    /// A file the index records is not there.
    MissingFile,
    /// A file's size differs from the recorded size.
    SizeMismatch,
    /// A file's SHA-256 differs from the recorded one.
    ChecksumMismatch,
    /// A file has the recorded checksum but does not decode as the format it claims.
    Undecodable,
    /// A file could not be read (permissions, I/O error) or is not a regular file.
    Unreadable,
    /// A done capture step lacks a frame its plan step asks for.
    MissingFrame,
    /// The index has a frame no plan step asks for.
    UnplannedFrame,
    /// A file in the run directory that the run does not know.
    StrayFile,
    /// A leftover temp file of an interrupted write.
    TempFile,
    /// The index (journal, paths) disagrees with the plan or cannot be read.
    Index,
    /// The plan file does not match the manifest's plan hash, or cannot be read.
    Plan,
}

/// One problem found by [`verify_run`].
#[derive(Debug, Clone, PartialEq, Serialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
pub struct Problem {
    /// What kind of problem.
    pub kind: ProblemKind,
    /// The file, relative to the run directory, when the problem is about one.
    pub path: Option<String>,
    /// The plan step concerned.
    pub step: Option<usize>,
    /// The frame's row id in the index (`frame_id` of the API), when it has a row.
    pub frame_id: Option<i64>,
    /// What is wrong and what to do about it.
    pub message: String,
}

/// The outcome of [`verify_run`]: what was checked and every problem found.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
pub struct VerifyReport {
    /// The run id (from the manifest).
    pub run_id: String,
    /// The run directory as given.
    pub run_dir: String,
    /// The run's status in the index (`running`, `done`, `failed`, `aborted`).
    pub status: String,
    /// Plan steps marked done in the journal.
    pub steps_done: usize,
    /// Plan steps.
    pub steps_total: usize,
    /// Files checked against the index (frames and ground truth).
    pub files_checked: usize,
    /// Bytes read and hashed.
    pub bytes_checked: u64,
    /// True when nothing is wrong.
    pub ok: bool,
    /// Every problem found, ordered by step, then path.
    pub problems: Vec<Problem>,
    /// Capture steps whose frames are missing, damaged or unplanned: capturing them again
    /// repairs the run.
    pub retake_steps: Vec<usize>,
    /// The command that captures `retake_steps` again, when there are any.
    pub retake_command: Option<String>,
}

/// A frame row as verification needs it.
struct FrameRow {
    id: i64,
    step: usize,
    path: String,
}

/// Everything read from the index.
struct IndexContents {
    status: String,
    /// Journal rows: step index → (kind, done).
    steps: BTreeMap<usize, (String, bool)>,
    frames: Vec<FrameRow>,
    recorded: Vec<RecordedFile>,
}

/// Checks the run at `run_dir` (see the module documentation) and reports every problem.
/// Errors only when `run_dir` is not a run directory at all (no manifest or index) or the
/// manifest cannot be read; everything else is a [`Problem`] in the report.
pub fn verify_run<P: RunPlan>(run_dir: &Path) -> Result<VerifyReport> {
    let manifest = crate::reader::read_manifest(run_dir)?;
    if !run_dir.join(layout::INDEX).is_file() {
        return Err(StorageError::NotARun {
            path: run_dir.to_path_buf(),
            missing: layout::INDEX,
        });
    }
    let mut problems = Vec::new();
    let plan: Option<P> = read_plan(run_dir, &manifest, &mut problems);
    let contents = match read_index(run_dir) {
        Ok(c) => c,
        Err(e) => {
            problems.push(Problem {
                kind: ProblemKind::Index,
                path: Some(layout::INDEX.into()),
                step: None,
                frame_id: None,
                message: format!(
                    "cannot read the index: {e}; the run's journal is damaged and cannot be \
                     repaired by a retake"
                ),
            });
            IndexContents {
                status: "unreadable".into(),
                steps: BTreeMap::new(),
                frames: Vec::new(),
                recorded: Vec::new(),
            }
        }
    };

    let checked: Vec<(u64, Option<Problem>)> = contents
        .recorded
        .par_iter()
        .map(|r| check_file(run_dir, r))
        .collect();
    let bytes_checked = checked.iter().map(|(b, _)| b).sum();
    problems.extend(checked.into_iter().filter_map(|(_, p)| p));
    if let Some(plan) = &plan {
        check_against_plan(plan, &contents, &mut problems);
    }
    check_layout(run_dir, &manifest, &contents, &mut problems);

    problems.sort_by(|a, b| {
        (a.step, &a.path, a.kind)
            .cmp(&(b.step, &b.path, b.kind))
            .then_with(|| a.message.cmp(&b.message))
    });
    let retake_steps: Vec<usize> = problems
        .iter()
        .filter(|p| {
            matches!(
                p.kind,
                ProblemKind::MissingFile
                    | ProblemKind::SizeMismatch
                    | ProblemKind::ChecksumMismatch
                    | ProblemKind::Undecodable
                    | ProblemKind::Unreadable
                    | ProblemKind::MissingFrame
                    | ProblemKind::UnplannedFrame
            )
        })
        .filter_map(|p| p.step)
        .filter(|&s| plan.as_ref().is_some_and(|plan| is_capture(plan, s)))
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let retake_command = (!retake_steps.is_empty())
        .then(|| retake_command(&retake_steps, &run_dir.display().to_string()));
    Ok(VerifyReport {
        run_id: manifest.run_id,
        run_dir: run_dir.display().to_string(),
        status: contents.status,
        steps_done: contents.steps.values().filter(|(_, done)| *done).count(),
        steps_total: plan
            .as_ref()
            .map_or(contents.steps.len(), |p| p.step_count()),
        files_checked: contents.recorded.len(),
        bytes_checked,
        ok: problems.is_empty(),
        problems,
        retake_steps,
        retake_command,
    })
}

/// `stagehand resume --retake 3,7 RUN_DIR`: the command that captures `steps` again, with the
/// directory quoted for a POSIX shell when it needs it.
pub fn retake_command(steps: &[usize], run_dir: &str) -> String {
    let list: Vec<String> = steps.iter().map(usize::to_string).collect();
    let plain = !run_dir.is_empty()
        && run_dir
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+:@,".contains(c));
    let dir = if plain {
        run_dir.to_string()
    } else {
        format!("'{}'", run_dir.replace('\'', r"'\''"))
    };
    format!("stagehand resume --retake {} {dir}", list.join(","))
}

/// Reads `plan.json` and checks it against the manifest's plan hash; a problem (and `None`)
/// when it cannot be used.
fn read_plan<P: RunPlan>(
    run_dir: &Path,
    manifest: &Manifest,
    problems: &mut Vec<Problem>,
) -> Option<P> {
    let mut problem = |message: String| {
        problems.push(Problem {
            kind: ProblemKind::Plan,
            path: Some(layout::PLAN.into()),
            step: None,
            frame_id: None,
            message,
        });
    };
    let bytes = match fs::read(run_dir.join(layout::PLAN)) {
        Ok(b) => b,
        Err(e) => {
            problem(format!(
                "cannot read the plan: {e}; without it the frames cannot be checked against \
                 the plan (restore plan.json from a backup of the run)"
            ));
            return None;
        }
    };
    let found = sha256_hex(&bytes);
    if found != manifest.plan_hash {
        problem(format!(
            "hashes to {found}, the manifest records {}; the plan was changed after the run \
             was created (restore plan.json from a backup of the run)",
            manifest.plan_hash
        ));
        return None;
    }
    match serde_json::from_slice(&bytes) {
        Ok(plan) => Some(plan),
        Err(e) => {
            problem(format!("is not a plan: {e}"));
            None
        }
    }
}

/// Reads the run status, the journal and every recorded file from the index (read-only).
fn read_index(run_dir: &Path) -> Result<IndexContents> {
    let reader = RunReader::open(run_dir)?;
    let status = reader.run()?.status.as_str().to_string();
    let steps = reader
        .steps()?
        .into_iter()
        .map(|s| (s.step, (s.kind, s.done)))
        .collect();
    let recorded = reader.recorded_files()?;
    let frames = recorded
        .iter()
        .filter(|r| r.kind != RecordedKind::GroundTruth)
        .map(|r| FrameRow {
            id: r.frame_id,
            step: r.step,
            path: r.path.clone(),
        })
        .collect();
    Ok(IndexContents {
        status,
        steps,
        frames,
        recorded,
    })
}

/// Checks one recorded file: path, presence, size, SHA-256, decoding. Returns the bytes read
/// and the problem, if any.
fn check_file(run_dir: &Path, r: &RecordedFile) -> (u64, Option<Problem>) {
    let problem = |kind, message: String| Problem {
        kind,
        path: Some(r.path.clone()),
        step: Some(r.step),
        frame_id: Some(r.frame_id),
        message,
    };
    let what = match r.kind {
        RecordedKind::GroundTruth => "ground-truth file",
        _ => "frame file",
    };
    if !layout::is_frame_path(&r.path) {
        return (
            0,
            Some(problem(
                ProblemKind::Index,
                format!(
                    "the index records a {what} outside frames/; the index was edited by hand \
                     or is damaged"
                ),
            )),
        );
    }
    let path = run_dir.join(&r.path);
    let meta = match fs::symlink_metadata(&path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return (
                0,
                Some(problem(
                    ProblemKind::MissingFile,
                    format!("the {what} is missing; retake step {}", r.step),
                )),
            );
        }
        Err(e) => {
            return (
                0,
                Some(problem(
                    ProblemKind::Unreadable,
                    format!("cannot stat the {what}: {e}"),
                )),
            );
        }
    };
    if !meta.is_file() {
        return (
            0,
            Some(problem(
                ProblemKind::Unreadable,
                format!(
                    "the {what} is not a regular file (a symlink or directory); retake step {}",
                    r.step
                ),
            )),
        );
    }
    if meta.len() != r.size_bytes {
        return (
            0,
            Some(problem(
                ProblemKind::SizeMismatch,
                format!(
                    "the {what} has {} bytes, the index recorded {}; retake step {}",
                    meta.len(),
                    r.size_bytes,
                    r.step
                ),
            )),
        );
    }
    let (bytes, found) = match read_hashed(&path, r.size_bytes) {
        Ok(read) => read,
        Err(e) => {
            return (
                0,
                Some(problem(
                    ProblemKind::Unreadable,
                    format!("cannot read the {what}: {e}"),
                )),
            );
        }
    };
    let n = bytes.len() as u64;
    if found != r.sha256 {
        return (
            n,
            Some(problem(
                ProblemKind::ChecksumMismatch,
                format!(
                    "the {what}'s SHA-256 is {found}, the index recorded {}; it changed after \
                     it was written; retake step {}",
                    r.sha256, r.step
                ),
            )),
        );
    }
    let decoded = match r.kind {
        RecordedKind::Raw => decode_png16(&r.path, &bytes).map(drop),
        RecordedKind::Hdr => decode_exr(&r.path, &bytes).map(drop),
        RecordedKind::GroundTruth => decode_exr_planes(&r.path, &bytes).map(drop),
    };
    match decoded {
        Ok(()) => (n, None),
        Err(e) => (
            n,
            Some(problem(
                ProblemKind::Undecodable,
                format!(
                    "matches its recorded SHA-256 but does not decode ({e}); it was written \
                     damaged; retake step {}",
                    r.step
                ),
            )),
        ),
    }
}

/// The frame files the plan asks of capture step `step` (relative paths).
fn planned_frames<P: RunPlan>(plan: &P, step: usize) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let Some(capture) = plan.step(step).and_then(|s| s.capture) else {
        return out;
    };
    let (cameras, exposures, hdr) = (capture.cameras, capture.exposures, capture.hdr);
    let frame = |name: String| format!("{}/{name}", layout::FRAMES_DIR);
    for camera in cameras {
        for e in 0..exposures {
            out.insert(frame(raw_file_name(step, camera, e)));
        }
        if hdr && exposures > 1 {
            out.insert(frame(hdr_file_name(step, camera)));
        }
    }
    out
}

/// Checks the journal and the frame rows against the plan.
fn check_against_plan<P: RunPlan>(plan: &P, contents: &IndexContents, problems: &mut Vec<Problem>) {
    let mut by_step: BTreeMap<usize, Vec<&FrameRow>> = BTreeMap::new();
    for f in &contents.frames {
        by_step.entry(f.step).or_default().push(f);
    }
    for (i, step) in (0..plan.step_count()).filter_map(|i| Some((i, plan.step(i)?))) {
        let index_problem = |message: String| Problem {
            kind: ProblemKind::Index,
            path: Some(layout::INDEX.into()),
            step: Some(i),
            frame_id: None,
            message,
        };
        let done = match contents.steps.get(&i) {
            None => {
                problems.push(index_problem(
                    "the journal has no row for this plan step; the index is damaged".into(),
                ));
                continue;
            }
            Some((kind, done)) => {
                if kind != step.kind {
                    problems.push(index_problem(format!(
                        "the journal says `{kind}`, the plan `{}`; the index belongs to another \
                         plan or is damaged",
                        step.kind
                    )));
                }
                *done
            }
        };
        let rows = by_step.remove(&i).unwrap_or_default();
        let expected = if done {
            planned_frames(plan, i)
        } else {
            BTreeSet::new()
        };
        for row in &rows {
            if !expected.contains(&row.path) {
                let why = if done {
                    "the plan step does not ask for this frame"
                } else {
                    "the step is not done, yet the index has this frame"
                };
                problems.push(Problem {
                    kind: ProblemKind::UnplannedFrame,
                    path: Some(row.path.clone()),
                    step: Some(i),
                    frame_id: Some(row.id),
                    message: format!("{why}; retake step {i}"),
                });
            }
        }
        let have: HashSet<&str> = rows.iter().map(|r| r.path.as_str()).collect();
        for path in expected.iter().filter(|p| !have.contains(p.as_str())) {
            problems.push(Problem {
                kind: ProblemKind::MissingFrame,
                path: Some(path.clone()),
                step: Some(i),
                frame_id: None,
                message: format!(
                    "step {i} is done but the index has no row for this frame the plan asks \
                     for; retake step {i}"
                ),
            });
        }
    }
    for (step, rows) in by_step {
        for row in rows {
            problems.push(Problem {
                kind: ProblemKind::UnplannedFrame,
                path: Some(row.path.clone()),
                step: Some(step),
                frame_id: Some(row.id),
                message: format!(
                    "the plan has no step {step}; the index belongs to another plan or is damaged"
                ),
            });
        }
    }
    for &extra in contents.steps.keys().filter(|&&k| k >= plan.step_count()) {
        problems.push(Problem {
            kind: ProblemKind::Index,
            path: Some(layout::INDEX.into()),
            step: Some(extra),
            frame_id: None,
            message: format!(
                "the journal has step {extra} but the plan has {} steps; the index belongs to \
                 another plan or is damaged",
                plan.step_count()
            ),
        });
    }
}

/// Checks the run directory and `frames/` for temp files and files the run does not know.
fn check_layout(
    run_dir: &Path,
    manifest: &Manifest,
    contents: &IndexContents,
    problems: &mut Vec<Problem>,
) {
    let index_files = [
        layout::INDEX.to_string(),
        format!("{}-wal", layout::INDEX),
        format!("{}-shm", layout::INDEX),
        format!("{}-journal", layout::INDEX),
    ];
    let mut known: HashSet<String> = [
        layout::MANIFEST,
        layout::PLAN,
        layout::RIG,
        layout::SCENE,
        layout::AS_BUILT,
        layout::FRAMES_DIR,
        layout::LOCK,
    ]
    .iter()
    .map(|s| s.to_string())
    .chain(index_files)
    .collect();
    known.insert(layout::script_copy_name(&manifest.script_name));
    let recorded: HashSet<&str> = contents.recorded.iter().map(|r| r.path.as_str()).collect();
    for (dir, rel) in [
        (run_dir.to_path_buf(), ""),
        (run_dir.join(layout::FRAMES_DIR), "frames/"),
    ] {
        let entries = match fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) => {
                problems.push(Problem {
                    kind: ProblemKind::Unreadable,
                    path: Some(format!("{rel}.")),
                    step: None,
                    frame_id: None,
                    message: format!("cannot list the directory: {e}"),
                });
                continue;
            }
        };
        for entry in entries.filter_map(std::result::Result::ok) {
            let name = entry.file_name().to_string_lossy().into_owned();
            let path = format!("{rel}{name}");
            let is_known = if rel.is_empty() {
                known.contains(&name)
            } else {
                recorded.contains(path.as_str())
            };
            if is_known {
                continue;
            }
            let (kind, message) = if is_temp_name(&name) {
                (
                    ProblemKind::TempFile,
                    format!(
                        "a leftover temp file of an interrupted write; `stagehand resume {}` \
                         removes it (or delete it)",
                        run_dir.display()
                    ),
                )
            } else if rel.is_empty() {
                (
                    ProblemKind::StrayFile,
                    "not part of a run directory; move it out of the run".to_string(),
                )
            } else {
                (
                    ProblemKind::StrayFile,
                    format!(
                        "no index row records this file: an orphan of a step interrupted before \
                         it was journaled (`stagehand resume {}` captures that step again and \
                         replaces it) or a file put there by hand (move it out of the run)",
                        run_dir.display()
                    ),
                )
            };
            problems.push(Problem {
                kind,
                path: Some(path),
                step: None,
                frame_id: None,
                message,
            });
        }
    }
}

impl VerifyReport {
    /// The report for a person: a summary line, every problem (file, step, frame, what is
    /// wrong and what to do), and the retake command when there is one.
    pub fn render(&self) -> String {
        let mut out = format!(
            "run {} ({}): {}/{} steps done; {} files checked ({})\n",
            self.run_id,
            self.status,
            self.steps_done,
            self.steps_total,
            self.files_checked,
            human_bytes(self.bytes_checked)
        );
        if self.ok {
            out.push_str(
                "ok: every file matches the index, the index matches the plan, and nothing \
                 else is in the run directory\n",
            );
            return out;
        }
        out.push_str(&format!("{} problem(s):\n", self.problems.len()));
        for p in &self.problems {
            let mut at = Vec::new();
            if let Some(step) = p.step {
                at.push(format!("step {step}"));
            }
            if let Some(id) = p.frame_id {
                at.push(format!("frame {id}"));
            }
            let at = if at.is_empty() {
                String::new()
            } else {
                format!(" ({})", at.join(", "))
            };
            out.push_str(&format!(
                "  {}{at}: {}\n",
                p.path.as_deref().unwrap_or("-"),
                p.message
            ));
        }
        if let Some(cmd) = &self.retake_command {
            out.push_str(&format!("repair: {cmd}\n"));
        }
        out
    }
}

/// Bytes in binary units: "512 B", "1.50 KiB", "3.21 GiB".
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    if bytes < 1024 {
        return format!("{bytes} B");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.2} {}", UNITS[unit])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retake_commands_are_ready_to_paste() {
        assert_eq!(
            retake_command(&[3, 7], "runs/quickstart-20261201-101500-1a2b3c4d"),
            "stagehand resume --retake 3,7 runs/quickstart-20261201-101500-1a2b3c4d"
        );
        assert_eq!(
            retake_command(&[1], "/data/my run's dir"),
            r"stagehand resume --retake 1 '/data/my run'\''s dir'"
        );
    }
}
