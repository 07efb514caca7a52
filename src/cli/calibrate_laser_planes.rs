//! `stagehand calibrate laser-planes RUN [--geometry ID]`: each laser position's sheet from the
//! run's frames of the two-height planes fixture under the laser, through a geometry
//! calibration, stored as a `laser-planes` calibration beside the run for
//! `stagehand process --products depth`.

use std::path::PathBuf;

use clap::Args;
use stagehand_devices::rig::AxisRole;
use stagehand_processing::calibration_store::{
    self, Calibration, CalibrationInput, CalibrationKind,
};
use stagehand_processing::laser_line::LineOptions;
use stagehand_processing::laser_plane_calibration::{
    LaserPlanesResult, LaserPlanesSetup, PlanesFixture, calibrate_laser_planes,
};

use super::calibrate::{processing_err, root_of, run_id, run_rig, store_err};
use crate::session::SessionError;

/// Arguments of `stagehand calibrate laser-planes`.
#[derive(Args, Debug)]
pub struct LaserPlanesArgs {
    /// The run with the planes fixture under each laser position.
    pub run_dir: PathBuf,
    /// The geometry calibration the line is triangulated through (default: the one the run's
    /// rig file named in `[calibration]`).
    #[arg(long, value_name = "ID")]
    pub geometry: Option<String>,
    /// Height of the fixture's raised plane (its half y > 0 of the sample frame) above the
    /// low one, mm.
    #[arg(long, default_value_t = 20.0)]
    pub step_mm: f64,
    /// Side of the fixture, mm (default: the run's `[sim] sample_size_mm`; required for a
    /// real rig's runs).
    #[arg(long, value_name = "MM")]
    pub fixture_mm: Option<f64>,
    /// Line points closer than this to the step or an outer edge are left out, mm.
    #[arg(long, default_value_t = 1.5)]
    pub margin_mm: f64,
    /// Print the stored calibration as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `stagehand calibrate laser-planes`.
pub fn run(args: LaserPlanesArgs) -> Result<i32, SessionError> {
    let run_dir = &args.run_dir;
    let (manifest, rig) = run_rig(run_dir)?;
    let laser = rig.laser.as_ref().ok_or_else(|| {
        SessionError::Io(format!(
            "laser-plane calibration needs a laser, and the run's rig `{}` has none",
            rig.rig.name
        ))
    })?;
    let geometry_id = match (&args.geometry, manifest.calibrations.get("geometry")) {
        (Some(id), _) => id.clone(),
        (None, Some(id)) => id.clone(),
        (None, None) => {
            return Err(SessionError::Io(
                "laser-plane calibration needs a geometric calibration: --geometry geometry-…, or name one in the rig file's [calibration] table (make one with `stagehand calibrate geometry`)".into(),
            ));
        }
    };
    let size_mm = match (args.fixture_mm, manifest.sim.as_ref()) {
        (Some(mm), _) => mm,
        (None, Some(sim)) => sim.sample_size_mm,
        (None, None) => {
            return Err(SessionError::Io(
                "give the planes fixture's side with --fixture-mm (mm)".into(),
            ));
        }
    };
    let root = root_of(run_dir);
    let stored_geometry = calibration_store::load(&root, &geometry_id).map_err(store_err)?;
    let cameras = stored_geometry
        .cameras()
        .map_err(store_err)?
        .into_iter()
        .map(|g| (g.camera.clone(), g))
        .collect();
    let setup = LaserPlanesSetup {
        geometry: (&cameras, &geometry_id),
        fixture: PlanesFixture {
            step_mm: args.step_mm,
            size_mm,
            margin_mm: args.margin_mm,
        },
        laser_distance_mm: laser.distance_mm,
        turntable_axis: rig
            .axis_with_role(AxisRole::Turntable)
            .map(|a| a.id.as_str()),
        light_arc_axis: rig
            .axis_with_role(AxisRole::LightArc)
            .map(|a| a.id.as_str()),
        line: LineOptions::default(),
    };
    let result = calibrate_laser_planes(run_dir, &setup).map_err(processing_err)?;
    let stored = store(&args, &setup, &geometry_id, &result)?;
    if args.json {
        super::print_json(&stored)?;
        return Ok(0);
    }
    println!(
        "calibration {} ({} laser positions from {} frames of {} cameras, through {geometry_id})",
        stored.id,
        result.planes.positions.len(),
        result.frames.len(),
        result.cameras.len()
    );
    for p in &result.planes.positions {
        let tilts: Vec<String> = p
            .sheets
            .iter()
            .map(|s| format!("{}°", s.tilt_deg))
            .collect();
        let worst_rms = p.sheets.iter().map(|s| s.rms_mm).fold(0.0, f64::max);
        let points: usize = p.sheets.iter().map(|s| s.points_low + s.points_high).sum();
        print!(
            "  {} nm, mount {}°, arc {}°: tilts {}; {points} points, fit RMS ≤ {worst_rms:.3} mm; {:.3}° from the rig file's sheet",
            p.colour_nm,
            p.mount_deg,
            p.light_arc_deg,
            tilts.join(", "),
            p.nominal_angle_deg
        );
        match p.pencil_check {
            Some([angle, offset]) => {
                println!("; middle tilts within {angle:.4}° and {offset:.3} mm of the pencil")
            }
            None => println!(),
        }
        for why in &p.skipped {
            println!("    left out: {why}");
        }
    }
    println!("stored in {}", root.join(&stored.id).display());
    Ok(0)
}

/// Stores the calibration beside the run.
fn store(
    args: &LaserPlanesArgs,
    setup: &LaserPlanesSetup<'_>,
    geometry_id: &str,
    result: &LaserPlanesResult,
) -> Result<calibration_store::StoredCalibration, SessionError> {
    let worst_rms = result
        .planes
        .positions
        .iter()
        .flat_map(|p| p.sheets.iter().map(|s| s.rms_mm))
        .fold(0.0, f64::max);
    let calibration = Calibration {
        kind: CalibrationKind::LaserPlanes,
        cameras: result.cameras.clone(),
        lamps: Vec::new(),
        inputs: vec![CalibrationInput {
            run_id: run_id(&args.run_dir),
            frames: result.frames.clone(),
        }],
        parameters: serde_json::json!({
            "geometry": geometry_id,
            "fixture": setup.fixture,
            "laser_distance_mm": setup.laser_distance_mm,
            "line": {"smoothing_px": setup.line.smoothing_px, "threshold_sigmas": setup.line.threshold_sigmas},
        }),
        result: serde_json::to_value(result).map_err(|e| SessionError::Io(e.to_string()))?,
        quality: serde_json::json!({
            "positions": result.planes.positions.len(),
            "worst_fit_rms_mm": worst_rms,
            "frames_used": result.frames.len(),
        }),
        software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
    };
    calibration_store::save(&root_of(&args.run_dir), calibration).map_err(store_err)
}
