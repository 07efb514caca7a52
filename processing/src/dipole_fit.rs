//! The dipole fit of seed 004 Ch. 5 on a laser line's lateral falloff: α′ from the reflectance
//! the profile carries, then σ′t by a coarse-to-fine 1-D search over [0.01, 10] mm⁻¹ against
//! the line-source integral of R_d, alternated until both settle (the joint fit is ill-posed,
//! L1194–1206). The profile is in units of the line's power per unit length (the laser power φ
//! calibrated on a reference sample), so its level fixes α′ and its shape σ′t.
//!
//! The line's own core (single scattering, specular reflection, saturation) is left out: both
//! the reflectance and the shape are matched beyond `core_mm`, model and data summed on the
//! same samples, so the window's truncation of the tails biases neither.

use serde::{Deserialize, Serialize};

use crate::dipole::DipoleMedium;
use crate::error::ProcessingError;
use crate::line_search::log_search;

/// One sample of the falloff: distance from the line's centre (mm) and the light leaving the
/// surface there per unit line power (mm⁻¹).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProfileSample {
    /// Signed distance from the line's centre, mm.
    pub x_mm: f64,
    /// Exitant light per unit line power, mm⁻¹.
    pub value: f64,
}

/// Settings of [`fit_dipole`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DipoleFitOptions {
    /// Relative index of refraction η (the seed's 1.3 unless known).
    pub eta: f64,
    /// Half-width of the line's core left out, mm.
    pub core_mm: f64,
    /// The σ′t search interval, mm⁻¹.
    pub sigma_range: [f64; 2],
    /// The samples' noise, for the weights of the shape fit: a sample of value v has standard
    /// deviation √((relative·v)² + floor²). The defaults weigh every sample alike; a sensor's
    /// shot noise is relative, its read noise the floor.
    pub relative_noise: f64,
    /// See `relative_noise`; in the profile's units, > 0.
    pub noise_floor: f64,
    /// The laser line's own width across: the standard deviation of its (Gaussian) irradiance
    /// profile, mm; 0 for an ideal line. The model is the line profile blurred by it, and the
    /// core is at least [`CORE_WIDTHS`] of it.
    #[serde(default)]
    pub line_width_mm: f64,
}

/// The core left out is at least this many line widths: the blurred model's quadrature
/// needs the profile smooth over ±2.7·√2 widths of each sample.
pub const CORE_WIDTHS: f64 = 4.0;

/// Gauss–Hermite nodes and weights (7 points) of ∫ f(t)·e^{−t²} dt.
const HERMITE: [(f64, f64); 7] = [
    (-2.651_961_356_835_233, 0.000_971_781_245_099_519),
    (-1.673_551_628_767_471, 0.054_515_582_819_127),
    (-0.816_287_882_858_964_7, 0.425_607_252_610_127_8),
    (0.0, 0.810_264_617_556_807_3),
    (0.816_287_882_858_964_7, 0.425_607_252_610_127_8),
    (1.673_551_628_767_471, 0.054_515_582_819_127),
    (2.651_961_356_835_233, 0.000_971_781_245_099_519),
];

/// The falloff of `m` at `x_mm` beside a line of Gaussian width `width_mm` (σ, mm).
pub fn blurred_profile(m: &DipoleMedium, x_mm: f64, width_mm: f64) -> f64 {
    if width_mm <= 0.0 {
        return m.line_profile(x_mm);
    }
    let step = std::f64::consts::SQRT_2 * width_mm;
    HERMITE
        .iter()
        .map(|(t, w)| w * m.line_profile(x_mm + step * t))
        .sum::<f64>()
        / std::f64::consts::PI.sqrt()
}

impl Default for DipoleFitOptions {
    fn default() -> Self {
        DipoleFitOptions {
            eta: 1.3,
            core_mm: 0.5,
            sigma_range: [0.01, 10.0],
            relative_noise: 0.0,
            noise_floor: 1.0,
            line_width_mm: 0.0,
        }
    }
}

/// Why a fitted parameter is weakly determined: reported beside the numbers, never hidden.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DipoleFlag {
    /// σ′t ended within 1 % of the search interval's end: the true value may lie beyond.
    SigmaAtSearchEnd,
    /// The profile carries more light than α′ = 1 explains (calibration of φ, or not a
    /// dipole medium): α′ is pinned at 1.
    AlbedoAboveOne,
    /// So little light that α′ is below 10⁻³: σ′t is barely determined.
    AlbedoNearZero,
}

/// What [`fit_dipole`] found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DipoleFit {
    /// Reduced albedo α′.
    pub alpha_p: f64,
    /// Reduced extinction σ′t, mm⁻¹.
    pub sigma_t_p: f64,
    /// The medium's total diffuse reflectance R (closed form, from α′).
    pub reflectance: f64,
    /// RMS of (data − model) over the samples used, relative to the data's RMS.
    pub relative_rms: f64,
    /// Samples used (outside the core).
    pub samples: usize,
    /// Weak determinations.
    pub flags: Vec<DipoleFlag>,
}

/// Least samples outside the core a fit needs.
pub const MIN_SAMPLES: usize = 8;

/// Points of the coarse σ′t grid (log-spaced), then golden-section steps of the fine search.
const COARSE: usize = 41;
const FINE: usize = 50;

/// Steps of the α′ root search at most.
const ALPHA_STEPS: usize = 60;

/// Fits α′ and σ′t to `profile` (any order; samples inside the core are skipped). Errors
/// when the profile cannot say anything: too few samples, a value that is not finite or is
/// negative, no light at all.
pub fn fit_dipole(
    profile: &[ProfileSample],
    options: &DipoleFitOptions,
) -> Result<DipoleFit, ProcessingError> {
    let ill = |why: String| ProcessingError::IllPosed {
        what: "dipole fit",
        why,
    };
    let [lo, hi] = options.sigma_range;
    if !(lo > 0.0 && hi > lo && hi.is_finite() && options.core_mm >= 0.0) {
        return Err(ill(format!(
            "the search interval [{lo}, {hi}] mm⁻¹ and the core {} mm must be positive and ordered",
            options.core_mm
        )));
    }
    if !(options.line_width_mm >= 0.0 && options.line_width_mm.is_finite()) {
        return Err(ill(format!(
            "the line width {} mm must be 0 or more",
            options.line_width_mm
        )));
    }
    if !(1.0..=3.0).contains(&options.eta) {
        return Err(ill(format!(
            "η {} is outside 1–3, where the diffuse Fresnel fit the dipole uses holds",
            options.eta
        )));
    }
    if !(options.noise_floor > 0.0
        && options.noise_floor.is_finite()
        && options.relative_noise >= 0.0
        && options.relative_noise.is_finite())
    {
        return Err(ill(format!(
            "the noise model (relative {}, floor {}) needs a floor above 0 and a relative part of 0 or more",
            options.relative_noise, options.noise_floor
        )));
    }
    if let Some(bad) = profile
        .iter()
        .find(|s| !(s.x_mm.is_finite() && s.value.is_finite() && s.value >= 0.0))
    {
        return Err(ill(format!(
            "a sample at {} mm is {}: values must be finite and ≥ 0 (saturated or missing pixels left out)",
            bad.x_mm, bad.value
        )));
    }
    let core_mm = options.core_mm.max(CORE_WIDTHS * options.line_width_mm);
    let width = options.line_width_mm;
    let mut used: Vec<ProfileSample> = profile
        .iter()
        .copied()
        .filter(|s| s.x_mm.abs() > core_mm)
        .collect();
    used.sort_by(|a, b| a.x_mm.total_cmp(&b.x_mm));
    if used.len() < MIN_SAMPLES {
        return Err(ill(format!(
            "{} samples outside the core of ±{core_mm} mm; at least {MIN_SAMPLES} are needed",
            used.len(),
        )));
    }
    let data_sum = window_sum(&used, |s| s.value);
    if data_sum <= 0.0 {
        return Err(ill(
            "no light beside the line: the sample absorbs everything, or the laser was off".into(),
        ));
    }
    // Weights from the model's value, not the data's (which would favour low noisy samples).
    let variance =
        |model: f64| (options.relative_noise * model).powi(2) + options.noise_floor.powi(2);
    let medium = |alpha_p: f64, sigma_t_p: f64| DipoleMedium {
        alpha_p,
        sigma_t_p,
        eta: options.eta,
    };
    // For a σ′t, the α′ that puts as much light on the samples as the data (monotone in α′:
    // false position with the Illinois step); the search is then over σ′t alone.
    let alpha_for = |sigma: f64| {
        let light = |a: f64| {
            let m = medium(a, sigma);
            window_sum(&used, |s| blurred_profile(&m, s.x_mm, width)) - data_sum
        };
        let (mut a0, mut a1) = (1e-9, 1.0);
        let (mut f0, mut f1) = (light(a0), light(a1));
        if f1 <= 0.0 {
            return 1.0;
        }
        if f0 >= 0.0 {
            return a0;
        }
        let mut side = 0;
        for _ in 0..ALPHA_STEPS {
            let a = (a0 * f1 - a1 * f0) / (f1 - f0);
            let f = light(a);
            if f.abs() <= 1e-12 * data_sum || (a1 - a0) < 1e-13 {
                return a;
            }
            if f < 0.0 {
                (a0, f0) = (a, f);
                if side == -1 {
                    f1 *= 0.5;
                }
                side = -1;
            } else {
                (a1, f1) = (a, f);
                if side == 1 {
                    f0 *= 0.5;
                }
                side = 1;
            }
        }
        0.5 * (a0 + a1)
    };
    let misfit = |sigma: f64| {
        let m = medium(alpha_for(sigma), sigma);
        used.iter()
            .map(|s| {
                let model = blurred_profile(&m, s.x_mm, width);
                (s.value - model).powi(2) / variance(model)
            })
            .sum::<f64>()
    };
    // σ′t: the log-spaced grid, then golden section about its best point.
    let sigma = log_search(&misfit, lo, hi, COARSE, FINE);
    let alpha = alpha_for(sigma);
    let mut flags = Vec::new();
    if sigma < lo * 1.01 || sigma > hi / 1.01 {
        flags.push(DipoleFlag::SigmaAtSearchEnd);
    }
    if alpha >= 1.0 {
        flags.push(DipoleFlag::AlbedoAboveOne);
    }
    if alpha < 1e-3 {
        flags.push(DipoleFlag::AlbedoNearZero);
    }
    let m = medium(alpha, sigma);
    let residual: f64 = used
        .iter()
        .map(|s| (s.value - blurred_profile(&m, s.x_mm, width)).powi(2))
        .sum();
    let scale: f64 = used.iter().map(|s| s.value * s.value).sum();
    Ok(DipoleFit {
        alpha_p: alpha,
        sigma_t_p: sigma,
        reflectance: m.total_reflectance(),
        relative_rms: (residual / scale.max(f64::MIN_POSITIVE)).sqrt(),
        samples: used.len(),
        flags,
    })
}

/// The trapezoid sum of `f` over the sorted samples, skipping the gap across the core (the
/// two sides are summed apart).
fn window_sum(samples: &[ProfileSample], f: impl Fn(&ProfileSample) -> f64) -> f64 {
    samples
        .windows(2)
        .filter(|w| w[0].x_mm.signum() == w[1].x_mm.signum())
        .map(|w| 0.5 * (f(&w[0]) + f(&w[1])) * (w[1].x_mm - w[0].x_mm))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The falloff of `medium` sampled every 0.25 mm over ±`half_mm`, with relative noise
    /// `noise` (deterministic).
    fn profile(medium: DipoleMedium, half_mm: f64, noise: f64) -> Vec<ProfileSample> {
        let n = (half_mm / 0.25) as i64;
        (-n..=n)
            .map(|i| {
                let x = 0.25 * i as f64;
                let wobble = noise * ((i as f64 * 12.9898).sin() * 43_758.547).fract();
                ProfileSample {
                    x_mm: x,
                    value: medium.line_profile(x) * (1.0 + 2.0 * wobble - noise),
                }
            })
            .collect()
    }

    fn medium(alpha_p: f64, sigma_t_p: f64) -> DipoleMedium {
        DipoleMedium {
            alpha_p,
            sigma_t_p,
            eta: 1.3,
        }
    }

    #[test]
    fn known_media_are_recovered_within_a_tenth_of_a_percent_without_noise() {
        // The seed's Monte Carlo material (α′ 0.425 / 0.99) and a range of extinctions.
        for (alpha_p, sigma_t_p) in [(0.425, 1.0), (0.99, 1.0), (0.9, 0.3), (0.7, 3.0)] {
            let fit = fit_dipole(
                &profile(medium(alpha_p, sigma_t_p), 20.0, 0.0),
                &DipoleFitOptions::default(),
            )
            .expect("a fit");
            assert!(
                (fit.alpha_p / alpha_p - 1.0).abs() < 1e-3,
                "{alpha_p}: {fit:?}"
            );
            assert!(
                (fit.sigma_t_p / sigma_t_p - 1.0).abs() < 1e-3,
                "{sigma_t_p}: {fit:?}"
            );
            assert!(fit.flags.is_empty(), "{fit:?}");
        }
    }

    #[test]
    fn with_one_percent_noise_within_three_percent() {
        let fit = fit_dipole(
            &profile(medium(0.8, 0.8), 20.0, 0.01),
            &DipoleFitOptions::default(),
        )
        .expect("a fit");
        assert!((fit.alpha_p / 0.8 - 1.0).abs() < 0.03, "{fit:?}");
        assert!((fit.sigma_t_p / 0.8 - 1.0).abs() < 0.03, "{fit:?}");
    }

    #[test]
    fn told_the_noise_the_fit_reads_the_tails_of_a_bright_medium() {
        // Jensen 2001's marble (blue): α′ near 1, where σ′t shows only in the tails' decay.
        let marble = medium(3.0 / 3.0071, 3.0071);
        let weighted = DipoleFitOptions {
            relative_noise: 0.01,
            noise_floor: 1e-9,
            ..DipoleFitOptions::default()
        };
        // Twelve draws of independent 1 % noise (a 64-bit LCG, uniform with σ = 1 %).
        let mut state = 3u64;
        let mut worst = [0.0f64; 2];
        for _ in 0..12 {
            let samples: Vec<ProfileSample> = profile(marble, 20.0, 0.0)
                .into_iter()
                .map(|s| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                    ProfileSample {
                        value: s.value * (1.0 + 0.01 * u * 12f64.sqrt()),
                        ..s
                    }
                })
                .collect();
            let fit = fit_dipole(&samples, &weighted).expect("a fit");
            worst[0] = worst[0].max((fit.alpha_p / marble.alpha_p - 1.0).abs());
            worst[1] = worst[1].max((fit.sigma_t_p / marble.sigma_t_p - 1.0).abs());
        }
        assert!(
            worst[0] < 0.03 && worst[1] < 0.03,
            "worst α′, σ′t errors {worst:?}"
        );
        let samples = profile(marble, 20.0, 0.0);
        for (relative_noise, noise_floor) in [(0.01, 0.0), (-0.1, 1.0), (f64::NAN, 1.0)] {
            let bad = DipoleFitOptions {
                relative_noise,
                noise_floor,
                ..DipoleFitOptions::default()
            };
            let e = fit_dipole(&samples, &bad).expect_err("a bad noise model");
            assert!(e.to_string().contains("noise model"), "{e}");
        }
    }

    #[test]
    fn the_ends_of_the_search_are_reached_and_flagged() {
        for sigma_t_p in [0.01, 10.0] {
            let fit = fit_dipole(
                &profile(medium(0.9, sigma_t_p), 40.0, 0.0),
                &DipoleFitOptions::default(),
            )
            .expect("a fit");
            assert!(
                fit.sigma_t_p.is_finite() && fit.alpha_p.is_finite(),
                "{fit:?}"
            );
            assert!(fit.flags.contains(&DipoleFlag::SigmaAtSearchEnd), "{fit:?}");
        }
    }

    #[test]
    fn albedo_near_one_and_near_zero() {
        let fit = fit_dipole(
            &profile(medium(0.9999, 1.0), 20.0, 0.0),
            &DipoleFitOptions::default(),
        )
        .expect("a fit");
        assert!((fit.alpha_p - 0.9999).abs() < 1e-4, "{fit:?}");
        assert!((fit.sigma_t_p - 1.0).abs() < 0.01, "{fit:?}");
        let fit = fit_dipole(
            &profile(medium(0.01, 1.0), 20.0, 0.0),
            &DipoleFitOptions::default(),
        )
        .expect("a fit");
        assert!((fit.alpha_p / 0.01 - 1.0).abs() < 0.01, "{fit:?}");
        assert!(fit.sigma_t_p.is_finite());
        // More light than any dipole gives: α′ pinned at 1 and said so.
        let mut bright = profile(medium(0.99, 1.0), 20.0, 0.0);
        for s in &mut bright {
            s.value *= 3.0;
        }
        let fit = fit_dipole(&bright, &DipoleFitOptions::default()).expect("a fit");
        assert!(fit.flags.contains(&DipoleFlag::AlbedoAboveOne), "{fit:?}");
    }

    #[test]
    fn a_saturated_core_is_left_out() {
        let mut p = profile(medium(0.8, 1.5), 20.0, 0.0);
        for s in p.iter_mut().filter(|s| s.x_mm.abs() <= 0.3) {
            s.value = 0.05; // clipped
        }
        let fit = fit_dipole(&p, &DipoleFitOptions::default()).expect("a fit");
        assert!((fit.alpha_p / 0.8 - 1.0).abs() < 1e-3, "{fit:?}");
        assert!((fit.sigma_t_p / 1.5 - 1.0).abs() < 1e-3, "{fit:?}");
    }

    #[test]
    fn profiles_that_say_nothing_are_refused() {
        let dark: Vec<ProfileSample> = (0..50)
            .map(|i| ProfileSample {
                x_mm: f64::from(i) * 0.2 - 5.0,
                value: 0.0,
            })
            .collect();
        let e = fit_dipole(&dark, &DipoleFitOptions::default()).unwrap_err();
        assert!(e.to_string().contains("no light beside the line"), "{e}");
        let mut nan = profile(medium(0.8, 1.0), 5.0, 0.0);
        nan[3].value = f64::NAN;
        let e = fit_dipole(&nan, &DipoleFitOptions::default()).unwrap_err();
        assert!(e.to_string().contains("finite"), "{e}");
        let glass = DipoleFitOptions {
            eta: 4.0,
            ..DipoleFitOptions::default()
        };
        let e = fit_dipole(&profile(medium(0.8, 1.0), 5.0, 0.0), &glass).unwrap_err();
        assert!(e.to_string().contains("outside 1–3"), "{e}");
        let e = fit_dipole(&nan[..4], &DipoleFitOptions::default()).unwrap_err();
        assert!(
            e.to_string().contains("finite") || e.to_string().contains("samples"),
            "{e}"
        );
    }

    #[test]
    fn a_wide_line_is_fitted_through_its_width() {
        // The falloff beside a Gaussian line of σ 0.25 mm, by a dense convolution (not the
        // quadrature the fit uses); a sharp red medium, where the blur lifts the tails most.
        let truth = medium(0.425, 1.0);
        let sigma = 0.25;
        let wide: Vec<ProfileSample> = (-60..=60)
            .map(|i| {
                let x = 0.1 * f64::from(i);
                let n = 2000;
                let h = 10.0 * sigma / f64::from(n);
                let value = (-n..=n)
                    .map(|k| {
                        let t = h * f64::from(k);
                        let g = (-0.5 * (t / sigma).powi(2)).exp()
                            / (sigma * (2.0 * std::f64::consts::PI).sqrt());
                        g * truth.line_profile(x - t) * h
                    })
                    .sum();
                ProfileSample { x_mm: x, value }
            })
            .collect();
        let told = DipoleFitOptions {
            line_width_mm: sigma,
            ..DipoleFitOptions::default()
        };
        let fit = fit_dipole(&wide, &told).expect("a fit");
        assert!((fit.alpha_p / 0.425 - 1.0).abs() < 2e-3, "{fit:?}");
        assert!((fit.sigma_t_p - 1.0).abs() < 2e-3, "{fit:?}");
        // Told nothing of the width, the same samples beyond the same core mislead the fit.
        let naive = DipoleFitOptions {
            core_mm: CORE_WIDTHS * sigma,
            ..DipoleFitOptions::default()
        };
        let off = fit_dipole(&wide, &naive).expect("a fit");
        assert!((off.alpha_p / 0.425 - 1.0).abs() > 5e-3, "{off:?}");
        let bad = DipoleFitOptions {
            line_width_mm: f64::NAN,
            ..DipoleFitOptions::default()
        };
        let e = fit_dipole(&wide, &bad).unwrap_err();
        assert!(e.to_string().contains("line width"), "{e}");
    }
}
