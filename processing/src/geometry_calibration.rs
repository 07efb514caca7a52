//! `stagehand calibrate geometry`: every camera's intrinsics, distortion and place in the rig
//! frame from a checkerboard run (`sequences/calibration_checkerboard.rhai`). Frames are grouped
//! into placements by the placement each prompt asked for and the turntable angle; the only
//! thing read from the placement is whether the board lay flat and centred (those views give
//! the turntable axis, the one at 0° the rig frame). Everything else is measured: the board is
//! detected in every frame (sub-pixel corners), and frames where it is not found are listed.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use stagehand_dataset::layout;
use stagehand_dataset::{FrameKind, FrameQuery};
use stagehand_devices::fixture_pose::FixturePose;
use stagehand_devices::rig::{AxisRole, parse_rig};

use crate::calibrate_camera::{BoardView, CalibrationOptions};
use crate::calibrate_geometry::{CameraGeometry, CameraViews, Placement, calibrate_geometry};
use crate::checkerboard::{CheckerboardSpec, detect_checkerboard};
use crate::error::ProcessingError;
use crate::gray_image::GrayImage;
use crate::run_frames::{dataset_err, decode_frame_in, open_run};

/// One placement as the run recorded it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlacementRecord {
    /// Flat and centred, and the turntable angle.
    pub placement: Placement,
    /// The placement the prompt asked for.
    pub pose: FixturePose,
    /// The capture step.
    pub step: usize,
}

/// The result of a geometric calibration run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeometryCalibration {
    /// Each camera's geometry in the rig frame.
    pub cameras: Vec<CameraGeometry>,
    /// (camera, why) for each camera that could not be calibrated or placed.
    pub failed: Vec<(String, String)>,
    /// The placements, indexed as in each camera's `view_rms_px`.
    pub placements: Vec<PlacementRecord>,
    /// The board the corners were detected for.
    pub board: CheckerboardSpec,
    /// Frames used.
    pub frames: Vec<String>,
    /// Frames where the board was not found, with why.
    pub not_detected: Vec<(String, String)>,
}

/// Calibrates the geometry of every camera of the checkerboard run at `run_dir`.
pub fn calibrate_geometry_run(
    run_dir: &Path,
    board: CheckerboardSpec,
    options: CalibrationOptions,
) -> Result<GeometryCalibration, ProcessingError> {
    let reader = open_run(run_dir)?;
    let rig_text = std::fs::read_to_string(run_dir.join(layout::RIG)).map_err(|e| {
        ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!("{} cannot be read: {e}", layout::RIG),
        }
    })?;
    let rig = parse_rig(&rig_text, layout::RIG).map_err(|e| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message: e.to_string(),
    })?;
    let turntable = rig
        .axis_with_role(AxisRole::Turntable)
        .map(|a| a.id.clone());
    let page = reader
        .frames(&FrameQuery {
            kind: Some(FrameKind::Raw),
            ..FrameQuery::default()
        })
        .map_err(dataset_err(run_dir))?;
    let boards: Vec<_> = page
        .frames
        .into_iter()
        .filter(|f| f.meta.fixture == "checkerboard")
        .collect();
    if boards.is_empty() {
        return Err(ProcessingError::MissingInput {
            run: run_dir.display().to_string(),
            what: "frame of the checkerboard".into(),
            hint: "capture one with sequences/calibration_checkerboard.rhai",
        });
    }
    // Placements in step order: one per (step) capture.
    let mut placements: Vec<PlacementRecord> = Vec::new();
    let mut index_of_step: BTreeMap<usize, usize> = BTreeMap::new();
    for f in &boards {
        if index_of_step.contains_key(&f.meta.step) {
            continue;
        }
        let table_deg = turntable
            .as_ref()
            .and_then(|id| f.meta.axes_deg.get(id))
            .copied()
            .unwrap_or(0.0);
        index_of_step.insert(f.meta.step, placements.len());
        placements.push(PlacementRecord {
            placement: Placement {
                flat: f.meta.fixture_pose.is_flat_centred(),
                table_deg,
            },
            pose: f.meta.fixture_pose,
            step: f.meta.step,
        });
    }
    let points = board.board_points();
    // Decoding and detection on every core; the views are then assembled in frame order.
    let detected: Vec<_> = boards
        .par_iter()
        .map(|f| {
            let png = decode_frame_in(run_dir, f)?;
            let gray = GrayImage {
                width: png.width as usize,
                height: png.height as usize,
                data: png
                    .pixels
                    .chunks_exact(3)
                    .map(|p| (f32::from(p[0]) + f32::from(p[1]) + f32::from(p[2])) / 3.0)
                    .collect(),
            };
            Ok(((png.width, png.height), detect_checkerboard(&gray, &board)))
        })
        .collect::<Result<_, ProcessingError>>()?;
    let mut cameras: BTreeMap<String, CameraViews> = BTreeMap::new();
    let mut frames = Vec::new();
    let mut not_detected = Vec::new();
    for (f, ((width, height), found)) in boards.iter().zip(detected) {
        let views = cameras
            .entry(f.meta.camera.clone())
            .or_insert_with(|| CameraViews {
                camera: f.meta.camera.clone(),
                width,
                height,
                views: Vec::new(),
            });
        match found {
            Ok(image) => {
                views.views.push((
                    index_of_step[&f.meta.step],
                    BoardView {
                        board: points.clone(),
                        image,
                    },
                ));
                frames.push(f.path.clone());
            }
            Err(e) => not_detected.push((f.path.clone(), e.to_string())),
        }
    }
    let views: Vec<CameraViews> = cameras.into_values().collect();
    let placement_list: Vec<Placement> = placements.iter().map(|p| p.placement).collect();
    let solution = calibrate_geometry(&placement_list, &views, options)?;
    Ok(GeometryCalibration {
        cameras: solution.cameras,
        failed: solution.failed,
        placements,
        board,
        frames,
        not_detected,
    })
}
