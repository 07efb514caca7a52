//! Pause, resume, abort and operator prompts, through the library's run control.

use crate::common;

use std::sync::Arc;

use common::*;
use stagehand::executor::{Event, RunControl};
use stagehand::storage::RunStatus;

#[test]
fn prompts_reach_the_operator_in_order() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let prepared = stagehand::session::prepare(
        script("mdf_laser.rhai"),
        &sets(&[
            ("views", "1"),
            ("positions", "2"),
            ("mounts", "2"),
            ("lines", "2"),
        ]),
        small_rig("lightstage", 32, 24),
    )
    .unwrap();
    let expected: Vec<usize> = prepared
        .plan
        .steps
        .iter()
        .filter(|s| s.action.kind() == "prompt")
        .map(|s| s.index)
        .collect();
    assert!(!expected.is_empty());
    let operator = ScriptedOperator::new(None);
    let out = run_prepared(prepared, tmp.path(), 1, operator.clone(), RunControl::new());
    out.result.expect("run");
    let asked: Vec<usize> = operator
        .prompts
        .lock()
        .unwrap()
        .iter()
        .map(|(s, _)| *s)
        .collect();
    assert_eq!(asked, expected);
    let prompted = out
        .events
        .iter()
        .filter(|e| matches!(e, Event::Prompt { .. }))
        .count();
    assert_eq!(prompted, expected.len());
}

#[test]
fn operator_abort_stops_safely_and_resume_finishes() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let over = [
        ("views", "1"),
        ("positions", "2"),
        ("mounts", "2"),
        ("lines", "2"),
    ];
    let prepared = stagehand::session::prepare(
        script("mdf_laser.rhai"),
        &sets(&over),
        small_rig("lightstage", 32, 24),
    )
    .unwrap();
    let total_raw = prepared.plan.raw_frames() as i64;
    // Abort at the second prompt.
    let second = prepared
        .plan
        .steps
        .iter()
        .filter(|s| s.action.kind() == "prompt")
        .nth(1)
        .map(|s| s.index)
        .unwrap();
    let out = run_prepared(
        prepared,
        tmp.path(),
        1,
        ScriptedOperator::new(Some(second)),
        RunControl::new(),
    );
    let err = out.result.expect_err("aborted");
    assert_eq!(err.exit_code(), 1);
    assert!(err.to_string().contains("aborted"), "{err}");
    let conn = db(&out.dir);
    assert_eq!(
        count(&conn, "SELECT count(*) FROM runs WHERE status='aborted'"),
        1
    );
    assert_eq!(
        count(
            &conn,
            &format!("SELECT count(*) FROM steps WHERE status='done' AND idx >= {second}")
        ),
        0
    );
    drop(conn);
    // The abort event says the laser and lamps ended off: check the last state event order.
    assert!(
        matches!(out.events.last(), Some(Event::RunFinished { status, .. }) if *status == RunStatus::Aborted)
    );

    let summary = resume(&out.dir, ScriptedOperator::new(None)).expect("resume");
    assert_eq!(summary.status, RunStatus::Done);
    let conn = db(&out.dir);
    assert_eq!(
        count(&conn, "SELECT count(*) FROM frames WHERE kind='raw'"),
        total_raw
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM runs WHERE status='done'"),
        1
    );
}

#[test]
fn pause_holds_at_a_step_boundary_and_resume_continues() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let prepared = stagehand::session::prepare(
        script("btf.rhai"),
        &sets(&[("views", "2"), ("lights", "1"), ("lamps", "2")]),
        small_rig("lightstage", 32, 24),
    )
    .unwrap();
    let control = RunControl::new();
    let runtime = stagehand::session::runtime_for(&prepared.rig).unwrap();
    let store = stagehand::session::create_run(&prepared, tmp.path(), 3).unwrap();
    let events = runtime.block_on(async {
        let (tx, mut rx) = tokio::sync::broadcast::channel(10_000);
        let ctl = control.clone();
        // Pause after step 3 finishes; resume once the pause is observed.
        let driver = tokio::spawn(async move {
            let mut seen = Vec::new();
            while let Ok(e) = rx.recv().await {
                match &e {
                    Event::StepFinished { step: 3, .. } => ctl.pause(),
                    Event::Paused { .. } => ctl.resume(),
                    _ => {}
                }
                let end = matches!(e, Event::RunFinished { .. });
                seen.push(e);
                if end {
                    break;
                }
            }
            seen
        });
        let wiring = stagehand::session::Wiring {
            events: tx,
            control: control.clone(),
            operator: Arc::new(stagehand::executor::AutoConfirm),
            reserve_bytes: 0,
        };
        let rig = stagehand::session::open_rig(&prepared.rig, 3, None).unwrap();
        stagehand::session::run(prepared, store, rig, wiring)
            .await
            .expect("run");
        driver.await.unwrap()
    });
    let paused_at = events.iter().find_map(|e| {
        if let Event::Paused { before_step } = e {
            Some(*before_step)
        } else {
            None
        }
    });
    assert!(
        matches!(paused_at, Some(4) | Some(5)),
        "paused at {paused_at:?}"
    );
    let p = events
        .iter()
        .position(|e| matches!(e, Event::Paused { .. }))
        .unwrap();
    // No step started between the pause and the resume.
    let r = events
        .iter()
        .position(|e| matches!(e, Event::Resumed { .. }))
        .unwrap();
    assert!(
        events[p..r]
            .iter()
            .all(|e| !matches!(e, Event::StepStarted { .. }))
    );
    assert!(
        matches!(events.last(), Some(Event::RunFinished { status, .. }) if *status == RunStatus::Done)
    );
}

#[test]
fn abort_mid_run_leaves_lamps_and_laser_off() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let prepared = stagehand::session::prepare(
        script("quickstart.rhai"),
        &[],
        small_rig("lightstage", 32, 24),
    )
    .unwrap();
    let control = RunControl::new();
    let runtime = stagehand::session::runtime_for(&prepared.rig).unwrap();
    let store = stagehand::session::create_run(&prepared, tmp.path(), 3).unwrap();
    let (result, world_after, laser_after) = runtime.block_on(async {
        let (tx, mut rx) = tokio::sync::broadcast::channel(10_000);
        let ctl = control.clone();
        // Abort as soon as a capture starts with the laser on (the sweep).
        let rig = stagehand::session::open_rig(&prepared.rig, 3, None).unwrap();
        let probe = rig.clone();
        tokio::spawn(async move {
            while let Ok(e) = rx.recv().await {
                let capturing = matches!(
                    e,
                    Event::StepStarted {
                        kind: "capture",
                        ..
                    }
                );
                if capturing && probe.laser.as_ref().is_some_and(|l| l.status().on) {
                    ctl.abort();
                }
            }
        });
        let wiring = stagehand::session::Wiring {
            events: tx,
            control: control.clone(),
            operator: Arc::new(stagehand::executor::AutoConfirm),
            reserve_bytes: 0,
        };
        let r = stagehand::session::run(prepared, store, rig.clone(), wiring).await;
        let world = rig.world.as_ref().unwrap().snapshot_at(rig.clock.now_s());
        (r, world, rig.laser.as_ref().unwrap().status())
    });
    assert!(
        world_after.laser.is_none(),
        "laser still emitting after abort"
    );
    assert!(
        world_after.lamps.values().all(|&v| v == 0.0),
        "lamps still on after abort: {:?}",
        world_after.lamps
    );
    assert!(!laser_after.armed && !laser_after.on);
    let err = result.expect_err("aborted");
    assert!(err.to_string().contains("aborted"), "{err}");
    let dir = std::fs::read_dir(tmp.path())
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    assert_eq!(
        count(
            &db(&dir),
            "SELECT count(*) FROM runs WHERE status='aborted'"
        ),
        1
    );
}

#[test]
fn resuming_a_finished_run_changes_nothing() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let out = run_sequence(
        "quickstart.rhai",
        small_rig("lightstage", 24, 18),
        &[],
        tmp.path(),
        2,
    );
    out.result.expect("run");
    let before = disk_checksums(&out.dir);
    let rows = count(&db(&out.dir), "SELECT count(*) FROM frames");
    let summary = resume(&out.dir, ScriptedOperator::new(None)).expect("resume");
    assert_eq!(summary.status, RunStatus::Done);
    assert_eq!(summary.frames_written, 0);
    assert_eq!(disk_checksums(&out.dir), before);
    assert_eq!(count(&db(&out.dir), "SELECT count(*) FROM frames"), rows);
}
