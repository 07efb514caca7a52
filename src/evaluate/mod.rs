//! `stagehand evaluate RUN`: every calibration and product of a simulated run measured against
//! the simulator's ground truth (`as_built.json`, written only for simulated runs with
//! `[sim.as_built]`), as one JSON report that tests and benchmarks share. This is the only
//! code that reads ground truth next to processing results; processing itself never does.

mod colour;
mod depth;
mod dipole;
mod entrance;
mod geometry;
mod hdr;
mod laser_planes;
mod material;
mod rectified;
mod response;
mod surface;

use std::path::Path;

use serde::Serialize;
use stagehand_processing::calibration_store::{self, CalibrationKind, calibrations_dir};

pub use colour::{ColourFigures, LampFigures, evaluate_colour};
pub use depth::{DepthFigures, evaluate_depth};
pub use dipole::{DipoleColourFigures, DipoleFigures, evaluate_dipole};
pub use entrance::{EntranceDirectionFigures, EntranceFigures, evaluate_entrance};
pub use geometry::{CameraFigures, GeometryFigures, evaluate_geometry, truth_geometry};
pub use hdr::{ErrorFigures, HdrFigures, evaluate_hdr};
pub use laser_planes::{LaserPlaneFigures, evaluate_laser_planes};
pub use material::{
    ExitFigures, LocalFigures, Spread, TransparencyFigures, WardFigures, evaluate_exit,
    evaluate_local, evaluate_transparency, evaluate_ward,
};
pub use rectified::{RectifiedFigures, evaluate_rectified};
pub use response::{ChannelFigures, ResponseFigures, evaluate_response};
pub use surface::{SurfaceFigures, evaluate_surface};

/// Errors of `evaluate`.
#[derive(Debug, thiserror::Error)]
pub enum EvaluateError {
    #[error(
        "run {0} has no as_built.json: evaluate needs a simulated run whose rig sets [sim.as_built]"
    )]
    NoTruth(String),
    #[error("{path}: {message}")]
    Truth { path: String, message: String },
    #[error("{0}")]
    Store(#[from] calibration_store::CalibrationStoreError),
}

/// The report: one section per calibration evaluated.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The run evaluated.
    pub run: String,
    /// Response calibrations: figures per calibration id.
    pub response: Vec<ResponseFigures>,
    /// Geometry calibrations: figures per calibration id.
    pub geometry: Vec<GeometryFigures>,
    /// Colour calibrations: scales per camera and lamp against the truth.
    pub colour: Vec<ColourFigures>,
    /// Laser-planes calibrations: sheet angles and offsets against the laser as built.
    pub laser_planes: Vec<LaserPlaneFigures>,
    /// The run's HDR products against its noise-free radiance (runs with ground truth).
    pub hdr: Option<HdrFigures>,
    /// The run's rectified images and BTF views against the true camera geometry.
    pub rectified: Option<RectifiedFigures>,
    /// The run's depth images against the ground-truth depth (runs with ground truth).
    pub depth: Option<DepthFigures>,
    /// The per-frame baseline's depth images, measured the same way.
    pub depth_per_frame: Option<DepthFigures>,
    /// The merged MDFs of the run's views, measured the same way.
    pub mdf: Option<DepthFigures>,
    /// The height and normal maps against the simulated sample's height field.
    pub surface: Option<SurfaceFigures>,
    /// The reflectometer's Ward maps against the material plane.
    pub ward: Option<WardFigures>,
    /// The reflectometer's transparency maps against the material plane.
    pub transparency: Option<TransparencyFigures>,
    /// The dipole fits against the simulated sample's medium.
    pub dipole: Option<DipoleFigures>,
    /// The mesostructure's exit-function maps against the material plane.
    pub exit: Option<ExitFigures>,
    /// The entrance functions against the simulator's Fresnel transmittance.
    pub entrance: Option<EntranceFigures>,
    /// The local reflectance maps against the material plane.
    pub local: Option<LocalFigures>,
}

/// The run's reader and its products of `kind`; `None` when it has none.
fn products_of(
    run_dir: &Path,
    kind: &str,
) -> Result<
    Option<(
        stagehand_dataset::RunReader,
        Vec<stagehand_dataset::products::StoredProduct>,
    )>,
    EvaluateError,
> {
    let err = |e: stagehand_dataset::StorageError| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message: e.to_string(),
    };
    let reader = stagehand_dataset::RunReader::open(run_dir).map_err(err)?;
    let products: Vec<_> = reader
        .products()
        .map_err(err)?
        .into_iter()
        .filter(|p| p.made.kind == kind)
        .collect();
    Ok((!products.is_empty()).then_some((reader, products)))
}

/// The simulator's truth of `run_dir` (`as_built.json`); an error for a run without one.
pub fn read_truth(run_dir: &Path) -> Result<serde_json::Value, EvaluateError> {
    let truth_path = run_dir.join(stagehand_dataset::layout::AS_BUILT);
    let text = std::fs::read_to_string(&truth_path)
        .map_err(|_| EvaluateError::NoTruth(run_dir.display().to_string()))?;
    serde_json::from_str(&text).map_err(|e| EvaluateError::Truth {
        path: truth_path.display().to_string(),
        message: e.to_string(),
    })
}

/// Evaluates every calibration of `kinds` stored beside `run_dir` that was computed from it.
pub fn evaluate(run_dir: &Path) -> Result<Report, EvaluateError> {
    let truth = read_truth(run_dir)?;
    let run_id = run_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let root = calibrations_dir(run_dir.parent().unwrap_or(Path::new(".")));
    let mut report = Report {
        run: run_id.clone(),
        response: Vec::new(),
        geometry: Vec::new(),
        colour: Vec::new(),
        laser_planes: Vec::new(),
        hdr: None,
        rectified: None,
        depth: None,
        depth_per_frame: None,
        mdf: None,
        surface: None,
        ward: None,
        transparency: None,
        dipole: None,
        exit: None,
        entrance: None,
        local: None,
    };
    for stored in calibration_store::list(&root)?.into_iter().flatten() {
        if !stored.calibration.inputs.iter().any(|i| i.run_id == run_id)
            || stored.calibration.parameters["from_truth"] == true
        {
            // Another run's, or the truth itself (`calibrate geometry --from-truth`).
            continue;
        }
        match stored.calibration.kind {
            CalibrationKind::Response => report.response.push(evaluate_response(&stored, &truth)?),
            CalibrationKind::Geometry => report.geometry.push(evaluate_geometry(&stored, &truth)?),
            CalibrationKind::Colour => report
                .colour
                .push(evaluate_colour(&stored, &truth, run_dir, &root)?),
            CalibrationKind::LaserPlanes => report
                .laser_planes
                .push(evaluate_laser_planes(&stored, &truth, run_dir)?),
            // In the response calibration's relative units: measured through the maps it
            // makes (the `ward` and `transparency` sections).
            CalibrationKind::Reflectometer => {}
        }
    }
    report.hdr = evaluate_hdr(run_dir, &root)?;
    report.rectified = evaluate_rectified(run_dir, &root, &truth)?;
    report.depth = evaluate_depth(run_dir, &root, "depth")?;
    report.depth_per_frame = evaluate_depth(run_dir, &root, "depth_per_frame")?;
    report.mdf = evaluate_depth(run_dir, &root, "mdf")?;
    report.surface = evaluate_surface(run_dir)?;
    report.ward = evaluate_ward(run_dir)?;
    report.transparency = evaluate_transparency(run_dir)?;
    report.dipole = evaluate_dipole(run_dir)?;
    report.exit = evaluate_exit(run_dir)?;
    report.entrance = evaluate_entrance(run_dir)?;
    report.local = evaluate_local(run_dir)?;
    Ok(report)
}
