//! Material maps against the simulator's material plane (ground truth `material`, runs with
//! `[sim] ground_truth = true`): the reflectometer's Ward maps (ρd per channel, ρs and α,
//! relative errors) and transparency maps (absolute error of T). Only pixels on the sample
//! (some material channel above 0) that the product saw count; a map's refused and poorly
//! fitted pixels count as not converged, its anisotropy flags against where the truth is
//! anisotropic.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_planes::{DecodedPlanes, decode_exr_planes};
use stagehand_processing::ward_fit::WardFlag;
use stagehand_processing::ward_map::{REFUSED, UNSEEN};

use super::EvaluateError;

/// Median and 95th percentile of an error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    /// Median.
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
}

impl Spread {
    /// The spread of `v`; `None` when empty.
    fn of(mut v: Vec<f64>) -> Option<Spread> {
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Some(Spread {
            median: at(0.5),
            p95: at(0.95),
        })
    }
}

/// The Ward maps of a run against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WardFigures {
    /// Maps compared.
    pub maps: usize,
    /// Pixels on the sample that the maps saw.
    pub pixels: usize,
    /// Relative error of ρd, every channel pooled, over the fitted pixels.
    pub rho_d: Option<Spread>,
    /// Relative error of ρs where the truth has a specular lobe and the fit determined it.
    pub rho_s: Option<Spread>,
    /// Relative error of α (the truth's isotropic α, or the mean of αx and αy) there.
    pub alpha: Option<Spread>,
    /// The re-render error: each fitted pixel's model under every tube stop against the
    /// captured radiance (relative RMS residual, the maps' `rms` channel).
    pub rerender: Option<Spread>,
    /// Fraction of the pixels whose fit was refused or flagged poor.
    pub not_converged: f64,
    /// Fraction of the pixels flagged anisotropic.
    pub flagged_anisotropic: f64,
    /// Fraction of the pixels whose truth is anisotropic (αx and αy differ by over 25 %).
    pub truly_anisotropic: f64,
    /// Of the truly anisotropic pixels, the fraction flagged anisotropic.
    pub anisotropy_found: Option<f64>,
    /// Of the other pixels, the fraction flagged anisotropic.
    pub anisotropy_false_alarms: Option<f64>,
    /// Fraction of the pixels flagged as showing no specular lobe.
    pub no_specular: f64,
}

/// The transparency maps of a run against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransparencyFigures {
    /// Maps compared.
    pub maps: usize,
    /// Pixels on the sample compared.
    pub pixels: usize,
    /// Absolute error of T, every channel pooled.
    pub error: Option<Spread>,
    /// Fraction of the pixels flagged clipped.
    pub clipped: f64,
}

/// A product and its truth plane, decoded, with the truth's channels by name.
struct Pair {
    product: DecodedPlanes,
    truth: DecodedPlanes,
}

/// Every product of `kind` with the material plane of its truth frame.
fn pairs(run_dir: &Path, kind: &str) -> Result<Option<Vec<Pair>>, EvaluateError> {
    let err = |message: String| EvaluateError::Truth {
        path: run_dir.display().to_string(),
        message,
    };
    let Some((reader, products)) = super::products_of(run_dir, kind)? else {
        return Ok(None);
    };
    let truth_rows: BTreeMap<String, String> = reader
        .ground_truth(None)
        .map_err(|e| err(e.to_string()))?
        .into_iter()
        .filter(|g| g.kind == "material")
        .map(|g| (g.frame_path, g.path))
        .collect();
    let read = |path: &str| {
        let bytes = std::fs::read(run_dir.join(path)).map_err(|e| err(format!("{path}: {e}")))?;
        decode_exr_planes(path, &bytes).map_err(|e| err(e.to_string()))
    };
    let mut out = Vec::new();
    for p in products.iter().filter(|p| p.path.ends_with(".exr")) {
        let Some(truth_path) = p.made.parameters["truth_frame"]
            .as_str()
            .and_then(|f| truth_rows.get(f))
        else {
            continue;
        };
        let pair = Pair {
            product: read(&p.path)?,
            truth: read(truth_path)?,
        };
        if (pair.product.width, pair.product.height) != (pair.truth.width, pair.truth.height) {
            return Err(err(format!("{} and {truth_path} differ in size", p.path)));
        }
        out.push(pair);
    }
    Ok((!out.is_empty()).then_some(out))
}

/// Channel `name` of `planes`, or an error naming it.
fn channel<'a>(planes: &'a DecodedPlanes, name: &str) -> Result<&'a [f32], EvaluateError> {
    planes.channel(name).ok_or_else(|| EvaluateError::Truth {
        path: name.to_string(),
        message: format!("a material map or plane lacks channel `{name}`"),
    })
}

/// Evaluates the run's `ward` products, if it has any and ground truth beside them.
pub fn evaluate_ward(run_dir: &Path) -> Result<Option<WardFigures>, EvaluateError> {
    let Some(pairs) = pairs(run_dir, "ward")? else {
        return Ok(None);
    };
    let (mut rho_d, mut rho_s, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    let mut rerender = Vec::new();
    let (mut pixels, mut poor, mut flagged, mut truly, mut no_spec) = (0, 0, 0, 0, 0);
    let (mut found, mut false_alarms) = (0, 0);
    for pair in &pairs {
        let (p, t) = (&pair.product, &pair.truth);
        let fitted: Vec<&[f32]> = [
            "rho_d.R", "rho_d.G", "rho_d.B", "rho_s", "alpha", "flags", "rms",
        ]
        .iter()
        .map(|c| channel(p, c))
        .collect::<Result<_, _>>()?;
        let truth: Vec<&[f32]> = ["albedo.R", "albedo.G", "albedo.B", "ks", "alpha", "alpha_y"]
            .iter()
            .map(|c| channel(t, c))
            .collect::<Result<_, _>>()?;
        for i in 0..fitted[0].len() {
            let on_sample = truth.iter().any(|c| c[i] > 0.0);
            let flags = fitted[5][i] as u16;
            if !on_sample || flags & UNSEEN != 0 {
                continue;
            }
            pixels += 1;
            let (ax, ay) = (f64::from(truth[4][i]), f64::from(truth[5][i]));
            let anisotropic = ax > 0.0 && ay > 0.0 && (ax - ay).abs() > 0.25 * 0.5 * (ax + ay);
            let flagged_here = flags & WardFlag::Anisotropic.bit() != 0;
            truly += usize::from(anisotropic);
            flagged += usize::from(flagged_here);
            found += usize::from(anisotropic && flagged_here);
            false_alarms += usize::from(!anisotropic && flagged_here);
            no_spec += usize::from(flags & WardFlag::NoSpecular.bit() != 0);
            if flags & REFUSED == 0 {
                rerender.push(f64::from(fitted[6][i]));
            }
            if flags & (REFUSED | WardFlag::PoorFit.bit()) != 0 {
                poor += 1;
                continue;
            }
            for c in 0..3 {
                let want = f64::from(truth[c][i]);
                if want > 0.0 {
                    rho_d.push((f64::from(fitted[c][i]) - want).abs() / want);
                }
            }
            let ks = f64::from(truth[3][i]);
            let undetermined = WardFlag::NoSpecular.bit()
                | WardFlag::SpecularPeakOutsideSweep.bit()
                | WardFlag::AlphaBelowStopSpacing.bit();
            if ks > 0.0 && flags & undetermined == 0 {
                rho_s.push((f64::from(fitted[3][i]) - ks).abs() / ks);
                let a = if ay > 0.0 { 0.5 * (ax + ay) } else { ax };
                if a > 0.0 {
                    alpha.push((f64::from(fitted[4][i]) - a).abs() / a);
                }
            }
        }
    }
    let fraction = |k: usize| {
        if pixels > 0 {
            k as f64 / pixels as f64
        } else {
            0.0
        }
    };
    Ok(Some(WardFigures {
        maps: pairs.len(),
        pixels,
        rho_d: Spread::of(rho_d),
        rho_s: Spread::of(rho_s),
        alpha: Spread::of(alpha),
        rerender: Spread::of(rerender),
        not_converged: fraction(poor),
        flagged_anisotropic: fraction(flagged),
        truly_anisotropic: fraction(truly),
        anisotropy_found: (truly > 0).then(|| found as f64 / truly as f64),
        anisotropy_false_alarms: (pixels > truly)
            .then(|| false_alarms as f64 / (pixels - truly) as f64),
        no_specular: fraction(no_spec),
    }))
}

/// Evaluates the run's `transparency` products, if it has any and ground truth beside them.
pub fn evaluate_transparency(run_dir: &Path) -> Result<Option<TransparencyFigures>, EvaluateError> {
    let Some(pairs) = pairs(run_dir, "transparency")? else {
        return Ok(None);
    };
    let (mut errors, mut pixels, mut clipped) = (Vec::new(), 0, 0);
    for pair in &pairs {
        let (p, t) = (&pair.product, &pair.truth);
        let fitted: Vec<&[f32]> = ["T.R", "T.G", "T.B", "flags"]
            .iter()
            .map(|c| channel(p, c))
            .collect::<Result<_, _>>()?;
        let truth: Vec<&[f32]> = [
            "albedo.R",
            "ks",
            "transmittance.R",
            "transmittance.G",
            "transmittance.B",
        ]
        .iter()
        .map(|c| channel(t, c))
        .collect::<Result<_, _>>()?;
        for i in 0..fitted[0].len() {
            if !truth.iter().any(|c| c[i] > 0.0) {
                continue;
            }
            pixels += 1;
            if fitted[3][i] as u8 & stagehand_processing::transparency::CLIPPED != 0 {
                clipped += 1;
                continue;
            }
            for c in 0..3 {
                errors.push(f64::from((fitted[c][i] - truth[2 + c][i]).abs()));
            }
        }
    }
    Ok(Some(TransparencyFigures {
        maps: pairs.len(),
        pixels,
        error: Spread::of(errors),
        clipped: if pixels > 0 {
            clipped as f64 / pixels as f64
        } else {
            0.0
        },
    }))
}

/// The exit-function maps (`process --products exit`) against the material plane's
/// `meso_out`. The maps are relative to the fitted homogeneous medium, whose level carries the
/// mesostructure's mean, so they are compared in shape: each map over its median ratio to the
/// truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExitFigures {
    /// Maps compared.
    pub maps: usize,
    /// Pixels the lines lit enough to measure, on the sample.
    pub pixels: usize,
    /// The median of the maps' exit over the true exit function (the scale left out).
    pub scale: f64,
    /// Relative error of the exit function after that scale, pooled over the maps.
    pub error: Option<Spread>,
}

/// Evaluates the run's `exit` products, if it has any and ground truth beside them.
pub fn evaluate_exit(run_dir: &Path) -> Result<Option<ExitFigures>, EvaluateError> {
    let Some(pairs) = pairs(run_dir, "exit")? else {
        return Ok(None);
    };
    let (mut pixels, mut errors, mut scales) = (0, Vec::new(), Vec::new());
    for Pair { product, truth } in &pairs {
        let (exit, weight) = (channel(product, "exit")?, channel(product, "weight")?);
        let meso = channel(truth, "meso_out")?;
        let medium = channel(truth, "medium")?;
        let ratios: Vec<(f64, f64)> = (0..exit.len())
            .filter(|&i| exit[i] > 0.0 && weight[i] > 0.0 && medium[i] > 0.0 && meso[i] > 0.0)
            .map(|i| (f64::from(exit[i]), f64::from(meso[i])))
            .collect();
        let mut r: Vec<f64> = ratios.iter().map(|(e, m)| e / m).collect();
        r.sort_by(f64::total_cmp);
        let Some(&scale) = r.get(r.len() / 2) else {
            continue;
        };
        scales.push(scale);
        pixels += ratios.len();
        errors.extend(ratios.iter().map(|(e, m)| (e / scale - m).abs() / m));
    }
    scales.sort_by(f64::total_cmp);
    Ok(Some(ExitFigures {
        maps: pairs.len(),
        pixels,
        scale: scales.get(scales.len() / 2).copied().unwrap_or(0.0),
        error: Spread::of(errors),
    }))
}

/// The local reflectance maps (`process --products local`) against the truth. The simulator's
/// surface reflects locally only through its BRDF: where it has no specular lobe (Lambert, or
/// ρs 0) the true local reflectance factor of a flat sample is its albedo (0 under a medium,
/// whose dipole supplies the diffuse light), which is what is compared; pixels with a lobe
/// are counted, not compared. Errors are fractions of the captured light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocalFigures {
    /// Maps compared.
    pub maps: usize,
    /// Known pixel channels compared.
    pub pixels: usize,
    /// Known pixel channels not compared (the truth has a specular lobe there).
    pub not_evaluated: usize,
    /// |global + true local − captured| / captured: the fitted material re-rendered under
    /// each lamp against the capture.
    pub rerender: Option<Spread>,
    /// The median of that error, signed (positive: the global term reads high).
    pub rerender_bias: f64,
    /// |local − true local| / captured.
    pub local_error: Option<Spread>,
    /// Fraction of the known pixel channels clamped at 0.
    pub clamped: f64,
}

/// Evaluates the run's `local` products, if it has any and ground truth beside them.
pub fn evaluate_local(run_dir: &Path) -> Result<Option<LocalFigures>, EvaluateError> {
    let Some(pairs) = pairs(run_dir, "local")? else {
        return Ok(None);
    };
    let (mut pixels, mut skipped, mut known, mut clamped) = (0, 0, 0, 0);
    let (mut rerender, mut signed, mut local_error) = (Vec::new(), Vec::new(), Vec::new());
    for Pair { product, truth } in &pairs {
        let (ks, model) = (channel(truth, "ks")?, channel(truth, "model")?);
        for name in ["R", "G", "B"] {
            let is_known = channel(product, &format!("known.{name}"))?;
            let local = channel(product, &format!("local.{name}"))?;
            let global = channel(product, &format!("global.{name}"))?;
            let captured = channel(product, &format!("captured.{name}"))?;
            let albedo = channel(truth, &format!("albedo.{name}"))?;
            for i in (0..is_known.len()).filter(|&i| is_known[i] > 0.0) {
                known += 1;
                clamped += usize::from(f64::from(captured[i]) < f64::from(global[i]));
                if model[i] != 0.0 && ks[i] > 0.0 {
                    skipped += 1;
                    continue;
                }
                let cap = f64::from(captured[i]);
                if cap <= 0.0 {
                    continue;
                }
                let truth_local = f64::from(albedo[i]);
                let e = (f64::from(global[i]) + truth_local - cap) / cap;
                pixels += 1;
                rerender.push(e.abs());
                signed.push(e);
                local_error.push((f64::from(local[i]) - truth_local).abs() / cap);
            }
        }
    }
    signed.sort_by(f64::total_cmp);
    Ok(Some(LocalFigures {
        maps: pairs.len(),
        pixels,
        not_evaluated: skipped,
        rerender: Spread::of(rerender),
        rerender_bias: signed.get(signed.len() / 2).copied().unwrap_or(0.0),
        local_error: Spread::of(local_error),
        clamped: if known > 0 {
            clamped as f64 / known as f64
        } else {
            0.0
        },
    }))
}
