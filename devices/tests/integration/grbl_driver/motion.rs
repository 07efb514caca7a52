//! Homing and moves: through the axis handle, two axes queued on one controller, an alarm
//! mid-move, a stop mid-move. The fake's motion runs on the paused clock, so where a move is
//! at a given instant is exact.

use std::sync::Arc;
use std::time::Duration;

use stagehand_devices::axis::{AxisDriver, AxisHandle};
use stagehand_devices::grbl::{GrblAxis, GrblController};
use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::time::Instant;

use super::{Fake, Script, assert_near, axis};

#[tokio::test(start_paused = true)]
async fn homes_moves_and_reports_positions_through_the_axis_handle() {
    let fake = Fake::start(Script {
        speed: 200.0,
        ..Script::default()
    });
    let ctl = fake.controller();
    ctl.set_keepalive(true);
    let spec = axis("turntable", "X");
    let mut x = GrblAxis::new(ctl.clone(), &spec).unwrap();
    let e = x.move_to(10.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { device, kind: DeviceErrorKind::NotHomed } if device == "turntable"),
        "{e}"
    );
    assert!(!ctl.is_homed('X').await);

    let handle = AxisHandle::spawn(spec, x);
    assert_near(handle.home().await.unwrap(), 0.0);
    assert!(ctl.is_homed('X').await && !ctl.is_homed('Y').await);
    let t0 = Instant::now();
    let p = handle.move_to(40.0).await.unwrap();
    assert!((p - 40.0).abs() < 1e-3, "{p}");
    // The fake takes 40° / 200°/s = 0.2 s: the driver waited for the move to finish, not just
    // for `ok`, and saw it at its first status poll (every 0.1 s) after the end.
    let took = t0.elapsed();
    assert!(
        took >= Duration::from_millis(200) && took <= Duration::from_millis(300),
        "{took:?}"
    );
    assert!((handle.position().await.unwrap() - 40.0).abs() < 1e-3);
    let p = handle.move_to(12.345).await.unwrap();
    assert!((p - 12.345).abs() < 1e-3, "{p}");
}

#[tokio::test(start_paused = true)]
async fn two_axes_queue_their_moves_on_one_controller() {
    let fake = Fake::start(Script {
        speed: 300.0,
        ..Script::default()
    });
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let mut y = GrblAxis::new(ctl.clone(), &axis("arc", "Y")).unwrap();
    x.home().await.unwrap();
    y.home().await.unwrap();
    let (px, py) = tokio::join!(x.move_to(60.0), y.move_to(90.0));
    assert!((px.unwrap() - 60.0).abs() < 1e-3);
    assert!((py.unwrap() - 90.0).abs() < 1e-3);
    let s = ctl.status("test").await.unwrap();
    // The status is in machine coordinates: 60° and 90° are machine 59.002 and 89.002 (home
    // at −0.998, the pull-off of 1 in whole steps).
    assert_eq!(&s.pos[..2], &[59.002, 89.002]);
}

#[tokio::test(start_paused = true)]
async fn an_alarm_during_a_move_loses_the_homing() {
    let fake = Fake::start(Script {
        speed: 200.0,
        ..Script::default()
    });
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    fake.script().alarm_on_move = Some(1);
    let e = x.move_to(100.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::HardLimit { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.is_recoverable());
    assert!(!ctl.is_homed('X').await);
    let e = x.move_to(10.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            }
        ),
        "{e}"
    );

    x.home().await.unwrap();
    fake.script().alarm_on_move = Some(2);
    let e = x.move_to(100.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Alarm { code: 2, meaning, .. }, .. } if meaning.contains("Soft limit")),
        "{e}"
    );
    x.home().await.unwrap();
    assert_near(x.move_to(10.0).await.unwrap(), 10.0);
}

#[tokio::test(start_paused = true)]
async fn stop_during_a_move_keeps_the_position() {
    let fake = Fake::start(Script {
        speed: 100.0,
        ..Script::default()
    });
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    let mut mover = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let moving = tokio::spawn(async move { mover.move_to(100.0).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let p = x.stop().await.unwrap();
    // Stopped on the way, where 0.3 s at 100°/s from 0° took it.
    assert_near(p, 30.0);
    let e = moving.await.unwrap().unwrap_err();
    assert!(e.to_string().contains("interrupted"), "{e}");
    // The reset came in Hold:0: still homed, the position is where it stopped.
    assert!(ctl.is_homed('X').await);
    assert_near(x.position().await.unwrap(), p);
    assert!((x.move_to(p + 5.0).await.unwrap() - (p + 5.0)).abs() < 1e-3);
}

/// Starts a long move (10°/s towards 300°) on a fake whose feed hold takes `decel_s` to bring
/// the axis to rest, stops it after 2 s, and returns the fake, the controller and the stopped position.
async fn stop_on_a_slow_hold(decel_s: f64) -> (Fake, Arc<GrblController>, f64) {
    let fake = Fake::start(Script {
        speed: 10.0,
        hold_decel_s: decel_s,
        ..Script::default()
    });
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    let mut mover = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let moving = tokio::spawn(async move { mover.move_to(300.0).await });
    tokio::time::sleep(Duration::from_secs(2)).await;
    let p = x.stop().await.unwrap();
    assert!(moving.await.unwrap().is_err());
    (fake, ctl, p)
}

#[tokio::test(start_paused = true)]
async fn a_stop_waits_for_a_hold_that_is_still_slowing_down() {
    // The axis' deceleration time is 30°/s ÷ 60°/s² × 1.5 + 1 s = 1.75 s; this board takes 3 s.
    let (_fake, ctl, p) = stop_on_a_slow_hold(3.0).await;
    // Reset in Hold:0, after the axis came to rest 3 s after the hold (at 10°/s from 20°).
    assert!(ctl.is_homed('X').await, "a slow hold keeps the position");
    assert_near(p, 50.0);
}

#[tokio::test(start_paused = true)]
async fn a_hold_that_never_ends_is_reset_after_four_deceleration_times() {
    let (_fake, ctl, p) = stop_on_a_slow_hold(60.0).await;
    // Reset while still moving, 4 × 1.75 s after the hold: GRBL's ALARM:3, homing lost.
    assert!(
        !ctl.is_homed('X').await,
        "a reset in motion loses the position"
    );
    assert!(p > 80.0 && p < 100.0, "stopped at {p}");
}
