//! `stagehand sim tradeoff` runs the `stagehand-tradeoff` program (crate `tradeoff/`, whose
//! own tests check its argument errors) with the arguments given and passes its exit code
//! on; without the program it says how to get it. The program is stood in for here by a
//! script named in `STAGEHAND_TRADEOFF`.

use std::os::unix::fs::PermissionsExt;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

fn sim(program: &std::path::Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .arg("sim")
        .args(args)
        .env("STAGEHAND_TRADEOFF", program)
        .output()
        .unwrap()
}

#[test]
fn arguments_and_exit_code_pass_through() {
    let _turn = crate::grbl_peer::alongside();
    let dir = tempfile::tempdir().unwrap();
    let fake = dir.path().join("fake-tradeoff");
    std::fs::write(&fake, "#!/bin/sh\necho \"args: $*\" >&2\nexit 2\n").unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let o = sim(
        &fake,
        &["tradeoff", "teapot", "--width", "0", "--target-rmse=1%"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("args: teapot --width 0 --target-rmse=1%"),
        "{err}"
    );
}

#[test]
fn a_missing_program_is_named() {
    let _turn = crate::grbl_peer::alongside();
    let o = sim(
        std::path::Path::new("/nonexistent/stagehand-tradeoff"),
        &["tradeoff"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("stagehand-tradeoff") && err.contains("cargo build"),
        "{err}"
    );
}

#[test]
fn unknown_subcommand() {
    let _turn = crate::grbl_peer::alongside();
    let o = Command::new(BIN).args(["sim", "melt"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
}
