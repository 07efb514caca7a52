//! `stagehand calibrate colour RUN --response ID [--geometry ID]`: the joint camera+lamp
//! channel scales from a colour-checker run (`sequences/calibration_colorchecker.rhai`),
//! stored as a `colour` calibration beside the run. The brackets are merged through the named
//! response calibration, which must cover every camera of the run's rig; the chart is found
//! through the named geometry calibration, or through the cameras the run's rig file describes
//! (nominal) when none is named.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use clap::Args;
use stagehand_devices::rig::{AxisRole, RigSpec};
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store::{
    self, Calibration, CalibrationInput, CalibrationKind, StoredCalibration,
};
use stagehand_processing::chart_layout::{ChartLayout, DEFAULT_SIZE_MM};
use stagehand_processing::chart_locate::LocateOptions;
use stagehand_processing::colour_calibration::{ColourOptions, ColourSet, calibrate_colour};
use stagehand_processing::nominal_geometry::{NominalCamera, nominal_geometry};
use stagehand_processing::response_calibration::ResponseSet;
use stagehand_processing::{Distortion, ProcessingError};

use super::calibrate::{processing_err, root_of, run_id, run_rig, store_err};
use crate::session::SessionError;

/// Arguments of `stagehand calibrate colour`.
#[derive(Args, Debug)]
pub struct ColourArgs {
    /// The run with the colour checker under each lamp.
    pub run_dir: PathBuf,
    /// The response calibration the brackets are merged with (`stagehand calibrations list`).
    #[arg(long, value_name = "ID")]
    pub response: String,
    /// A geometry calibration to find the chart with (searched within ±3 % of the image
    /// width); without it, the cameras as the run's rig file describes them (searched within
    /// ±12 %, for their mounting errors).
    #[arg(long, value_name = "ID")]
    pub geometry: Option<String>,
    /// Long side of the colour checker in mm (default: the run's `[sim] sample_size_mm`, the
    /// size of the rig's fixtures, else 80).
    #[arg(long, value_name = "MM")]
    pub chart_mm: Option<f64>,
    /// Print the stored calibration as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The rig file's description of `cam`, for [`nominal_geometry`].
pub fn nominal_camera(cam: &stagehand_devices::rig::CameraSpec) -> NominalCamera {
    NominalCamera {
        id: cam.id.clone(),
        width: cam.width,
        height: cam.height,
        azimuth_deg: cam.azimuth_deg,
        elevation_deg: cam.elevation_deg,
        distance_mm: cam.distance_mm,
        fov_deg: cam.fov_deg,
        principal_offset_px: [cam.cx, cam.cy],
        distortion: Distortion {
            k1: cam.k1,
            k2: cam.k2,
            p1: cam.p1,
            p2: cam.p2,
            k3: cam.k3,
        },
    }
}

/// Each camera's geometry: from calibration `id` (which must cover `cameras`), or nominal
/// from the rig file.
pub(super) fn camera_geometry(
    rig: &RigSpec,
    cameras: &[String],
    id: Option<&str>,
    root: &std::path::Path,
) -> Result<BTreeMap<String, CameraGeometry>, SessionError> {
    let list = match id {
        Some(id) => {
            let stored = calibration_store::load(root, id).map_err(store_err)?;
            stored.check_covers(cameras, &[]).map_err(store_err)?;
            stored.cameras().map_err(store_err)?
        }
        None => rig
            .cameras
            .iter()
            .map(|c| nominal_geometry(&nominal_camera(c)))
            .collect::<Result<_, ProcessingError>>()
            .map_err(processing_err)?,
    };
    Ok(list.into_iter().map(|g| (g.camera.clone(), g)).collect())
}

/// Runs `stagehand calibrate colour`.
pub fn run(args: ColourArgs) -> Result<i32, SessionError> {
    let run_dir = &args.run_dir;
    let (manifest, rig) = run_rig(run_dir)?;
    let cameras: Vec<String> = rig.cameras.iter().map(|c| c.id.clone()).collect();
    let root = root_of(run_dir);
    let response = calibration_store::load(&root, &args.response).map_err(store_err)?;
    response.check_covers(&cameras, &[]).map_err(store_err)?;
    let responses: ResponseSet = response
        .result(CalibrationKind::Response)
        .map_err(store_err)?;
    let geometry = camera_geometry(&rig, &cameras, args.geometry.as_deref(), &root)?;
    let (size_mm, size_from) = match (args.chart_mm, manifest.sim.as_ref()) {
        (Some(mm), _) => (mm, "--chart-mm"),
        (None, Some(sim)) => (sim.sample_size_mm, "the rig's [sim] sample_size_mm"),
        (None, None) => (DEFAULT_SIZE_MM, "the default"),
    };
    let options = ColourOptions {
        chart: ChartLayout { size_mm },
        turntable_axis: rig
            .axis_with_role(AxisRole::Turntable)
            .map(|a| a.id.clone()),
        // A calibrated geometry puts the chart within a pixel: search a narrow window.
        locate: match args.geometry {
            Some(_) => LocateOptions::calibrated(),
            None => LocateOptions::default(),
        },
        ..ColourOptions::default()
    };
    let set = calibrate_colour(run_dir, &responses, &geometry, &options).map_err(processing_err)?;
    let stored = store(&args, &options, size_from, &set)?;
    if args.json {
        super::print_json(&stored)?;
    } else {
        print_summary(&stored, &set, size_mm, size_from, args.geometry.is_some());
        println!("stored in {}", root.join(&stored.id).display());
    }
    Ok(0)
}

/// Stores the calibration beside the run.
fn store(
    args: &ColourArgs,
    options: &ColourOptions,
    size_from: &str,
    set: &ColourSet,
) -> Result<StoredCalibration, SessionError> {
    let lamps: BTreeSet<&String> = set.values().flat_map(|c| c.lamps.keys()).collect();
    let frames: Vec<String> = set
        .values()
        .flat_map(|c| c.lamps.values())
        .flat_map(|l| &l.views)
        .flat_map(|v| v.frames.iter().cloned())
        .collect();
    let quality: serde_json::Map<String, serde_json::Value> = set
        .iter()
        .map(|(camera, c)| {
            let lamps: serde_json::Map<String, serde_json::Value> = c
                .lamps
                .iter()
                .map(|(lamp, s)| {
                    (
                        lamp.clone(),
                        serde_json::json!({
                            "rel_residual": s.fit.rel_residual,
                            "rel_std": s.fit.rel_std,
                            "patches": s.views.iter().map(|v| v.patches.len()).sum::<usize>(),
                        }),
                    )
                })
                .collect();
            let chart: Vec<serde_json::Value> = c
                .chart
                .iter()
                .map(|v| {
                    serde_json::json!({
                        "turntable_deg": v.turntable_deg,
                        "ncc": v.fit.ncc,
                        "offset_px": v.fit.offset_px,
                        "min_patch_pixels": v.min_patch_pixels,
                    })
                })
                .collect();
            (
                camera.clone(),
                serde_json::json!({"lamps": lamps, "chart": chart}),
            )
        })
        .collect();
    let calibration = Calibration {
        kind: CalibrationKind::Colour,
        cameras: set.keys().cloned().collect(),
        lamps: lamps.into_iter().cloned().collect(),
        inputs: vec![CalibrationInput {
            run_id: run_id(&args.run_dir),
            frames,
        }],
        parameters: serde_json::json!({
            "response": args.response,
            "geometry": args.geometry.as_deref().unwrap_or("nominal"),
            "chart": {"size_mm": options.chart.size_mm, "from": size_from},
            "turntable_axis": options.turntable_axis,
            "core_fraction": options.core_fraction,
            "locate": options.locate,
            "fixture": options.fixture,
        }),
        result: serde_json::to_value(set).map_err(|e| SessionError::Io(e.to_string()))?,
        quality: serde_json::Value::Object(quality),
        software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
    };
    calibration_store::save(&root_of(&args.run_dir), calibration).map_err(store_err)
}

fn print_summary(
    stored: &StoredCalibration,
    set: &ColourSet,
    size_mm: f64,
    size_from: &str,
    calibrated: bool,
) {
    println!(
        "calibration {} ({} cameras × {} lamps; chart {size_mm} mm from {size_from}, located through the {} geometry)",
        stored.id,
        stored.calibration.cameras.len(),
        stored.calibration.lamps.len(),
        if calibrated { "calibrated" } else { "nominal" }
    );
    for (camera, c) in set {
        for v in &c.chart {
            println!(
                "  {camera} at table {:.1}°: chart found {:.1} px from the projection, correlation {:.3}, ≥ {} px per patch",
                v.turntable_deg,
                v.fit.offset_px[0].hypot(v.fit.offset_px[1]),
                v.fit.ncc,
                v.min_patch_pixels
            );
        }
        for (lamp, s) in &c.lamps {
            let [r, g, b] = s.fit.scale;
            let res = s.fit.rel_residual.map(|x| 100.0 * x);
            println!(
                "    {lamp}: S = ({r:.4e}, {g:.4e}, {b:.4e}), fit residual {:.2} / {:.2} / {:.2} %",
                res[0], res[1], res[2]
            );
        }
    }
}
