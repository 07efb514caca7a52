//! `stagehand calibrate geometry RUN`: the cameras' intrinsics, distortion and rig poses from a
//! checkerboard run, stored as a `geometry` calibration beside the runs.

use std::path::Path;

use stagehand_processing::calibrate_camera::CalibrationOptions;
use stagehand_processing::calibration_store::{
    self, Calibration, CalibrationInput, CalibrationKind,
};
use stagehand_processing::checkerboard::CheckerboardSpec;
use stagehand_processing::geometry_calibration::calibrate_geometry_run;

use super::calibrate::{processing_err, root_of, run_id, store_err};
use crate::session::SessionError;

/// Parses `COLSxROWS` inner corners, e.g. `7x7`.
pub fn parse_corners(text: &str) -> Result<(usize, usize), String> {
    let (c, r) = text
        .split_once(['x', '×'])
        .ok_or_else(|| format!("`{text}` is not COLSxROWS inner corners, e.g. 7x7"))?;
    let parse = |s: &str| {
        s.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| *n >= 3)
            .ok_or_else(|| format!("`{s}` in `{text}`: give a whole number of inner corners ≥ 3"))
    };
    Ok((parse(c)?, parse(r)?))
}

/// Runs `stagehand calibrate geometry`.
pub fn calibrate_geometry(
    run_dir: &Path,
    corners: (usize, usize),
    square_mm: f64,
    fit_k3: bool,
    json: bool,
) -> Result<i32, SessionError> {
    if !(square_mm.is_finite() && square_mm > 0.0) {
        return Err(SessionError::Io(format!(
            "--square-mm {square_mm}: give the side of a board square in millimetres, > 0"
        )));
    }
    let board = CheckerboardSpec {
        cols: corners.0,
        rows: corners.1,
        square_mm,
    };
    let options = CalibrationOptions { fit_k3 };
    let result = calibrate_geometry_run(run_dir, board, options).map_err(processing_err)?;
    let quality = serde_json::json!({
        "rms_px": result.cameras.iter().map(|c| (c.camera.clone(), c.rms_px)).collect::<std::collections::BTreeMap<_, _>>(),
        "frames_used": result.frames.len(),
        "not_detected": result.not_detected.len(),
        "failed": result.failed,
    });
    let calibration = Calibration {
        kind: CalibrationKind::Geometry,
        cameras: result.cameras.iter().map(|c| c.camera.clone()).collect(),
        lamps: Vec::new(),
        inputs: vec![CalibrationInput {
            run_id: run_id(run_dir),
            frames: result.frames.clone(),
        }],
        parameters: serde_json::json!({"board": board, "fit_k3": fit_k3}),
        result: serde_json::to_value(&result).map_err(|e| SessionError::Io(e.to_string()))?,
        quality,
        software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
    };
    let stored = calibration_store::save(&root_of(run_dir), calibration).map_err(store_err)?;
    // A calibration that leaves a camera out is stored (the others are good) but is not a
    // success: scripts see it in the exit status.
    let status = if result.failed.is_empty() { 0 } else { 1 };
    if json {
        super::print_json(&stored)?;
        return Ok(status);
    }
    println!(
        "calibration {} ({} cameras, {} placements, {} frames; board not found in {})",
        stored.id,
        result.cameras.len(),
        result.placements.len(),
        result.frames.len(),
        result.not_detected.len()
    );
    for c in &result.cameras {
        let k = &c.model.intrinsics;
        println!(
            "  {}: reprojection RMS {:.3} px, f {:.1}/{:.1} px, principal point ({:.1}, {:.1}), centre ({:.1}, {:.1}, {:.1}) mm",
            c.camera,
            c.rms_px,
            k.fx,
            k.fy,
            k.cx,
            k.cy,
            c.centre_mm[0],
            c.centre_mm[1],
            c.centre_mm[2]
        );
    }
    for (camera, why) in &result.failed {
        println!("  {camera} LEFT OUT: {why}");
    }
    for (frame, why) in &result.not_detected {
        println!("  not found in {frame}: {why}");
    }
    println!("stored in {}", root_of(run_dir).join(&stored.id).display());
    Ok(status)
}

/// Runs `stagehand calibrate geometry --from-truth`: the simulator's exact cameras stored as a
/// geometry calibration (marked `from_truth`, which `evaluate` leaves out).
pub fn geometry_from_truth(run_dir: &Path, json: bool) -> Result<i32, SessionError> {
    let cameras = crate::evaluate::read_truth(run_dir)
        .and_then(|truth| crate::evaluate::truth_geometry(&truth))
        .map_err(|e| SessionError::Io(format!("--from-truth: {e}")))?;
    let calibration = Calibration {
        kind: CalibrationKind::Geometry,
        cameras: cameras.iter().map(|c| c.camera.clone()).collect(),
        lamps: Vec::new(),
        inputs: vec![CalibrationInput {
            run_id: run_id(run_dir),
            frames: Vec::new(),
        }],
        parameters: serde_json::json!({"from_truth": true}),
        result: serde_json::json!({ "cameras": cameras }),
        quality: serde_json::json!({"note": "the simulator's cameras as built, not a fit"}),
        software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
    };
    let stored = calibration_store::save(&root_of(run_dir), calibration).map_err(store_err)?;
    if json {
        super::print_json(&stored)?;
    } else {
        println!(
            "calibration {} ({} cameras from the simulator's truth)\nstored in {}",
            stored.id,
            cameras.len(),
            root_of(run_dir).join(&stored.id).display()
        );
    }
    Ok(0)
}
