//! Errors at their place: misuse of the capture API, unknown functions, syntax errors,
//! thrown errors inside functions, and script files that cannot be read.

use super::*;

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
        (
            "wait(1);\nprompt(\"x\", #{fixture: \"checkerboard\", placement: #{tilt_deg: 95.0}});",
            "placement: tilt_deg 95 is outside",
        ),
        (
            "wait(1);\nprompt(\"x\", #{placement: #{tilt: 30.0}});",
            "unknown option `tilt`",
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
