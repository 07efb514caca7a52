//! Tests of the whole run store: create, commit, crash, resume, formats and queries.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use super::*;
use crate::checksum::sha256_hex;
use crate::exr_hdr::decode_exr;
use crate::frame_meta::tests::sample_meta;
use crate::plan::{PlannedCapture, PlannedStep, RunPlan};
use crate::png16::decode_png16;
use crate::products::{NewProduct, ProductStore};
use serde::{Deserialize, Serialize};

type TestResult = std::result::Result<(), Box<dyn std::error::Error>>;

/// A plan as the engine's would serialise, reduced to what the dataset reads of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Plan {
    script: String,
    params: BTreeMap<String, serde_json::Value>,
    steps: Vec<Step>,
}

/// One step: its action kind, block, script line and (captures) what it records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Step {
    index: usize,
    block: String,
    line: u32,
    kind: String,
    cameras: Vec<String>,
    exposures_s: Vec<f64>,
    hdr: bool,
    /// Move targets (moves only), to give the plan a float to round-trip.
    targets: BTreeMap<String, f64>,
}

impl RunPlan for Plan {
    fn step_count(&self) -> usize {
        self.steps.len()
    }

    fn step(&self, index: usize) -> Option<PlannedStep<'_>> {
        let s = self.steps.get(index)?;
        Some(PlannedStep {
            kind: &s.kind,
            block: &s.block,
            line: s.line,
            col: 3,
            capture: (s.kind == "capture").then_some(PlannedCapture {
                cameras: &s.cameras,
                exposures: s.exposures_s.len(),
                hdr: s.hdr,
            }),
        })
    }
}

impl Plan {
    fn hash(&self) -> String {
        crate::plan_hash(self).unwrap_or_default()
    }
}

fn step(index: usize, kind: &str) -> Step {
    Step {
        index,
        block: "turntable".into(),
        line: index as u32 + 1,
        kind: kind.into(),
        cameras: Vec::new(),
        exposures_s: Vec::new(),
        hdr: false,
        targets: BTreeMap::new(),
    }
}

fn capture(index: usize, cameras: &[&str]) -> Step {
    Step {
        exposures_s: vec![0.01, 0.02],
        cameras: cameras.iter().map(|c| c.to_string()).collect(),
        hdr: true,
        ..step(index, "capture")
    }
}

fn plan() -> Plan {
    Plan {
        script: "sequences/olat scan.rhai".into(),
        params: BTreeMap::from([("steps".into(), serde_json::json!(3))]),
        steps: vec![
            step(0, "home"),
            capture(1, &["cam5", "cam6"]),
            capture(2, &["cam5"]),
            Step {
                targets: BTreeMap::from([("turntable".into(), 0.1 + 0.2)]),
                ..step(3, "move")
            },
        ],
    }
}

fn manifest() -> Manifest {
    Manifest {
        format_version: 0,
        run_id: String::new(),
        created_unix_s: 1_795_268_707.5,
        software_version: "0.1.0".into(),
        script_name: "sequences/olat scan.rhai".into(),
        script_text: "// scan\nhome([\"turntable\"]);\n".into(),
        plan_hash: String::new(),
        params: BTreeMap::from([("steps".into(), serde_json::json!(3))]),
        rig_name: "lab".into(),
        rig_toml: "name = \"lab\"\n".into(),
        seed: 42,
        simulated: true,
        sim: None,
        calibrations: BTreeMap::new(),
    }
}

fn raw_frame(step: usize, camera: &str, exposure_index: usize, lamps: &[&str]) -> FrameToWrite {
    let mut meta = sample_meta(step, camera, exposure_index);
    meta.lamps_on = lamps.iter().map(|l| l.to_string()).collect();
    let n = (meta.width * meta.height * 3) as usize;
    let seed = step * 1000 + exposure_index * 10 + camera.len();
    let pixels = (0..n)
        .map(|i| ((i * 977 + seed * 131) % 4096) as u16)
        .collect();
    FrameToWrite {
        meta,
        pixels: FramePixels::Raw(pixels),
        ground_truth: None,
    }
}

fn hdr_frame(step: usize, camera: &str) -> FrameToWrite {
    let mut meta = sample_meta(step, camera, 0);
    meta.kind = FrameKind::Hdr;
    meta.exposure_index = None;
    meta.exposures_s = vec![0.01, 0.02];
    meta.exposure_s = 0.02;
    meta.bit_depth = 32;
    meta.sample_shift = 0;
    meta.trigger_id = None;
    let n = (meta.width * meta.height * 3) as usize;
    let pixels = (0..n).map(|i| 1.0e5 * i as f32 + 0.125).collect();
    FrameToWrite {
        meta,
        pixels: FramePixels::Hdr(pixels),
        ground_truth: None,
    }
}

fn record(step: usize, end: f64) -> StepRecord {
    StepRecord {
        step,
        kind: "capture".into(),
        block: "turntable".into(),
        rig_time_start_s: end - 1.0,
        rig_time_end_s: end,
        wall_time_unix_s: 1_795_268_800.0 + end,
    }
}

/// Step 1: cam5 and cam6, two exposures each, lamps 1 and 3, plus cam5's HDR.
fn step1_frames() -> Vec<FrameToWrite> {
    let mut frames = Vec::new();
    for cam in ["cam5", "cam6"] {
        for e in 0..2 {
            frames.push(raw_frame(1, cam, e, &["lamp1", "lamp3"]));
        }
    }
    frames.push(hdr_frame(1, "cam5"));
    frames
}

fn frame_row_count(store: &RunStore) -> rusqlite::Result<i64> {
    store
        .index()
        .conn()
        .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
}

fn files_in(dir: &Path) -> std::io::Result<Vec<String>> {
    let mut names: Vec<String> = fs::read_dir(dir)?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    Ok(names)
}

#[test]
fn create_commit_reopen() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let root = tmp.path().join("out");
    let plan = plan();
    let mut store = RunStore::create(&root, manifest(), &plan)?;
    let dir = store.dir().to_path_buf();
    assert_eq!(
        dir.file_name().and_then(|n| n.to_str()),
        Some(format!("olat_scan-20261121-134507-{}", &plan.hash()[..8]).as_str())
    );
    for f in [
        "manifest.json",
        "plan.json",
        "olat_scan.rhai",
        "rig.toml",
        "index.sqlite",
        "frames",
    ] {
        assert!(dir.join(f).exists(), "{f} missing");
    }
    assert_eq!(store.status()?, (RunStatus::Running, None));
    assert!(store.done_steps()?.is_empty());
    assert_eq!(store.last_rig_time_s()?, 0.0);
    assert!(store.available_bytes()? > 0);

    store.commit_step(&record(0, 4.0), Vec::new())?;
    let written = store.commit_step(&record(1, 9.5), step1_frames())?;
    assert_eq!(written.len(), 5);
    assert!(
        written
            .iter()
            .all(|p| p.starts_with(dir.join("frames")) && p.is_file())
    );
    store.set_status(RunStatus::Failed, Some("camera cam6 timed out"))?;
    drop(store);

    let (store, manifest, reopened_plan) = RunStore::open::<Plan>(&dir)?;
    assert_eq!(reopened_plan, plan);
    assert_eq!(manifest.plan_hash, plan.hash());
    assert_eq!(manifest.format_version, Manifest::FORMAT_VERSION);
    assert_eq!(manifest.run_id, store.run_id());
    assert_eq!(
        store.done_steps()?.into_iter().collect::<Vec<_>>(),
        vec![0, 1]
    );
    assert_eq!(store.last_rig_time_s()?, 9.5);
    assert_eq!(
        store.status()?,
        (RunStatus::Failed, Some("camera cam6 timed out".into()))
    );

    // Every row round-trips its metadata and checksums its file.
    let rows = store.frames(Some(1))?;
    assert_eq!(rows.len(), 5);
    let mut expected: Vec<FrameMeta> = step1_frames().into_iter().map(|f| f.meta).collect();
    expected.sort_by_key(frame_file_name);
    for (row, meta) in rows.iter().zip(&expected) {
        assert_eq!(&row.meta, meta);
        assert_eq!(row.path, format!("frames/{}", frame_file_name(meta)));
        let bytes = fs::read(dir.join(&row.path))?;
        assert_eq!(row.sha256, sha256_hex(&bytes));
        assert_eq!(row.size_bytes, bytes.len() as u64);
    }
    Ok(())
}

#[test]
fn second_run_with_same_name_gets_a_suffix() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let a = RunStore::create(tmp.path(), manifest(), &plan())?;
    let b = RunStore::create(tmp.path(), manifest(), &plan())?;
    let c = RunStore::create(tmp.path(), manifest(), &plan())?;
    assert_eq!(b.run_id(), format!("{}-2", a.run_id()));
    assert_eq!(c.run_id(), format!("{}-3", a.run_id()));
    Ok(())
}

#[test]
fn plan_hash_mismatch_is_an_error() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    drop(store);
    let mut changed = plan();
    changed.steps.pop();
    fs::write(dir.join("plan.json"), serde_json::to_vec(&changed)?)?;
    let err = RunStore::open::<Plan>(&dir)
        .err()
        .ok_or("open accepted a changed plan")?;
    assert!(
        matches!(err, StorageError::PlanHashMismatch { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("start a new run"));

    // A manifest that names another plan's hash is refused at creation, too.
    let mut m = manifest();
    m.plan_hash = changed.hash();
    let err = RunStore::create(tmp.path(), m, &plan())
        .err()
        .ok_or("create accepted a wrong hash")?;
    assert!(
        matches!(err, StorageError::PlanHashMismatch { .. }),
        "{err}"
    );
    Ok(())
}

#[test]
fn commit_is_idempotent() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let first = store.commit_step(&record(1, 9.5), step1_frames())?;
    let rows_before = store.frames(None)?;
    let second = store.commit_step(&record(1, 9.5), step1_frames())?;
    assert_eq!(first, second);
    assert_eq!(store.frames(None)?, rows_before);
    assert_eq!(frame_row_count(&store)?, 5);
    assert_eq!(files_in(&store.dir().join("frames"))?.len(), 5);
    assert_eq!(store.done_steps()?.into_iter().collect::<Vec<_>>(), vec![1]);
    Ok(())
}

#[test]
fn crash_between_files_and_commit_leaves_no_duplicates() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    store.commit_step(&record(1, 9.5), step1_frames())?;
    // Step 2: files land on disk, then the process "dies" before the commit.
    let frames2 = vec![
        raw_frame(2, "cam5", 0, &["lamp2"]),
        raw_frame(2, "cam5", 1, &["lamp2"]),
    ];
    let orphans = store.write_frames(2, &frames2)?;
    assert_eq!(orphans.len(), 2);
    // ... and a write of step 3 was cut short, leaving a temp file.
    let stale = dir
        .join("frames")
        .join(".s000003_cam5_e0.png.999.0.stagehand-tmp");
    fs::write(&stale, b"torn")?;
    drop(store);

    let (mut store, _, _) = RunStore::open::<Plan>(&dir)?;
    assert!(!stale.exists(), "open must remove stale temp files");
    assert_eq!(store.done_steps()?.into_iter().collect::<Vec<_>>(), vec![1]);
    assert_eq!(frame_row_count(&store)?, 5);
    // Resume re-runs step 2; the deterministic names overwrite the orphans.
    let written = store.commit_step(&record(2, 12.0), frames2)?;
    let orphan_paths: Vec<PathBuf> = orphans.into_iter().map(|w| w.path).collect();
    assert_eq!(written, orphan_paths);
    assert_eq!(frame_row_count(&store)?, 7);
    let files = files_in(&dir.join("frames"))?;
    assert_eq!(files.len(), 7);
    let paths: Vec<String> = store.frames(None)?.into_iter().map(|r| r.path).collect();
    let on_disk: Vec<String> = files.iter().map(|f| format!("frames/{f}")).collect();
    assert_eq!(paths, on_disk, "exactly one row per file");
    Ok(())
}

#[test]
fn png_round_trip_and_identical_bytes_without_wall_time() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let frame = raw_frame(1, "cam5", 1, &["lamp3"]);
    let FramePixels::Raw(pixels) = frame.pixels.clone() else {
        return Err("not raw".into());
    };
    let meta = frame.meta.clone();
    let paths = store.commit_step(&record(1, 9.5), vec![frame.clone()])?;
    let bytes_a = fs::read(&paths[0])?;

    let decoded = decode_png16("t", &bytes_a)?;
    assert_eq!((decoded.width, decoded.height), (meta.width, meta.height));
    assert_eq!(decoded.pixels, pixels, "the DN come back exactly");
    // Stored MSB-aligned (12-bit sensor: shifted by 4, sBIT 12), and the shift is recorded.
    assert_eq!((decoded.significant_bits, decoded.shift), (12, 4));
    let embedded: serde_json::Value =
        serde_json::from_str(decoded.metadata.as_deref().ok_or("no iTXt")?)?;
    assert_eq!(embedded["camera"], "cam5");
    assert_eq!(embedded["exposure_index"], 1);
    assert_eq!(embedded["sample_shift"], 4);
    assert!(embedded.get("wall_time_unix_s").is_none());

    let mut later = frame;
    later.meta.wall_time_unix_s += 3600.0;
    let paths_b = store.commit_step(&record(1, 9.5), vec![later])?;
    let bytes_b = fs::read(&paths_b[0])?;
    assert_eq!(bytes_a, bytes_b);
    let rows = store.frames(Some(1))?;
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].meta.sample_shift, 4);
    assert_eq!(rows[0].sha256, sha256_hex(&bytes_a));
    assert_eq!(
        rows[0].meta.wall_time_unix_s,
        meta.wall_time_unix_s + 3600.0
    );
    Ok(())
}

/// A writer behind the cameras stores every other raw frame uncompressed: both kinds are PNG
/// that decode to the same DN and are indexed with their own size and hash.
#[test]
fn half_stored_frames_decode_alike() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    // Frames large enough for deflate to pay: a smooth 64×48 gradient.
    let mut frames = step1_frames();
    for f in &mut frames {
        if let FramePixels::Raw(px) = &mut f.pixels {
            (f.meta.width, f.meta.height) = (64, 48);
            *px = (0..64 * 48 * 3).map(|i| (i / 3 % 64 * 16) as u16).collect();
        }
    }
    let raw: Vec<(String, Option<usize>, Vec<u16>)> = frames
        .iter()
        .filter_map(|f| match &f.pixels {
            FramePixels::Raw(px) => {
                Some((f.meta.camera.clone(), f.meta.exposure_index, px.clone()))
            }
            FramePixels::Hdr(_) => None,
        })
        .collect();
    store.commit_steps_with(vec![(record(1, 9.5), frames)], RawCompression::HalfStored)?;
    let (mut stored, mut deflated) = (0, 0);
    for row in store.frames(Some(1))? {
        let bytes = fs::read(dir.join(&row.path))?;
        assert_eq!(row.sha256, sha256_hex(&bytes));
        assert_eq!(row.size_bytes, bytes.len() as u64);
        if row.meta.kind != FrameKind::Raw {
            continue;
        }
        let (_, _, pixels) = raw
            .iter()
            .find(|(c, e, _)| *c == row.meta.camera && *e == row.meta.exposure_index)
            .ok_or("a row for no frame")?;
        assert_eq!(
            &decode_png16(&row.path, &bytes)?.pixels,
            pixels,
            "{}",
            row.path
        );
        // Stored: every sample's two bytes and more; deflated: far less.
        if bytes.len() > pixels.len() * 2 {
            stored += 1;
        } else {
            deflated += 1;
        }
    }
    assert_eq!((stored, deflated), (2, 2));
    Ok(())
}

/// A dataset written before MSB alignment and ground truth (index schema 1, PNGs with the DN
/// unshifted and no sBIT) verifies clean, opens, is upgraded to schema 3 with shift 0 in every
/// row, and reads the same DN.
#[test]
fn old_datasets_without_sample_shift_still_read() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    // Every frame step 1 of the plan asks for, so the dataset verifies clean.
    let mut frames = step1_frames();
    frames.push(hdr_frame(1, "cam6"));
    store.commit_step(&record(1, 9.5), frames.clone())?;
    drop(store);
    // Turn it into what an older stagehand wrote.
    let conn = rusqlite::Connection::open(dir.join(layout::INDEX))?;
    for f in &frames {
        let FramePixels::Raw(px) = &f.pixels else {
            continue;
        };
        let name = frame_file_name(&f.meta);
        let mut old_meta = f.meta.clone();
        old_meta.sample_shift = 0;
        let json = old_meta.embedded_json()?;
        let bytes = crate::png16::encode_png16_unshifted(&name, 4, 3, px, &json)?;
        fs::write(dir.join("frames").join(&name), &bytes)?;
        conn.execute(
            "UPDATE frames SET sha256 = ?1, size_bytes = ?2 WHERE path = ?3",
            rusqlite::params![
                sha256_hex(&bytes),
                bytes.len() as i64,
                format!("frames/{name}")
            ],
        )?;
    }
    conn.execute_batch(
        "DROP VIEW frame_lamps; ALTER TABLE frames DROP COLUMN sample_shift;
         ALTER TABLE frames DROP COLUMN fixture_pose; DROP TABLE products;
         CREATE VIEW frame_lamps AS
             SELECT frames.*, j.value AS lamp FROM frames, json_each(frames.lamps_on) AS j;
         DROP TABLE ground_truth;
         PRAGMA user_version = 1;",
    )?;
    drop(conn);
    let report = verify::verify_run::<Plan>(&dir)?;
    assert!(report.ok, "{}", report.render());
    assert_eq!(report.files_checked, frames.len());

    let (store, _, _) = RunStore::open::<Plan>(&dir)?;
    let version: i32 = store
        .index()
        .conn()
        .query_row("PRAGMA user_version", [], |r| r.get(0))?;
    assert_eq!(version, index::SCHEMA_VERSION);
    let rows = store.frames(Some(1))?;
    assert_eq!(rows.len(), frames.len());
    for row in &rows {
        assert_eq!(row.meta.sample_shift, 0, "{}", row.path);
        if row.meta.kind != FrameKind::Raw {
            continue;
        }
        let written = frames
            .iter()
            .find(|f| format!("frames/{}", frame_file_name(&f.meta)) == row.path)
            .ok_or("a written frame")?;
        let decoded = decode_png16(&row.path, &fs::read(dir.join(&row.path))?)?;
        assert_eq!(FramePixels::Raw(decoded.pixels), written.pixels);
        assert_eq!(decoded.shift, 0);
    }
    // The lamp view still works on the upgraded index.
    let n: i64 = store.index().conn().query_row(
        "SELECT count(*) FROM frame_lamps WHERE lamp = 'lamp3' AND sample_shift = 0",
        [],
        |r| r.get(0),
    )?;
    assert_eq!(n, frames.len() as i64);
    Ok(())
}

#[test]
fn exr_round_trip() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let frame = hdr_frame(2, "cam5");
    let FramePixels::Hdr(pixels) = frame.pixels.clone() else {
        return Err("not hdr".into());
    };
    let paths = store.commit_step(&record(2, 3.0), vec![frame])?;
    assert!(paths[0].ends_with("frames/s000002_cam5_hdr.exr"));
    let decoded = decode_exr("t", &fs::read(&paths[0])?)?;
    assert_eq!(decoded.pixels, pixels);
    let embedded: serde_json::Value =
        serde_json::from_str(decoded.metadata.as_deref().ok_or("no attribute")?)?;
    assert_eq!(embedded["kind"], "hdr");
    Ok(())
}

#[test]
fn lamp_and_camera_query() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    store.commit_step(&record(1, 9.5), step1_frames())?;
    store.commit_step(
        &record(2, 12.0),
        vec![
            raw_frame(2, "cam5", 0, &["lamp2"]),
            raw_frame(2, "cam5", 1, &["lamp2", "lamp4"]),
        ],
    )?;
    drop(store);
    // Query the file with a plain connection, as `sqlite3` would.
    let dirs = files_in(tmp.path())?;
    let conn = rusqlite::Connection::open(tmp.path().join(&dirs[0]).join("index.sqlite"))?;
    let query = |sql: &str| -> rusqlite::Result<Vec<String>> {
        let mut stmt = conn.prepare(sql)?;
        stmt.query_map([], |r| r.get(0))?.collect()
    };
    let want = vec![
        "frames/s000001_cam5_e0.png",
        "frames/s000001_cam5_e1.png",
        "frames/s000001_cam5_hdr.exr",
    ];
    let joined = query(
        "SELECT frames.path FROM frames, json_each(frames.lamps_on) j WHERE camera='cam5' AND j.value='lamp3' \
         ORDER BY 1",
    )?;
    assert_eq!(joined, want);
    let via_view =
        query("SELECT path FROM frame_lamps WHERE camera='cam5' AND lamp='lamp3' ORDER BY path")?;
    assert_eq!(via_view, want);
    // json_each has a `path` column of its own, so the unqualified form is ambiguous.
    let unqualified = query(
        "SELECT path FROM frames, json_each(frames.lamps_on) j WHERE camera='cam5' AND j.value='lamp3'",
    );
    assert!(unqualified.is_err_and(|e| e.to_string().contains("ambiguous column name: path")));
    let turntable: f64 = conn.query_row(
        "SELECT json_extract(axes_deg, '$.turntable') FROM frames WHERE path = 'frames/s000002_cam5_e1.png'",
        [],
        |r| r.get(0),
    )?;
    assert_eq!(turntable, 15.0);
    Ok(())
}

#[test]
fn unwritable_root_is_a_clear_error() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let file = tmp.path().join("file");
    fs::write(&file, b"not a directory")?;
    let root = file.join("sub");
    let err = RunStore::create(&root, manifest(), &plan())
        .err()
        .ok_or("create succeeded below a file")?;
    assert!(matches!(err, StorageError::CreateRoot { .. }), "{err}");
    let text = err.to_string();
    assert!(text.contains(&root.display().to_string()), "{text}");
    assert!(text.contains("--out"), "{text}");
    Ok(())
}

#[test]
fn second_writer_and_incomplete_runs_are_refused() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let err = RunStore::open::<Plan>(store.dir())
        .err()
        .ok_or("second writer admitted")?;
    assert!(matches!(err, StorageError::RunInUse { .. }), "{err}");

    let half = tmp.path().join("half-made");
    fs::create_dir(&half)?;
    fs::write(half.join("plan.json"), b"{}")?;
    let err = RunStore::open::<Plan>(&half)
        .err()
        .ok_or("incomplete run opened")?;
    assert!(
        matches!(
            err,
            StorageError::NotARun {
                missing: "manifest.json",
                ..
            }
        ),
        "{err}"
    );
    Ok(())
}

#[test]
fn inconsistent_commits_are_refused() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let bad = [
        (record(9, 1.0), vec![]),
        (record(1, 1.0), vec![raw_frame(2, "cam5", 0, &[])]),
        (
            record(1, 1.0),
            vec![raw_frame(1, "cam5", 0, &[]), raw_frame(1, "cam5", 0, &[])],
        ),
        (record(1, 1.0), {
            let mut f = raw_frame(1, "cam5", 0, &[]);
            f.meta.kind = FrameKind::Hdr;
            vec![f]
        }),
        (record(1, 1.0), {
            let mut f = raw_frame(1, "cam5", 0, &[]);
            f.meta.width += 1;
            vec![f]
        }),
    ];
    for (rec, frames) in bad {
        let err = store
            .commit_step(&rec, frames)
            .err()
            .ok_or("bad commit accepted")?;
        assert!(
            matches!(
                err,
                StorageError::InvalidCommit { .. } | StorageError::InvalidFrame { .. }
            ),
            "{err}"
        );
    }
    assert!(store.done_steps()?.is_empty());
    assert_eq!(frame_row_count(&store)?, 0);
    Ok(())
}

/// Verification against the plan: a done capture step missing a frame its plan step asks for,
/// a frame no plan step asks for, and a stray file are each reported, with the steps to retake.
#[test]
fn verify_checks_the_index_against_the_plan() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    let home = StepRecord {
        kind: "home".into(),
        ..record(0, 4.0)
    };
    store.commit_step(&home, Vec::new())?;
    // Step 1 asks for cam5 and cam6, two exposures each, and both cameras' HDR merges.
    let mut step1 = step1_frames();
    step1.push(hdr_frame(1, "cam6"));
    store.commit_step(&record(1, 9.5), step1)?;
    let report = verify::verify_run::<Plan>(&dir)?;
    assert!(report.ok, "{}", report.render());
    assert_eq!(report.files_checked, 6);

    // Step 2 asks for cam5 only: without its HDR merge, and with a cam7 frame.
    store.commit_step(
        &record(2, 12.0),
        vec![
            raw_frame(2, "cam5", 0, &[]),
            raw_frame(2, "cam5", 1, &[]),
            raw_frame(2, "cam7", 0, &[]),
        ],
    )?;
    fs::write(dir.join("notes.txt"), "mine")?;
    let report = verify::verify_run::<Plan>(&dir)?;
    let found: Vec<(verify::ProblemKind, Option<&str>, Option<usize>)> = report
        .problems
        .iter()
        .map(|p| (p.kind, p.path.as_deref(), p.step))
        .collect();
    assert_eq!(
        found,
        vec![
            (verify::ProblemKind::StrayFile, Some("notes.txt"), None),
            (
                verify::ProblemKind::MissingFrame,
                Some("frames/s000002_cam5_hdr.exr"),
                Some(2)
            ),
            (
                verify::ProblemKind::UnplannedFrame,
                Some("frames/s000002_cam7_e0.png"),
                Some(2)
            ),
        ]
    );
    assert_eq!(report.retake_steps, vec![2]);
    let command = format!("stagehand resume --retake 2 {}", dir.display());
    assert_eq!(report.retake_command.as_deref(), Some(command.as_str()));
    assert!(report.render().contains(&format!("repair: {command}")));
    Ok(())
}

#[test]
fn a_placed_fixture_is_indexed_and_embedded_and_a_flat_one_is_left_out() -> TestResult {
    use stagehand_devices::fixture_pose::FixturePose;
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let mut frames = step1_frames();
    let pose = FixturePose {
        tilt_deg: 30.0,
        tilt_toward_deg: 90.0,
        ..FixturePose::default()
    };
    frames[0].meta.fixture_pose = pose;
    let flat_json = frames[1].meta.embedded_json()?;
    assert!(!flat_json.contains("fixture_pose"), "{flat_json}");
    assert!(
        frames[0]
            .meta
            .embedded_json()?
            .contains("\"tilt_deg\":30.0")
    );
    store.commit_step(&record(1, 9.5), frames.clone())?;
    let rows = store.frames(Some(1))?;
    let placed: Vec<FixturePose> = rows.iter().map(|r| r.meta.fixture_pose).collect();
    assert_eq!(placed.iter().filter(|p| **p == pose).count(), 1);
    assert_eq!(
        placed.iter().filter(|p| p.is_flat_centred()).count(),
        rows.len() - 1
    );
    let reader = RunReader::open(store.dir())?;
    assert_eq!(reader.schema_version(), index::SCHEMA_VERSION);
    Ok(())
}

/// A run created and closed (its lock released), in a temp dir kept alive by the first value.
fn closed_run() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let store = RunStore::create(&tmp.path().join("out"), manifest(), &plan()).unwrap();
    let dir = store.dir().to_path_buf();
    drop(store);
    (tmp, dir)
}
fn product_named(file_name: &str) -> NewProduct {
    NewProduct {
        kind: "btf".into(),
        key: format!("btf/{file_name}"),
        file_name: file_name.into(),
        inputs: vec!["frames/a.png".into()],
        calibrations: vec!["geometry-1".into()],
        software: "test".into(),
        parameters: serde_json::json!({"size": 4}),
    }
}

#[test]
fn a_product_in_folders_is_written_indexed_and_current() {
    let (_tmp, dir) = closed_run();
    let mut store = ProductStore::open(&dir).unwrap();
    let chunk = product_named("btf.zarr/radiance/c/0/1/0/0/0");
    let stored = store.write(chunk.clone(), &[1, 2, 3]).unwrap();
    assert_eq!(stored.path, "products/btf/btf.zarr/radiance/c/0/1/0/0/0");
    assert_eq!(std::fs::read(dir.join(&stored.path)).unwrap(), [1, 2, 3]);
    assert!(store.is_current(&chunk).unwrap());
    let listed = store.products().unwrap();
    assert_eq!(listed.len(), 1);
    assert_eq!(listed[0].made, chunk, "the file name keeps its folders");
    // Changed bytes on disk: no longer current.
    std::fs::write(dir.join(&stored.path), [9]).unwrap();
    assert!(!store.is_current(&chunk).unwrap());
}

#[test]
fn a_file_name_that_leaves_its_folder_is_refused() {
    let (_tmp, dir) = closed_run();
    let mut store = ProductStore::open(&dir).unwrap();
    for bad in ["../escape", "a//b", "./a", "a/", ""] {
        let err = store.write(product_named(bad), &[0]).unwrap_err();
        assert!(err.to_string().contains("relative path"), "{bad}: {err}");
    }
    let mut wrong_kind = product_named("ok");
    wrong_kind.kind = "../x".into();
    assert!(store.write(wrong_kind, &[0]).is_err());
    assert!(store.products().unwrap().is_empty());
}
