//! Bad input: every case gives a clear message naming the place, a non-zero exit, never a
//! panic, and leaves no inconsistent dataset.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::*;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

fn stagehand(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// Checks exit code 2, no panic, and that the messages (stdout report + stderr) name the place.
fn assert_bad(o: &Output, needles: &[&str]) {
    let err = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(o));
    assert_eq!(
        o.status.code(),
        Some(2),
        "exit code for bad input; stderr: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "expected `{n}` in: {err}");
    }
}

#[test]
fn syntax_error_names_file_line_col() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let s = write(
        tmp.path(),
        "broken.rhai",
        "home();\nmove_to(\"turntable\", 30\ncapture(0.01);\n",
    );
    let o = stagehand(&["plan", &s]);
    assert_bad(&o, &["broken.rhai:"]);
    let o = stagehand(&[
        "run",
        &s,
        "--out",
        tmp.path().join("runs").to_str().unwrap(),
        "--yes",
    ]);
    assert_bad(&o, &["broken.rhai:"]);
    assert!(
        !tmp.path().join("runs").exists()
            || std::fs::read_dir(tmp.path().join("runs")).unwrap().count() == 0,
        "no run directory for a bad script"
    );
}

#[test]
fn runaway_script_is_stopped() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let s = write(tmp.path(), "spin.rhai", "let x = 0;\nloop { x += 1; }\n");
    let o = stagehand(&["plan", &s]);
    assert_bad(&o, &["spin.rhai:"]);
}

#[test]
fn unknown_device_is_reported_at_the_call() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let s = write(
        tmp.path(),
        "unknown.rhai",
        "home();\nmove_to(\"turntabel\", 30);\n",
    );
    let o = stagehand(&[
        "run",
        &s,
        "--yes",
        "--out",
        tmp.path().join("runs").to_str().unwrap(),
    ]);
    assert_bad(&o, &["unknown.rhai:2:", "turntabel"]);
}

#[test]
fn target_outside_soft_limits() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let s = write(
        tmp.path(),
        "far.rhai",
        "home();\n\nmove_to(\"laser_tilt\", 75);\n",
    );
    let o = stagehand(&["plan", &s]);
    assert_bad(&o, &["far.rhai:3:", "soft limits"]);
}

#[test]
fn negative_and_absurd_exposures() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let s = write(
        tmp.path(),
        "neg.rhai",
        "lamp(\"lamp1\", true);\ncapture(-0.01);\n",
    );
    assert_bad(&stagehand(&["plan", &s]), &["neg.rhai:2:"]);
    let s = write(
        tmp.path(),
        "huge.rhai",
        "lamp(\"lamp1\", true);\ncapture(86400.0);\n",
    );
    assert_bad(&stagehand(&["plan", &s]), &["huge.rhai:2:", "cam1"]);
}

#[test]
fn missing_and_malformed_rig_files() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let seq = root().join("sequences/quickstart.rhai");
    let o = stagehand(&["plan", seq.to_str().unwrap(), "--rig", "/no/such/rig.toml"]);
    assert_bad(&o, &["/no/such/rig.toml"]);
    let bad = write(
        tmp.path(),
        "bad.toml",
        "[rig]\nname = \"x\"\n\n[[axis]]\nid = \"t\"\nbackend = \"sim\"\nrole = \"turntable\"\nspeed_deg_s = \"fast\"\n",
    );
    let o = stagehand(&["plan", seq.to_str().unwrap(), "--rig", &bad]);
    assert_bad(&o, &["bad.toml:8:"]);
}

#[test]
fn bad_set_override() {
    let _turn = crate::grbl_peer::alongside();
    let seq = root().join("sequences/quickstart.rhai");
    let o = stagehand(&["plan", seq.to_str().unwrap(), "--set", "no_such_param=3"]);
    assert_bad(&o, &["no_such_param"]);
    let o = stagehand(&["plan", seq.to_str().unwrap(), "--set", "garbage"]);
    assert_bad(&o, &["garbage"]);
}

#[test]
fn realtime_priority_out_of_range() {
    let _turn = crate::grbl_peer::alongside();
    let seq = root().join("sequences/quickstart.rhai");
    for bad in ["0", "100", "high"] {
        let o = stagehand(&["plan", seq.to_str().unwrap(), "--realtime-priority", bad]);
        assert_bad(&o, &["--realtime-priority", bad, "1 to 99, or `off`"]);
    }
    let o = stagehand(&["plan", seq.to_str().unwrap(), "--realtime-priority", "off"]);
    assert!(o.status.success(), "`off` is accepted: {}", stderr(&o));
}

#[test]
fn unwritable_output_directory() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let file = write(tmp.path(), "not-a-dir", "x");
    let seq = root().join("sequences/quickstart.rhai");
    let out = format!("{file}/runs");
    let o = stagehand(&["run", seq.to_str().unwrap(), "--out", &out, "--yes"]);
    assert_bad(&o, &["not-a-dir"]);
}

#[test]
fn disk_full_fails_cleanly_and_resumes() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let rig = small_rig_file(tmp.path(), "lightstage", 32, 24);
    let seq = root().join("sequences/quickstart.rhai");
    let out = tmp.path().join("runs");
    // A reserve larger than any disk: the first capture step cannot be written.
    let o = stagehand(&[
        "run",
        seq.to_str().unwrap(),
        "--rig",
        rig.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--yes",
        "--reserve-mib",
        "1000000000",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("disk nearly full"), "{}", stderr(&o));
    let dir = std::fs::read_dir(&out)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let conn = db(&dir);
    assert_eq!(
        count(&conn, "SELECT count(*) FROM runs WHERE status='failed'"),
        1
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM frames"),
        0,
        "no frame row without its step"
    );
    drop(conn);
    let o = stagehand(&["resume", dir.to_str().unwrap(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        count(&db(&dir), "SELECT count(*) FROM runs WHERE status='done'"),
        1
    );
}

#[test]
fn prompt_without_an_operator_aborts_safely() {
    let _turn = crate::grbl_peer::alongside();
    // No --yes and stdin closed: the run stops at the first prompt, resumable.
    let tmp = tempfile::tempdir().unwrap();
    let rig = small_rig_file(tmp.path(), "lightstage", 32, 24);
    let seq = root().join("sequences/quickstart.rhai");
    let out = tmp.path().join("runs");
    let o = Command::new(BIN)
        .args([
            "run",
            seq.to_str().unwrap(),
            "--rig",
            rig.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("aborted"), "{}", stderr(&o));
}
