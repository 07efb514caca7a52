//! Tests of the script builder and of every sequence in `sequences/`.

use std::time::{Duration, Instant};

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};

use super::*;
use crate::plan::{Action, Plan};

fn lightstage() -> RigSpec {
    parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("built-in rig parses")
}

fn reflectometer() -> RigSpec {
    parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").expect("built-in rig parses")
}

fn src(text: &str) -> ScriptSource {
    ScriptSource {
        name: "test.rhai".into(),
        text: text.into(),
    }
}

fn sets(pairs: &[&str]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|p| parse_set(p).expect("valid --set"))
        .collect()
}

fn run(text: &str) -> Result<Plan, ScriptError> {
    build_plan(&src(text), &[], &lightstage())
}

fn run_ok(text: &str) -> Plan {
    match run(text) {
        Ok(p) => p,
        Err(e) => panic!("script failed: {e}"),
    }
}

fn run_err(text: &str) -> ScriptError {
    match run(text) {
        Ok(p) => panic!("script should fail but made {} steps", p.steps.len()),
        Err(e) => e,
    }
}

fn count(plan: &Plan, kind: &str) -> usize {
    plan.steps
        .iter()
        .filter(|s| s.action.kind() == kind)
        .count()
}

// ---- sequences ----------------------------------------------------------------------------------

const QUICKSTART: &str = include_str!("../../sequences/quickstart.rhai");
const BTF: &str = include_str!("../../sequences/btf.rhai");
const MDF: &str = include_str!("../../sequences/mdf_laser.rhai");
const QH: &str = include_str!("../../sequences/quasi_homogeneous.rhai");
const REFLECTOMETER: &str = include_str!("../../sequences/reflectometer.rhai");
const CHECKERBOARD: &str = include_str!("../../sequences/calibration_checkerboard.rhai");
const COLORCHECKER: &str = include_str!("../../sequences/calibration_colorchecker.rhai");

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
    assert_eq!(count(&p, "capture"), positions * (1 + 64));
    assert_eq!(p.raw_frames(), positions * 65 * 8);
    assert_eq!(p.steps.len(), 44_067);
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
    assert_eq!(remounts, 12 * 5);
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
    assert_eq!(count(&p, "capture"), 7 * 3);
    // 7 positions over 3 mounts: 3 + 2 + 2.
    let per_mount: Vec<usize> = (0..3)
        .map(|m| {
            let prefix = format!("view 0/mount {m}/");
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
    assert_eq!(count(&p, "capture"), step1 + step2 + step3);
    assert_eq!(p.raw_frames(), (step1 + step2) * 8 + step3 * 3 * 8);
    assert_eq!(p.hdr_frames(), step3 * 8);
    assert_eq!(p.steps.len(), 40_222);
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
    assert_eq!(count(&p, "capture"), 2 * (2 * 3 + 2 * 3) + 2 * 2);
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
    assert_eq!(count(&p, "capture"), 8);
    assert_eq!(p.raw_frames(), 64);
    assert_eq!(p.steps.len(), 20);
    assert!(p.steps.iter().all(|s| match &s.action {
        Action::Prompt { fixture, .. } => fixture.as_deref() == Some("checkerboard"),
        _ => true,
    }));
    let p = sequence(
        "calibration_checkerboard.rhai",
        CHECKERBOARD,
        &lightstage(),
        &["placements=2"],
    );
    assert_eq!(count(&p, "capture"), 2);

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
    let readme = include_str!("../../sequences/README.md");
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

// ---- the capture API ----------------------------------------------------------------------------

#[test]
fn empty_script_makes_an_empty_plan() {
    let p = run_ok("let x = 1 + 2;\nfor i in 0..10 { x += i; }\nprint(`x = ${x}`);\n");
    assert!(p.steps.is_empty());
    assert!(p.params.is_empty());
    assert_eq!(p.script, "test.rhai");
}

#[test]
fn steps_record_their_call_position() {
    let text = "home();\n  move_to(\"turntable\", 30);\nfor i in 0..2 {\n    capture(0.01);\n}\n";
    let p = run_ok(text);
    let at: Vec<(u32, u32)> = p.steps.iter().map(|s| (s.at.line, s.at.col)).collect();
    assert_eq!(at, vec![(1, 1), (2, 3), (4, 5), (4, 5)]);
    assert_eq!(
        p.steps[1].action,
        Action::Move {
            targets: [("turntable".to_string(), 30.0)].into()
        }
    );
}

#[test]
fn positions_inside_functions_and_closures() {
    let text = "fn shoot(e) {\n  capture(e);\n}\nlet f = || lamps_off();\nshoot(0.1);\nf.call();\n";
    let p = run_ok(text);
    assert_eq!((p.steps[0].at.line, p.steps[0].at.col), (2, 3));
    assert_eq!((p.steps[1].at.line, p.steps[1].at.col), (4, 12));
}

#[test]
fn blocks_nest_and_pop() {
    let text = r#"
block("a", || {
    capture(0.01);
    block("b", || {
        block("c", || { wait(1); });
        capture(0.02, #{label: "x"});
    });
    wait(2);
});
wait(3);
let r = block("d", || 42);
if r != 42 { throw "block must return the closure's value"; }
"#;
    let p = run_ok(text);
    let blocks: Vec<&str> = p.steps.iter().map(|s| s.block.as_str()).collect();
    assert_eq!(blocks, vec!["a", "a/b/c", "a/b", "a", ""]);
    match &p.steps[0].action {
        Action::Capture {
            label,
            hdr,
            gain,
            cameras,
            min_interval_s,
            ..
        } => {
            assert_eq!(label, "a");
            assert!(!hdr);
            assert_eq!(*gain, 1.0);
            assert_eq!(cameras.len(), 8);
            assert_eq!(*min_interval_s, 0.0);
        }
        other => panic!("unexpected {other:?}"),
    }
    match &p.steps[2].action {
        Action::Capture { label, .. } => assert_eq!(label, "x"),
        other => panic!("unexpected {other:?}"),
    }
}

#[test]
fn block_stack_pops_after_a_caught_error() {
    let text = r#"
try { block("a", || { throw "boom"; }); } catch { }
wait(1);
"#;
    let p = run_ok(text);
    assert_eq!(p.steps[0].block, "");
}

#[test]
fn block_names_are_checked() {
    let e = run_err("block(\"a/b\", || {});");
    assert!(e.to_string().contains("must not contain `/`"), "{e}");
    let e = run_err("block(\"a\", 3);");
    assert!(e.to_string().contains("closure"), "{e}");
    assert_eq!(e.position(), Some((1, 1)));
}

#[test]
fn home_move_lamps_laser_actions() {
    let text = r#"
home();
home("turntable");
home(["turntable", "light_arc"]);
move_to(#{turntable: 10, light_arc: 20.5});
lamp("lamp2", true);
lamps_on(["lamp1", "lamp3"]);
only_lamp("lamp4");
lamps_off();
laser_off();
laser_arm();
laser_on(532);
laser_off();
prompt("swap", #{laser_fit_nm: 473, laser_mount_deg: 60, fixture: "planes"});
laser_off();
laser_disarm();
cart_to(12);
wait(0.5);
prompt("hello");
"#;
    let p = run_ok(text);
    let a: Vec<&Action> = p.steps.iter().map(|s| &s.action).collect();
    assert_eq!(
        a[0],
        &Action::Home {
            axes: vec!["turntable".into(), "light_arc".into(), "laser_tilt".into()]
        }
    );
    assert_eq!(
        a[1],
        &Action::Home {
            axes: vec!["turntable".into()]
        }
    );
    assert_eq!(
        a[2],
        &Action::Home {
            axes: vec!["turntable".into(), "light_arc".into()]
        }
    );
    assert_eq!(
        a[3],
        &Action::Move {
            targets: [
                ("turntable".to_string(), 10.0),
                ("light_arc".to_string(), 20.5)
            ]
            .into()
        }
    );
    assert_eq!(
        a[4],
        &Action::Lamps {
            states: [("lamp2".to_string(), true)].into()
        }
    );
    assert_eq!(
        a[5],
        &Action::Lamps {
            states: [("lamp1".to_string(), true), ("lamp3".to_string(), true)].into()
        }
    );
    match a[6] {
        Action::Lamps { states } => {
            assert_eq!(states.len(), 8);
            assert_eq!(
                states
                    .iter()
                    .filter(|(_, on)| **on)
                    .map(|(id, _)| id.as_str())
                    .collect::<Vec<_>>(),
                vec!["lamp4"]
            );
        }
        other => panic!("{other:?}"),
    }
    match a[7] {
        Action::Lamps { states } => assert!(states.len() == 8 && states.values().all(|on| !on)),
        other => panic!("{other:?}"),
    }
    // Before any laser_on: the rig's fitted colour.
    assert_eq!(
        a[8],
        &Action::Laser {
            on: false,
            colour_nm: 650
        }
    );
    assert_eq!(a[9], &Action::LaserArm);
    assert_eq!(
        a[10],
        &Action::Laser {
            on: true,
            colour_nm: 532
        }
    );
    assert_eq!(
        a[11],
        &Action::Laser {
            on: false,
            colour_nm: 532
        }
    );
    assert_eq!(
        a[12],
        &Action::Prompt {
            message: "swap".into(),
            fixture: Some("planes".into()),
            laser_mount_deg: Some(60.0),
            laser_fit_nm: Some(473),
        }
    );
    // After a prompt fits another laser, laser_off names it.
    assert_eq!(
        a[13],
        &Action::Laser {
            on: false,
            colour_nm: 473
        }
    );
    assert_eq!(a[14], &Action::LaserDisarm);
    assert_eq!(a[15], &Action::CartTo { position_mm: 12.0 });
    assert_eq!(a[16], &Action::Wait { seconds: 0.5 });
    assert_eq!(
        a[17],
        &Action::Prompt {
            message: "hello".into(),
            fixture: None,
            laser_mount_deg: None,
            laser_fit_nm: None
        }
    );
}

#[test]
fn rig_queries() {
    let text = r#"
if cameras().len() != 8 { throw "cameras"; }
if lamps() != ["lamp1", "lamp2", "lamp3", "lamp4", "lamp5", "lamp6", "lamp7", "lamp8"] { throw "lamps"; }
if axes() != ["turntable", "light_arc", "laser_tilt"] { throw "axes"; }
if !has_laser() || has_cart() { throw "laser/cart"; }
if laser_colours() != [650, 532, 473] || laser_fitted() != 650 { throw "colours"; }
if laser_tilt_axis() != "laser_tilt" || rig_name() != "lightstage" { throw "names"; }
if rig_sample() != "bumps" { throw "sample"; }
if lamps("tube") != [] || lamps("all").len() != 8 { throw "kinds"; }
"#;
    run_ok(text);
    let text = r#"
if cameras() != ["cam1"] || lamps() != [] || axes() != [] { throw "ids"; }
if has_laser() || !has_cart() || cart_travel_mm() != 240.0 { throw "cart"; }
if lamps("tube") != ["tube"] || lamps("backlight") != ["backlight"] { throw "kinds"; }
home();
lamps_off();
"#;
    let p = build_plan(&src(text), &[], &reflectometer()).expect("runs");
    // No axes: home() adds nothing; lamps_off() switches tube and backlight.
    assert_eq!(p.steps.len(), 1);
    assert_eq!(
        p.steps[0].action,
        Action::Lamps {
            states: [
                ("backlight".to_string(), false),
                ("tube".to_string(), false)
            ]
            .into()
        }
    );
    let e = build_plan(&src("\nlaser_off();"), &[], &reflectometer()).expect_err("no laser");
    assert_eq!(e.position(), Some((2, 1)));
    assert!(e.to_string().contains("has no laser"), "{e}");
}

#[test]
fn capture_options_and_defaults() {
    let text = r#"
capture([0.01, 0.02]);
capture([0.01, 0.02], #{hdr: false, cameras: ["cam2", "cam5"], gain: 2, label: "L", min_interval_s: 0.5});
capture(1);
"#;
    let p = run_ok(text);
    match &p.steps[0].action {
        Action::Capture {
            hdr, exposures_s, ..
        } => {
            assert!(*hdr);
            assert_eq!(exposures_s, &vec![0.01, 0.02]);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        p.steps[1].action,
        Action::Capture {
            exposures_s: vec![0.01, 0.02],
            cameras: vec!["cam2".into(), "cam5".into()],
            gain: 2.0,
            hdr: false,
            label: "L".into(),
            min_interval_s: 0.5,
        }
    );
    assert_eq!(p.raw_frames(), 16 + 4 + 8);
    assert_eq!(p.hdr_frames(), 8);
}

#[test]
fn laser_sweep_steps() {
    let p = run_ok(
        "block(\"s\", || laser_sweep(#{from_deg: -2, to_deg: 2, lines: 5, rate_hz: 4, exposure_s: 0.001, cameras: [\"cam1\"]}));",
    );
    assert_eq!(p.steps.len(), 10);
    let angles: Vec<f64> = p
        .steps
        .iter()
        .filter_map(|s| match &s.action {
            Action::Move { targets } => targets.get("laser_tilt").copied(),
            _ => None,
        })
        .collect();
    assert_eq!(angles, vec![-2.0, -1.0, 0.0, 1.0, 2.0]);
    match &p.steps[1].action {
        Action::Capture {
            min_interval_s,
            exposures_s,
            cameras,
            hdr,
            label,
            ..
        } => {
            assert_eq!(*min_interval_s, 0.25);
            assert_eq!(exposures_s, &vec![0.001]);
            assert_eq!(cameras, &vec!["cam1".to_string()]);
            assert!(!hdr);
            assert_eq!(label, "s line 0");
        }
        other => panic!("{other:?}"),
    }
    let p = run_ok(
        "laser_sweep(#{from_deg: 3, to_deg: 9, lines: 1, rate_hz: 7.5, exposure_s: 0.002});",
    );
    assert_eq!(
        p.steps[0].action,
        Action::Move {
            targets: [("laser_tilt".to_string(), 3.0)].into()
        }
    );
}

#[test]
fn api_misuse_is_an_error_at_the_call() {
    let cases: &[(&str, &str)] = &[
        (
            "wait(1);\ncapture(0.01, #{gian: 2});",
            "unknown option `gian`",
        ),
        (
            "wait(1);\nlaser_sweep(#{from_deg: 0, to_deg: 1, lines: 0, rate_hz: 1, exposure_s: 0.1});",
            "lines must be at least 1",
        ),
        (
            "wait(1);\nlaser_sweep(#{from_deg: 0, to_deg: 1, lines: 3, rate_hz: 1});",
            "missing option exposure_s",
        ),
        (
            "wait(1);\nlaser_sweep(#{from_deg: 0, to_deg: 1, lines: 3, rate_hz: 1, exposure_s: 0.1, speed: 2});",
            "unknown option `speed`",
        ),
        (
            "wait(1);\nprompt(\"x\", #{fixtrue: \"planes\"});",
            "unknown option `fixtrue`",
        ),
        ("wait(1);\ncapture([]);", "list of exposures is empty"),
        (
            "wait(1);\ncapture(\"fast\");",
            "must be a number of seconds",
        ),
        (
            "wait(1);\nmove_to(\"turntable\", \"far\");",
            "must be a number",
        ),
        ("wait(1);\nmove_to(\"turntable\", 1.0 / 0.0);", "finite"),
        ("wait(1);\nmove_to(#{});", "empty"),
        ("wait(1);\ncapture(parse_float(\"NaN\"));", "finite"),
        ("wait(1);\nlamp(\"lamp1\", 1);", "true or false"),
        ("wait(1);\nlaser_on(-5);", "positive wavelength"),
        ("wait(1);\nwait(-1);", "must not be negative"),
        ("wait(1);\nhome(3);", "axis id"),
        ("wait(1);\nlamps_on([]);", "empty"),
        (
            "wait(1);\ncapture(0.1, #{cameras: []});",
            "cameras is empty",
        ),
    ];
    for (text, needle) in cases {
        let e = run_err(text);
        assert!(matches!(e, ScriptError::Api { .. }), "{text}: {e:?}");
        assert_eq!(e.position(), Some((2, 1)), "{text}: {e}");
        let msg = e.to_string();
        assert!(msg.starts_with("test.rhai:2:1: "), "{msg}");
        assert!(msg.contains(needle), "{text}: `{msg}` lacks `{needle}`");
    }
}

#[test]
fn api_errors_cannot_be_caught() {
    let e = run_err("try {\n  capture([]);\n} catch (err) { }\nwait(1);");
    assert_eq!(e.position(), Some((2, 3)));
}

#[test]
fn unknown_function_and_wrong_arity_carry_a_position() {
    let e = run_err("wait(1);\n  captur(0.01);");
    assert_eq!(e.position(), Some((2, 3)));
    let msg = e.to_string();
    assert!(
        msg.starts_with("test.rhai:2:3: no function matches `captur"),
        "{msg}"
    );
    let e = run_err("block(\"a\", || {\n    move_to(\"turntable\", 1, 2);\n});");
    assert_eq!(e.position(), Some((2, 5)), "{e}");
    assert!(e.to_string().contains("move_to"), "{e}");
}

#[test]
fn syntax_error_position() {
    let e = run_err("home();\nlet x = (1 + ;\n");
    assert!(matches!(e, ScriptError::Syntax { line: 2, .. }), "{e:?}");
    assert!(e.to_string().starts_with("test.rhai:2:"), "{e}");
    let e = run_err("home();\n\n   capture(undefined_var);\n");
    assert_eq!(e.position(), Some((3, 12)), "{e}");
    assert!(
        e.to_string().contains("unknown variable `undefined_var`"),
        "{e}"
    );
}

#[test]
fn thrown_errors_report_position_and_function() {
    let e = run_err("fn f() {\n  throw \"nope\";\n}\nf();");
    assert_eq!(e.position(), Some((2, 3)));
    let msg = e.to_string();
    assert!(
        msg.contains("nope") && msg.contains("in function `f` called at 4:1"),
        "{msg}"
    );
}

// ---- parameters -----------------------------------------------------------------------------

const PARAMS: &str = r#"
let n = param("n", 3);
let x = param("x", 0.5);
let on = param("on", true);
let who = param("who", "sample");
let e = param("e", [0.01, 0.02]);
let ids = param("ids", ["cam1"]);
for i in 0..n { capture(e, #{cameras: ids, gain: x, hdr: on, label: who}); }
"#;

#[test]
fn params_defaults_are_recorded() {
    let p = run_ok(PARAMS);
    assert_eq!(count(&p, "capture"), 3);
    assert_eq!(
        serde_json::Value::Object(p.params.clone().into_iter().collect()),
        serde_json::json!({"n": 3, "x": 0.5, "on": true, "who": "sample", "e": [0.01, 0.02], "ids": ["cam1"]})
    );
}

#[test]
fn params_overrides_parse_to_the_default_type() {
    let o = sets(&[
        "n=2",
        "x=3",
        "on=false",
        "who=planes",
        "e=[0.1, 1]",
        "ids=cam2,cam3",
    ]);
    let p = build_plan(&src(PARAMS), &o, &lightstage()).expect("runs");
    assert_eq!(count(&p, "capture"), 2);
    assert_eq!(
        p.steps[0].action,
        Action::Capture {
            exposures_s: vec![0.1, 1.0],
            cameras: vec!["cam2".into(), "cam3".into()],
            gain: 3.0,
            hdr: false,
            label: "planes".into(),
            min_interval_s: 0.0,
        }
    );
    assert_eq!(p.params["x"], serde_json::json!(3.0));
    assert_eq!(p.params["e"], serde_json::json!([0.1, 1.0]));
    // A later --set wins.
    let o = sets(&["n=2", "n=1"]);
    let p = build_plan(&src(PARAMS), &o, &lightstage()).expect("runs");
    assert_eq!(count(&p, "capture"), 1);
}

#[test]
fn params_bad_values_name_the_parameter_and_type() {
    for (set, expected) in [
        ("n=2.5", "an integer"),
        ("x=fast", "a finite number"),
        ("x=inf", "a finite number"),
        ("on=yes", "true or false"),
        ("e=0.1,x", "comma-separated list of finite numbers"),
    ] {
        let e = build_plan(&src(PARAMS), &sets(&[set]), &lightstage()).expect_err(set);
        let name = set.split('=').next().unwrap_or_default();
        match &e {
            ScriptError::BadParamValue {
                name: n,
                expected: exp,
                ..
            } => {
                assert_eq!(n, name);
                assert!(exp.contains(expected), "{exp}");
            }
            other => panic!("{set}: {other:?}"),
        }
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("parameter `{name}` expects")),
            "{msg}"
        );
        assert!(msg.starts_with("test.rhai:"), "{msg}");
    }
}

#[test]
fn params_unknown_set_lists_declared() {
    let e = build_plan(&src(PARAMS), &sets(&["nn=2", "x=1"]), &lightstage()).expect_err("unknown");
    assert_eq!(
        e,
        ScriptError::UnknownParam {
            file: "test.rhai".into(),
            unknown: vec!["nn".into()],
            declared: ["e", "ids", "n", "on", "who", "x"]
                .iter()
                .map(|s| s.to_string())
                .collect(),
        }
    );
    assert_eq!(e.position(), None);
    let msg = e.to_string();
    assert!(msg.starts_with("test.rhai: --set nn:"), "{msg}");
    assert!(
        msg.contains("declared parameters: e, ids, n, on, who, x"),
        "{msg}"
    );
    let e = run_err_with("capture(0.1);", &["views=2"]);
    assert!(e.to_string().contains("declared parameters: none"), "{e}");
}

fn run_err_with(text: &str, overrides: &[&str]) -> ScriptError {
    build_plan(&src(text), &sets(overrides), &lightstage()).expect_err("should fail")
}

#[test]
fn params_redeclared_and_bad_defaults() {
    // The same default twice is fine (e.g. a helper function called twice).
    let p = run_ok(
        "fn v() { param(\"v\", 2) }\nlet a = v();\nlet b = v();\nif a + b != 4 { throw \"x\"; }",
    );
    assert_eq!(p.params["v"], serde_json::json!(2));
    let e = run_err("param(\"v\", 2);\nparam(\"v\", 3);");
    assert_eq!(e.position(), Some((2, 1)));
    assert!(e.to_string().contains("already declared at 1:1"), "{e}");
    let e = run_err("param(\"v\", #{a: 1});");
    assert!(e.to_string().contains("parameter default must be"), "{e}");
    let e = run_err("param(\"my param\", 1);");
    assert!(e.to_string().contains("not a valid parameter name"), "{e}");
}

#[test]
fn parse_set_forms() {
    assert_eq!(parse_set("views=4"), Ok(("views".into(), "4".into())));
    assert_eq!(parse_set("label=a=b"), Ok(("label".into(), "a=b".into())));
    assert_eq!(parse_set("label="), Ok(("label".into(), String::new())));
    for bad in ["views", "=4", "9x=1", "a b=1"] {
        let e = parse_set(bad).expect_err(bad);
        assert!(e.to_string().starts_with(&format!("--set {bad}: ")), "{e}");
        assert_eq!(e.position(), None);
    }
}

// ---- limits -------------------------------------------------------------------------------------

fn quick_limits() -> ScriptLimits {
    ScriptLimits {
        max_operations: 2_000_000,
        max_wall_time: Duration::from_secs(5),
        ..ScriptLimits::default()
    }
}

fn run_limited(text: &str, limits: &ScriptLimits) -> ScriptError {
    build_plan_with_limits(&src(text), &[], &lightstage(), limits).expect_err("should hit a limit")
}

#[test]
fn endless_loop_is_stopped() {
    let started = Instant::now();
    let e = run_limited("home();\nloop {}\n", &quick_limits());
    assert!(started.elapsed() < Duration::from_secs(2));
    match &e {
        ScriptError::Limit { limit, at, .. } => {
            assert_eq!(*limit, "max_operations");
            assert_eq!(at.map(|(l, _)| l), Some(2));
        }
        other => panic!("{other:?}"),
    }
    let msg = e.to_string();
    assert!(msg.starts_with("test.rhai:2:"), "{msg}");
    assert!(msg.contains("max_operations"), "{msg}");
}

#[test]
fn wall_clock_limit_stops_a_script() {
    let limits = ScriptLimits {
        max_operations: 0,
        max_wall_time: Duration::from_millis(200),
        ..ScriptLimits::default()
    };
    let started = Instant::now();
    let e = run_limited("let i = 0;\nloop { i += 1; }\n", &limits);
    assert!(started.elapsed() < Duration::from_secs(2));
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_wall_time",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("max_wall_time"), "{e}");
    assert!(e.position().is_some());
}

#[test]
fn huge_arrays_and_strings_are_stopped() {
    let started = Instant::now();
    let e = run_limited("let a = [];\na.pad(100000000, 0);\n", &quick_limits());
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_array_items",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().starts_with("test.rhai:2:"), "{e}");
    // Rhai re-measures an array after every push, so a push loop is quadratic: keep it small.
    let small = ScriptLimits {
        max_array_items: 10_000,
        ..quick_limits()
    };
    let e = run_limited("let a = [];\nloop { a.push(1); }\n", &small);
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_array_items",
                ..
            }
        ),
        "{e:?}"
    );
    let e = run_limited("let s = \"x\";\nloop { s += s; }\n", &quick_limits());
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_string_bytes",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(started.elapsed() < Duration::from_secs(2));
}

#[test]
fn deep_recursion_is_stopped() {
    let e = run_limited("fn f(n) { f(n + 1) }\nf(0);\n", &quick_limits());
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_call_depth",
                ..
            }
        ),
        "{e:?}"
    );
    let e = run_limited(
        "fn b(n) { block(`b${n}`, || b(n + 1)) }\nb(0);\n",
        &quick_limits(),
    );
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_call_depth",
                ..
            }
        ),
        "{e:?}"
    );
}

#[test]
fn plan_step_cap() {
    let limits = ScriptLimits {
        max_steps: 100,
        ..quick_limits()
    };
    let e = run_limited("for i in 0..1000 {\n  wait(1);\n}\n", &limits);
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_steps",
                at: Some((2, 3)),
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("100 steps"), "{e}");
    let e = run_limited(
        "laser_sweep(#{from_deg: 0, to_deg: 1, lines: 1000000000, rate_hz: 1, exposure_s: 0.1});",
        &limits,
    );
    assert!(
        matches!(
            e,
            ScriptError::Limit {
                limit: "max_steps",
                ..
            }
        ),
        "{e:?}"
    );
    // The default cap is two million steps.
    assert_eq!(ScriptLimits::default().max_steps, 2_000_000);
}

#[test]
fn expression_depth_is_limited() {
    let deep = format!("let x = {}1{};", "(".repeat(300), ")".repeat(300));
    let e = run_err(&deep);
    assert!(matches!(e, ScriptError::Syntax { .. }), "{e:?}");
    assert!(e.to_string().contains("max_expr_depth"), "{e}");
}

#[test]
fn imports_and_eval_are_disabled() {
    let e = run_err("import \"other\" as o;");
    assert!(e.position().is_some(), "{e}");
    let e = run_err("eval(\"home()\");");
    assert!(e.position().is_some(), "{e}");
}

#[test]
fn script_source_from_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.rhai");
    std::fs::write(&path, "home();").expect("write");
    let s = ScriptSource::from_file(&path).expect("reads");
    assert_eq!(s.text, "home();");
    assert_eq!(s.name, path.display().to_string());
    let missing = dir.path().join("missing.rhai");
    let e = ScriptSource::from_file(&missing).expect_err("missing");
    assert!(
        e.to_string()
            .starts_with(&format!("{}: cannot read the script", missing.display())),
        "{e}"
    );
    assert_eq!(e.position(), None);
}
