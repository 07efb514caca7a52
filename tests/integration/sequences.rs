//! Every sequence of the seed rig, scaled down, runs end to end on the simulated rig and
//! writes a complete, consistent dataset.

use crate::common;

use common::*;
use stagehand::storage::RunStatus;

/// Runs `seq` and checks the dataset against the plan; returns the run directory and the
/// temporary directory that holds it (removed when dropped).
fn check_sequence(
    seq: &str,
    rig: &str,
    overrides: &[(&str, &str)],
) -> (tempfile::TempDir, std::path::PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let rig_src = small_rig(rig, 48, 36);
    let prepared = stagehand::session::prepare(script(seq), &sets(overrides), rig_src.clone())
        .expect("prepares");
    let expected_raw = prepared.plan.raw_frames() as i64;
    let expected_hdr = prepared.plan.hdr_frames() as i64;
    let steps = prepared.plan.steps.len() as i64;
    let out = run_prepared(
        prepared,
        tmp.path(),
        7,
        std::sync::Arc::new(stagehand::executor::AutoConfirm),
        stagehand::executor::RunControl::new(),
    );
    let summary = out
        .result
        .unwrap_or_else(|e| panic!("{seq}: run failed: {e}"));
    assert_eq!(summary.status, RunStatus::Done);
    assert!(
        summary.safety_violations.is_empty(),
        "{seq}: {:?}",
        summary.safety_violations
    );
    assert!(
        expected_raw > 0,
        "{seq}: the scaled-down plan should still capture"
    );

    let conn = db(&out.dir);
    assert_eq!(
        count(&conn, "SELECT count(*) FROM frames WHERE kind='raw'"),
        expected_raw,
        "{seq}: raw frames"
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM frames WHERE kind='hdr'"),
        expected_hdr,
        "{seq}: hdr frames"
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM steps WHERE status='done'"),
        steps,
        "{seq}: every step done"
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM runs WHERE status='done'"),
        1
    );
    // Metadata completeness: every raw frame knows every axis, its trigger, exposure and times.
    let axes = rig_src.spec.axes.len() as i64;
    let incomplete = count(
        &conn,
        &format!(
            "SELECT count(*) FROM frames WHERE kind='raw' AND (trigger_id IS NULL OR exposure_s <= 0 OR gain < 1 \
             OR rig_time_s IS NULL OR wall_time_unix_s <= 0 OR sha256 IS NULL OR length(sha256) != 64 \
             OR (SELECT count(*) FROM json_each(frames.axes_deg)) != {axes} OR fixture = '' OR camera = '')"
        ),
    );
    assert_eq!(incomplete, 0, "{seq}: frames with incomplete metadata");
    // Every frame file exists with the recorded checksum, and nothing else is in frames/.
    let mut indexed: Vec<String> = checksums(&out.dir)
        .into_iter()
        .map(|(_, sha)| sha)
        .collect();
    let mut on_disk: Vec<String> = disk_checksums(&out.dir)
        .into_iter()
        .map(|(_, sha)| sha)
        .collect();
    indexed.sort();
    on_disk.sort();
    assert_eq!(indexed, on_disk, "{seq}: index and files agree");
    // One frame per camera per trigger.
    assert_eq!(
        count(
            &conn,
            "SELECT count(*) FROM (SELECT trigger_id, camera FROM frames WHERE kind='raw' GROUP BY 1,2 HAVING count(*) > 1)"
        ),
        0
    );
    // The manifest describes the run.
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.dir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["seed"], 7);
    assert!(
        manifest["script_text"]
            .as_str()
            .unwrap()
            .contains("capture")
    );
    assert!(manifest["rig_toml"].as_str().unwrap().contains("[rig]"));
    (tmp, out.dir)
}

#[test]
fn quickstart() {
    let _turn = crate::grbl_peer::alongside();
    let (_tmp, dir) = check_sequence("quickstart.rhai", "lightstage", &[]);
    let conn = db(&dir);
    // The laser sweep frames record the laser on, armed, with its tilt.
    assert!(
        count(
            &conn,
            "SELECT count(*) FROM frames WHERE laser_on = 1 AND laser_armed = 1 AND laser_tilt_deg IS NOT NULL"
        ) > 0
    );
    // The README's query: frames of one lamp seen by one camera.
    assert!(
        count(
            &conn,
            "SELECT count(*) FROM frames, json_each(frames.lamps_on) j WHERE camera='cam5' AND j.value='lamp1'"
        ) > 0
    );
}

#[test]
fn btf_scaled_down() {
    let _turn = crate::grbl_peer::alongside();
    check_sequence(
        "btf.rhai",
        "lightstage",
        &[("views", "2"), ("lights", "2"), ("lamps", "2")],
    );
}

#[test]
fn mdf_laser_scaled_down() {
    let _turn = crate::grbl_peer::alongside();
    check_sequence(
        "mdf_laser.rhai",
        "lightstage",
        &[
            ("views", "1"),
            ("positions", "2"),
            ("mounts", "2"),
            ("lines", "3"),
        ],
    );
}

#[test]
fn quasi_homogeneous_scaled_down() {
    let _turn = crate::grbl_peer::alongside();
    check_sequence(
        "quasi_homogeneous.rhai",
        "lightstage",
        &[
            ("mounts", "1"),
            ("rotations", "2"),
            ("views", "2"),
            ("lines", "2"),
            ("lights", "1"),
            ("lamps", "2"),
        ],
    );
}

#[test]
fn reflectometer() {
    let _turn = crate::grbl_peer::alongside();
    let (_tmp, dir) = check_sequence("reflectometer.rhai", "reflectometer", &[("positions", "4")]);
    let conn = db(&dir);
    assert!(
        count(&conn, "SELECT count(DISTINCT cart_mm) FROM frames") >= 3,
        "frames along the cart's travel"
    );
    // A second sweep with the sample turned 90°: the frames record the turn (the simulator
    // renders the sample so placed), the first sweep's do not.
    let (_tmp, dir) = check_sequence(
        "reflectometer.rhai",
        "reflectometer",
        &[("positions", "4"), ("turned", "true")],
    );
    let conn = db(&dir);
    let turned = "SELECT count(*) FROM frames WHERE fixture_pose LIKE '%\"turn_deg\":90%'";
    assert_eq!(count(&conn, turned), 4, "the turned sweep's frames");
    assert_eq!(
        count(
            &conn,
            "SELECT count(*) FROM frames WHERE label LIKE 'scan turned %'"
        ),
        4
    );
}

#[test]
fn calibration_checkerboard() {
    let _turn = crate::grbl_peer::alongside();
    let (_tmp, dir) = check_sequence(
        "calibration_checkerboard.rhai",
        "lightstage",
        &[("placements", "2")],
    );
    assert!(
        count(
            &db(&dir),
            "SELECT count(*) FROM frames WHERE fixture='checkerboard'"
        ) > 0
    );
}

#[test]
fn calibration_colorchecker() {
    let _turn = crate::grbl_peer::alongside();
    let (_tmp, dir) = check_sequence(
        "calibration_colorchecker.rhai",
        "lightstage",
        &[("lamps", "2")],
    );
    assert!(
        count(
            &db(&dir),
            "SELECT count(*) FROM frames WHERE fixture='colorchecker'"
        ) > 0
    );
}
