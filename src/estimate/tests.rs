//! Tests of [`super`].

use super::*;
use crate::plan::SourcePos;
use proptest::prelude::*;

use super::test_rigs::{lightstage, reflectometer};
use crate::test_support::{lamps, mv, plan_at};

fn plan(actions: Vec<Action>) -> Plan {
    plan_at("test.rhai", actions, |i| SourcePos {
        line: i as u32 + 1,
        col: 1,
    })
}

/// The estimate with the run-start homing taken out (it has its own test below), so the
/// hand-computed cases read as the steps' costs alone.
fn estimate(p: &Plan, rig: &RigSpec) -> Estimate {
    let mut e = super::estimate(p, rig);
    let start = if p.steps.is_empty() {
        0.0
    } else {
        establish_s(rig, &RigState::power_on(rig))
    };
    e.rig_time_s -= start;
    for t in &mut e.step_end_s {
        *t -= start;
    }
    e
}

#[test]
fn a_run_starts_with_homing_and_a_resume_with_re_establishing() {
    let rig = lightstage();
    let settle = rig.axes.iter().map(|a| a.settle_s).fold(0.0, f64::max);
    let one = plan(vec![Action::Wait { seconds: 0.0 }]);
    assert_eq!(super::estimate(&one, &rig).rig_time_s, settle);
    assert_eq!(super::estimate(&plan(vec![]), &rig).rig_time_s, 0.0);
    let mut state = RigState::power_on(&rig);
    state.axes_deg.insert("turntable".into(), 90.0);
    let turntable = rig.axis("turntable").unwrap();
    let expected = settle + stagehand_devices::axis::planned_move_s(turntable, 0.0, 90.0);
    assert!((establish_s(&rig, &state) - expected).abs() < 1e-12);
}

fn capture(exposures: &[f64], cameras: &[&str], hdr: bool, min_interval_s: f64) -> Action {
    Action::Capture {
        exposures_s: exposures.to_vec(),
        cameras: cameras.iter().map(|c| c.to_string()).collect(),
        gain: 1.0,
        hdr,
        label: String::new(),
        min_interval_s,
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[track_caller]
fn assert_close(a: f64, b: f64) {
    assert!(close(a, b), "{a} != {b}");
}

#[test]
fn empty_plan_costs_nothing() {
    let rig = lightstage();
    let e = estimate(&plan(vec![]), &rig);
    assert_eq!(e.steps, 0);
    assert_eq!(e.rig_time_s, 0.0);
    assert_eq!(e.bytes, 0);
    assert!(e.step_end_s.is_empty());
    assert_eq!(e.per_device.len(), 3 + 8 + 1 + 8 + 1);
    assert!(
        e.per_device
            .values()
            .all(|u| u.busy_s == 0.0 && u.on_s == 0.0 && u.travel == 0.0)
    );
    assert_eq!(e.per_device["turntable"].kind, DeviceKind::Axis);
    assert_eq!(e.per_device["laser"].kind, DeviceKind::Laser);
    assert_eq!(e.per_device["trigger"].kind, DeviceKind::Trigger);
}

#[test]
fn a_move_is_a_trapezoid_plus_settle() {
    let rig = lightstage();
    // turntable: 30 °/s, 60 °/s²: 0.5 s ramps covering 15°, 75° at cruise = 2.5 s; settle 0.15 s.
    let e = estimate(&plan(vec![mv(&[("turntable", 90.0)])]), &rig);
    assert_close(e.rig_time_s, 3.5 + 0.15);
    assert_close(e.step_end_s[0], 3.65);
    let u = &e.per_device["turntable"];
    assert_close(u.busy_s, 3.65);
    assert_close(u.travel, 90.0);
    assert_eq!(u.operations, 1);
}

#[test]
fn a_zero_move_takes_no_time_and_no_settle() {
    let rig = lightstage();
    let e = estimate(&plan(vec![mv(&[("turntable", 0.0)])]), &rig);
    assert_eq!(e.rig_time_s, 0.0);
    assert_eq!(e.per_device["turntable"].travel, 0.0);
}

#[test]
fn a_negative_move_takes_up_backlash() {
    let rig = lightstage();
    let e = estimate(
        &plan(vec![mv(&[("turntable", 90.0)]), mv(&[("turntable", 0.0)])]),
        &rig,
    );
    // 90 → -0.05: 90.05° = 1 s of ramps + 75.05/30 s; -0.05 → 0: triangular, 2·sqrt(0.05/60).
    let down = 1.0 + 75.05 / 30.0 + 2.0 * (0.05f64 / 60.0).sqrt() + 0.15;
    assert_close(e.step_end_s[1] - e.step_end_s[0], down);
    assert_close(e.rig_time_s, 3.65 + down);
    assert_close(e.per_device["turntable"].travel, 180.1);
    assert_eq!(e.per_device["turntable"].operations, 2);
}

#[test]
fn parallel_axes_take_the_longest() {
    let rig = lightstage();
    // light_arc: 20 °/s, 40 °/s²: 0.5 s ramps covering 10°, 80° at cruise = 4 s; settle 0.3 s.
    let e = estimate(
        &plan(vec![mv(&[("turntable", 90.0), ("light_arc", 90.0)])]),
        &rig,
    );
    assert_close(e.rig_time_s, 5.3);
    assert_close(e.per_device["turntable"].busy_s, 3.65);
    assert_close(e.per_device["light_arc"].busy_s, 5.3);
}

#[test]
fn home_runs_at_homing_speed_and_always_settles() {
    let rig = lightstage();
    let home = Action::Home {
        axes: vec!["turntable".into(), "light_arc".into()],
    };
    let e = estimate(&plan(vec![mv(&[("turntable", 90.0)]), home.clone()]), &rig);
    // turntable 90° at 40 °/s + 0.15 s; light_arc at 0° still settles 0.3 s.
    assert_close(e.step_end_s[1] - e.step_end_s[0], 90.0 / 40.0 + 0.15);
    let e = estimate(&plan(vec![home]), &rig);
    assert_close(e.rig_time_s, 0.3);
}

#[test]
fn a_capture_bracket_waits_exposure_plus_readout_per_trigger() {
    let rig = lightstage();
    let p = plan(vec![capture(
        &[0.01, 0.1, 1.0],
        &["cam1", "cam2"],
        true,
        0.0,
    )]);
    let e = estimate(&p, &rig);
    assert_close(e.rig_time_s, 1.11 + 3.0 / 15.0);
    assert_eq!(e.captures, 1);
    assert_eq!(e.raw_frames, 6);
    assert_eq!(e.hdr_frames, 2);
    assert_eq!(e.raw_frames, p.raw_frames());
    assert_eq!(e.hdr_frames, p.hdr_frames());
    assert_eq!(e.bytes, 1024 * 768 * (6 * 6 + 2 * 12));
    assert_eq!(e.per_device["cam1"].frames, 3);
    assert_close(e.per_device["cam2"].busy_s, 1.11 + 3.0 / 15.0);
    assert_eq!(e.per_device["cam3"].frames, 0);
    assert_eq!(e.per_device["trigger"].operations, 3);
}

#[test]
fn capture_waits_for_lamp_warm_up() {
    let rig = lightstage();
    let e = estimate(
        &plan(vec![
            lamps(&[("lamp1", true)]),
            capture(&[0.1], &["cam1"], false, 0.0),
        ]),
        &rig,
    );
    assert_close(e.rig_time_s, 0.8 + 0.1 + 1.0 / 15.0);
    // The lamp was on from 0 s until the end.
    assert_close(e.per_device["lamp1"].on_s, e.rig_time_s);
    assert_eq!(e.per_device["lamp1"].operations, 1);
}

#[test]
fn a_move_covers_the_warm_up() {
    let rig = lightstage();
    let p = plan(vec![
        lamps(&[("lamp1", true)]),
        mv(&[("turntable", 90.0)]),
        capture(&[0.1], &["cam1"], false, 0.0),
        lamps(&[("lamp1", false)]),
    ]);
    let e = estimate(&p, &rig);
    assert_close(e.rig_time_s, 3.65 + 0.1 + 1.0 / 15.0);
    assert_close(e.per_device["lamp1"].on_s, e.rig_time_s);
    assert_eq!(e.per_device["lamp1"].operations, 2);
}

#[test]
fn min_interval_paces_captures_from_first_trigger_to_first_trigger() {
    let rig = lightstage();
    let p = plan(vec![
        capture(&[0.01], &["cam1"], false, 5.0),
        capture(&[0.01], &["cam1"], false, 1.0),
    ]);
    let e = estimate(&p, &rig);
    // The first capture has no predecessor; the second fires 1 s after the first fired.
    assert_close(e.step_end_s[0], 0.01 + 1.0 / 15.0);
    assert_close(e.rig_time_s, 1.0 + 0.01 + 1.0 / 15.0);
}

#[test]
fn laser_on_time_and_cart_and_wait() {
    let rig = lightstage();
    let p = plan(vec![
        Action::LaserArm,
        Action::Laser {
            on: true,
            colour_nm: 650,
        },
        Action::Wait { seconds: 2.0 },
        Action::LaserDisarm,
        Action::Wait { seconds: 1.0 },
    ]);
    let e = estimate(&p, &rig);
    assert_close(e.rig_time_s, 3.0);
    assert_close(e.per_device["laser"].on_s, 2.0);
    assert_eq!(e.per_device["laser"].operations, 2);

    let rig = reflectometer();
    let p = plan(vec![
        Action::CartTo { position_mm: 120.0 },
        Action::CartTo { position_mm: 60.0 },
    ]);
    let e = estimate(&p, &rig);
    assert_close(e.rig_time_s, 15.0);
    assert_close(e.per_device["cart"].travel, 180.0);
    assert_eq!(e.per_device["cart"].operations, 2);
}

#[test]
fn prompts_cost_no_rig_time() {
    let rig = lightstage();
    let prompt = Action::Prompt {
        message: "place".into(),
        fixture: Some("planes".into()),
        placement: None,
        laser_mount_deg: None,
        laser_fit_nm: None,
    };
    let e = estimate(&plan(vec![prompt.clone(), prompt]), &rig);
    assert_eq!(e.prompts, 2);
    assert_eq!(e.rig_time_s, 0.0);
}

#[test]
fn state_before_folds_earlier_steps() {
    let rig = lightstage();
    let p = plan(vec![
        mv(&[("turntable", 30.0), ("light_arc", -20.0)]),
        lamps(&[("lamp2", true), ("lamp3", true)]),
        Action::Prompt {
            message: "fit".into(),
            fixture: Some("checkerboard".into()),
            placement: None,
            laser_mount_deg: Some(30.0),
            laser_fit_nm: Some(532),
        },
        Action::LaserArm,
        Action::Laser {
            on: true,
            colour_nm: 532,
        },
        lamps(&[("lamp2", false)]),
        Action::Home {
            axes: vec!["turntable".into()],
        },
        Action::LaserDisarm,
    ]);
    let s0 = state_before(&p, &rig, 0);
    assert_eq!(s0, RigState::power_on(&rig));
    assert_eq!(s0.laser_fitted_nm, 650);
    assert_eq!(s0.laser_mount_deg, 45.0);
    assert_eq!(s0.fixture, "bumps");
    assert_eq!(s0.axes_deg.len(), 3);

    let s = state_before(&p, &rig, 5);
    assert_eq!(s.axes_deg["turntable"], 30.0);
    assert_eq!(s.axes_deg["light_arc"], -20.0);
    assert_eq!(
        s.lamps_on,
        BTreeSet::from(["lamp2".to_string(), "lamp3".to_string()])
    );
    assert!(s.laser_armed && s.laser_on);
    assert_eq!(s.laser_fitted_nm, 532);
    assert_eq!(s.laser_mount_deg, 30.0);
    assert_eq!(s.fixture, "checkerboard");

    let end = state_before(&p, &rig, 8);
    assert_eq!(end.axes_deg["turntable"], 0.0);
    assert_eq!(end.lamps_on, BTreeSet::from(["lamp3".to_string()]));
    assert!(!end.laser_armed && !end.laser_on);
    assert_eq!(state_before(&p, &rig, 100), end);
}

#[test]
fn estimate_from_resumes_from_a_state() {
    let rig = lightstage();
    let p = plan(vec![
        mv(&[("turntable", 90.0)]),
        lamps(&[("lamp1", true)]),
        capture(&[0.1], &["cam1"], false, 0.0),
        mv(&[("turntable", 0.0)]),
    ]);
    let full = super::estimate(&p, &rig);
    assert_eq!(estimate_from(&p, &rig, 0, &state_before(&p, &rig, 0)), full);
    // From step 2 the turntable is re-established at 90° and the lamp is on in the start
    // state: its warm-up is waited for again after that.
    let start = state_before(&p, &rig, 2);
    let rest = estimate_from(&p, &rig, 2, &start);
    assert_eq!(rest.steps, 2);
    assert_eq!(rest.step_end_s.len(), 4);
    assert_eq!(rest.step_end_s[0], 0.0);
    assert_close(
        rest.step_end_s[2],
        establish_s(&rig, &start) + 0.8 + 0.1 + 1.0 / 15.0,
    );
    let down = full.step_end_s[3] - full.step_end_s[2];
    assert_close(rest.rig_time_s, rest.step_end_s[2] + down);
    assert_eq!(rest.captures, 1);
    let past = estimate_from(&p, &rig, 10, &state_before(&p, &rig, 10));
    assert_eq!(past.steps, 0);
    assert_eq!(past.rig_time_s, 0.0);
}

#[test]
fn degenerate_values_never_give_nan() {
    let rig = lightstage();
    let p = plan(vec![
        Action::Home { axes: vec![] },
        mv(&[]),
        mv(&[
            ("turntable", f64::NAN),
            ("nope", 5.0),
            ("light_arc", f64::INFINITY),
        ]),
        mv(&[("turntable", 1e308)]),
        mv(&[("turntable", -1e308)]),
        capture(&[], &[], true, f64::NAN),
        capture(
            &[f64::NAN, -1.0, f64::INFINITY],
            &["cam1", "cam1", "cam99"],
            true,
            -5.0,
        ),
        Action::Wait { seconds: f64::NAN },
        Action::Wait { seconds: -3.0 },
        Action::Wait {
            seconds: f64::INFINITY,
        },
        Action::CartTo { position_mm: 50.0 },
        lamps(&[("lamp99", true)]),
    ]);
    let e = estimate(&p, &rig);
    assert!(e.rig_time_s.is_finite() && e.rig_time_s >= 0.0);
    assert!(e.step_end_s.iter().all(|t| t.is_finite() && *t >= 0.0));
    for u in e.per_device.values() {
        for v in [u.busy_s, u.travel, u.on_s] {
            assert!(v.is_finite() && v >= 0.0);
        }
    }
    // The bad start state of a resume is sanitised too.
    let mut start = RigState::power_on(&rig);
    start.axes_deg.insert("turntable".into(), f64::NAN);
    start.cart_mm = f64::NAN;
    let e = estimate_from(&p, &rig, 0, &start);
    assert!(e.rig_time_s.is_finite());
}

fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -400.0f64..400.0,
        1 => 0.0f64..2.0,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(1e308),
        1 => Just(-1e308),
    ]
}

fn any_id(ids: &'static [&'static str]) -> impl Strategy<Value = String> {
    prop::sample::select(ids).prop_map(str::to_string)
}

fn any_action() -> impl Strategy<Value = Action> {
    let axes: &'static [&'static str] = &["turntable", "light_arc", "laser_tilt", "nope"];
    let lamp_ids: &'static [&'static str] = &["lamp1", "lamp2", "lamp8", "lamp9"];
    let cams: &'static [&'static str] = &["cam1", "cam2", "cam8", "cam0"];
    prop_oneof![
        prop::collection::vec(any_id(axes), 0..3).prop_map(|axes| Action::Home { axes }),
        prop::collection::btree_map(any_id(axes), any_f64(), 0..3)
            .prop_map(|targets| Action::Move { targets }),
        prop::collection::btree_map(any_id(lamp_ids), any::<bool>(), 0..3)
            .prop_map(|states| Action::Lamps { states }),
        Just(Action::LaserArm),
        Just(Action::LaserDisarm),
        (any::<bool>(), prop::sample::select(vec![650u32, 532, 808]))
            .prop_map(|(on, colour_nm)| Action::Laser { on, colour_nm }),
        (
            prop::collection::vec(any_f64(), 0..4),
            prop::collection::vec(any_id(cams), 0..3),
            any::<bool>(),
            any_f64()
        )
            .prop_map(|(exposures_s, cameras, hdr, min_interval_s)| {
                Action::Capture {
                    exposures_s,
                    cameras,
                    gain: 1.0,
                    hdr,
                    label: String::new(),
                    min_interval_s,
                }
            }),
        any_f64().prop_map(|position_mm| Action::CartTo { position_mm }),
        Just(Action::Prompt {
            message: String::new(),
            fixture: None,
            placement: None,
            laser_mount_deg: None,
            laser_fit_nm: Some(532)
        }),
        any_f64().prop_map(|seconds| Action::Wait { seconds }),
    ]
}

proptest! {
    #[test]
    fn estimate_is_monotone_in_steps_and_never_negative(actions in prop::collection::vec(any_action(), 0..12)) {
        let rig = lightstage();
        let mut previous: Option<Estimate> = None;
        for n in 0..=actions.len() {
            let e = estimate(&plan(actions[..n].to_vec()), &rig);
            prop_assert!(e.rig_time_s.is_finite() && e.rig_time_s >= 0.0);
            let mut last = 0.0;
            for &t in &e.step_end_s {
                prop_assert!(t.is_finite() && t >= last);
                last = t;
            }
            for u in e.per_device.values() {
                for v in [u.busy_s, u.travel, u.on_s] {
                    prop_assert!(v.is_finite() && v >= 0.0);
                }
            }
            if let Some(p) = &previous {
                prop_assert!(e.rig_time_s >= p.rig_time_s);
                prop_assert!(e.raw_frames >= p.raw_frames && e.bytes >= p.bytes && e.captures >= p.captures);
                prop_assert_eq!(&e.step_end_s[..n - 1], &p.step_end_s[..]);
                for (id, u) in &e.per_device {
                    let q = &p.per_device[id];
                    prop_assert!(u.busy_s >= q.busy_s && u.travel >= q.travel && u.on_s >= q.on_s - 1e-9);
                    prop_assert!(u.operations >= q.operations && u.frames >= q.frames);
                }
            }
            previous = Some(e);
        }
    }
}
