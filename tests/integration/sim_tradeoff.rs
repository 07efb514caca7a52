//! `stagehand sim tradeoff` argument errors: a clear message and exit code 2, before any
//! rendering starts. (The sweep itself is tested in the simulator's `tradeoff` module.)

use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

fn tradeoff(args: &[&str]) -> Output {
    let out = tempfile::tempdir().unwrap();
    let mut all = vec!["sim", "tradeoff", "--out", out.path().to_str().unwrap()];
    all.extend_from_slice(args);
    Command::new(BIN).args(&all).output().unwrap()
}

fn assert_bad(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
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
fn unknown_scene_is_named() {
    let _turn = crate::grbl_peer::alongside();
    assert_bad(&tradeoff(&["teapot"]), &["unknown scene `teapot`", "bumps"]);
}

#[test]
fn bad_numbers_are_named() {
    let _turn = crate::grbl_peer::alongside();
    assert_bad(&tradeoff(&["--width", "0"]), &["--width", "1 to 4096"]);
    assert_bad(&tradeoff(&["--height=-3"]), &["--height"]);
    assert_bad(&tradeoff(&["--width", "wide"]), &["--width"]);
    assert_bad(
        &tradeoff(&["--target-rmse", "abc"]),
        &["--target-rmse", "abc"],
    );
    assert_bad(&tradeoff(&["--target-rmse=-1%"]), &["--target-rmse"]);
    assert_bad(&tradeoff(&["--repeat", "0"]), &["--repeat"]);
    assert_bad(&tradeoff(&["--mitsuba-spp", "1,x"]), &["--mitsuba-spp"]);
    assert_bad(&tradeoff(&["--camera", "cam9"]), &["cam9", "cam4"]);
}

#[test]
fn unknown_subcommand_and_flag() {
    let _turn = crate::grbl_peer::alongside();
    let o = Command::new(BIN).args(["sim", "melt"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_bad(&tradeoff(&["--fast"]), &["--fast"]);
}
