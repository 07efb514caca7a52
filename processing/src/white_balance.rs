//! Joint camera and lamp white balance from the colour checker (seed 004 §3.1): per channel c
//! the scale S_c that best maps the chart's published reflectances ρ to the measured values m,
//! S_c = Σ_p m_pc ρ_pc / Σ_p ρ_pc² (least squares of m = S·ρ). A lamp so dim that the chart
//! is lost in the noise makes S meaningless: that is an error, never a division by ~0.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;

/// Published sRGB values of the 24 ColorChecker Classic patches (row by row, dark skin first).
const COLORCHECKER_SRGB: [[u8; 3]; 24] = [
    [115, 82, 68],
    [194, 150, 130],
    [98, 122, 157],
    [87, 108, 67],
    [133, 128, 177],
    [103, 189, 170],
    [214, 126, 44],
    [80, 91, 166],
    [193, 90, 99],
    [94, 60, 108],
    [157, 188, 64],
    [224, 163, 46],
    [56, 61, 150],
    [70, 148, 73],
    [175, 54, 60],
    [231, 199, 31],
    [187, 86, 149],
    [8, 133, 161],
    [243, 243, 242],
    [200, 200, 200],
    [160, 160, 160],
    [122, 122, 121],
    [85, 85, 85],
    [52, 52, 52],
];

/// The neutral row: white to black.
pub const NEUTRAL_PATCHES: std::ops::Range<usize> = 18..24;

/// Linear reflectance of ColorChecker patch `index` (0..24) per channel, from its published
/// sRGB value.
pub fn checker_reflectance(index: usize) -> [f64; 3] {
    let lin = |v: u8| {
        let c = f64::from(v) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let p = COLORCHECKER_SRGB[index.min(23)];
    [lin(p[0]), lin(p[1]), lin(p[2])]
}

/// One patch as measured: its mean linear value per channel over its central area, and the
/// standard error of that mean.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PatchMeasurement {
    /// Patch index, 0..24.
    pub patch: usize,
    /// Mean linear value per channel.
    pub mean: [f64; 3],
    /// Standard error of the mean per channel.
    pub std_err: [f64; 3],
}

/// The scale of each channel for one camera under one lamp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WhiteBalance {
    /// S_r, S_g, S_b: measured value per unit reflectance.
    pub scale: [f64; 3],
    /// Relative standard error of each scale.
    pub rel_std: [f64; 3],
    /// RMS residual m − S·ρ over the RMS prediction S·ρ, per channel: how well one scale
    /// explains the chart (a non-linear response or glare shows here). Ratios of sums, not a
    /// mean of per-patch ratios: a channel a patch barely reflects (cyan's red, 0.2 %) would
    /// turn its noise into a huge relative error.
    pub rel_residual: [f64; 3],
}

/// Largest relative standard error of a scale accepted.
pub const MAX_REL_STD: f64 = 0.02;

/// A robust patch statistic: the mean of `values` after dropping those more than 3 MADs from
/// the median (specular glare, dust), with its standard error. `None` for fewer than 4 values.
pub fn patch_mean(values: &[f64]) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.len() < 4 {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let median = v[v.len() / 2];
    let mut dev: Vec<f64> = v.iter().map(|x| (x - median).abs()).collect();
    dev.sort_by(f64::total_cmp);
    let mad = dev[dev.len() / 2].max(1e-12);
    let kept: Vec<f64> = v
        .into_iter()
        .filter(|x| (x - median).abs() <= 3.0 * 1.4826 * mad)
        .collect();
    let n = kept.len() as f64;
    let mean = kept.iter().sum::<f64>() / n;
    let var = kept.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    Some((mean, (var / n).sqrt()))
}

/// Fits the channel scales from `patches`.
pub fn white_balance(patches: &[PatchMeasurement]) -> Result<WhiteBalance, ProcessingError> {
    if patches.len() < 3 {
        return Err(ProcessingError::IllPosed {
            what: "white balance",
            why: format!(
                "only {} chart patches were measured; at least the 6 neutral ones are needed",
                patches.len()
            ),
        });
    }
    let mut scale = [0.0; 3];
    let mut rel_std = [0.0; 3];
    let mut rel_residual = [0.0; 3];
    for c in 0..3 {
        let (mut num, mut den, mut var) = (0.0, 0.0, 0.0);
        for p in patches {
            let rho = checker_reflectance(p.patch)[c];
            num += p.mean[c] * rho;
            den += rho * rho;
            var += rho * rho * p.std_err[c].powi(2);
        }
        let s = num / den;
        let sigma = var.sqrt() / den;
        let channel = ["red", "green", "blue"][c];
        if !(s.is_finite() && sigma.is_finite()) || s <= 0.0 || sigma > MAX_REL_STD * s {
            return Err(ProcessingError::IllPosed {
                what: "white balance",
                why: format!(
                    "the {channel} channel's scale is {s:.3e} ± {sigma:.1e}: the chart is lost in the noise (the lamp is too dim or off, or the exposure too short); lengthen the exposure or check the lamp"
                ),
            });
        }
        scale[c] = s;
        rel_std[c] = sigma / s;
        let (mut sq, mut signal) = (0.0, 0.0);
        for p in patches {
            let predicted = s * checker_reflectance(p.patch)[c];
            sq += (p.mean[c] - predicted).powi(2);
            signal += predicted * predicted;
        }
        rel_residual[c] = (sq / signal).sqrt();
    }
    Ok(WhiteBalance {
        scale,
        rel_std,
        rel_residual,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measure(scale: [f64; 3], noise: f64) -> Vec<PatchMeasurement> {
        (0..24)
            .map(|patch| {
                let rho = checker_reflectance(patch);
                PatchMeasurement {
                    patch,
                    mean: [0, 1, 2].map(|c| scale[c] * rho[c]),
                    std_err: [noise; 3],
                }
            })
            .collect()
    }

    #[test]
    fn recovers_the_channel_scales_of_a_warm_lamp() {
        let truth = [0.92, 0.61, 0.28];
        let wb = white_balance(&measure(truth, 1e-4)).unwrap();
        for (c, t) in truth.iter().enumerate() {
            assert!((wb.scale[c] / t - 1.0).abs() < 1e-9);
            assert!(wb.rel_residual[c] < 1e-9);
            assert!(wb.rel_std[c] < 1e-3);
        }
    }

    #[test]
    fn a_lamp_lost_in_the_noise_is_an_error_not_a_nan() {
        // Blue at 1e-4 of full scale with noise 1e-3: unmeasurable.
        let err = white_balance(&measure([0.5, 0.3, 1e-4], 1e-3)).unwrap_err();
        assert!(err.to_string().contains("blue"), "{err}");
        let err = white_balance(&measure([0.0, 0.0, 0.0], 0.0)).unwrap_err();
        assert!(matches!(err, ProcessingError::IllPosed { .. }));
        assert!(white_balance(&measure([0.5; 3], 1e-4)[..2]).is_err());
    }

    #[test]
    fn glare_on_a_patch_is_rejected_by_the_robust_mean() {
        let mut values = vec![0.4; 90];
        values.extend([0.95; 10]);
        let (mean, err) = patch_mean(&values).unwrap();
        assert!((mean - 0.4).abs() < 1e-9 && err < 1e-6);
        assert!(patch_mean(&[1.0, f64::NAN, 2.0]).is_none());
    }
}
