//! Rectification and the BTF end to end, after the geometric calibration of
//! [`super::calibration`]: the checkerboard run itself rectified (the flat board's corners,
//! detected in the rectified images, must land where the board's layout puts them on the
//! reference plane), then a small BTF capture of `bumps` processed into rectified images and
//! the Zarr BTF, measured by `evaluate` against the rig as built, and resumed.

use std::path::Path;

use stagehand::rig::RigSource;
use stagehand_dataset::exr_planes::decode_exr_planes;
use stagehand_dataset::products::ProductStore;
use stagehand_dataset::{FrameQuery, RunReader};
use stagehand_processing::checkerboard::{CheckerboardSpec, detect_checkerboard};
use stagehand_processing::gray_image::GrayImage;

use super::common::calibration::{as_built_rig, stagehand};
use super::common::run_sequence;

/// Output pixels per side, and the square kept: the simulated sample's 80 mm.
const SIZE_PX: usize = 256;
const SQUARE_MM: f64 = 80.0;

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// The simulated board: 9×8 squares of 8 mm centred on the sample's origin; its inner
/// corners in output pixels of the rectified square.
fn true_corners() -> Vec<(f64, f64)> {
    let pixel = SQUARE_MM / SIZE_PX as f64;
    let mut out = Vec::new();
    for j in 1..8 {
        for i in 1..9 {
            let (x, y) = ((i as f64 - 4.5) * 8.0, (j as f64 - 4.0) * 8.0);
            // Output pixel centres sit at +0.5: position (i, j) in pixels is pixel i − 0.5.
            out.push((
                (x + 0.5 * SQUARE_MM) / pixel - 0.5,
                (y + 0.5 * SQUARE_MM) / pixel - 0.5,
            ));
        }
    }
    out
}

/// The checkerboard run's flat placements, rectified, and the board's corners detected in
/// them: the median and largest distance (output pixels) of a detected corner from the
/// board's true corner.
fn flat_board_corners_align(
    run: &Path,
    response: &str,
    geometry: &str,
    cameras: &str,
) -> (f64, f64) {
    let done = stagehand(&[
        "process",
        path(run),
        "--products",
        "rectified",
        "--calibration",
        response,
        "--calibration",
        geometry,
        "--cameras",
        cameras,
        "--json",
    ]);
    assert!(done["rectified"]["written"].as_u64() > Some(0), "{done}");
    let reader = RunReader::open(run).unwrap();
    let flat_steps: std::collections::BTreeSet<usize> = reader
        .frames(&FrameQuery::default())
        .unwrap()
        .frames
        .into_iter()
        .filter(|f| f.meta.fixture_pose.is_flat_centred())
        .map(|f| f.meta.step)
        .collect();
    let truth = true_corners();
    let spec = CheckerboardSpec {
        cols: 8,
        rows: 7,
        square_mm: 8.0,
    };
    let (mut errors, mut checked) = (Vec::new(), 0);
    for p in ProductStore::open(run).unwrap().products().unwrap() {
        let step: usize = p.made.key.split('/').nth(1).unwrap()[1..].parse().unwrap();
        if p.made.kind != "rectified" || !flat_steps.contains(&step) {
            continue;
        }
        let bytes = std::fs::read(run.join(&p.path)).unwrap();
        let exr = decode_exr_planes(&p.path, &bytes).unwrap();
        let (r, g, b) = (
            exr.channel("R").unwrap(),
            exr.channel("G").unwrap(),
            exr.channel("B").unwrap(),
        );
        let gray = GrayImage {
            width: exr.width as usize,
            height: exr.height as usize,
            data: (0..r.len()).map(|i| r[i] + g[i] + b[i]).collect(),
        };
        let Ok(corners) = detect_checkerboard(&gray, &spec) else {
            continue;
        };
        for (u, v) in corners {
            let nearest = truth
                .iter()
                .map(|(x, y)| (x - u).hypot(y - v))
                .fold(f64::INFINITY, f64::min);
            errors.push(nearest);
        }
        checked += 1;
    }
    // 4 flat placements per camera: most are found (the grazing cameras' images are blurred
    // along one axis by the footprint averaging and may not be).
    assert!(checked >= 12, "rectified flat boards checked: {checked}");
    errors.sort_by(f64::total_cmp);
    (errors[errors.len() / 2], errors[errors.len() - 1])
}

/// Runs the rectification checks on the checkerboard run `board_run` of `rig`, whose
/// geometry calibration `geometry` covers `cameras`.
pub fn captures_are_rectified_and_assembled_into_a_btf(
    out: &Path,
    rig: &RigSource,
    board_run: &Path,
    geometry: &str,
    cameras: &[String],
) {
    let cameras = cameras.join(",");
    // The same cameras (as-built seed and response), rendered without antialiasing: the
    // sweep's chart must fill the grazing cameras' windows with varied tones (with 2×2
    // samples it is too smooth there and their fit is not monotonic).
    let sweep = run_sequence(
        "calibration_response.rhai",
        as_built_rig("gentle", 12),
        &[],
        out,
        1,
    );
    sweep.result.as_ref().expect("the response sweep runs");
    let response = stagehand(&["calibrate", "response", path(&sweep.dir), "--json"])["id"]
        .as_str()
        .expect("an id")
        .to_string();

    // The board's corners in the rectified images against the layout, detector error
    // included (measured: 0.1–0.3 px median per view, about 1 px on the 75° camera whose
    // rectified image is blurred 4× along one axis; worst 2.2 px).
    let (median, worst) = flat_board_corners_align(board_run, &response, geometry, &cameras);
    assert!(
        median < 0.3,
        "rectified corners off by {median} px (median)"
    );
    assert!(worst < 3.0, "rectified corners off by up to {worst} px");

    // A BTF of bumps: 2 table angles × 2 light-arc angles × 1 lamp.
    let btf = run_sequence(
        "btf.rhai",
        rig.clone(),
        &[("views", "2"), ("lights", "2"), ("lamps", "1")],
        out,
        1,
    );
    btf.result.as_ref().expect("the btf capture runs");
    let args = [
        "process",
        path(&btf.dir),
        "--products",
        "rectified,btf",
        "--calibration",
        &response,
        "--calibration",
        geometry,
        "--cameras",
        &cameras,
        "--size-px",
        "256",
        "--json",
    ];
    let first = stagehand(&args);
    let n = cameras.split(',').count();
    let captures = 4 * n; // 2 × 2 captures per camera
    assert_eq!(first["captures"], captures, "{first}");
    assert_eq!(first["rectified"]["written"], captures, "{first}");
    // Views: 2 table angles per camera; lights: the lamp at relative azimuths 0° and 180°.
    let layout = &first["btf_layout"];
    assert_eq!(layout["views"], 2 * n, "{first}");
    assert_eq!(layout["lights"], 2, "{first}");
    assert_eq!(layout["cells"], captures, "{first}");
    // 3 metadata files, a chunk per capture, a seen mask per view.
    assert_eq!(first["btf"]["written"], 3 + captures + 2 * n, "{first}");

    // The Zarr group as a reader sees it (the v3 spec: zarr.json + c/… chunks).
    let zarr = btf.dir.join("products/btf/btf.zarr");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(zarr.join("radiance/zarr.json")).unwrap()).unwrap();
    assert_eq!(meta["shape"], serde_json::json!([2 * n, 2, 256, 256, 3]));
    let group: serde_json::Value =
        serde_json::from_slice(&std::fs::read(zarr.join("zarr.json")).unwrap()).unwrap();
    let views = group["attributes"]["views"].as_array().unwrap();
    for v in views {
        let theta = v["theta_deg"].as_f64().unwrap();
        assert!((0.0..90.0).contains(&theta), "{v}");
    }
    let lights = group["attributes"]["lights"].as_array().unwrap();
    assert!(lights.iter().all(|l| l["phi_deg"].as_f64().is_some()));
    let chunk = std::fs::read(zarr.join("radiance/c/0/0/0/0/0")).unwrap();
    assert_eq!(chunk.len(), 256 * 256 * 3 * 4);
    let values: Vec<f32> = chunk
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert!(values.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(values.iter().filter(|v| **v > 0.0).count() > values.len() / 2);

    // Against the rig as built (measured at 256 px over 80 mm: median 0.14 px, worst 1.6 px,
    // on the grazing cameras).
    let report = stagehand(&["evaluate", path(&btf.dir)]);
    let rect = &report["rectified"];
    assert!(rect["median_px"].as_f64().unwrap() < 0.2, "{rect:#}");
    assert!(rect["max_px"].as_f64().unwrap() < 3.0, "{rect:#}");

    // A rerun skips everything; a lost chunk is made again, alone.
    let again = stagehand(&args);
    assert_eq!(again["merged"], 0, "{again}");
    std::fs::remove_file(zarr.join("radiance/c/0/1/0/0/0")).unwrap();
    let repaired = stagehand(&args);
    assert_eq!(repaired["merged"], 1, "{repaired}");
    assert_eq!(repaired["btf"]["written"], 1, "{repaired}");
}
