//! `stagehand calibrate …`, `stagehand calibrations …` and `stagehand evaluate`: calibrations
//! computed from runs and stored as versioned artefacts in `calibrations/` beside the runs (the
//! run directory's parent), and a simulated run's calibrations measured against its truth.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use stagehand_processing::calibration_store::{
    self, Calibration, CalibrationInput, CalibrationKind, calibrations_dir,
};
use stagehand_processing::response_calibration::calibrate_response;

use crate::session::SessionError;

/// Subcommands of `stagehand calibrate`.
#[derive(Subcommand, Debug)]
pub enum CalibrateCommand {
    /// Each camera's inverse response per channel (Debevec–Malik) from a bracket sweep of a
    /// static scene (sequences/calibration_response.rhai).
    Response {
        /// The run with the bracket sweep.
        run_dir: PathBuf,
        /// Smoothness weight λ of the fit (relative to the data; see the processing docs).
        #[arg(long, default_value_t = 100.0)]
        smoothness: f64,
        /// Print the stored calibration as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Each camera's intrinsics, lens distortion and place in the rig frame (Zhang, then
    /// Levenberg–Marquardt) from a checkerboard run (sequences/calibration_checkerboard.rhai).
    Geometry {
        /// The run with the checkerboard placements.
        run_dir: PathBuf,
        /// Inner corners of the board, COLSxROWS: an odd sum tells the board from its half turn
        /// (the simulated board's default).
        #[arg(long, default_value = "8x7", value_parser = super::calibrate_geometry::parse_corners)]
        corners: (usize, usize),
        /// Side of a board square, millimetres.
        #[arg(long, default_value_t = 8.0)]
        square_mm: f64,
        /// Fit the r⁶ radial distortion term k3 too (for lenses whose distortion reaches far).
        #[arg(long)]
        fit_k3: bool,
        /// Store the simulator's exact cameras (RUN/as_built.json; simulated runs only)
        /// instead of a fit, to measure other products apart from calibration error.
        #[arg(long, conflicts_with_all = ["corners", "square_mm", "fit_k3"])]
        from_truth: bool,
        /// Print the stored calibration as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Joint camera+lamp channel scales (S_r, S_g, S_b) per camera and lamp from the colour
    /// checker under each lamp (sequences/calibration_colorchecker.rhai), in the units of a
    /// response calibration.
    Colour(super::calibrate_colour::ColourArgs),
    /// Each laser position's sheet from the two-height planes fixture under the laser
    /// (sequences/mdf_laser.rhai's calibration frames), through a geometry calibration.
    LaserPlanes(super::calibrate_laser_planes::LaserPlanesArgs),
    /// The reflectometer's tube intensity and backlight panel radiance per camera, from a
    /// reflectometer run over a reference sample of known albedo and transmittance
    /// (sequences/reflectometer.rhai with `--set sample=opal_reference`).
    Reflectometer(super::calibrate_reflectometer::ReflectometerArgs),
}

/// Subcommands of `stagehand calibrations`.
#[derive(Subcommand, Debug)]
pub enum CalibrationsCommand {
    /// List the calibrations stored in DATA/calibrations.
    List {
        /// The dataset root (where the runs are).
        #[arg(long, default_value = "runs")]
        data: PathBuf,
    },
    /// Print one calibration as JSON.
    Show {
        /// Calibration id (`<kind>-<hash>`).
        id: String,
        /// The dataset root (where the runs are).
        #[arg(long, default_value = "runs")]
        data: PathBuf,
    },
}

/// A calibration store error as the CLI reports it.
pub(super) fn store_err(e: calibration_store::CalibrationStoreError) -> SessionError {
    SessionError::Io(e.to_string())
}

/// A processing error as the CLI reports it.
pub(super) fn processing_err(e: stagehand_processing::ProcessingError) -> SessionError {
    SessionError::Io(e.to_string())
}

/// The calibrations directory for a run: beside it, in its dataset root.
pub(super) fn root_of(run_dir: &Path) -> PathBuf {
    calibrations_dir(run_dir.parent().unwrap_or(Path::new(".")))
}

/// A run's manifest and the rig file it was captured with.
pub(super) fn run_rig(
    run_dir: &Path,
) -> Result<(stagehand_dataset::Manifest, stagehand_devices::rig::RigSpec), SessionError> {
    let manifest = stagehand_dataset::read_manifest(run_dir).map_err(SessionError::Storage)?;
    let rig = stagehand_devices::rig::parse_rig(
        &manifest.rig_toml,
        &run_dir
            .join(stagehand_dataset::layout::RIG)
            .display()
            .to_string(),
    )?;
    Ok((manifest, rig))
}

/// The run's id: its directory name.
pub(super) fn run_id(run_dir: &Path) -> String {
    run_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Runs `stagehand calibrate …`.
pub fn calibrate(command: CalibrateCommand) -> Result<i32, SessionError> {
    match command {
        CalibrateCommand::Geometry {
            run_dir,
            from_truth: true,
            json,
            ..
        } => super::calibrate_geometry::geometry_from_truth(&run_dir, json),
        CalibrateCommand::Geometry {
            run_dir,
            corners,
            square_mm,
            fit_k3,
            json,
            ..
        } => super::calibrate_geometry::calibrate_geometry(
            &run_dir, corners, square_mm, fit_k3, json,
        ),
        CalibrateCommand::Response {
            run_dir,
            smoothness,
            json,
        } => {
            let set = calibrate_response(&run_dir, smoothness).map_err(processing_err)?;
            let quality = serde_json::json!(
                set.iter()
                    .map(|(id, c)| (
                        id.clone(),
                        serde_json::json!({"rms_residual": c.rms_residual, "pixels": c.pixels})
                    ))
                    .collect::<serde_json::Map<_, _>>()
            );
            let calibration = Calibration {
                kind: CalibrationKind::Response,
                cameras: set.keys().cloned().collect(),
                lamps: Vec::new(),
                inputs: vec![CalibrationInput {
                    run_id: run_id(&run_dir),
                    frames: set
                        .values()
                        .flat_map(|c| c.frames.iter().cloned())
                        .collect(),
                }],
                parameters: serde_json::json!({"smoothness": smoothness}),
                result: serde_json::to_value(&set).map_err(|e| SessionError::Io(e.to_string()))?,
                quality,
                software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
            };
            let stored =
                calibration_store::save(&root_of(&run_dir), calibration).map_err(store_err)?;
            if json {
                super::print_json(&stored)?;
            } else {
                println!("calibration {} ({} cameras)", stored.id, set.len());
                for (id, c) in &set {
                    println!(
                        "  {id}: fit residual r {:.4} g {:.4} b {:.4} (ln units), {} samples",
                        c.rms_residual[0], c.rms_residual[1], c.rms_residual[2], c.pixels[1]
                    );
                }
                println!("stored in {}", root_of(&run_dir).join(&stored.id).display());
            }
            Ok(0)
        }
        CalibrateCommand::Colour(args) => super::calibrate_colour::run(args),
        CalibrateCommand::LaserPlanes(args) => super::calibrate_laser_planes::run(args),
        CalibrateCommand::Reflectometer(args) => super::calibrate_reflectometer::run(args),
    }
}

/// Runs `stagehand calibrations …`.
pub fn calibrations(command: CalibrationsCommand) -> Result<i32, SessionError> {
    match command {
        CalibrationsCommand::List { data } => {
            let root = calibrations_dir(&data);
            let all = calibration_store::list(&root).map_err(store_err)?;
            if all.is_empty() {
                println!("no calibrations in {}", root.display());
            }
            for entry in all {
                match entry {
                    Ok(s) => println!(
                        "{}  cameras {}  from {}",
                        s.id,
                        s.calibration.cameras.join(","),
                        s.calibration
                            .inputs
                            .iter()
                            .map(|i| i.run_id.as_str())
                            .collect::<Vec<_>>()
                            .join(",")
                    ),
                    Err(e) => println!("damaged: {e}"),
                }
            }
            Ok(0)
        }
        CalibrationsCommand::Show { id, data } => {
            let stored =
                calibration_store::load(&calibrations_dir(&data), &id).map_err(store_err)?;
            super::print_json(&stored)?;
            Ok(0)
        }
    }
}

/// Runs `stagehand evaluate RUN`.
pub fn evaluate(run_dir: &Path) -> Result<i32, SessionError> {
    let report = crate::evaluate::evaluate(run_dir).map_err(|e| SessionError::Io(e.to_string()))?;
    super::print_json(&report)?;
    Ok(0)
}
