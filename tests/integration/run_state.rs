//! No frame is recorded in a state the plan did not ask for: an interlock that opens during the
//! laser sweep pauses the run (resumable, with a warning) and the step is retaken whole; a
//! single capture in place takes the rig as it is and leaves it so. Simulated rig, virtual
//! clock.

use crate::common;

use std::sync::Arc;

use common::*;
use stagehand::executor::{AutoConfirm, Event, RunControl, Start};
use stagehand::session::{self, Wiring};
use stagehand::storage::RunStatus;

/// Runs quickstart on a small rig; `on_event` sees every event with the rig and the control.
fn quickstart_with(
    out: &std::path::Path,
    on_event: impl Fn(&Event, &stagehand::rig::Rig, &RunControl) + Send + 'static,
) -> (Outcome, Vec<Option<String>>) {
    let prepared = session::prepare(
        script("quickstart.rhai"),
        &[],
        small_rig("lightstage", 32, 24),
    )
    .expect("prepares");
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, out, 5).expect("create run");
    let dir = store.dir().to_path_buf();
    let control = RunControl::new();
    let (result, events, reasons) = runtime.block_on(async move {
        let (tx, mut rx) = tokio::sync::broadcast::channel(100_000);
        let rig = session::open_rig(&prepared.rig, 5, None).expect("open rig");
        let probe = rig.clone();
        let ctl = control.clone();
        let driver = tokio::spawn(async move {
            let mut seen = Vec::new();
            let mut reasons = Vec::new();
            while let Ok(e) = rx.recv().await {
                if matches!(e, Event::Paused { .. }) {
                    reasons.push(ctl.pause_reason());
                }
                on_event(&e, &probe, &ctl);
                let end = matches!(e, Event::RunFinished { .. });
                seen.push(e);
                if end {
                    break;
                }
            }
            (seen, reasons)
        });
        let wiring = Wiring {
            events: tx,
            control,
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        let r = session::run(prepared, store, rig, wiring).await;
        let (seen, reasons) = driver.await.unwrap_or_default();
        (r, seen, reasons)
    });
    (
        Outcome {
            dir,
            result,
            events,
        },
        reasons,
    )
}

/// Opens the interlock as the first capture with the laser on starts (once per flag).
fn open_door_at_first_laser_capture(
    e: &Event,
    rig: &stagehand::rig::Rig,
    opened: &std::sync::atomic::AtomicBool,
) {
    let capture = matches!(
        e,
        Event::StepStarted {
            kind: "capture",
            ..
        }
    );
    if capture
        && rig.laser.as_ref().is_some_and(|l| l.status().on)
        && !opened.swap(true, std::sync::atomic::Ordering::SeqCst)
    {
        rig.interlock
            .set_closed(false)
            .expect("simulated interlock");
    }
}

fn warnings(o: &Outcome) -> Vec<String> {
    o.events
        .iter()
        .filter_map(|e| match e {
            Event::Warning { message } => Some(message.clone()),
            _ => None,
        })
        .collect()
}

/// Laser frames in the index, and how many of them were taken with the laser dark.
fn laser_frames(o: &Outcome) -> (i64, i64) {
    let conn = db(&o.dir);
    (
        count(&conn, "SELECT COUNT(*) FROM frames WHERE laser_armed = 1"),
        count(
            &conn,
            "SELECT COUNT(*) FROM frames WHERE laser_armed = 1 AND laser_on = 0",
        ),
    )
}

#[test]
fn an_interlock_opened_mid_sweep_pauses_the_run_and_the_step_is_retaken() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("tmp");
    let (undisturbed, _) = quickstart_with(&tmp.path().join("a"), |_, _, _| {});
    undisturbed.result.as_ref().expect("undisturbed run");
    let (frames, dark) = laser_frames(&undisturbed);
    assert!(frames > 0, "quickstart sweeps the laser");
    assert_eq!(dark, 0);

    // Open the door as the first capture with the laser on starts; close it and resume once
    // the run has paused.
    let opened = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (o, reasons) = quickstart_with(&tmp.path().join("b"), move |e, rig, ctl| match e {
        Event::StepStarted { .. } => open_door_at_first_laser_capture(e, rig, &opened),
        Event::Paused { .. } => {
            rig.interlock.set_closed(true).expect("simulated interlock");
            ctl.resume();
        }
        _ => {}
    });
    let summary = o
        .result
        .as_ref()
        .expect("the run completes after the resume");
    assert_eq!(summary.status, RunStatus::Done);
    let w = warnings(&o);
    assert_eq!(w.len(), 1, "one warning: {w:?}");
    assert!(w[0].contains("interlock"), "{}", w[0]);
    assert!(w[0].contains("resume"), "says what to do: {}", w[0]);
    assert_eq!(reasons.len(), 1);
    assert!(
        reasons[0]
            .as_deref()
            .is_some_and(|r| r.contains("interlock")),
        "the pause carries its reason: {reasons:?}"
    );
    assert_eq!(
        laser_frames(&o),
        (frames, 0),
        "no dark laser frame recorded"
    );
    assert_eq!(
        raw_pixels(&o.dir),
        raw_pixels(&undisturbed.dir),
        "the retaken step recorded exactly the undisturbed frames"
    );
}

#[test]
fn a_stalled_simulated_camera_is_retaken_and_blames_no_cable() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("tmp");
    let stalled = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stalled.clone();
    let (o, _) = quickstart_with(tmp.path(), move |e, rig, _| {
        if matches!(e, Event::RunStarted { .. })
            && !flag.swap(true, std::sync::atomic::Ordering::SeqCst)
        {
            rig.world
                .as_ref()
                .expect("simulated")
                .stall_camera("cam1", 1);
        }
    });
    o.result.as_ref().expect("run completes");
    let faults: Vec<&String> = o
        .events
        .iter()
        .filter_map(|e| match e {
            Event::DeviceFault { message, .. } => Some(message),
            _ => None,
        })
        .collect();
    assert_eq!(faults.len(), 1, "{faults:?}");
    assert!(faults[0].contains("simulated device"), "{}", faults[0]);
    assert!(!faults[0].contains("cable"), "{}", faults[0]);
}

#[test]
fn resuming_with_the_door_still_open_pauses_again() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("tmp");
    let opened = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let pauses = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let n = pauses.clone();
    let (o, reasons) = quickstart_with(tmp.path(), move |e, rig, ctl| match e {
        Event::StepStarted { .. } => open_door_at_first_laser_capture(e, rig, &opened),
        Event::Paused { .. } => {
            // The first resume comes with the door still open.
            if n.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= 1 {
                rig.interlock.set_closed(true).expect("simulated interlock");
            }
            ctl.resume();
        }
        _ => {}
    });
    o.result.as_ref().expect("run completes");
    assert_eq!(pauses.load(std::sync::atomic::Ordering::SeqCst), 2);
    assert_eq!(warnings(&o).len(), 2, "{:?}", warnings(&o));
    assert!(reasons.iter().all(|r| r.is_some()), "{reasons:?}");
    assert_eq!(laser_frames(&o).1, 0);
}

#[test]
fn a_capture_in_place_neither_homes_nor_changes_the_rig() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("tmp");
    let rig_source = small_rig("lightstage", 32, 24);
    let capture = stagehand::script::ScriptSource {
        name: "capture.rhai".into(),
        text: r#"capture(0.01, #{cameras: ["cam1"], label: "capture"});"#.into(),
    };
    let prepared = session::prepare(capture, &[], rig_source).expect("prepares");
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, tmp.path(), 1).expect("create run");
    let dir = store.dir().to_path_buf();
    let (summary, after) = runtime.block_on(async move {
        let rig = session::open_rig(&prepared.rig, 1, None).expect("open rig");
        for a in rig.axes.values() {
            a.home().await.expect("home");
        }
        let turntable = &rig.axes["turntable"];
        turntable.move_to(250.0).await.expect("move");
        let lamp = &rig.lamps["lamp1"];
        rig.banks[&lamp.bank]
            .set_many(&[(lamp.channel, true)])
            .await
            .expect("lamp on");
        let laser = rig.laser.as_ref().expect("laser");
        laser.arm().await.expect("arm");
        laser.on(laser.status().fitted_nm).await.expect("on");
        let (tx, _) = tokio::sync::broadcast::channel(1024);
        let wiring = Wiring {
            events: tx,
            control: RunControl::new(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        let summary = session::run_from(prepared, store, rig.clone(), wiring, Start::InPlace)
            .await
            .expect("capture");
        let bank = rig.banks[&lamp.bank].states();
        let after = (
            rig.axes["turntable"].status(),
            bank[lamp.channel as usize - 1],
            rig.laser.as_ref().expect("laser").status(),
        );
        (summary, after)
    });
    assert!(
        summary.session_rig_s < 2.0,
        "no homing: the capture took {} s of rig time",
        summary.session_rig_s
    );
    let (turntable, lamp_on, laser) = after;
    assert!(
        (turntable.position_deg - 250.0).abs() < 0.01 && turntable.homed,
        "{turntable:?}"
    );
    assert!(lamp_on, "the lamp is still on");
    assert!(laser.armed && laser.on, "the laser still emits");
    let conn = db(&dir);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM frames"), 1);
    assert_eq!(
        count(
            &conn,
            "SELECT COUNT(*) FROM frames WHERE laser_on = 1 AND lamps_on LIKE '%lamp1%'"
        ),
        1,
        "the frame records the rig as it was"
    );
}

#[test]
fn a_capture_in_place_refuses_axes_that_are_not_homed() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("tmp");
    let capture = stagehand::script::ScriptSource {
        name: "capture.rhai".into(),
        text: r#"capture(0.01, #{cameras: ["cam1"]});"#.into(),
    };
    let prepared =
        session::prepare(capture, &[], small_rig("lightstage", 32, 24)).expect("prepares");
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, tmp.path(), 1).expect("create run");
    let err = runtime.block_on(async move {
        let rig = session::open_rig(&prepared.rig, 1, None).expect("open rig");
        let (tx, _) = tokio::sync::broadcast::channel(1024);
        let wiring = Wiring {
            events: tx,
            control: RunControl::new(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        session::run_from(prepared, store, rig, wiring, Start::InPlace)
            .await
            .expect_err("not homed")
    });
    assert!(err.to_string().contains("not homed"), "{err}");
}
