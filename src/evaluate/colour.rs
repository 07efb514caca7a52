//! Recovered colour scales against the simulated rig's. What S should be, from the sensor and
//! light models of the simulator (`render/sensor.rs`, `render/lights.rs`):
//!
//! - A matte chart patch of reflectance ρ_c at point p, lit by one halogen lamp, has radiance
//!   L_c = ρ_c·E_c(p)/π, where E_c(p) is the lamp's irradiance in reference units: its
//!   as-built intensity × rig power × warm-up output × the halogen colour × its as-built tint,
//!   × 800² cos θ_i / r² (`DirectLight::irradiance`, the renderer's own function).
//! - The sensor collects x = L_c·π·FILL/T_ref·gain·Δt of its full well (`Sensor::new`: white
//!   Lambert under the reference lamp fills FILL of the well in T_ref at gain 1).
//! - The merge through a recovered response gives exp g(Z)/Δt, and g = ln x − offset_c, the
//!   offset being the response calibration's free constant per channel (the solver pins g to 0
//!   at its middle knot); it is measured as [`super::response`] does, the median of ln x − g
//!   over the DN range that evaluation trusts.
//!
//! So the merged value of the patch is S_c(p)·ρ_c with S_c(p) = FILL/T_ref · gain · E_c(p) ·
//! exp(−offset_c): the joint camera+lamp scale in the response calibration's units. The
//! irradiance varies over the chart (a lamp 800 mm away, ±40 mm of chart), and the fit is least
//! squares over the patches it measured, so the true S is the same fit of the exact S_c(p) at
//! those patches' centres: Σ_p S_c(p)·ρ_pc² / Σ_p ρ_pc². The report gives the relative error of
//! each recovered S_c against it.

use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3A;
use serde::Serialize;
use stagehand_dataset::{FrameKind, FrameMeta, FrameQuery, RunReader, read_manifest};
use stagehand_devices::rig::{LampKind, parse_rig};
use stagehand_processing::calibration_store::{self, CalibrationKind, StoredCalibration};
use stagehand_processing::colour_calibration::ColourSet;
use stagehand_processing::response_calibration::ResponseSet;
use stagehand_simulator::as_built::{AsBuilt, LampAsBuilt};
use stagehand_simulator::render::geometry::{RigAngles, ToSample};
use stagehand_simulator::render::irradiance::{DirectLight, MAX_TUBE_POINTS};
use stagehand_simulator::render::lights::lit_lamps;
use stagehand_simulator::render::sample::{colorchecker_patch, colorchecker_patch_centre};
use stagehand_simulator::render::sensor::{REFERENCE_EXPOSURE_S, REFERENCE_FILL};
use stagehand_simulator::world_snapshot::WorldSnapshot;

use super::EvaluateError;
use super::response::CameraTruth;

/// One camera's scales under one lamp, recovered and true.
#[derive(Debug, Clone, Serialize)]
pub struct LampFigures {
    /// The calibration's S_r, S_g, S_b.
    pub recovered: [f64; 3],
    /// What they should be (see the module docs).
    pub truth: [f64; 3],
    /// recovered / truth − 1 per channel.
    pub rel_error: [f64; 3],
}

/// Figures of one colour calibration.
#[derive(Debug, Clone, Serialize)]
pub struct ColourFigures {
    /// Calibration id.
    pub calibration: String,
    /// The response calibration its scales are in the units of.
    pub response: String,
    /// Per camera, per lamp.
    pub cameras: BTreeMap<String, BTreeMap<String, LampFigures>>,
    /// The largest |rel_error| of any channel.
    pub worst_rel_error: f64,
}

fn bad(what: impl std::fmt::Display) -> EvaluateError {
    EvaluateError::Truth {
        path: "colour evaluation".into(),
        message: what.to_string(),
    }
}

/// The output of `lamp` when `meta`'s frame was exposed, from the renderer's frame notes.
fn lamp_output(meta: &FrameMeta, lamp: &str) -> Option<f64> {
    meta.notes["lights"]
        .as_array()?
        .iter()
        .find(|l| l["id"].as_str() == Some(lamp))?["output"]
        .as_f64()
}

/// Evaluates one stored colour calibration of the run at `run_dir` against `truth`
/// (as_built.json), with the calibrations under `root`.
pub fn evaluate_colour(
    stored: &StoredCalibration,
    truth: &serde_json::Value,
    run_dir: &Path,
    root: &Path,
) -> Result<ColourFigures, EvaluateError> {
    let set: ColourSet = stored.result(CalibrationKind::Colour)?;
    let response_id = stored.calibration.parameters["response"]
        .as_str()
        .ok_or_else(|| bad(format!("{} names no response calibration", stored.id)))?;
    let responses: ResponseSet =
        calibration_store::load(root, response_id)?.result(CalibrationKind::Response)?;
    let manifest = read_manifest(run_dir).map_err(bad)?;
    let rig = parse_rig(&manifest.rig_toml, "rig.toml").map_err(bad)?;
    let size = manifest
        .sim
        .as_ref()
        .ok_or_else(|| bad("the run is not simulated"))?
        .sample_size_mm as f32;
    let lamps: BTreeMap<String, LampAsBuilt> = serde_json::from_value(truth["lamps"].clone())
        .map_err(|e| bad(format!("as_built.json lamps: {e}")))?;
    let as_built = AsBuilt {
        spec: None,
        cameras: BTreeMap::new(),
        lamps,
    };
    let reader = RunReader::open(run_dir).map_err(bad)?;
    let mut cameras = BTreeMap::new();
    let mut worst = 0.0f64;
    for (camera, colour) in &set {
        let response = responses
            .get(camera)
            .ok_or_else(|| bad(format!("{response_id} has no camera `{camera}`")))?;
        let cam = CameraTruth::new(truth, camera)?;
        let mut offset = [0.0; 3];
        for (c, g) in response.channels.iter().enumerate() {
            let (lo, hi) = cam.evaluated_range(c, g)?;
            offset[c] = cam.log_offset(c, g, lo, hi)?.1;
        }
        let mut per_lamp = BTreeMap::new();
        for (lamp, scale) in &colour.lamps {
            if rig.lamp(lamp).is_none_or(|l| l.kind != LampKind::Halogen) {
                return Err(bad(format!(
                    "lamp `{lamp}` is not a halogen lamp of the rig"
                )));
            }
            let (mut num, mut den) = ([0.0f64; 3], [0.0f64; 3]);
            for view in &scale.views {
                let meta = reader
                    .frames(&FrameQuery {
                        camera: Some(camera.clone()),
                        step: Some(view.step),
                        kind: Some(FrameKind::Raw),
                        limit: Some(1),
                        ..FrameQuery::default()
                    })
                    .map_err(bad)?
                    .frames
                    .into_iter()
                    .next()
                    .ok_or_else(|| bad(format!("step {} has no frame of {camera}", view.step)))?
                    .meta;
                let output = lamp_output(&meta, lamp).ok_or_else(|| {
                    bad(format!(
                        "step {}: the frame notes give no output of {lamp}",
                        view.step
                    ))
                })?;
                let world = WorldSnapshot {
                    rig_time_s: meta.rig_time_s,
                    axes: meta.axes_deg.clone(),
                    lamps: BTreeMap::from([(lamp.clone(), output)]),
                    laser: None,
                    cart_mm: meta.cart_mm.unwrap_or(0.0),
                    fixture: meta.fixture.clone(),
                    fixture_pose: meta.fixture_pose,
                };
                let angles = RigAngles::from_world(&rig, &world.axes);
                let to_sample = ToSample::placed(angles.turntable_deg, &world.fixture_pose);
                let (lights, _) = lit_lamps(&rig, &as_built, &world, angles, to_sample);
                let direct = DirectLight {
                    lights: &lights,
                    laser: None,
                    grid: None,
                    shadows: false,
                    tube_points: MAX_TUBE_POINTS,
                };
                let per_irradiance = REFERENCE_FILL / REFERENCE_EXPOSURE_S * meta.gain;
                for patch in &view.patches {
                    let (x, y) = colorchecker_patch_centre(size, patch.patch);
                    let mut rays = 0;
                    let e =
                        direct.irradiance(Vec3A::new(x, y, 0.0), Vec3A::Z, 0.0, |_| 1.0, &mut rays);
                    let rho = colorchecker_patch(patch.patch);
                    for c in 0..3 {
                        let s = per_irradiance * f64::from(e[c]) * (-offset[c]).exp();
                        let r2 = f64::from(rho[c]).powi(2);
                        num[c] += s * r2;
                        den[c] += r2;
                    }
                }
            }
            let truth_s = [0, 1, 2].map(|c| num[c] / den[c]);
            if truth_s.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(bad(format!(
                    "{camera} under {lamp}: no patch to compare (true scale {truth_s:?})"
                )));
            }
            let rel_error = [0, 1, 2].map(|c| scale.fit.scale[c] / truth_s[c] - 1.0);
            worst = rel_error.iter().fold(worst, |w, e| w.max(e.abs()));
            per_lamp.insert(
                lamp.clone(),
                LampFigures {
                    recovered: scale.fit.scale,
                    truth: truth_s,
                    rel_error,
                },
            );
        }
        cameras.insert(camera.clone(), per_lamp);
    }
    Ok(ColourFigures {
        calibration: stored.id.clone(),
        response: response_id.to_string(),
        cameras,
        worst_rel_error: worst,
    })
}

#[cfg(test)]
mod tests {
    use stagehand_processing::chart_layout::{ChartLayout, PATCHES};

    use super::*;

    /// Processing's chart layout (the physical chart) is the simulator's drawing of it.
    #[test]
    fn processing_places_the_patches_where_the_simulator_draws_them() {
        for size in [80.0, 57.5] {
            let layout = ChartLayout { size_mm: size };
            for i in 0..PATCHES {
                let (x, y) = colorchecker_patch_centre(size as f32, i);
                let c = layout.patch_centre(i);
                assert!(
                    (c[0] - f64::from(x)).abs() < 1e-4 && (c[1] - f64::from(y)).abs() < 1e-4,
                    "patch {i}: {c:?} vs ({x}, {y})"
                );
            }
            let half = 0.5 * layout.patch_mm();
            let (x, y) = colorchecker_patch_centre(size as f32, 7);
            assert_eq!(
                layout.patch_at(f64::from(x) + 0.99 * half, f64::from(y) - 0.99 * half),
                Some(7)
            );
        }
    }
}
