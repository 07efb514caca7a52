//! Helpers of the calibration tests: the built-in rig drawn as built, and the CLI.

use std::path::Path;
use std::process::{Command, Output};

use stagehand::rig::RigSource;
use stagehand_processing::calibrate_camera::IntrinsicsStd;
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store::{self, Calibration, CalibrationKind};
use stagehand_processing::rig_frame::TurntableAxis;
use stagehand_processing::{CameraModel, Distortion, Intrinsics, Pose};

use super::small_rig;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

/// The built-in rig at 480×360 (the grazing cam1 sees the chart's patches a few pixels tall,
/// enough for the 5×5 sample windows) drawn as built with `response` style, at `bits` per
/// sample, with `edit` applied to the rig file's text.
pub fn as_built_rig_with(response: &str, bits: u8, edit: impl Fn(String) -> String) -> RigSource {
    let rig = small_rig("lightstage", 480, 360);
    let mut text = rig
        .text
        .replace("bit_depth = 12", &format!("bit_depth = {bits}"));
    text.push_str(&format!(
        "\n[sim.as_built]\nseed = 3\nresponse = \"{response}\"\n"
    ));
    RigSource::from_text(&edit(text), "test:lightstage+as_built").expect("rig parses")
}

/// [`as_built_rig_with`] unedited.
pub fn as_built_rig(response: &str, bits: u8) -> RigSource {
    as_built_rig_with(response, bits, |t| t)
}

/// Runs the stagehand CLI with `args`.
pub fn stagehand_output(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("stagehand runs")
}

/// Runs the stagehand CLI with `args`, expecting success and JSON on stdout.
pub fn stagehand(args: &[&str]) -> serde_json::Value {
    let out = stagehand_output(args);
    assert!(
        out.status.success(),
        "stagehand {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

/// The Rodrigues vector of rotation matrix `m` (through its quaternion, Shepperd's method).
fn rodrigues(m: [[f64; 3]; 3]) -> [f64; 3] {
    let trace = m[0][0] + m[1][1] + m[2][2];
    let (w, x, y, z) = if trace > 0.0 {
        let s = 2.0 * (1.0 + trace).sqrt();
        let (a, b, c) = (m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]);
        (0.25 * s, a / s, b / s, c / s)
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = 2.0 * (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt();
        let (a, b, c) = (m[2][1] - m[1][2], m[0][1] + m[1][0], m[0][2] + m[2][0]);
        (a / s, 0.25 * s, b / s, c / s)
    } else if m[1][1] > m[2][2] {
        let s = 2.0 * (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt();
        let (a, b, c) = (m[0][2] - m[2][0], m[0][1] + m[1][0], m[1][2] + m[2][1]);
        (a / s, b / s, 0.25 * s, c / s)
    } else {
        let s = 2.0 * (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt();
        let (a, b, c) = (m[1][0] - m[0][1], m[0][2] + m[2][0], m[1][2] + m[2][1]);
        (a / s, b / s, c / s, 0.25 * s)
    };
    let n = (x * x + y * y + z * z).sqrt();
    if n < 1e-12 {
        return [0.0; 3];
    }
    let angle = 2.0 * n.atan2(w);
    [x / n * angle, y / n * angle, z / n * angle]
}

/// A geometry calibration of every camera exactly as built (OpenCV's convention, from
/// as_built.json), stored under `root`: what a perfect geometric calibration would store.
pub fn exact_geometry(root: &Path, truth: &serde_json::Value) -> String {
    let num = |v: &serde_json::Value| v.as_f64().expect("a number");
    let cameras: Vec<CameraGeometry> = truth["cameras"]
        .as_object()
        .expect("cameras")
        .iter()
        .map(|(id, cam)| {
            let g = &cam["geometry"];
            let rows = [0, 1, 2].map(|r| [0, 1, 2].map(|c| num(&g["rotation"][r][c])));
            let t = [0, 1, 2].map(|i| num(&g["translation"][i]));
            let d = [0, 1, 2, 3, 4].map(|i| num(&g["distortion"][i]));
            CameraGeometry {
                camera: id.clone(),
                model: CameraModel {
                    intrinsics: Intrinsics {
                        fx: num(&g["fx"]),
                        fy: num(&g["fy"]),
                        cx: num(&g["cx"]),
                        cy: num(&g["cy"]),
                    },
                    distortion: Distortion {
                        k1: d[0],
                        k2: d[1],
                        p1: d[2],
                        p2: d[3],
                        k3: d[4],
                    },
                },
                rig_to_camera: Pose {
                    rotation: rodrigues(rows),
                    translation: t,
                },
                centre_mm: [0, 1, 2].map(|i| num(&g["centre_mm"][i])),
                rms_px: 0.0,
                view_rms_px: Vec::new(),
                std: IntrinsicsStd {
                    fx: 0.0,
                    fy: 0.0,
                    cx: 0.0,
                    cy: 0.0,
                },
                axis: TurntableAxis {
                    point: t,
                    direction: [rows[0][2], rows[1][2], rows[2][2]],
                    radius_mm: 0.0,
                    rms_mm: 0.0,
                },
            }
        })
        .collect();
    let calibration = Calibration {
        kind: CalibrationKind::Geometry,
        cameras: cameras.iter().map(|c| c.camera.clone()).collect(),
        lamps: Vec::new(),
        inputs: Vec::new(),
        parameters: serde_json::json!({"exact": true}),
        result: serde_json::to_value(&cameras).expect("json"),
        quality: serde_json::json!({}),
        software: "test".into(),
    };
    calibration_store::save(root, calibration)
        .expect("stored")
        .id
}
