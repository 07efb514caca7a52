//! A run store's life: create, commit, reopen, crash and the writers it refuses.

use super::*;

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

/// The writer hears of each step of a batch once that step's files are written, with its
/// frames' pixels and ground truth already freed, so it can take in the next frames while the
/// rest of the batch is written; a frameless step is reported at once. One call per step.
#[test]
fn each_step_of_a_batch_is_reported_once_its_files_are_written() -> TestResult {
    use crate::frame_meta::ground_truth_file_name;
    use stagehand_devices::ground_truth::{GroundTruthData, GroundTruthPlane};
    use std::sync::{Arc, Mutex};

    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let frames_dir = store.dir().join(crate::layout::FRAMES_DIR);
    let mut step1 = step1_frames();
    let (w, h) = (step1[0].meta.width, step1[0].meta.height);
    let truth = Arc::new(GroundTruthData {
        width: w,
        height: h,
        planes: vec![GroundTruthPlane {
            kind: "depth".into(),
            channels: vec!["Z".into()],
            samples: vec![1.5; (w * h) as usize],
        }],
        notes: serde_json::json!({}),
    });
    step1[0].ground_truth = Some(Arc::clone(&truth));
    let step2 = vec![raw_frame(2, "cam5", 0, &[])];
    let mut names: Vec<Vec<String>> = [&step1, &step2]
        .iter()
        .map(|frames| frames.iter().map(|f| frame_file_name(&f.meta)).collect())
        .collect();
    names[0].push(ground_truth_file_name(&step1[0].meta, "depth"));
    names.push(Vec::new());
    let seen = Mutex::new(Vec::new());
    store.commit_steps_with(
        vec![
            (record(1, 9.5), step1),
            (record(2, 12.0), step2),
            (record(3, 13.0), Vec::new()),
        ],
        RawCompression::Deflate,
        &|i| {
            let written = names[i].iter().all(|n| frames_dir.join(n).is_file());
            // Step 1's ground truth is held here only, once its frame is written.
            let truth_freed = i != 0 || Arc::strong_count(&truth) == 1;
            seen.lock().unwrap().push((i, written, truth_freed));
        },
    )?;
    let mut seen = seen.into_inner()?;
    seen.sort();
    assert_eq!(
        seen,
        vec![(0, true, true), (1, true, true), (2, true, true)]
    );
    assert_eq!(
        store.done_steps()?.into_iter().collect::<Vec<_>>(),
        vec![1, 2, 3]
    );
    Ok(())
}
