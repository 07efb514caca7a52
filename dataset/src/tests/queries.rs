//! Finding frames by lamp and camera, and checking the index against the plan.

use super::*;

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
