//! The capture API: call positions, nested blocks, the steps each function appends, rig
//! queries, capture options and laser sweeps.

use super::*;
use crate::plan::Action;

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
            placement: None,
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
            placement: None,
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
