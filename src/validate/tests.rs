//! Tests of [`super`].

use super::*;

use crate::estimate::test_rigs::{lightstage, reflectometer};
use crate::test_support::{lamps, mv, plan_at};

fn plan(actions: Vec<Action>) -> Plan {
    plan_at("test.rhai", actions, pos)
}

fn pos(index: usize) -> SourcePos {
    SourcePos {
        line: index as u32 * 2 + 3,
        col: index as u32 + 5,
    }
}

fn capture(exposures: &[f64], cameras: &[&str]) -> Action {
    Action::Capture {
        exposures_s: exposures.to_vec(),
        cameras: cameras.iter().map(|c| c.to_string()).collect(),
        gain: 1.0,
        hdr: false,
        label: "x".into(),
        min_interval_s: 0.0,
    }
}

fn with(action: Action, f: impl FnOnce(&mut Vec<f64>, &mut f64, &mut bool, &mut f64)) -> Action {
    match action {
        Action::Capture {
            mut exposures_s,
            cameras,
            mut gain,
            mut hdr,
            label,
            mut min_interval_s,
        } => {
            f(&mut exposures_s, &mut gain, &mut hdr, &mut min_interval_s);
            Action::Capture {
                exposures_s,
                cameras,
                gain,
                hdr,
                label,
                min_interval_s,
            }
        }
        other => other,
    }
}

fn prompt(fixture: Option<&str>, mount: Option<f64>, fit: Option<u32>) -> Action {
    Action::Prompt {
        message: "do it".into(),
        fixture: fixture.map(str::to_string),
        placement: None,
        laser_mount_deg: mount,
        laser_fit_nm: fit,
    }
}

/// A lit, clean prefix of two steps; the step under test is step 2.
fn lit(mut rest: Vec<Action>) -> Vec<Action> {
    let mut v = vec![
        Action::Home {
            axes: vec!["turntable".into()],
        },
        lamps(&[("lamp1", true)]),
    ];
    v.append(&mut rest);
    v.push(lamps(&[("lamp1", false)]));
    v
}

/// Validates `actions` on `rig` and expects exactly one violation, at `step`, containing all
/// of `words`.
#[track_caller]
fn one(rig: &RigSpec, actions: Vec<Action>, step: usize, severity: Severity, words: &[&str]) {
    let v = validate(&plan(actions), rig);
    assert_eq!(v.len(), 1, "{v:#?}");
    assert_eq!(v[0].step, step, "{v:#?}");
    assert_eq!(v[0].at, pos(step));
    assert_eq!(v[0].severity, severity, "{v:#?}");
    for w in words {
        assert!(v[0].message.contains(w), "{:?} lacks {w:?}", v[0].message);
    }
}

#[test]
fn a_clean_plan_has_no_violations() {
    let rig = lightstage();
    let p = plan(vec![
        Action::Home {
            axes: vec!["turntable".into(), "light_arc".into(), "laser_tilt".into()],
        },
        prompt(Some("colorchecker"), None, None),
        mv(&[("turntable", 30.0), ("light_arc", -30.0)]),
        lamps(&[("lamp1", true)]),
        Action::Capture {
            exposures_s: vec![0.01, 0.1, 1.0],
            cameras: vec!["cam1".into(), "cam8".into()],
            gain: 2.0,
            hdr: true,
            label: "view 1".into(),
            min_interval_s: 0.0,
        },
        lamps(&[("lamp1", false)]),
        prompt(None, Some(60.0), Some(532)),
        Action::LaserArm,
        Action::Laser {
            on: true,
            colour_nm: 532,
        },
        mv(&[("laser_tilt", -10.0)]),
        capture(&[0.05], &["cam3"]),
        Action::Laser {
            on: false,
            colour_nm: 532,
        },
        Action::LaserDisarm,
        Action::Wait { seconds: 10.0 },
    ]);
    assert_eq!(validate(&plan(vec![]), &rig), vec![]);
    assert_eq!(validate(&p, &rig), vec![]);
    let refl = reflectometer();
    let p = plan(vec![
        lamps(&[("tube", true)]),
        Action::CartTo { position_mm: 240.0 },
        capture(&[0.1], &["cam1"]),
        Action::CartTo { position_mm: 0.0 },
        lamps(&[("tube", false)]),
    ]);
    assert_eq!(validate(&p, &refl), vec![]);
}

#[test]
fn unknown_devices_list_the_known_ones() {
    let rig = lightstage();
    one(
        &rig,
        lit(vec![Action::Home {
            axes: vec!["tilt".into()],
        }]),
        2,
        Severity::Error,
        &["`tilt`", "turntable, light_arc, laser_tilt"],
    );
    one(
        &rig,
        lit(vec![mv(&[("arc", 1.0)])]),
        2,
        Severity::Error,
        &["move_to", "`arc`", "laser_tilt"],
    );
    one(
        &rig,
        lit(vec![lamps(&[("lamp9", false)])]),
        2,
        Severity::Error,
        &["`lamp9`", "lamp1, lamp2", "lamp8"],
    );
    one(
        &rig,
        lit(vec![capture(&[0.1], &["cam9"])]),
        2,
        Severity::Error,
        &["`cam9`", "cam1, cam2", "cam8"],
    );
}

#[test]
fn move_targets_must_be_inside_the_soft_limits() {
    let rig = lightstage();
    one(
        &rig,
        lit(vec![mv(&[("light_arc", 400.0)])]),
        2,
        Severity::Error,
        &[
            "move_to: light_arc target 400° is outside the soft limits [-180°, 360°]; choose a target inside the limits or widen them in the rig file",
        ],
    );
    one(
        &rig,
        lit(vec![mv(&[("laser_tilt", -31.0)])]),
        2,
        Severity::Error,
        &["[-30°, 30°]"],
    );
    one(
        &rig,
        lit(vec![mv(&[("turntable", f64::NAN)])]),
        2,
        Severity::Error,
        &["not a number"],
    );
    one(
        &rig,
        lit(vec![mv(&[("turntable", f64::INFINITY)])]),
        2,
        Severity::Error,
        &["not a number"],
    );
    // The limits themselves are allowed.
    assert_eq!(
        validate(
            &plan(lit(vec![mv(&[
                ("turntable", 360.0),
                ("light_arc", -180.0)
            ])])),
            &rig
        ),
        vec![]
    );
}

#[test]
fn home_and_move_need_axes() {
    let rig = lightstage();
    one(
        &rig,
        lit(vec![Action::Home { axes: vec![] }]),
        2,
        Severity::Error,
        &["home: no axes", "turntable"],
    );
    one(
        &rig,
        lit(vec![mv(&[])]),
        2,
        Severity::Error,
        &["move_to: no axes", "light_arc"],
    );
}

#[test]
fn the_laser_must_be_armed_and_fitted() {
    let rig = lightstage();
    one(
        &rig,
        vec![
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::Laser {
                on: false,
                colour_nm: 650,
            },
        ],
        0,
        Severity::Error,
        &["not armed", "laser_arm"],
    );
    // Disarming disarms.
    let v = validate(
        &plan(vec![
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::LaserDisarm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::Laser {
                on: false,
                colour_nm: 650,
            },
        ]),
        &rig,
    );
    assert_eq!(v.len(), 1, "{v:#?}");
    assert_eq!((v[0].step, v[0].at), (3, pos(3)));
    // The fitted colour is tracked through prompts.
    one(
        &rig,
        vec![
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 532,
            },
            Action::LaserDisarm,
        ],
        1,
        Severity::Error,
        &[
            "532 nm is not fitted (650 nm is)",
            "add a prompt that fits it",
        ],
    );
    let fitted = vec![
        prompt(None, None, Some(532)),
        Action::LaserArm,
        Action::Laser {
            on: true,
            colour_nm: 532,
        },
        Action::LaserDisarm,
    ];
    assert_eq!(validate(&plan(fitted), &rig), vec![]);
    one(
        &rig,
        vec![
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 808,
            },
            Action::LaserDisarm,
        ],
        1,
        Severity::Error,
        &["808 nm", "650, 532, 473 nm"],
    );
    // Switching off needs neither arming nor the fitted colour.
    assert_eq!(
        validate(
            &plan(vec![Action::Laser {
                on: false,
                colour_nm: 1
            }]),
            &rig
        ),
        vec![]
    );
}

#[test]
fn laser_steps_need_a_laser() {
    let rig = reflectometer();
    let v = validate(
        &plan(vec![
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::LaserDisarm,
        ]),
        &rig,
    );
    assert_eq!(v.len(), 3, "{v:#?}");
    assert!(
        v.iter()
            .enumerate()
            .all(|(i, v)| v.step == i && v.at == pos(i) && v.severity == Severity::Error)
    );
    assert!(v.iter().all(|v| v.message.contains("no laser")));
    one(
        &rig,
        vec![prompt(None, None, Some(650))],
        0,
        Severity::Error,
        &["no laser"],
    );
    one(
        &rig,
        vec![prompt(None, Some(45.0), None)],
        0,
        Severity::Error,
        &["no laser"],
    );
}

#[test]
fn prompts_check_colour_mount_and_fixture() {
    let rig = lightstage();
    one(
        &rig,
        vec![prompt(None, None, Some(808))],
        0,
        Severity::Error,
        &["laser_fit_nm 808 nm", "650, 532, 473 nm"],
    );
    one(
        &rig,
        vec![prompt(None, Some(95.0), None)],
        0,
        Severity::Error,
        &["laser_mount_deg 95°", "[0°, 90°]"],
    );
    one(
        &rig,
        vec![prompt(None, Some(-1.0), None)],
        0,
        Severity::Error,
        &["laser_mount_deg -1°"],
    );
    one(
        &rig,
        vec![prompt(None, Some(f64::NAN), None)],
        0,
        Severity::Error,
        &["laser_mount_deg NaN°"],
    );
    one(
        &rig,
        vec![prompt(Some("teapot"), None, None)],
        0,
        Severity::Error,
        &[
            "`teapot`",
            "flat, bumps, steps, weave, checkerboard, colorchecker, planes",
        ],
    );
    assert_eq!(
        validate(
            &plan(vec![prompt(Some("planes"), Some(0.0), Some(473))]),
            &rig
        ),
        vec![]
    );
    // Scene files are accepted by path; the renderer checks they exist when it builds them.
    for fixture in ["marble", "scenes/my_sample.toml"] {
        assert_eq!(
            validate(&plan(vec![prompt(Some(fixture), None, None)]), &rig),
            vec![]
        );
    }
}

#[test]
fn capture_lists_are_checked() {
    let rig = lightstage();
    one(
        &rig,
        lit(vec![capture(&[], &["cam1"])]),
        2,
        Severity::Error,
        &["no exposures"],
    );
    one(
        &rig,
        lit(vec![capture(&[0.1], &[])]),
        2,
        Severity::Error,
        &["no cameras", "cam1, cam2"],
    );
    one(
        &rig,
        lit(vec![capture(&[0.1], &["cam1", "cam2", "cam1"])]),
        2,
        Severity::Error,
        &["`cam1` is listed twice"],
    );
}

#[test]
fn exposures_are_checked_against_each_camera() {
    let rig = lightstage();
    for bad in [0.0, -0.1, f64::NAN, f64::INFINITY] {
        one(
            &rig,
            lit(vec![capture(&[0.1, bad], &["cam1"])]),
            2,
            Severity::Error,
            &["not a positive time"],
        );
    }
    one(
        &rig,
        lit(vec![capture(&[5.0], &["cam1", "cam4"])]),
        2,
        Severity::Error,
        &["exposure 5 s", "[0.00002 s, 4 s]", "cameras cam1, cam4"],
    );
    one(
        &rig,
        lit(vec![capture(&[0.00001], &["cam2"])]),
        2,
        Severity::Error,
        &["exposure 0.00001 s", "camera cam2;"],
    );
    // Cameras with different ranges are named separately.
    let mut rig2 = rig.clone();
    rig2.cameras[1].max_exposure_s = 8.0;
    rig2.cameras[2].max_exposure_s = 2.0;
    let v = validate(
        &plan(lit(vec![capture(&[3.0], &["cam1", "cam2", "cam3"])])),
        &rig2,
    );
    assert_eq!(v.len(), 1, "{v:#?}");
    assert!(v[0].message.contains("camera cam3") && v[0].message.contains("2 s]"));
}

#[test]
fn gain_and_interval_are_checked() {
    let rig = lightstage();
    let c = || capture(&[0.1], &["cam1", "cam2"]);
    for g in [0.5, f64::NAN] {
        one(
            &rig,
            lit(vec![with(c(), |_, gain, _, _| *gain = g)]),
            2,
            Severity::Error,
            &["at least 1"],
        );
    }
    one(
        &rig,
        lit(vec![with(c(), |_, gain, _, _| *gain = 20.0)]),
        2,
        Severity::Error,
        &["gain 20", "maximum gain 16", "cameras cam1, cam2"],
    );
    for m in [-1.0, f64::NAN] {
        one(
            &rig,
            lit(vec![with(c(), |_, _, _, mi| *mi = m)]),
            2,
            Severity::Error,
            &["min_interval_s"],
        );
    }
    one(
        &rig,
        lit(vec![with(c(), |_, _, _, mi| *mi = 1e6)]),
        2,
        Severity::Error,
        &["24 h"],
    );
}

#[test]
fn cart_steps_are_checked() {
    let rig = lightstage();
    one(
        &rig,
        lit(vec![Action::CartTo { position_mm: 10.0 }]),
        2,
        Severity::Error,
        &["`lightstage` has no reflectometer cart"],
    );
    let rig = reflectometer();
    for bad in [-1.0, 240.5] {
        one(
            &rig,
            vec![Action::CartTo { position_mm: bad }],
            0,
            Severity::Error,
            &["outside the cart's travel [0 mm, 240 mm]"],
        );
    }
    one(
        &rig,
        vec![Action::CartTo {
            position_mm: f64::NAN,
        }],
        0,
        Severity::Error,
        &["not a number"],
    );
}

#[test]
fn waits_are_checked() {
    let rig = lightstage();
    for bad in [-1.0, f64::NAN, f64::NEG_INFINITY] {
        one(
            &rig,
            vec![Action::Wait { seconds: bad }],
            0,
            Severity::Error,
            &["wait:", "≥ 0"],
        );
    }
    one(
        &rig,
        vec![Action::Wait { seconds: 86_401.0 }],
        0,
        Severity::Error,
        &["longer than 24 h"],
    );
    assert_eq!(
        validate(
            &plan(vec![
                Action::Wait { seconds: 86_400.0 },
                Action::Wait { seconds: 0.0 }
            ]),
            &rig
        ),
        vec![]
    );
}

#[test]
fn dark_captures_and_single_exposure_hdr_warn() {
    let rig = lightstage();
    one(
        &rig,
        vec![capture(&[0.1], &["cam1"])],
        0,
        Severity::Warning,
        &["dark"],
    );
    // The laser alone lights the frame.
    let lasered = vec![
        Action::LaserArm,
        Action::Laser {
            on: true,
            colour_nm: 650,
        },
        capture(&[0.1], &["cam1"]),
        Action::LaserDisarm,
    ];
    assert_eq!(validate(&plan(lasered), &rig), vec![]);
    one(
        &rig,
        lit(vec![with(capture(&[0.1], &["cam1"]), |_, _, hdr, _| {
            *hdr = true
        })]),
        2,
        Severity::Warning,
        &["single exposure"],
    );
}

#[test]
fn things_left_on_warn_where_they_were_switched_on() {
    let rig = lightstage();
    let v = validate(
        &plan(vec![
            lamps(&[("lamp1", true), ("lamp2", true)]),
            lamps(&[("lamp3", true), ("lamp2", false)]),
            lamps(&[("lamp2", true)]),
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            lamps(&[("lamp3", false)]),
        ]),
        &rig,
    );
    assert_eq!(v.len(), 3, "{v:#?}");
    assert!(v.iter().all(|v| v.severity == Severity::Warning));
    assert_eq!((v[0].step, v[0].at), (0, pos(0)));
    assert!(
        v[0].message
            .contains("lamp lamp1 switched on here is still on"),
        "{}",
        v[0].message
    );
    // lamp2 was switched off and on again at step 2; lamp3 was switched off.
    assert_eq!((v[1].step, v[1].at), (2, pos(2)));
    assert!(v[1].message.contains("lamp lamp2 "), "{}", v[1].message);
    assert_eq!((v[2].step, v[2].at), (4, pos(4)));
    assert!(
        v[2].message.contains("laser switched on here"),
        "{}",
        v[2].message
    );
    let v = validate(
        &plan(vec![lamps(&[("lamp1", true), ("lamp2", true)])]),
        &rig,
    );
    assert_eq!(v.len(), 1);
    assert!(
        v[0].message
            .contains("lamps lamp1, lamp2 switched on here are still on")
    );
    one(
        &rig,
        vec![
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
        ],
        1,
        Severity::Warning,
        &["laser switched on here is still on"],
    );
}

#[test]
fn an_arm_without_laser_on_warns() {
    let rig = lightstage();
    one(
        &rig,
        vec![Action::LaserArm, Action::LaserDisarm],
        0,
        Severity::Warning,
        &["armed here but never switched on"],
    );
    one(
        &rig,
        vec![Action::Wait { seconds: 1.0 }, Action::LaserArm],
        1,
        Severity::Warning,
        &["never switched on"],
    );
    let v = validate(
        &plan(vec![
            Action::LaserArm,
            Action::LaserDisarm,
            Action::LaserArm,
            Action::Laser {
                on: true,
                colour_nm: 650,
            },
            Action::LaserDisarm,
        ]),
        &rig,
    );
    assert_eq!(v.len(), 1);
    assert_eq!(v[0].step, 0);
}

#[test]
fn violations_come_in_step_order_and_misnumbered_steps_are_errors() {
    let rig = lightstage();
    let mut p = plan(vec![
        lamps(&[("lamp1", true)]),
        mv(&[("turntable", 999.0)]),
        capture(&[0.1], &["camX"]),
    ]);
    p.steps[2].index = 7;
    let v = validate(&p, &rig);
    let steps: Vec<usize> = v.iter().map(|v| v.step).collect();
    assert_eq!(steps, vec![0, 1, 2, 2], "{v:#?}");
    assert!(v[2].message.contains("says it is step 7"));
}
