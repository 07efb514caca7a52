//! A laser-planes calibration against the simulated laser as built: for each calibrated laser
//! position, the sheet the simulator renders (its unit's drawn deviations from the mount,
//! arc, tilt zero and roll: `AsBuilt::laser`) compared with the calibrated sheet, at each
//! calibrated tilt and at tilts across the sweep between them (the pencil the depth
//! triangulates against). Angles between normals in degrees; offsets as the distance between
//! the two planes at the rig origin along the true normal, mm.

use std::path::Path;

use serde::{Deserialize, Serialize};
use stagehand_devices::rig::parse_rig;
use stagehand_processing::calibration_store::{CalibrationKind, StoredCalibration};
use stagehand_processing::laser_plane_calibration::LaserPlanesResult;
use stagehand_processing::laser_planes::{angle_between, oriented_like};
use stagehand_processing::ray_plane::Plane;
use stagehand_simulator::as_built::{AsBuilt, AsBuiltSpec};
use stagehand_simulator::render::geometry::ToSample;
use stagehand_simulator::render::laser::LaserSheet;
use stagehand_simulator::world_snapshot::LaserBeam;

use super::EvaluateError;

/// The figures of one laser-planes calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserPlaneFigures {
    /// Calibration id.
    pub id: String,
    /// Laser positions calibrated.
    pub positions: usize,
    /// Calibrated sheets compared (positions × tilts).
    pub sheets: usize,
    /// Largest angle of a calibrated sheet from its true sheet, degrees.
    pub max_angle_deg: f64,
    /// Median of those angles.
    pub median_angle_deg: f64,
    /// Largest offset at the rig origin, mm.
    pub max_offset_mm: f64,
    /// Over 9 tilts across each position's calibrated range: the largest angle of the sheet
    /// the calibration predicts from its true sheet, degrees.
    pub sweep_max_angle_deg: f64,
    /// The same for offsets, mm.
    pub sweep_max_offset_mm: f64,
    /// For comparison: the largest angle of the rig file's nominal sheet from the true one.
    pub nominal_max_angle_deg: f64,
}

/// The true sheet, rig frame.
fn true_sheet(
    rig: &stagehand_devices::rig::RigSpec,
    as_built: &AsBuilt,
    colour_nm: u32,
    mount_deg: f64,
    arc_deg: f64,
    tilt_deg: f64,
) -> Option<Plane> {
    let spec = rig.laser.as_ref()?;
    let beam = LaserBeam {
        colour_nm,
        tilt_deg,
        mount_elevation_deg: mount_deg,
    };
    let sheet = LaserSheet::built(
        spec,
        &beam,
        arc_deg,
        ToSample::new(0.0),
        &as_built.laser(mount_deg),
    );
    let n = [sheet.normal.x, sheet.normal.y, sheet.normal.z].map(f64::from);
    let o = [sheet.origin.x, sheet.origin.y, sheet.origin.z].map(f64::from);
    Plane::through(o, n)
}

/// The run's rig file and the rig as the simulator built it (drawn from the truth's spec).
pub(super) fn rig_as_built(
    run_dir: &Path,
    truth: &serde_json::Value,
) -> Result<(stagehand_devices::rig::RigSpec, AsBuilt), EvaluateError> {
    let rig_path = run_dir.join(stagehand_dataset::layout::RIG);
    let bad = |message: String| EvaluateError::Truth {
        path: rig_path.display().to_string(),
        message,
    };
    let text = std::fs::read_to_string(&rig_path).map_err(|e| bad(e.to_string()))?;
    let rig = parse_rig(&text, &rig_path.display().to_string()).map_err(|e| bad(e.to_string()))?;
    let spec: AsBuiltSpec = serde_json::from_value(truth["spec"].clone())
        .map_err(|e| bad(format!("as_built.json spec: {e}")))?;
    let as_built = AsBuilt::draw(&rig, spec);
    Ok((rig, as_built))
}

/// Angle (degrees) and offset at the origin (mm) of `calibrated` from `truth`.
fn errors(calibrated: &Plane, truth: &Plane) -> (f64, f64) {
    let calibrated = oriented_like(*calibrated, truth);
    (
        angle_between(&calibrated, truth),
        (calibrated.d - truth.d).abs(),
    )
}

/// Evaluates `stored` against the truth of the run at `run_dir`.
pub fn evaluate_laser_planes(
    stored: &StoredCalibration,
    truth: &serde_json::Value,
    run_dir: &Path,
) -> Result<LaserPlaneFigures, EvaluateError> {
    let bad = |message: String| EvaluateError::Truth {
        path: format!("calibration {}", stored.id),
        message,
    };
    let result: LaserPlanesResult = stored
        .result(CalibrationKind::LaserPlanes)
        .map_err(|e| bad(e.to_string()))?;
    let (rig, as_built) = rig_as_built(run_dir, truth)?;
    let no_truth = || bad("the run's rig has no laser to compare with".into());
    let (mut angles, mut max_offset) = (Vec::new(), 0.0f64);
    let (mut sweep_angle, mut sweep_offset, mut nominal_angle) = (0.0f64, 0.0f64, 0.0f64);
    let nominal = AsBuilt::nominal(&rig);
    for p in &result.planes.positions {
        let at = |built: &AsBuilt, tilt: f64| {
            true_sheet(&rig, built, p.colour_nm, p.mount_deg, p.light_arc_deg, tilt)
                .ok_or_else(no_truth)
        };
        for s in &p.sheets {
            let t = at(&as_built, s.tilt_deg)?;
            let (angle, offset) = errors(&s.plane, &t);
            angles.push(angle);
            max_offset = max_offset.max(offset);
            nominal_angle = nominal_angle.max(errors(&at(&nominal, s.tilt_deg)?, &t).0);
        }
        let (lo, hi) = match (p.sheets.first(), p.sheets.last()) {
            (Some(a), Some(b)) => (a.tilt_deg, b.tilt_deg),
            _ => continue,
        };
        for k in 0..9 {
            let tilt = lo + (hi - lo) * f64::from(k) / 8.0;
            let Some(predicted) = p.sheet(tilt) else {
                return Err(bad(format!(
                    "position {} nm, mount {}°, arc {}° gives no sheet at tilt {tilt}°",
                    p.colour_nm, p.mount_deg, p.light_arc_deg
                )));
            };
            let (angle, offset) = errors(&predicted, &at(&as_built, tilt)?);
            sweep_angle = sweep_angle.max(angle);
            sweep_offset = sweep_offset.max(offset);
        }
    }
    angles.sort_by(f64::total_cmp);
    Ok(LaserPlaneFigures {
        id: stored.id.clone(),
        positions: result.planes.positions.len(),
        sheets: angles.len(),
        max_angle_deg: angles.last().copied().unwrap_or(0.0),
        median_angle_deg: angles.get(angles.len() / 2).copied().unwrap_or(0.0),
        max_offset_mm: max_offset,
        sweep_max_angle_deg: sweep_angle,
        sweep_max_offset_mm: sweep_offset,
        nominal_max_angle_deg: nominal_angle,
    })
}
