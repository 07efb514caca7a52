//! The whole acquisition loop through real drivers and real bytes: the lab rig
//! (`devices/rigs/lightstage-lab.toml`: one GRBL controller for the three axes and the laser,
//! a Numato relay board for the lamps and the trigger line) runs against the firmware
//! emulators on pseudo-terminals, in real time. Each fault the emulators can inject must
//! pause the run with a typed error naming the device, recover (reconnect, re-home) and
//! finish with exactly the frames of an undisturbed run, byte for byte.

use crate::common;

use std::path::Path;
use std::sync::Arc;

use stagehand::executor::{AutoConfirm, Event, RunControl};
use stagehand::rig::Emulation;
use stagehand::rig::RigSource;
use stagehand::script::ScriptSource;
use stagehand::session;
use stagehand::storage::RunStatus;
use stagehand_simulator::emulators::{Fault, Faults};

use common::{Outcome, db, raw_pixels, root, run_prepared_with};

const GRBL_PORT: &str = "/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0";
const RELAY_PORT: &str = "/dev/serial/by-id/usb-Numato_Systems_Pvt._Ltd._Numato_Lab_8_Channel_USB_Relay_Module_NL0001-if00";

/// The axes (and laser) on the GRBL controller: any of them may be the one that notices.
const GRBL_AXES: &[&str] = &["turntable", "light_arc", "laser_tilt", "laser"];

/// How much faster than the lab's physics the test rig runs: speeds ×K, accelerations ×K²,
/// settle and warm-up times ÷K. Every timeout the drivers derive from the physics scales with
/// it, the emulators take their rates from the same file, and frames (all shot at rest) do not
/// change, so the tours keep their meaning in a quarter of the wall time.
const SPEED_UP: f64 = 8.0;

/// The lab rig with its cameras shrunk so the frames render fast, and its physics sped up
/// [`SPEED_UP`] times.
fn lab_rig(w: u32, h: u32) -> RigSource {
    let text =
        std::fs::read_to_string(root().join("devices/rigs/lightstage-lab.toml")).expect("lab rig");
    let text = text
        .replace("width = 1024", &format!("width = {w}"))
        .replace("height = 768", &format!("height = {h}"));
    let scaled: Vec<String> = text
        .lines()
        .map(|line| {
            let factor = match line.split_once(" = ").map(|(k, _)| k) {
                Some("speed_deg_s" | "homing_speed_deg_s") => SPEED_UP,
                Some("accel_deg_s2") => SPEED_UP * SPEED_UP,
                Some("settle_s" | "warmup_s") => 1.0 / SPEED_UP,
                _ => return line.to_string(),
            };
            let (key, value) = line.split_once(" = ").expect("matched above");
            let value: f64 = value.trim().parse().expect("a number in the lab rig");
            format!("{key} = {:?}", value * factor)
        })
        .collect();
    RigSource::from_text(&scaled.join("\n"), "test:lightstage-lab").expect("lab rig parses")
}

/// A short tour: homing, moves both ways (backlash take-up), two lamps, an HDR bracket and a
/// laser sweep, so every device and every kind of step crosses the wire.
const TOUR: &str = r#"
home();
lamps_off();
move_to(#{turntable: 30.0, light_arc: 45.0});
only_lamp("lamp1");
capture(0.01);
move_to(#{turntable: 10.0, light_arc: 20.0});
only_lamp("lamp2");
capture([0.01, 0.03]);
lamps_off();
laser_arm();
laser_on(laser_fitted());
laser_sweep(#{from_deg: -1.0, to_deg: 1.0, lines: 2, rate_hz: 7.5, exposure_s: 0.002});
laser_off();
laser_disarm();
home();
"#;

fn run_emulated(
    script: ScriptSource,
    overrides: &[(&str, &str)],
    faults: &[(&str, Arc<Faults>)],
    out: &Path,
) -> Outcome {
    let links = tempfile::tempdir().expect("link dir");
    let mut emulation = Emulation::new(links.path());
    for (port, f) in faults {
        emulation.faults.insert(port.to_string(), f.clone());
    }
    let prepared = session::prepare(script, &common::sets(overrides), lab_rig(48, 36))
        .expect("script prepares");
    run_prepared_with(
        prepared,
        out,
        5,
        Arc::new(AutoConfirm),
        RunControl::new(),
        Some(emulation),
    )
}

fn tour() -> ScriptSource {
    ScriptSource {
        name: "tour.rhai".into(),
        text: TOUR.into(),
    }
}

/// Raw frames of two runs are the same frames, pixel for pixel.
fn assert_same_frames(a: &Path, b: &Path) {
    let (fa, fb) = (raw_pixels(a), raw_pixels(b));
    assert_eq!(
        fa.iter().map(|(p, _)| p).collect::<Vec<_>>(),
        fb.iter().map(|(p, _)| p).collect::<Vec<_>>()
    );
    for ((p, x), (_, y)) in fa.iter().zip(&fb) {
        assert!(
            x == y,
            "{p}: pixels differ between {} and {}",
            a.display(),
            b.display()
        );
    }
}

fn frame_count(dir: &Path) -> i64 {
    db(dir)
        .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
        .expect("count")
}

/// (camera, trigger id) of every frame is unique: nothing was recorded twice.
fn assert_no_duplicates(dir: &Path) {
    let dups: i64 = db(dir)
        .query_row(
            "SELECT COUNT(*) FROM (SELECT camera, trigger_id, kind FROM frames
             GROUP BY camera, trigger_id, kind HAVING COUNT(*) > 1)",
            [],
            |r| r.get(0),
        )
        .expect("query");
    assert_eq!(dups, 0, "duplicated frames in {}", dir.display());
}

fn assert_done(o: &Outcome) {
    match &o.result {
        Ok(s) => {
            assert_eq!(s.status, RunStatus::Done, "{s:?}");
            assert!(
                s.safety_violations.is_empty(),
                "motion during exposure: {:?}",
                s.safety_violations
            );
        }
        Err(e) => panic!("run failed: {e}\nevents: {:#?}", o.events),
    }
}

fn faults_seen(o: &Outcome) -> Vec<(String, String)> {
    o.events
        .iter()
        .filter_map(|e| match e {
            Event::DeviceFault {
                device, message, ..
            } => Some((device.clone(), message.clone())),
            _ => None,
        })
        .collect()
}

/// The undisturbed tour through the emulators, run once per test binary.
fn clean_tour() -> &'static std::path::PathBuf {
    static CLEAN: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    CLEAN.get_or_init(|| {
        let out = common::static_dir("clean-tour");
        let o = run_emulated(tour(), &[], &[], &out);
        assert_done(&o);
        assert!(faults_seen(&o).is_empty(), "{:?}", faults_seen(&o));
        o.dir
    })
}

/// Runs the tour with `fault` injected on `port`, checks it fired, paused the run with an
/// error naming `device`, and that the dataset equals the undisturbed one byte for byte.
fn tour_survives(port: &str, fault: Fault, devices: &[&str]) {
    let clean_dir = clean_tour();
    let faults = Faults::new([fault.clone()]);
    let out = tempfile::tempdir().expect("out");
    let o = run_emulated(tour(), &[], &[(port, faults.clone())], out.path());
    assert!(faults.all_fired(), "{fault:?} never fired");
    assert_done(&o);
    let seen = faults_seen(&o);
    assert!(
        seen.iter().any(|(d, _)| devices.contains(&d.as_str())),
        "expected a fault naming one of {devices:?}, saw {seen:?}"
    );
    assert!(
        o.events
            .iter()
            .any(|e| matches!(e, Event::Recovered { .. })),
        "no recovery event"
    );
    assert_no_duplicates(&o.dir);
    assert_eq!(frame_count(&o.dir), frame_count(clean_dir));
    assert_same_frames(&o.dir, clean_dir);
}

#[test]
fn tour_through_emulators_matches_the_simulated_rig_byte_for_byte() {
    let _turn = crate::grbl_peer::alongside();
    let dir = clean_tour();
    assert_no_duplicates(dir);
    // The same tour on the simulated devices (virtual clock, no bytes) records the same frames:
    // the emulators move the same world, and hardware-triggered frames get the same ids.
    let out = tempfile::tempdir().expect("out");
    let rig = common::small_rig("lightstage", 48, 36);
    let prepared = session::prepare(tour(), &[], rig).expect("prepares");
    let sim = common::run_prepared(
        prepared,
        out.path(),
        5,
        Arc::new(AutoConfirm),
        RunControl::new(),
    );
    assert_done(&sim);
    assert_eq!(frame_count(dir), frame_count(&sim.dir));
    assert!(frame_count(dir) > 0);
    assert_same_frames(dir, &sim.dir);
}

#[test]
fn grbl_disconnect_mid_move_reconnects_and_rehomes() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(
        GRBL_PORT,
        Fault::Disconnect {
            after_commands: 6,
            for_s: 1.0,
        },
        GRBL_AXES,
    );
}

#[test]
fn grbl_garbage_is_a_protocol_error_and_recovers() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(
        GRBL_PORT,
        Fault::Garbage {
            after_commands: 5,
            bytes: b"\x00\xff<Idle|MPos:1.0,zz\r\n@@@@\r\n".to_vec(),
        },
        GRBL_AXES,
    );
}

#[test]
fn grbl_dropped_reply_times_out_and_recovers() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(GRBL_PORT, Fault::DropReply { nth_command: 6 }, GRBL_AXES);
}

#[test]
fn grbl_alarm_during_a_move_rehomes() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(
        GRBL_PORT,
        Fault::AlarmDuringMove {
            nth_move: 1,
            code: 1,
        },
        GRBL_AXES,
    );
}

#[test]
fn relay_board_reset_restores_the_lamps() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(
        RELAY_PORT,
        Fault::BoardReset { after_commands: 26 },
        &["lamps"],
    );
}

#[test]
fn stalled_camera_is_a_missing_frame_and_the_step_is_retaken() {
    let _turn = crate::grbl_peer::alongside();
    tour_survives(
        GRBL_PORT,
        Fault::StallCamera {
            camera: "cam3".into(),
            frames: 1,
        },
        &["cam3"],
    );
}

#[test]
fn slow_replies_within_the_timeout_are_no_fault() {
    let _turn = crate::grbl_peer::alongside();
    let faults = Faults::new([Fault::SlowReply {
        nth_command: 4,
        delay_s: 0.3,
    }]);
    let out = tempfile::tempdir().expect("out");
    let o = run_emulated(tour(), &[], &[(RELAY_PORT, faults.clone())], out.path());
    assert!(faults.all_fired());
    assert_done(&o);
    assert!(faults_seen(&o).is_empty(), "{:?}", faults_seen(&o));
}

#[test]
fn quickstart_runs_with_every_serial_device_a_real_driver() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().expect("out");
    let script = ScriptSource::from_file(&root().join("sequences/quickstart.rhai")).unwrap();
    let o = run_emulated(script, &[], &[], out.path());
    assert_done(&o);
    assert!(faults_seen(&o).is_empty(), "{:?}", faults_seen(&o));
    assert_no_duplicates(&o.dir);
    let raw: i64 = db(&o.dir)
        .query_row("SELECT COUNT(*) FROM frames WHERE kind = 'raw'", [], |r| {
            r.get(0)
        })
        .expect("count");
    assert_eq!(raw, 72);
}
