//! The dipole fits (`process --products dipole`) against the simulated sample's medium: per
//! laser colour, α′ and σ′t of the channel the laser is read in against σ′s/(σa + σ′s) and
//! σa + σ′s of that channel, with η assumed against η true.

use std::path::Path;

use serde::Serialize;
use stagehand_processing::dipole_products::DipoleProduct;

use super::EvaluateError;

/// One colour's fit against the truth.
#[derive(Debug, Clone, Serialize)]
pub struct DipoleColourFigures {
    /// The laser's wavelength, nm.
    pub colour_nm: u32,
    /// The RGB channel it was read in.
    pub channel: usize,
    /// α′ fitted.
    pub alpha_p: f64,
    /// α′ of the medium in that channel.
    pub alpha_p_true: f64,
    /// Relative error of α′.
    pub alpha_p_error: f64,
    /// σ′t fitted, mm⁻¹.
    pub sigma_t_p: f64,
    /// σ′t of the medium, mm⁻¹.
    pub sigma_t_p_true: f64,
    /// Relative error of σ′t.
    pub sigma_t_p_error: f64,
    /// The total diffuse reflectance fitted.
    pub reflectance: f64,
    /// η the fit assumed.
    pub eta: f64,
    /// η of the medium.
    pub eta_true: f64,
    /// Largest relative deviation of a camera's own α′ from the pooled fit.
    pub camera_alpha_spread: f64,
    /// Largest relative deviation of a camera's own σ′t from the pooled fit.
    pub camera_sigma_spread: f64,
    /// The fitted medium re-rendered at the captured pixels: relative RMS error.
    pub rerender_relative_rms: f64,
    /// Its median relative error per pixel.
    pub rerender_median: f64,
    /// Cameras whose own fit failed.
    pub cameras_failed: usize,
    /// The fit's flags.
    pub flags: Vec<String>,
}

/// The dipole section of the report.
#[derive(Debug, Clone, Serialize)]
pub struct DipoleFigures {
    /// The sample (fixture name).
    pub sample: String,
    /// The sample is not a homogeneous flat slab (relief or a mesostructure): the dipole
    /// then fits an effective medium, and the errors are not the fit's alone.
    pub quasi_homogeneous: bool,
    /// Per colour.
    pub colours: Vec<DipoleColourFigures>,
}

/// Evaluates the run's dipole products, if it has any.
pub fn evaluate_dipole(run_dir: &Path) -> Result<Option<DipoleFigures>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((_, products)) = super::products_of(run_dir, "dipole")? else {
        return Ok(None);
    };
    let (sample, centre, medium) = super::surface::centre_medium(run_dir, "dipole")?;
    let mut colours = Vec::new();
    for p in &products {
        let bytes =
            std::fs::read(run_dir.join(&p.path)).map_err(|e| err(format!("{}: {e}", p.path)))?;
        let d: DipoleProduct =
            serde_json::from_slice(&bytes).map_err(|e| err(format!("{}: {e}", p.path)))?;
        let c = d.channel.min(2);
        let (a, s) = (
            f64::from(medium.sigma_a[c]),
            f64::from(medium.sigma_s_prime[c]),
        );
        let (alpha_true, sigma_true) = (s / (a + s), a + s);
        let spread = |f: &dyn Fn(&stagehand_processing::dipole_fit::DipoleFit) -> f64,
                      pooled: f64| {
            d.cameras
                .values()
                .filter_map(|r| r.as_ref().ok())
                .map(|fit| (f(fit) / pooled - 1.0).abs())
                .fold(0.0f64, f64::max)
        };
        colours.push(DipoleColourFigures {
            colour_nm: d.colour_nm,
            channel: c,
            alpha_p: d.fit.alpha_p,
            alpha_p_true: alpha_true,
            alpha_p_error: d.fit.alpha_p / alpha_true - 1.0,
            sigma_t_p: d.fit.sigma_t_p,
            sigma_t_p_true: sigma_true,
            sigma_t_p_error: d.fit.sigma_t_p / sigma_true - 1.0,
            reflectance: d.fit.reflectance,
            eta: d.eta,
            eta_true: f64::from(medium.eta),
            camera_alpha_spread: spread(&|f| f.alpha_p, d.fit.alpha_p),
            camera_sigma_spread: spread(&|f| f.sigma_t_p, d.fit.sigma_t_p),
            cameras_failed: d.cameras.values().filter(|r| r.is_err()).count(),
            rerender_relative_rms: d.rerender.relative_rms,
            rerender_median: d.rerender.median_relative,
            flags: d.fit.flags.iter().map(|f| format!("{f:?}")).collect(),
        });
    }
    colours.sort_by_key(|c| c.colour_nm);
    Ok(Some(DipoleFigures {
        sample: sample.name.clone(),
        quasi_homogeneous: sample.grid.is_some() || centre.meso_in != 1.0 || centre.meso_out != 1.0,
        colours,
    }))
}
