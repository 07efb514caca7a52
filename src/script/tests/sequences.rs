//! Every sequence in `sequences/` builds on the rig it is written for, with its defaults and
//! scaled down with `--set`, and every step points at the call that made it; the sequences'
//! README documents every function of the capture API.

use super::*;
use crate::plan::Action;

const QUICKSTART: &str = include_str!("../../../sequences/quickstart.rhai");
const BTF: &str = include_str!("../../../sequences/btf.rhai");
const MDF: &str = include_str!("../../../sequences/mdf_laser.rhai");
const QH: &str = include_str!("../../../sequences/quasi_homogeneous.rhai");
const REFLECTOMETER: &str = include_str!("../../../sequences/reflectometer.rhai");
const CHECKERBOARD: &str = include_str!("../../../sequences/calibration_checkerboard.rhai");
const COLORCHECKER: &str = include_str!("../../../sequences/calibration_colorchecker.rhai");

fn sequence(name: &str, text: &str, rig: &RigSpec, overrides: &[&str]) -> Plan {
    let source = ScriptSource {
        name: format!("sequences/{name}"),
        text: text.into(),
    };
    match build_plan(&source, &sets(overrides), rig) {
        Ok(p) => {
            assert_eq!(p.script, format!("sequences/{name}"));
            for (i, s) in p.steps.iter().enumerate() {
                assert_eq!(s.index, i);
                assert!(
                    s.at.line > 0 && s.at.col > 0,
                    "{name}: step {i} has no position"
                );
            }
            p
        }
        Err(e) => panic!("{name} failed: {e}"),
    }
}

/// Every step's position points at the API call that made it, on the line of the source.
fn assert_positions_match_calls(text: &str, plan: &Plan) {
    let lines: Vec<&str> = text.lines().collect();
    for s in &plan.steps {
        let line = lines[s.at.line as usize - 1];
        let rest: String = line.chars().skip(s.at.col as usize - 1).collect();
        let expected: &[&str] = match &s.action {
            Action::Home { .. } => &["home("],
            Action::Move { .. } => &["move_to(", "laser_sweep("],
            Action::Lamps { .. } => &["lamp(", "lamps_on(", "only_lamp(", "lamps_off("],
            Action::LaserArm => &["laser_arm("],
            Action::LaserDisarm => &["laser_disarm("],
            Action::Laser { on: true, .. } => &["laser_on("],
            Action::Laser { on: false, .. } => &["laser_off("],
            Action::Capture { .. } => &["capture(", "laser_sweep("],
            Action::CartTo { .. } => &["cart_to("],
            Action::Prompt { .. } => &["prompt("],
            Action::Wait { .. } => &["wait("],
        };
        assert!(
            expected.iter().any(|e| rest.starts_with(e)),
            "step {} ({}) at {}:{} points at `{rest}`",
            s.index,
            s.action.kind(),
            s.at.line,
            s.at.col
        );
    }
}

#[test]
fn quickstart_defaults() {
    let p = sequence("quickstart.rhai", QUICKSTART, &lightstage(), &[]);
    assert_eq!(count(&p, "capture"), 8);
    assert_eq!(p.raw_frames(), 72);
    assert_eq!(p.hdr_frames(), 8);
    assert_eq!(p.steps.len(), 28);
    assert_eq!(count(&p, "laser_arm"), 1);
    assert_eq!(count(&p, "laser_disarm"), 1);
    let bumps = p
        .steps
        .iter()
        .any(|s| matches!(&s.action, Action::Prompt { fixture: Some(f), .. } if f == "bumps"));
    assert!(bumps, "quickstart prompts for the bumps fixture");
    assert_positions_match_calls(QUICKSTART, &p);
}

#[test]
fn quickstart_scaled() {
    let p = sequence(
        "quickstart.rhai",
        QUICKSTART,
        &lightstage(),
        &["lamp_count=1", "sweep_lines=2", "turntable_deg=0"],
    );
    // 1 position × 1 lamp + 1 HDR bracket + 2 sweep lines.
    assert_eq!(count(&p, "capture"), 4);
    assert_eq!(p.params["turntable_deg"], serde_json::json!([0.0]));
}

#[test]
fn btf_defaults() {
    let p = sequence("btf.rhai", BTF, &lightstage(), &[]);
    assert_eq!(count(&p, "capture"), 12 * 12 * 8);
    assert_eq!(p.raw_frames(), 12 * 12 * 8 * 3 * 8);
    assert_eq!(p.hdr_frames(), 12 * 12 * 8 * 8);
    assert_eq!(p.steps.len(), 2464);
    // One lamp at a time.
    for s in &p.steps {
        if let Action::Lamps { states } = &s.action
            && s.block.contains("lamp")
        {
            assert_eq!(states.len(), 8);
            assert_eq!(states.values().filter(|on| **on).count(), 1);
        }
    }
    assert_eq!(p.steps[4].block, "view 0/light 0/lamp1");
    assert_positions_match_calls(BTF, &p);
}

#[test]
fn btf_scaled() {
    let p = sequence(
        "btf.rhai",
        BTF,
        &lightstage(),
        &["views=2", "lights=3", "lamps=2", "exposures=0.01,0.04"],
    );
    assert_eq!(count(&p, "capture"), 2 * 3 * 2);
    assert_eq!(p.raw_frames(), 2 * 3 * 2 * 2 * 8);
    let turntable: Vec<f64> = p
        .steps
        .iter()
        .filter_map(|s| match &s.action {
            Action::Move { targets } => targets.get("turntable").copied(),
            _ => None,
        })
        .collect();
    assert_eq!(turntable, vec![0.0, 180.0]);
    assert_eq!(p.params["exposures"], serde_json::json!([0.01, 0.04]));
}

#[test]
fn mdf_defaults() {
    let p = sequence("mdf_laser.rhai", MDF, &lightstage(), &[]);
    let positions = 12 * 26;
    // Three calibration frames per laser position, once for all 12 views.
    assert_eq!(count(&p, "capture"), 26 * 3 + positions * 64);
    assert_eq!(p.raw_frames(), (26 * 3 + positions * 64) * 8);
    assert_eq!(p.steps.len(), 41_860);
    let remounts = p
        .steps
        .iter()
        .filter(|s| {
            matches!(
                s.action,
                Action::Prompt {
                    laser_mount_deg: Some(_),
                    ..
                }
            )
        })
        .count();
    assert_eq!(remounts, 5);
    let fixtures = p
        .steps
        .iter()
        .filter(|s| {
            matches!(
                &s.action,
                Action::Prompt {
                    fixture: Some(_),
                    ..
                }
            )
        })
        .count();
    assert_eq!(fixtures, 5 * 2);
    // Every sweep capture is paced at 7.5 Hz.
    let paced = p
        .steps
        .iter()
        .filter(|s| matches!(&s.action, Action::Capture { min_interval_s, .. } if (*min_interval_s - 1.0 / 7.5).abs() < 1e-12))
        .count();
    assert_eq!(paced, positions * 64);
    assert_positions_match_calls(MDF, &p);
}

#[test]
fn mdf_scaled_splits_positions_over_mounts() {
    let p = sequence(
        "mdf_laser.rhai",
        MDF,
        &lightstage(),
        &["views=1", "positions=7", "mounts=3", "lines=2"],
    );
    assert_eq!(count(&p, "capture"), 7 * 3 + 7 * 2);
    // 7 positions over 3 mounts: 3 + 2 + 2.
    let per_mount: Vec<usize> = (0..3)
        .map(|m| {
            let prefix = format!("mount {m}/view 0/");
            let mut blocks: Vec<&str> = p
                .steps
                .iter()
                .filter(|s| s.block.starts_with(&prefix))
                .map(|s| s.block.as_str())
                .collect();
            blocks.dedup();
            blocks.len()
        })
        .collect();
    assert_eq!(per_mount, vec![3, 2, 2]);
    // The laser is armed only around laser captures and never during a prompt.
    let mut armed = false;
    for s in &p.steps {
        match &s.action {
            Action::LaserArm => armed = true,
            Action::LaserDisarm => armed = false,
            Action::Prompt { .. } => {
                assert!(!armed, "laser armed during prompt at step {}", s.index)
            }
            _ => {}
        }
    }
}

#[test]
fn quasi_homogeneous_defaults() {
    let p = sequence("quasi_homogeneous.rhai", QH, &lightstage(), &[]);
    let step1 = 3 * 7 * 12 * 64;
    let step2 = 3 * 12 * 64;
    let step3 = 12 * 8 * 12;
    // Step 2 of each colour opens with the laser's line on the reference, a 2-exposure bracket.
    let reference = 3;
    assert_eq!(count(&p, "capture"), step1 + step2 + step3 + reference);
    assert_eq!(
        p.raw_frames(),
        (step1 + step2) * 8 + step3 * 3 * 8 + reference * 2 * 8
    );
    assert_eq!(p.hdr_frames(), step3 * 8 + reference * 8);
    assert_eq!(p.steps.len(), 40_249);
    let fixtures: Vec<&str> = p
        .steps
        .iter()
        .filter_map(|s| match &s.action {
            Action::Prompt {
                fixture: Some(f), ..
            } => Some(f.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(fixtures.len(), 6, "{fixtures:?}");
    assert!(
        fixtures
            .chunks(2)
            .all(|f| f[0] == "opal_reference" && f[1] == "bumps"),
        "{fixtures:?}"
    );
    let swaps: Vec<u32> = p
        .steps
        .iter()
        .filter_map(|s| match s.action {
            Action::Prompt {
                laser_fit_nm: Some(nm),
                ..
            } => Some(nm),
            _ => None,
        })
        .collect();
    assert_eq!(swaps, vec![650, 532, 473]);
    // laser_on uses the fitted colour.
    for s in &p.steps {
        if let Action::Laser { colour_nm, .. } = s.action {
            assert!(
                s.block.starts_with(&format!("{colour_nm} nm")),
                "{}",
                s.block
            );
        }
    }
    assert_positions_match_calls(QH, &p);
}

#[test]
fn quasi_homogeneous_scaled() {
    let p = sequence(
        "quasi_homogeneous.rhai",
        QH,
        &lightstage(),
        &[
            "colours=650,473",
            "mounts=1",
            "rotations=2",
            "views=2",
            "lines=3",
            "lights=1",
            "lamps=2",
            "views3=2",
        ],
    );
    assert_eq!(count(&p, "capture"), 2 * (2 * 3 + 2 * 3 + 1) + 2 * 2);
    let p = sequence(
        "quasi_homogeneous.rhai",
        QH,
        &lightstage(),
        &[
            "step1=false",
            "step2=false",
            "lights=1",
            "lamps=1",
            "views3=1",
        ],
    );
    assert_eq!(count(&p, "capture"), 1);
    assert_eq!(count(&p, "laser"), 0);
}

#[test]
fn reflectometer_defaults() {
    let p = sequence("reflectometer.rhai", REFLECTOMETER, &reflectometer(), &[]);
    assert_eq!(count(&p, "capture"), 122);
    assert_eq!(p.raw_frames(), 122);
    assert_eq!(p.steps.len(), 251);
    let stops: Vec<f64> = p
        .steps
        .iter()
        .filter_map(|s| match s.action {
            Action::CartTo { position_mm } => Some(position_mm),
            _ => None,
        })
        .collect();
    assert_eq!(stops.len(), 123);
    assert_eq!(stops[1], 0.0);
    assert!((stops[121] - 240.0).abs() < 1e-9);
    assert_eq!(*stops.last().unwrap_or(&-1.0), 0.0);
    assert_positions_match_calls(REFLECTOMETER, &p);
}

#[test]
fn reflectometer_scaled_and_wrong_rig() {
    let p = sequence(
        "reflectometer.rhai",
        REFLECTOMETER,
        &reflectometer(),
        &["positions=3"],
    );
    assert_eq!(count(&p, "capture"), 4);
    let first = &p.steps[3].action;
    assert_eq!(
        first,
        &Action::Lamps {
            states: [("backlight".to_string(), true)].into()
        }
    );
    let err = build_plan(&src(REFLECTOMETER), &[], &lightstage()).expect_err("no cart");
    assert!(err.to_string().contains("needs a rig with a cart"), "{err}");
}

#[test]
fn calibration_sequences() {
    let p = sequence(
        "calibration_checkerboard.rhai",
        CHECKERBOARD,
        &lightstage(),
        &[],
    );
    assert_eq!(count(&p, "capture"), 15);
    assert_eq!(p.raw_frames(), 120);
    assert_eq!(p.steps.len(), 45);
    assert!(p.steps.iter().all(|s| match &s.action {
        Action::Prompt { fixture, .. } => fixture.as_deref() == Some("checkerboard"),
        _ => true,
    }));
    // The first placement is flat and centred (the reference), the others tilted or moved.
    let placements: Vec<_> = p
        .steps
        .iter()
        .filter_map(|s| match &s.action {
            Action::Prompt { placement, .. } => Some(placement.unwrap_or_default()),
            _ => None,
        })
        .collect();
    assert_eq!(placements.len(), 10);
    assert!(placements[0].is_flat_centred());
    assert!(placements[1..].iter().all(|p| !p.is_flat_centred()));
    let p = sequence(
        "calibration_checkerboard.rhai",
        CHECKERBOARD,
        &lightstage(),
        &["placements=2"],
    );
    assert_eq!(count(&p, "capture"), 6);

    let p = sequence(
        "calibration_colorchecker.rhai",
        COLORCHECKER,
        &lightstage(),
        &[],
    );
    assert_eq!(count(&p, "capture"), 8);
    assert_eq!(p.raw_frames(), 192);
    assert_eq!(p.hdr_frames(), 64);
    assert_eq!(p.steps.len(), 21);
    let p = sequence(
        "calibration_colorchecker.rhai",
        COLORCHECKER,
        &lightstage(),
        &["lamps=2", "exposures=0.02"],
    );
    assert_eq!(count(&p, "capture"), 2);
    assert_eq!(p.hdr_frames(), 0);
}

#[test]
fn sequences_readme_lists_every_function() {
    let readme = include_str!("../../../sequences/README.md");
    for f in [
        "param(",
        "cameras()",
        "lamps()",
        "axes()",
        "has_laser()",
        "has_cart()",
        "block(",
        "home(",
        "move_to(",
        "lamp(",
        "lamps_on(",
        "only_lamp(",
        "lamps_off()",
        "laser_arm()",
        "laser_on(",
        "laser_off()",
        "laser_disarm()",
        "capture(",
        "laser_sweep(",
        "cart_to(",
        "prompt(",
        "wait(",
        "laser_colours()",
        "laser_fitted()",
        "laser_tilt_axis()",
        "cart_travel_mm()",
        "rig_name()",
        "block_path()",
    ] {
        assert!(readme.contains(f), "README does not document {f}");
    }
}
