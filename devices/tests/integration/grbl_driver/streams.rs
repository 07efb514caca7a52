//! What goes over the wire: the exact bytes of each request (on the paused clock, and once
//! over a real pty), and the idle keepalive.

use std::time::Duration;

use stagehand_devices::axis::AxisDriver;
use stagehand_devices::grbl::{GrblAxis, GrblLaser};
use stagehand_devices::laser::LaserDriver;

use super::{Fake, Script, assert_near, axis, show};

/// Handshake, home, move, stop and laser; returns each request's bytes (see [`show`]) under
/// its name. Both tests below compare them with the one snapshot file
/// `snapshots/..._byte_streams.snap`, so the pty carries exactly the bytes the duplex does.
async fn handshake_home_move_stop_and_laser(fake: &Fake) -> String {
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let mut laser = GrblLaser::new(ctl.clone(), "laser");
    let mut streams = String::new();
    let mut record = |name: &str| streams += &format!("# {name}\n{}", show(&fake.take_bytes()));

    // The handshake (reset, banner, `$I`, `$$`, `?`), then the position's own `?`. Machine 5
    // is 5.998° before homing: the map puts 0° at machine −`$27` in whole steps (−0.998),
    // where homing ends.
    assert_near(x.position().await.unwrap(), 5.998);
    record("connect and position");

    assert_near(x.home().await.unwrap(), 0.0);
    record("home");

    assert_near(x.move_to(12.5).await.unwrap(), 12.5);
    record("move to 12.5°");

    // Nothing moving: a stop only reads the position (a feed hold and reset are for motion).
    assert_near(x.stop().await.unwrap(), 12.5);
    record("stop while idle");

    laser.set_emission(true, 520).await.unwrap();
    assert!(fake.laser_on());
    laser.set_emission(false, 520).await.unwrap();
    assert!(!fake.laser_on());
    record("laser on and off");
    streams
}

#[tokio::test(start_paused = true)]
async fn byte_streams_of_handshake_home_move_stop_and_laser() {
    let fake = Fake::start(Script::default());
    let streams = handshake_home_move_stop_and_laser(&fake).await;
    insta::assert_snapshot!("byte_streams", streams);
}

/// The serial path: the same requests and bytes through a real pseudo-terminal, on the real
/// clock (no timing asserted: it completes).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn smoke_test_over_a_real_pty() {
    let fake = Fake::start_on_pty(Script::default());
    let streams = handshake_home_move_stop_and_laser(&fake).await;
    insta::assert_snapshot!("byte_streams", streams);
}

#[tokio::test(start_paused = true)]
async fn the_keepalive_polls_only_while_idle_and_enabled() {
    let fake = Fake::start(Script::default());
    let ctl = fake.controller();
    ctl.set_keepalive(true);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.position().await.unwrap();
    fake.take_bytes();
    // A `?` every 0.5 s after the last exchange: at 0.5 s and 1.0 s.
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let polls = fake.take_bytes().iter().filter(|b| **b == b'?').count();
    assert_eq!(polls, 2, "{polls} keepalive polls in 1.3 s");
    ctl.set_keepalive(false);
    tokio::time::sleep(Duration::from_millis(700)).await;
    assert!(fake.take_bytes().is_empty());
}
