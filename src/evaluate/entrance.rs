//! The entrance functions (`process --products entrance`) against the simulator's: the
//! renderer lets in E·F_t(η, cos θi)·meso_in of a light's irradiance E
//! (`simulator/src/render/subsurface.rs`), so relative to normal incidence a direction lets
//! in F_t(η, cos θi)/F_t(η, 1) of the light, times the mesostructure's mean entrance (1 for a
//! homogeneous sample). The angle of incidence is the simulated laser's, as built (its mount
//! and tilt zero off their marks by up to half a degree: 2 % of F_t at 75°), at tilt 0.

use std::path::Path;

use serde::Serialize;
use stagehand_processing::dipole_products::EntranceProduct;
use stagehand_simulator::as_built::AsBuilt;
use stagehand_simulator::materials::fresnel::fresnel_transmittance;
use stagehand_simulator::render::geometry::ToSample;
use stagehand_simulator::render::laser::LaserSheet;
use stagehand_simulator::world_snapshot::LaserBeam;

use super::EvaluateError;

/// One direction of one colour against the truth.
#[derive(Debug, Clone, Serialize)]
pub struct EntranceDirectionFigures {
    /// The laser's wavelength, nm.
    pub colour_nm: u32,
    /// Angle of incidence from the normal, degrees (the laser's mount as marked).
    pub incidence_deg: f64,
    /// The simulated laser's angle of incidence as built, degrees.
    pub incidence_true_deg: f64,
    /// Azimuth of incidence on the sample, degrees.
    pub azimuth_deg: f64,
    /// f(ω_i) measured.
    pub entrance: f64,
    /// f(ω_i) of the simulated sample.
    pub entrance_true: f64,
    /// Relative error.
    pub error: f64,
    /// Largest relative deviation of a camera's own value from the mean.
    pub camera_spread: f64,
}

/// The entrance section of the report.
#[derive(Debug, Clone, Serialize)]
pub struct EntranceFigures {
    /// The sample (fixture name).
    pub sample: String,
    /// The sample has a mesostructure: the truth then assumes its mean entrance is its
    /// centre's.
    pub quasi_homogeneous: bool,
    /// Every direction of every colour.
    pub directions: Vec<EntranceDirectionFigures>,
    /// Largest |error| over the directions.
    pub max_error: f64,
}

/// Evaluates the run's entrance products, if it has any.
pub fn evaluate_entrance(run_dir: &Path) -> Result<Option<EntranceFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((_, products)) = super::products_of(run_dir, "entrance")? else {
        return Ok(None);
    };
    let (sample, centre, medium) = super::surface::centre_medium(run_dir, "entrance function")?;
    let eta = f64::from(medium.eta);
    let truth = super::read_truth(run_dir)?;
    let (rig, as_built) = super::laser_planes::rig_as_built(run_dir, &truth)?;
    let mut directions = Vec::new();
    for p in &products {
        let bytes =
            std::fs::read(run_dir.join(&p.path)).map_err(|e| err(format!("{}: {e}", p.path)))?;
        let e: EntranceProduct =
            serde_json::from_slice(&bytes).map_err(|e| err(format!("{}: {e}", p.path)))?;
        for d in &e.directions {
            let cos_in = true_cos_in(&rig, &as_built, e.colour_nm, d).ok_or_else(|| {
                err(format!(
                    "the run's rig has no laser to light the sample from {}°",
                    d.mount_deg
                ))
            })?;
            let truth = fresnel_transmittance(cos_in, eta) / fresnel_transmittance(1.0, eta)
                * f64::from(centre.meso_in);
            let spread = d
                .cameras
                .values()
                .map(|v| (v / d.entrance - 1.0).abs())
                .fold(0.0f64, f64::max);
            directions.push(EntranceDirectionFigures {
                colour_nm: e.colour_nm,
                incidence_deg: d.incidence_deg,
                incidence_true_deg: cos_in.acos().to_degrees(),
                azimuth_deg: d.azimuth_deg,
                entrance: d.entrance,
                entrance_true: truth,
                error: d.entrance / truth - 1.0,
                camera_spread: spread,
            });
        }
    }
    let max_error = directions
        .iter()
        .map(|d| d.error.abs())
        .fold(0.0f64, f64::max);
    Ok(Some(EntranceFigures {
        sample: sample.name.clone(),
        quasi_homogeneous: sample.grid.is_some() || centre.meso_in != 1.0,
        directions,
        max_error,
    }))
}

/// The cosine of the simulated laser's angle of incidence at the sample's centre: its central
/// ray as built, at tilt 0, on the mount and light-arc angle of `direction`.
fn true_cos_in(
    rig: &stagehand_devices::rig::RigSpec,
    as_built: &AsBuilt,
    colour_nm: u32,
    direction: &stagehand_processing::dipole_entrance::EntranceDirection,
) -> Option<f64> {
    let spec = rig.laser.as_ref()?;
    let beam = LaserBeam {
        colour_nm,
        tilt_deg: 0.0,
        mount_elevation_deg: direction.mount_deg,
    };
    // A flat sample: the turntable's turn about the normal leaves the angle as it is.
    let sheet = LaserSheet::built(
        spec,
        &beam,
        direction.azimuth_deg,
        ToSample::new(0.0),
        &as_built.laser(direction.mount_deg),
    );
    Some(f64::from(-sheet.centre.z).clamp(0.0, 1.0))
}
