//! Paced captures: a trigger fires at its pacing deadline (a sweep's rate, a lamp's warm-up)
//! however long the step's device round trips take, because the capture does them before the
//! deadline. Here the lamp bank answers its read-back after a varying delay, as a relay board
//! on a serial line does.

use std::sync::Arc;

use stagehand::executor::{AutoConfirm, Event, RunControl};
use stagehand::script::ScriptSource;
use stagehand::session::{self, Wiring};
use stagehand_devices::DeviceResult;
use stagehand_devices::clock::RigClock;
use stagehand_devices::switch_bank::{SwitchBankDriver, SwitchBankHandle};

use crate::common::*;

/// Each capture at least this long after the last.
const INTERVAL_S: f64 = 0.25;

/// A switch bank that remembers its outputs and reads them back after a delay that changes
/// from read to read (0 to 90 ms of rig time).
struct SlowReadBank {
    states: Vec<bool>,
    clock: RigClock,
    reads: u64,
}

impl SwitchBankDriver for SlowReadBank {
    async fn set(&mut self, channel: u32, on: bool) -> DeviceResult<()> {
        self.states[channel as usize - 1] = on;
        Ok(())
    }

    async fn read_all(&mut self) -> DeviceResult<Vec<bool>> {
        self.reads += 1;
        self.clock
            .sleep_s((self.reads * 37 % 10) as f64 * 0.01)
            .await;
        Ok(self.states.clone())
    }
}

#[test]
fn a_paced_trigger_fires_at_its_deadline_however_slow_the_read_back() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let captures = format!("capture(0.01, #{{min_interval_s: {INTERVAL_S}}});\n").repeat(6);
    let script = ScriptSource {
        name: "paced.rhai".into(),
        text: format!("home();\nlamps_on(lamps());\n{captures}lamps_off();\n"),
    };
    let prepared = session::prepare(script, &[], small_rig("lightstage", 16, 12)).unwrap();
    let runtime = session::runtime_for(&prepared.rig).unwrap();
    let store = session::create_run(&prepared, tmp.path(), 1).unwrap();
    let dir = store.dir().to_path_buf();
    let summary = runtime.block_on(async {
        let mut rig = session::open_rig(&prepared.rig, 1, None).unwrap();
        let spec = rig.spec.bank("lamps").unwrap().clone();
        let bank = SlowReadBank {
            states: vec![false; spec.channels as usize],
            clock: rig.clock,
            reads: 0,
        };
        rig.banks
            .insert("lamps".into(), SwitchBankHandle::spawn(spec, bank));
        let (events, _rx) = tokio::sync::broadcast::channel(10_000);
        let wiring = Wiring {
            events,
            control: RunControl::new(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        session::run(prepared, store, rig, wiring).await
    });
    let summary = summary.expect("the run finishes");
    assert_eq!(summary.frames_written, 6 * 8);

    // Every camera exposed at the trigger, and the triggers came exactly one interval apart.
    let conn = db(&dir);
    let mut stmt = conn
        .prepare("SELECT DISTINCT rig_time_s FROM frames ORDER BY rig_time_s")
        .unwrap();
    let triggers: Vec<f64> = stmt
        .query_map([], |r| r.get(0))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(triggers.len(), 6, "one trigger per capture: {triggers:?}");
    for pair in triggers.windows(2) {
        let interval = pair[1] - pair[0];
        assert!(
            (interval - INTERVAL_S).abs() < 1e-6,
            "triggers {:.4} s apart, not {INTERVAL_S} s: {triggers:?}",
            interval
        );
    }
}

#[test]
fn an_abort_during_the_pacing_wait_leaves_no_camera_armed() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    // The capture waits for the lamps' 0.8 s warm-up with its cameras armed.
    let script = ScriptSource {
        name: "warm-up.rhai".into(),
        text: "home();\nlamps_on(lamps());\ncapture(0.01);\nlamps_off();\n".into(),
    };
    let prepared = session::prepare(script, &[], small_rig("lightstage", 16, 12)).unwrap();
    let runtime = session::runtime_for(&prepared.rig).unwrap();
    let store = session::create_run(&prepared, tmp.path(), 1).unwrap();
    let control = RunControl::new();
    let (result, armed_during, armed_after) = runtime.block_on(async {
        let rig = session::open_rig(&prepared.rig, 1, None).unwrap();
        let world = rig.world.clone().unwrap();
        let (events, mut rx) = tokio::sync::broadcast::channel(10_000);
        let ctl = control.clone();
        let probe = world.clone();
        let aborter = tokio::spawn(async move {
            while let Ok(e) = rx.recv().await {
                if matches!(
                    e,
                    Event::StepStarted {
                        kind: "capture",
                        ..
                    }
                ) {
                    // Halfway through the warm-up.
                    tokio::time::sleep(std::time::Duration::from_millis(400)).await;
                    let armed = probe.armed_cameras();
                    ctl.abort();
                    return armed;
                }
            }
            0
        });
        let wiring = Wiring {
            events,
            control: control.clone(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        let result = session::run(prepared, store, rig, wiring).await;
        (result, aborter.await.unwrap(), world.armed_cameras())
    });
    assert!(result.is_err(), "the run was aborted");
    assert_eq!(armed_during, 8, "the cameras wait armed for the trigger");
    assert_eq!(armed_after, 0, "the safe state disarms every camera");
}
