//! The limits a script runs under: operations, wall-clock time, value sizes, call and
//! expression depth, plan steps, and the disabled `import` and `eval`.

use std::time::{Duration, Instant};

use super::*;

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
