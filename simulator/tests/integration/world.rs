//! The simulated rig behaves physically: moves take their profile time on the virtual clock,
//! backlash shows up unless the approach takes it up, lamps warm up, and a move during an
//! exposure is caught.

use std::sync::Arc;

use stagehand_devices::axis::{AxisDriver, AxisHandle};
use stagehand_devices::clock::RigClock;
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, RigSpec, parse_rig};
use stagehand_devices::switch_bank::SwitchBankDriver;
use stagehand_devices::{DeviceError, DeviceErrorKind};
use stagehand_simulator::World;
use stagehand_simulator::sim_devices::{SimAxis, SimSwitchBank};
use stagehand_simulator::world::warmup_fraction;

fn rig() -> Arc<RigSpec> {
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", "width = 16")
        .replace("height = 768", "height = 12");
    Arc::new(parse_rig(&text, "lightstage.toml").unwrap())
}

fn world() -> Arc<World> {
    World::new(rig(), RigClock::default(), 1).unwrap()
}

#[tokio::test(start_paused = true)]
async fn a_move_takes_its_trapezoid_time_on_the_virtual_clock() {
    let _turn = crate::grbl_peer::alongside();
    let w = world();
    let spec = w.rig().axis("turntable").unwrap().clone();
    let axis = AxisHandle::spawn(spec.clone(), SimAxis::new(spec.clone(), w.clone()));
    axis.home().await.unwrap();
    let t0 = w.clock().now_s();
    axis.move_to(90.0).await.unwrap();
    let took = w.clock().now_s() - t0;
    let expected = stagehand_devices::axis::planned_move_s(&spec, 0.0, 90.0);
    assert!(
        (took - expected).abs() < 0.01,
        "took {took}, profile says {expected}"
    );
    let at = w.snapshot_at(w.clock().now_s()).axes["turntable"];
    assert!((at - 90.0).abs() <= 1.0 / spec.steps_per_deg, "{at}");
}

#[tokio::test(start_paused = true)]
async fn backlash_is_taken_up_by_the_positive_final_approach() {
    let _turn = crate::grbl_peer::alongside();
    let w = world();
    let spec = w.rig().axis("light_arc").unwrap().clone();
    assert!(spec.backlash_deg > 0.0);
    // Through the handle: 60 → 30 approaches from below, so the load sits at the target.
    let axis = AxisHandle::spawn(spec.clone(), SimAxis::new(spec.clone(), w.clone()));
    axis.home().await.unwrap();
    axis.move_to(60.0).await.unwrap();
    axis.move_to(30.0).await.unwrap();
    let load = w.snapshot_at(w.clock().now_s()).axes["light_arc"];
    assert!(
        (load - 30.0).abs() <= 1.0 / spec.steps_per_deg,
        "load at {load}"
    );

    // The bare driver moving down shows the backlash on the load side.
    let w2 = world();
    let mut bare = SimAxis::new(spec.clone(), w2.clone());
    bare.home().await.unwrap();
    bare.move_to(60.0).await.unwrap();
    bare.move_to(30.0).await.unwrap();
    let load = w2.snapshot_at(w2.clock().now_s()).axes["light_arc"];
    assert!(
        (load - 30.0 - spec.backlash_deg).abs() <= 1.0 / spec.steps_per_deg,
        "load at {load}"
    );
}

#[tokio::test(start_paused = true)]
async fn moving_while_a_camera_exposes_is_refused_and_recorded() {
    let _turn = crate::grbl_peer::alongside();
    let w = world();
    let spec = w.rig().axis("turntable").unwrap().clone();
    let mut axis = SimAxis::new(spec, w.clone());
    axis.home().await.unwrap();
    let now = w.clock().now_s();
    w.begin_exposure_for_test(now, now + 1.0);
    let err = axis.move_to(10.0).await.unwrap_err();
    assert!(
        matches!(
            err,
            DeviceError {
                kind: DeviceErrorKind::MovingWhileExposing,
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(w.violations().len(), 1);
}

#[test]
fn lamp_warm_up_reaches_exactly_full_output() {
    let _turn = crate::grbl_peer::alongside();
    assert_eq!(warmup_fraction(0.0, 0.8), 0.0);
    assert!(warmup_fraction(0.4, 0.8) > 0.5 && warmup_fraction(0.4, 0.8) < 1.0);
    assert_eq!(warmup_fraction(0.8, 0.8), 1.0);
    assert_eq!(warmup_fraction(100.0, 0.8), 1.0);
    assert_eq!(warmup_fraction(0.1, 0.0), 1.0);
    let mut last = 0.0;
    for i in 0..=100 {
        let f = warmup_fraction(i as f64 * 0.01, 0.8);
        assert!(f >= last && (0.0..=1.0).contains(&f));
        last = f;
    }
}

#[tokio::test(start_paused = true)]
async fn a_pattern_camera_delivers_a_new_test_pattern_per_trigger_without_rendering() {
    use stagehand_devices::camera::CameraDriver;
    use stagehand_devices::trigger::TriggerDriver;
    use stagehand_simulator::sim_devices::{SimCamera, SimTrigger};
    let _turn = crate::grbl_peer::alongside();
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", "width = 16")
        .replace("height = 768", "height = 12")
        .replace("bit_depth = 12", "bit_depth = 16")
        .replacen("[sim]\n", "[sim]\nframes = \"pattern\"\n", 1);
    let w = World::new(
        Arc::new(parse_rig(&text, "lightstage.toml").unwrap()),
        RigClock::default(),
        1,
    )
    .unwrap();
    let spec = w.rig().cameras[0].clone();
    let mut cam = SimCamera::new(spec.clone(), w.clone());
    let mut trigger = SimTrigger::new(w.clone());
    cam.configure(0.001, 1.0).await.unwrap();
    cam.arm().await.unwrap();
    let mut frames = Vec::new();
    for id in [1001, 2001] {
        let t0 = w.clock().now_s();
        trigger.fire(id).await.unwrap();
        let frame = cam.next_frame().await.unwrap();
        // Exposure and readout are kept as for a rendered frame.
        let took = w.clock().now_s() - t0;
        // (The virtual clock's timers tick in milliseconds.)
        assert!((took - (0.001 + spec.readout_s())).abs() < 2e-3, "{took}");
        assert_eq!(frame.trigger_id, id);
        assert_eq!(frame.notes["source"], "test pattern");
        assert!(frame.ground_truth.is_none());
        assert_eq!(frame.pixels.len(), 16 * 12 * 3);
        frames.push(frame.pixels);
    }
    assert_ne!(frames[0], frames[1], "every trigger shows a new frame");
    assert!(
        frames[0].iter().any(|v| *v > u16::MAX / 2),
        "the range is used"
    );
}

/// The world without its time: what a frame's radiance depends on.
fn untimed(mut w: stagehand_simulator::world_snapshot::WorldSnapshot) -> String {
    w.rig_time_s = 0.0;
    format!("{w:?}")
}

/// While the rig settles, the world it will settle into is known exactly: a downward move's
/// target with the backlash it leaves, a lamp at full output once warm.
#[tokio::test(start_paused = true)]
async fn the_settled_world_is_predicted_exactly_while_the_rig_settles() {
    let _turn = crate::grbl_peer::alongside();
    let w = world();
    let spec = w.rig().axis("light_arc").unwrap().clone();
    let mut arc = SimAxis::new(spec, w.clone());
    arc.home().await.unwrap();
    arc.move_to(60.0).await.unwrap();
    let bank = w.rig().switch_banks[0].clone();
    let mut lamps = SimSwitchBank::new(bank, w.clone());
    lamps.set(1, true).await.unwrap();
    let mover = tokio::spawn(async move { arc.move_to(30.0).await });
    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    let now = w.snapshot_at(w.clock().now_s());
    let predicted = w.settled_snapshot().expect("no cart runs");
    assert_ne!(
        untimed(now.clone()),
        untimed(predicted.clone()),
        "still settling"
    );
    assert!(now.axes["light_arc"] > 30.0 && now.lamps["lamp1"] < 1.0);
    mover.await.unwrap().unwrap();
    let warm = w.rig().lamp("lamp1").unwrap().warmup_s;
    tokio::time::sleep(std::time::Duration::from_secs_f64(warm)).await;
    let settled = w.snapshot_at(w.clock().now_s());
    assert_eq!(untimed(predicted), untimed(settled));
}

/// A rig that renders ahead traces the settled world while it settles: every camera's frame
/// of that world then reuses the trace, and reads the same as a frame rendered afresh.
#[tokio::test(start_paused = true)]
async fn a_rig_rendering_ahead_traces_the_settled_world_before_its_frames() {
    let _turn = crate::grbl_peer::alongside();
    let w = world();
    let bank = w.rig().switch_banks[0].clone();
    let mut lamps = SimSwitchBank::new(bank, w.clone());
    // Off (no run drives the rig): a change traces nothing.
    w.set_render_ahead(true).unwrap();
    w.set_render_ahead(false).unwrap();
    lamps.set(2, true).await.unwrap();
    w.wait_render_ahead();
    let at = w.snapshot_at(w.clock().now_s() + 10.0);
    w.renderer().render(&at, "cam1", 0.02, 1.0, 0).unwrap();
    assert_eq!(
        w.renderer().radiance_reused(),
        0,
        "nothing was traced ahead"
    );
    lamps.set(2, false).await.unwrap();
    // On: the settled world is traced before its frames.
    w.set_render_ahead(true).unwrap();
    lamps.set(3, true).await.unwrap();
    w.wait_render_ahead();
    let warm = w.rig().lamp("lamp3").unwrap().warmup_s;
    tokio::time::sleep(std::time::Duration::from_secs_f64(warm)).await;
    let at = w.snapshot_at(w.clock().now_s());
    let fresh = stagehand_simulator::render::Renderer::new(w.rig()).unwrap();
    for (k, cam) in w.rig().cameras.iter().enumerate() {
        let frame = w
            .renderer()
            .render(&at, &cam.id, 0.02, 1.0, k as u64)
            .unwrap();
        let again = fresh.render(&at, &cam.id, 0.02, 1.0, k as u64).unwrap();
        assert!(frame.pixels == again.pixels, "{}", cam.id);
    }
    assert_eq!(w.renderer().radiance_reused(), w.rig().cameras.len() as u64);
    assert_eq!(fresh.radiance_reused(), 0);
}
