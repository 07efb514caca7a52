//! Calibration end to end on a simulated rig as built (`[sim.as_built]`): a response sweep
//! captured with `sequences/calibration_response.rhai`, `stagehand calibrate response`, and
//! `stagehand evaluate` against the simulator's truth in `as_built.json`, through the CLI.

use std::path::Path;

use super::common::calibration::{as_built_rig, stagehand};
use super::common::run_sequence;

fn calibrate_and_evaluate(dir: &Path) -> serde_json::Value {
    let dir = dir.to_str().expect("utf-8 path");
    let stored = stagehand(&["calibrate", "response", dir, "--json"]);
    assert!(
        stored["id"]
            .as_str()
            .is_some_and(|id| id.starts_with("response-"))
    );
    // The same run and settings give the same calibration.
    assert_eq!(
        stagehand(&["calibrate", "response", dir, "--json"])["id"],
        stored["id"]
    );
    stagehand(&["evaluate", dir])
}

#[test]
fn the_response_of_scientific_cameras_is_recovered_within_1_percent() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().unwrap();
    let run = run_sequence(
        "calibration_response.rhai",
        as_built_rig("gentle", 12),
        &[],
        out.path(),
        1,
    );
    run.result.as_ref().expect("the sweep runs");
    assert!(run.dir.join("as_built.json").is_file());
    let report = calibrate_and_evaluate(&run.dir);
    let worst = report["response"][0]["worst_rel_error"]
        .as_f64()
        .expect("figures");
    assert!(worst < 0.01, "worst relative error {worst}: {report:#}");
}

#[test]
fn the_strong_response_of_8_bit_cameras_is_recovered_within_1_percent() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().unwrap();
    let run = run_sequence(
        "calibration_response.rhai",
        as_built_rig("strong", 8),
        &[],
        out.path(),
        1,
    );
    run.result.as_ref().expect("the sweep runs");
    let report = calibrate_and_evaluate(&run.dir);
    let worst = report["response"][0]["worst_rel_error"]
        .as_f64()
        .expect("figures");
    assert!(worst < 0.01, "worst relative error {worst}: {report:#}");
}
