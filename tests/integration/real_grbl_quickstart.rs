//! The quickstart on a hybrid rig (all but its closing `home()`, see below): the turntable, the light arc, the laser tilt and the
//! laser on the real GRBL 1.1h firmware (`simulator/tests/integration/grbl_peer`, a stock build on a pty,
//! through the real driver), the lamps, trigger and cameras simulated. The simulated cameras
//! render the World at the positions the real axes report, so every frame must match the same
//! quickstart on the all-simulated rig, and the laser frames must show the laser the real
//! board switched on.

use crate::grbl_peer;

use crate::common;

use std::path::Path;
use std::sync::Arc;

use grbl_peer::{Board, Build};
use stagehand::executor::{AutoConfirm, Event, RunControl};
use stagehand::rig::RigSource;
use stagehand::script::ScriptSource;
use stagehand::session;
use stagehand::storage::RunStatus;

use common::{db, raw_pixels, root, run_prepared_with};

/// The board set up for the rig below: each axis's speed, acceleration and travel.
const BOARD: &str = "$110=3600 $111=2400 $112=1200 $120=600 $121=600 $122=600 \
    $130=365 $131=365 $132=65";

/// The built-in rig's axis speeds and accelerations, and the test's: twice the speed and the
/// boards' fast acceleration (`grbl_peer::FAST`), so the real board's run takes half the rig
/// time (grbl-sim simulates it in real time, with the rest of the test binary waiting).
const MOTION: [(&str, &str); 3] = [
    (
        "speed_deg_s = 30.0\naccel_deg_s2 = 60.0",
        "speed_deg_s = 60.0\naccel_deg_s2 = 600.0",
    ),
    (
        "speed_deg_s = 20.0\naccel_deg_s2 = 40.0",
        "speed_deg_s = 40.0\naccel_deg_s2 = 600.0",
    ),
    (
        "speed_deg_s = 10.0\naccel_deg_s2 = 200.0",
        "speed_deg_s = 20.0\naccel_deg_s2 = 600.0",
    ),
];

/// The quickstart without its closing `home()`: the peer's simulated homing switches
/// (`patches/homing-switches.diff`) do not survive a second homing cycle on one power-on (on
/// the peer alone, `$H`, `G53 G0 X-2`, `$H` ends in `ALARM:8`; measured), so only the real
/// board's first homing is part of this run.
fn quickstart_without_closing_home() -> ScriptSource {
    let text =
        std::fs::read_to_string(root().join("sequences/quickstart.rhai")).expect("quickstart");
    let cut = text.rfind("home();").expect("a closing home()");
    ScriptSource {
        name: "quickstart.rhai".into(),
        text: format!("{}{}", &text[..cut], &text[cut + "home();".len()..]),
    }
}

/// The built-in light stage with small cameras and faster axes ([`MOTION`]); with `link`, its axes and laser on the GRBL
/// board there. The turntable and arc run 0…360° homed at 0° (machine −1…−361), the tilt
/// −30…30° homed at +30° (machine −61…−1), so GRBL's soft limits hold.
fn rig(link: Option<&Path>) -> RigSource {
    let text =
        std::fs::read_to_string(root().join("devices/rigs/lightstage.toml")).expect("rig file");
    let mut text = text
        .replace("width = 1024", "width = 64")
        .replace("height = 768", "height = 48")
        .replacen("min_deg = -180.0", "min_deg = 0.0", 2);
    for (built_in, fast) in MOTION {
        assert!(
            text.contains(built_in),
            "the built-in rig's motion changed: {built_in}"
        );
        text = text.replace(built_in, fast);
    }
    let grbl = |letter: &str, home: f64, sign: f64| match link {
        Some(l) => format!(
            "backend = \"grbl\"\nport = \"{}\"\ncontroller_axis = \"{letter}\"\nsteps_per_deg = 142.222\nhome_deg = {home:.1}\nmachine_sign = {sign:.1}",
            l.display()
        ),
        None => format!(
            "backend = \"sim\"\nsteps_per_deg = 142.222\nhome_deg = {home:.1}\nmachine_sign = {sign:.1}"
        ),
    };
    for (id, letter, home, sign) in [
        ("turntable", "X", 0.0, -1.0),
        ("light_arc", "Y", 0.0, -1.0),
        ("laser_tilt", "Z", 30.0, 1.0),
    ] {
        text = text.replace(
            &format!("id = \"{id}\"\nbackend = \"sim\""),
            &format!("id = \"{id}\"\n{}", grbl(letter, home, sign)),
        );
    }
    if let Some(l) = link {
        text = text.replace(
            "id = \"laser\"\nbackend = \"sim\"",
            &format!(
                "id = \"laser\"\nbackend = \"grbl\"\nport = \"{}\"",
                l.display()
            ),
        );
    }
    RigSource::from_text(&text, "test:lightstage-grbl").expect("rig parses")
}

fn run(rig: RigSource, out: &Path) -> common::Outcome {
    let prepared = session::prepare(quickstart_without_closing_home(), &[], rig).expect("prepares");
    run_prepared_with(
        prepared,
        out,
        5,
        Arc::new(AutoConfirm),
        RunControl::new(),
        None,
    )
}

#[test]
fn quickstart_runs_on_the_real_grbl_firmware() {
    let _one_at_a_time = grbl_peer::exclusive();
    // grbl-sim simulates the AVR in real time and now and then garbles a reply under load
    // (seen once: a status report that lost its first bytes, then a second homing the peer's
    // switches do not survive; in the clean-clone CI of 89378d6 a homing and then a status
    // report that never came, twice in a row): a failure counts only if fresh boards show it
    // three times in a row.
    for attempt in 1..=2 {
        if std::panic::catch_unwind(quickstart_on_a_fresh_board).is_ok() {
            return;
        }
        eprintln!("retrying the quickstart on a fresh board (attempt {attempt} failed)");
    }
    quickstart_on_a_fresh_board();
}

/// The quickstart on a freshly powered board, checked frame by frame against the simulated
/// rig.
fn quickstart_on_a_fresh_board() {
    let Some(board) = Board::start(Build::Stock, BOARD) else {
        return;
    };
    let out = tempfile::tempdir().expect("out");
    let started = std::time::Instant::now();
    let real = run(rig(Some(&board.link)), out.path());
    let wall_s = started.elapsed().as_secs_f64();
    let summary = match &real.result {
        Ok(s) => s.clone(),
        // The faults go last: CI shows the tail of a long failure message.
        Err(e) => panic!(
            "run failed: {e}\nevents: {:#?}\ntraffic:\n{}\nfaults: {:#?}\nrun failed: {e}",
            real.events,
            board.traffic(),
            real.events
                .iter()
                .filter(|e| matches!(e, Event::DeviceFault { .. }))
                .collect::<Vec<_>>(),
        ),
    };
    assert_eq!(summary.status, RunStatus::Done, "{summary:?}");
    assert!(summary.safety_violations.is_empty(), "{summary:?}");
    let faults: Vec<&Event> = real
        .events
        .iter()
        .filter(|e| matches!(e, Event::DeviceFault { .. }))
        .collect();
    assert!(faults.is_empty(), "{faults:#?}");
    eprintln!(
        "quickstart on real GRBL 1.1h: {}/{} steps, {} frames, rig time {:.1} s against an estimate of {:.1} s ({:.1} s wall)",
        summary.steps_done,
        summary.steps_total,
        summary.frames_written,
        summary.rig_time_s,
        summary.estimated_rig_time_s,
        wall_s
    );
    // The laser frames were taken with the laser the real board switched on (and confirmed).
    let laser_frames: i64 = db(&real.dir)
        .query_row(
            "SELECT COUNT(*) FROM frames WHERE kind = 'raw' AND laser_on = 1",
            [],
            |r| r.get(0),
        )
        .expect("count");
    assert!(laser_frames >= 8, "{laser_frames} laser frames");
    // Every frame is the frame the all-simulated rig renders at the same positions: the
    // cameras saw what the real axes did.
    let sim_out = tempfile::tempdir().expect("out");
    let sim = run(rig(None), sim_out.path());
    assert!(sim.result.is_ok(), "{:?}", sim.result.err());
    let (a, b) = (raw_pixels(&real.dir), raw_pixels(&sim.dir));
    assert_eq!(a.len(), b.len());
    assert_eq!(a.len(), 72);
    for ((p, x), (_, y)) in a.iter().zip(&b) {
        let diff = x
            .iter()
            .zip(y)
            .map(|(u, v)| (*u as f64 - *v as f64).abs())
            .sum::<f64>()
            / x.len() as f64;
        assert!(
            diff < 1.0,
            "{p}: mean difference {diff} DN from the simulated rig"
        );
    }
}

/// `stagehand devices --check --rig RIG` against the real board: `ok` and exit 0 for a board
/// set up for the rig; exit 1 naming the `$N=` to send for one that is not.
#[test]
fn devices_check_reports_a_board_fit_or_the_settings_to_send() {
    let _one_at_a_time = grbl_peer::exclusive();
    for (extra, fit, want) in [
        ("", true, "ok: fit for the rig"),
        ("$32=1", false, "`$32=0`"),
    ] {
        let Some(board) = Board::start(Build::SingleAxis, &format!("{BOARD} {extra}")) else {
            return;
        };
        let dir = tempfile::tempdir().expect("dir");
        let rig_file = dir.path().join("rig.toml");
        std::fs::write(&rig_file, rig(Some(&board.link)).text).expect("write rig");
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_stagehand"))
            .args(["devices", "--check", "--rig"])
            .arg(&rig_file)
            .output()
            .expect("run stagehand");
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(out.status.success(), fit, "{extra}: {text}");
        assert!(text.contains(want), "{extra}: {text}");
        assert!(
            text.contains("GRBL board on") && text.contains("turntable"),
            "{text}"
        );
        assert!(
            text.contains("no watchdog"),
            "the GRBL laser has none: {text}"
        );
        if fit {
            assert!(
                text.contains("1.1h.20190830") && text.contains("single-axis homing"),
                "{text}"
            );
        }
    }
}
