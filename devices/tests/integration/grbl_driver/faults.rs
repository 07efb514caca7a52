//! What goes wrong: the wrong firmware or settings, `error:N`, garbage, a mute controller, an
//! unplugged port, an axis the controller does not serve.

use std::time::Duration;

use stagehand_devices::axis::AxisDriver;
use stagehand_devices::grbl::{GrblAxis, GrblController, GrblLaser};
use stagehand_devices::laser::LaserDriver;
use stagehand_devices::rig::GRBL_BAUD;
use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::time::Instant;

use super::{Fake, STEPS, Script, assert_near, axis};

#[tokio::test(start_paused = true)]
async fn a_wrong_banner_is_the_wrong_firmware() {
    let fake = Fake::start(Script {
        banner: "Grbl 0.9j ['$' for help]".into(),
        ..Script::default()
    });
    let mut x = GrblAxis::new(fake.controller(), &axis("turntable", "X")).unwrap();
    let e = x.position().await.unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Protocol { .. },
                ..
            }
        ),
        "{text}"
    );
    assert!(
        text.contains("wrong firmware banner `Grbl 0.9j") && text.contains("expected GRBL 1.1"),
        "{text}"
    );
    assert!(
        text.contains("turntable") && text.contains(&fake.path),
        "{text}"
    );
}

#[tokio::test(start_paused = true)]
async fn wrong_steps_per_degree_say_which_setting_to_change() {
    let fake = Fake::start(Script {
        steps: [STEPS, 80.0, 250.0],
        ..Script::default()
    });
    let mut y = GrblAxis::new(fake.controller(), &axis("arc", "Y")).unwrap();
    let e = y.home().await.unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Misconfigured { .. },
                ..
            }
        ),
        "{text}"
    );
    assert!(text.contains("`$101=142.222`"), "{text}");
    assert!(text.starts_with("arc:"), "{text}");
}

#[tokio::test(start_paused = true)]
async fn an_error_reply_is_rejected_with_its_meaning() {
    let fake = Fake::start(Script::default());
    let ctl = fake.controller();
    let mut laser = GrblLaser::new(ctl.clone(), "laser");
    // In Alarm after connecting: G-code is locked out.
    let e = laser.set_emission(true, 520).await.unwrap_err();
    assert_eq!(
        e,
        DeviceError::new(
            "laser",
            DeviceErrorKind::Rejected {
                command: "M3 S1000".into(),
                code: 9,
                meaning: "G-code lock".into()
            }
        )
    );
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    fake.script().reject_next = Some(20);
    let e = x.move_to(3.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Rejected { code: 20, command, .. }, .. } if command == "G53 G0 X2.002"),
        "{e}"
    );
    // The flow counter was freed by the error: the next line goes through.
    assert_near(x.move_to(3.0).await.unwrap(), 3.0);
}

#[tokio::test(start_paused = true)]
async fn garbage_resynchronises_and_the_position_is_unverified_afterwards() {
    let fake = Fake::start(Script::default());
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    x.move_to(20.0).await.unwrap();
    assert_eq!(fake.resets(), 1);
    fake.script().garbage_on_status = true;
    let e = x.position().await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Protocol { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("line noise"), "{e}");
    // The next request reconnects with a handshake (soft reset) ...
    assert_near(x.position().await.unwrap(), 20.0);
    assert_eq!(fake.resets(), 2);
    // ... and refuses to move at a position it has not verified.
    let e = x.move_to(30.0).await.unwrap_err();
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
    assert_near(x.move_to(30.0).await.unwrap(), 30.0);
}

#[tokio::test(start_paused = true)]
async fn a_status_report_cut_short_is_asked_again_without_a_reset() {
    let fake = Fake::start(Script::default());
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    x.move_to(20.0).await.unwrap();
    let resets = fake.resets();
    fake.script().cut_status = true;
    assert_near(x.position().await.unwrap(), 20.0);
    assert_eq!(fake.resets(), resets, "no reconnect");
    // The position stays verified: the axis moves on without homing again.
    assert_near(x.move_to(30.0).await.unwrap(), 30.0);
}

#[tokio::test(start_paused = true)]
async fn a_mute_controller_times_out_and_an_unplugged_port_is_disconnected() {
    let fake = Fake::start(Script::default());
    let ctl = fake.controller();
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.position().await.unwrap();
    fake.script().mute = true;
    // A timeout, not a hang: it comes after exactly the timeout it reports.
    let t0 = Instant::now();
    let e = x.position().await.unwrap_err();
    let DeviceError {
        kind: DeviceErrorKind::Timeout { timeout_s, .. },
        ..
    } = e
    else {
        panic!("not a timeout: {e}")
    };
    assert_eq!(t0.elapsed(), Duration::from_secs_f64(timeout_s), "{e}");
    // Reconnecting to a mute controller: no banner.
    let t0 = Instant::now();
    let e = x.position().await.unwrap_err();
    let DeviceError {
        kind: DeviceErrorKind::Timeout {
            ref request,
            timeout_s,
        },
        ..
    } = e
    else {
        panic!("not a timeout: {e}")
    };
    assert!(request.contains("banner"), "{e}");
    assert_eq!(t0.elapsed(), Duration::from_secs_f64(timeout_s), "{e}");
    // The port disappears while the link is closed: reopening it fails.
    fake.unplug();
    let e = x.position().await.unwrap_err();
    assert!(e.is_recoverable(), "{e}");
    assert!(
        matches!(
            &e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { port, .. },
                ..
            } if port == &fake.path
        ),
        "{e}"
    );
    assert!(e.to_string().contains("turntable"), "{e}");
}

#[test]
fn an_axis_needs_a_letter_the_controller_serves() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let ctl = GrblController::new("t", "/dev/null", GRBL_BAUD, vec![axis("t", "X")]);
        let e = GrblAxis::new(ctl.clone(), &axis("tilt", "Q"))
            .err()
            .unwrap();
        assert!(e.to_string().contains("controller_axis"), "{e}");
        let e = GrblAxis::new(ctl.clone(), &axis("tilt", "Z"))
            .err()
            .unwrap();
        assert!(e.to_string().starts_with("tilt:"), "{e}");
        assert_eq!(
            GrblAxis::new(ctl, &axis("t", "x")).ok().map(|a| a.letter()),
            Some('X')
        );
    });
}
