//! Script parameters: declared defaults, `--set` overrides parsed to the default's type, bad
//! values, unknown names and redeclarations.

use super::*;
use crate::plan::Action;

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
