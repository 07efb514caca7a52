//! The GRBL driver against the real GRBL 1.1h firmware (stock and single-axis-homing builds,
//! `grbl_peer`) and against the emulator, with the same scenario: connect (`$I`/`$$` checks),
//! home, move every axis with read-back, stop mid-move, switch the laser on and off verified
//! from the status report, a soft-limit alarm and its recovery, and (on the real board) a port
//! that disappears and comes back. Settings that cannot work for the rig are refused at
//! connect with the `$N=` to send.

use crate::grbl_peer;

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use grbl_peer::{Board, Build, FAST};
use stagehand_devices::axis::{AxisDriver, AxisHandle};
use stagehand_devices::clock::RigClock;
use stagehand_devices::grbl::codec::Command;
use stagehand_devices::grbl::{GrblAxis, GrblController, GrblLaser};
use stagehand_devices::laser::LaserDriver;
use stagehand_devices::rig::{AxisSpec, BUILTIN_LIGHTSTAGE, GRBL_BAUD, parse_rig};
use stagehand_devices::{DeviceError, DeviceErrorKind};
use stagehand_simulator::World;
use stagehand_simulator::emulators::grbl::GrblBuild;
use stagehand_simulator::emulators::{Faults, GrblEmulator};

/// The light stage's three axes placed in GRBL's negative machine space: the turntable and
/// the arc (0…300°) run toward −machine from home at 0°, the tilt (−30…30°) homes at +30°.
fn rig_axes() -> Vec<AxisSpec> {
    let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
    rig.axes
        .iter()
        .zip(["X", "Y", "Z"])
        .map(|(a, l)| {
            let tilt = l == "Z";
            AxisSpec {
                controller_axis: Some(l.into()),
                steps_per_deg: 142.222,
                speed_deg_s: 30.0,
                accel_deg_s2: 600.0, // the boards' FAST
                homing_speed_deg_s: 40.0,
                min_deg: if tilt { -30.0 } else { 0.0 },
                max_deg: if tilt { 30.0 } else { 300.0 },
                home_deg: if tilt { 30.0 } else { 0.0 },
                machine_sign: if tilt { 1.0 } else { -1.0 },
                backlash_deg: 0.05,
                settle_s: 0.0,
                ..a.clone()
            }
        })
        .collect()
}

/// The rig's axes and laser on the controller at `port`.
struct Rig {
    ctl: Arc<GrblController>,
    axes: Vec<AxisHandle>,
    laser: GrblLaser,
}

fn open(port: &Path) -> Rig {
    let specs = rig_axes();
    let ctl = GrblController::new(
        "grbl",
        &port.display().to_string(),
        GRBL_BAUD,
        specs.clone(),
    );
    let laser = GrblLaser::new(ctl.clone(), "laser");
    let axes = specs
        .iter()
        .map(|s| {
            let driver = GrblAxis::new(ctl.clone(), s).expect("axis");
            // Room for a stock `$H` homing all three axes.
            AxisHandle::spawn_shared(s.clone(), driver, 60.0)
        })
        .collect();
    Rig { ctl, axes, laser }
}

fn near(a: f64, b: f64) -> bool {
    (a - b).abs() < 0.01
}

/// The scenario every target must pass. `unplug` powers the board off and on again.
async fn scenario(rig: &mut Rig, unplug: Option<&mut dyn FnMut(bool)>) {
    let [tt, arc, tilt] = [&rig.axes[0], &rig.axes[1], &rig.axes[2]];
    // Not homed after connecting: no move at an unverified position.
    let e = tt.position().await.map(|_| ()).and(Ok(()));
    assert!(e.is_ok(), "position reads before homing: {e:?}");
    assert!(matches!(
        tt.move_to(10.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::NotHomed,
            ..
        })
    ));
    for (axis, home) in [(tt, 0.0), (arc, 0.0), (tilt, 30.0)] {
        let p = axis.home().await.expect("home");
        assert!(near(p, home), "{} homed at {p}, expected {home}", axis.id());
    }
    // Every axis moves, and reads back where it went (tilt approaches from below).
    for (axis, target) in [(tt, 20.0), (arc, 10.5), (tilt, 20.0), (tilt, 12.25)] {
        let p = axis.move_to(target).await.expect("move");
        assert!(near(p, target), "{} at {p}, wanted {target}", axis.id());
        let r = axis.position().await.expect("read back");
        assert!(near(r, target), "{} reads {r}, wanted {target}", axis.id());
    }
    // Laser: confirmed on and off from the status report.
    rig.laser.set_emission(true, 650).await.expect("laser on");
    rig.laser.set_emission(false, 650).await.expect("laser off");
    // Stop mid-move: the position is kept (feed hold, then reset in Hold:0).
    let mover = tt.clone();
    let moving = tokio::spawn(async move { mover.move_to(280.0).await });
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let stopped = tt.stop().await.expect("stop");
    assert!(stopped > 21.0 && stopped < 279.0, "stopped at {stopped}");
    assert!(moving.await.expect("join").is_err());
    assert!(rig.ctl.is_homed('X').await, "a stop keeps the position");
    let p = tt.move_to(25.0).await.expect("move after stop");
    assert!(near(p, 25.0), "{p}");
    // A soft-limit alarm (machine +5 is beyond 0): typed, loses homing, recovered by a reset
    // and a new homing cycle.
    let e = rig
        .ctl
        .command(
            "turntable",
            Command::Move {
                axis: 'X',
                machine: 5.0,
            },
            2.0,
        )
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Alarm { code: 2, .. },
                ..
            }
        ),
        "soft limit: {e}"
    );
    assert!(!rig.ctl.is_homed('X').await);
    let r = tt.move_to(10.0).await;
    assert!(
        matches!(
            r,
            Err(DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            })
        ),
        "{r:?}"
    );
    // Recovery: a new homing cycle. On the real board it follows a power cycle (the port
    // disappears and comes back: a typed error naming the axis, then a reconnect that requires
    // homing), because the peer's simulated switches do not survive a second homing cycle on
    // one power-on (`patches/homing-switches.diff`; `$H`, `G53 G0 X-2`, `$H` ends in ALARM:8
    // on the peer alone, measured).
    if let Some(unplug) = unplug {
        unplug(false);
        let e = tt.position().await.unwrap_err();
        assert!(e.is_recoverable(), "{e}");
        assert!(e.to_string().contains("turntable"), "{e}");
        unplug(true);
        let mut reconnected = tt.position().await;
        for _ in 0..3 {
            if reconnected.is_ok() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(500)).await;
            reconnected = tt.position().await;
        }
        reconnected.expect("reconnected");
        assert!(
            !rig.ctl.is_homed('X').await,
            "a new connection is not homed"
        );
    }
    let p = tt.home().await.expect("home after the alarm");
    assert!(near(p, 0.0), "{p}");
    let p = tt.move_to(5.0).await.expect("move after the alarm");
    assert!(near(p, 5.0), "{p}");
}

fn on_real(build: Build) {
    let _one_at_a_time = grbl_peer::exclusive();
    // grbl-sim simulates the AVR in real time and now and then loses motion under load (a move
    // that never ends, a feed hold that does not settle before the reset): a failure counts
    // only if fresh boards show it three times in a row (the clean-clone CI of c2a8d6c saw two
    // such losses in a row; the scenario passes alone).
    for attempt in 1..=2 {
        if std::panic::catch_unwind(|| on_real_board(build)).is_ok() {
            return;
        }
        eprintln!("retrying the scenario on a fresh board (attempt {attempt} failed)");
    }
    on_real_board(build);
}

/// The scenario on one freshly powered board.
fn on_real_board(build: Build) {
    let Some(mut board) = Board::start(build, FAST) else {
        return;
    };
    let rt = grbl_peer::runtime();
    rt.block_on(async {
        let mut rig = open(&board.link);
        let build_info = {
            rig.axes[0].position().await.expect("connect");
            rig.ctl.build_info().await
        };
        assert_eq!(build_info.version, "1.1h.20190830");
        assert_eq!(build_info.single_axis_homing(), build == Build::SingleAxis);
        let mut unplug = |on: bool| {
            if on {
                board.power_on_again();
            } else {
                board.power_off();
            }
        };
        scenario(&mut rig, Some(&mut unplug)).await;
    });
}

#[test]
fn the_driver_runs_a_stock_grbl_1_1h() {
    on_real(Build::Stock);
}

#[test]
fn the_driver_runs_a_grbl_1_1h_with_single_axis_homing() {
    on_real(Build::SingleAxis);
}

#[test]
fn the_driver_runs_the_emulator_the_same_way() {
    let _turn = grbl_peer::alongside();
    let rt = grbl_peer::runtime();
    rt.block_on(async {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
        rig.axes = rig_axes();
        let axes = rig.axes.clone();
        let world = World::new(Arc::new(rig), RigClock::starting_at(0.0), 1).expect("world");
        let settings = grbl_peer::settings(FAST);
        let h = GrblEmulator::spawn_with(
            world.clone(),
            &axes,
            dir.path(),
            "grbl",
            Faults::none(),
            GrblBuild {
                single_axis_homing: false,
                settings,
            },
        )
        .expect("emulator");
        let mut r = open(h.path());
        scenario(&mut r, None).await;
        // The World followed the emulated axes.
        let t = world.clock().now_s();
        assert!(near(world.snapshot_at(t).axes["turntable"], 5.0));
    });
}

/// Settings that cannot work for the rig are refused at connect, naming what to send.
#[test]
fn wrong_settings_are_refused_at_connect_with_the_setting_to_send() {
    let _one_at_a_time = grbl_peer::exclusive();
    for (extra, want) in [
        ("$32=1", "`$32=0`"),
        ("$130=100", "`$130=302.000`"),
        ("$101=80", "`$101=142.222`"),
        ("$22=0", "`$22=1`"),
    ] {
        // grbl-sim now and then garbles a reply under load (`$2=0h` while the driver reads
        // `$$`; the case passes alone): a failure counts only if three fresh boards show it.
        let passed = (1..3).any(|attempt| {
            let ok = std::panic::catch_unwind(|| refused_at_connect(extra, want)).is_ok();
            if !ok {
                eprintln!("{extra}: retrying on a fresh board (attempt {attempt} failed)");
            }
            ok
        });
        if !passed {
            refused_at_connect(extra, want);
        }
    }
}

/// A fresh stock board with the setting `extra` refuses the driver at connect, naming the
/// setting to send (`want`) and the port.
fn refused_at_connect(extra: &str, want: &str) {
    let Some(board) = Board::start(Build::Stock, extra) else {
        return;
    };
    let rt = grbl_peer::runtime();
    rt.block_on(async {
        let rig = open(&board.link);
        let e = rig.axes[0].home().await.unwrap_err();
        assert!(
            matches!(
                e,
                DeviceError {
                    kind: DeviceErrorKind::Misconfigured { .. },
                    ..
                }
            ),
            "{extra}: {e}"
        );
        let text = e.to_string();
        assert!(text.contains(want), "{extra}: {text}");
        assert!(text.contains(&board.link.display().to_string()), "{text}");
    });
}

/// A GRBL axis through the driver trait directly (no handle): homing a stock board once
/// homes every axis, and a second axis asking to home is already home.
#[test]
fn a_stock_board_homes_all_axes_once() {
    let _one_at_a_time = grbl_peer::exclusive();
    let Some(board) = Board::start(Build::Stock, FAST) else {
        return;
    };
    let rt = grbl_peer::runtime();
    rt.block_on(async {
        let specs = rig_axes();
        let ctl = GrblController::new(
            "grbl",
            &board.link.display().to_string(),
            GRBL_BAUD,
            specs.clone(),
        );
        let mut x = GrblAxis::new(ctl.clone(), &specs[0]).expect("x");
        let mut y = GrblAxis::new(ctl.clone(), &specs[1]).expect("y");
        x.home().await.expect("home x");
        assert!(ctl.is_homed('Y').await && ctl.is_homed('Z').await);
        // Lines sent to the firmware, as the traffic log records them.
        let homings = || board.traffic().matches("> b'$H\\n'").count();
        let before = homings();
        y.home().await.expect("home y");
        assert_eq!(homings(), before, "no second $H");
        assert_eq!(before, 1, "one `$H` for all axes:\n{}", board.traffic());
    });
}

/// A homing switch that never triggers (`$130=2`: the seek ends 3 units out, the switch is 5
/// away): a typed error naming the axis and the settings to check, no hang, and no move
/// afterwards at an unverified position.
#[test]
fn a_homing_switch_that_never_triggers_is_a_typed_error() {
    let _one_at_a_time = grbl_peer::exclusive();
    let Some(board) = Board::start(Build::SingleAxis, "$20=0 $130=2") else {
        return;
    };
    let rt = grbl_peer::runtime();
    rt.block_on(async {
        let rig = open(&board.link);
        let e = rig.axes[0].home().await.unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(
                e,
                DeviceError {
                    kind: DeviceErrorKind::HomingFailed { code: 9, .. },
                    ..
                }
            ),
            "{text}\n{}",
            board.traffic()
        );
        for needle in ["turntable", "$HX", "$5", "$23", "$25", "$13x"] {
            assert!(text.contains(needle), "{needle} missing: {text}");
        }
        assert!(matches!(
            rig.axes[0].move_to(10.0).await,
            Err(DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            })
        ));
    });
}
