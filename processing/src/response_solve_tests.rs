//! Tests of the response fit on synthetic brackets with known responses.

use super::*;
use crate::response_samples::BracketImage;

/// A scene of `patches` flat 10×10 patches whose radiances are log-spaced over `decades`,
/// exposed at `times` through `response` (relative exposure → DN before noise), with
/// deterministic noise of `noise_dn` standard deviation and clipping at `max_dn`.
fn bracket(
    patches: usize,
    decades: f64,
    times: &[f64],
    response: &dyn Fn(f64) -> f64,
    noise_dn: f64,
    max_dn: f64,
) -> Bracket {
    let (pw, w, h) = (10, 10 * patches, 10);
    let radiance = |x: usize| 10f64.powf(decades * (x / pw) as f64 / (patches - 1) as f64);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = move || {
        // Sum of 4 uniforms ≈ Gaussian, σ = 1.
        let mut s = 0.0;
        for _ in 0..4 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            s += (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        }
        s * 3f64.sqrt()
    };
    let images = times
        .iter()
        .map(|&t| BracketImage {
            exposure_s: t,
            dn: (0..w * h)
                .map(|i| {
                    let z = response(radiance(i % w) * t) + noise_dn * noise();
                    z.round().clamp(0.0, max_dn) as u16
                })
                .collect(),
        })
        .collect();
    Bracket {
        width: w,
        height: h,
        images,
    }
}

/// Largest relative error of exp(g) against the true inverse response over `[lo, hi]`, after
/// removing the best constant scale (g is relative).
fn worst_relative_error(
    fit: &InverseResponse,
    truth_inv: &dyn Fn(f64) -> f64,
    lo: f64,
    hi: f64,
) -> f64 {
    let zs: Vec<f64> = (0..200)
        .map(|i| lo + (hi - lo) * i as f64 / 199.0)
        .collect();
    let offsets: Vec<f64> = zs.iter().map(|&z| truth_inv(z).ln() - fit.g(z)).collect();
    let mut sorted = offsets.clone();
    sorted.sort_by(f64::total_cmp);
    let offset = sorted[sorted.len() / 2];
    offsets
        .iter()
        .map(|o| ((o - offset).exp() - 1.0).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_strong_8_bit_gamma_is_recovered_within_1_percent() {
    let gamma = 2.2;
    let response = |x: f64| 255.0 * x.min(1.0).powf(1.0 / gamma);
    let inverse = |z: f64| (z / 255.0).powf(gamma);
    let times: Vec<f64> = (0..12).map(|j| 2f64.powi(j - 14)).collect();
    let b = bracket(24, 3.0, &times, &response, 0.6, 255.0);
    let range = DnRange::new(8.0, 250.0).unwrap();
    let fit = solve_response(&b, &ResponseParams::for_range(range)).unwrap();
    let (lo, hi) = (
        fit.response.observed.lo.max(16.0),
        fit.response.observed.hi.min(245.0),
    );
    let err = worst_relative_error(&fit.response, &inverse, lo, hi);
    assert!(
        err < 0.01,
        "worst error {:.4} over DN {lo}–{hi}, fit {fit:?}",
        err
    );
}

#[test]
fn a_12_bit_gently_curved_response_with_black_level_is_recovered_within_1_percent() {
    // The simulator's sensor: y = x(1 − c + c x), black level 2 % of full scale.
    let (max, black, c) = (4095.0, 82.0, 0.03);
    let response = |x: f64| {
        let x = x.min(1.0);
        black + (max - black) * x * (1.0 - c + c * x)
    };
    let inverse = |z: f64| {
        let y = (z - black) / (max - black);
        // Solve c x² + (1 − c) x − y = 0 for x ≥ 0.
        (-(1.0 - c) + ((1.0 - c) * (1.0 - c) + 4.0 * c * y).sqrt()) / (2.0 * c)
    };
    let times: Vec<f64> = (0..10).map(|j| 2f64.powi(j - 12)).collect();
    let b = bracket(24, 3.0, &times, &response, 3.0, max);
    let range = DnRange::new(black + 30.0, 0.98 * max).unwrap();
    let fit = solve_response(&b, &ResponseParams::for_range(range)).unwrap();
    let err = worst_relative_error(
        &fit.response,
        &inverse,
        fit.response.observed.lo.max(black + 60.0),
        fit.response.observed.hi,
    );
    assert!(
        err < 0.01,
        "worst error {err:.4}; fit {:?}",
        fit.rms_residual
    );
}

#[test]
fn saturated_and_black_pixels_do_not_disturb_the_fit() {
    let response = |x: f64| 255.0 * x.min(1.0).powf(1.0 / 2.2);
    let inverse = |z: f64| (z / 255.0).powf(2.2);
    // 6 decades: the brightest patches saturate in most exposures, the darkest stay black.
    let times: Vec<f64> = (0..10).map(|j| 2f64.powi(j - 14)).collect();
    let b = bracket(24, 6.0, &times, &response, 0.5, 255.0);
    assert!(b.images.iter().any(|i| i.dn.contains(&255)));
    assert!(b.images[0].dn.iter().any(|&z| z < 8));
    let fit = solve_response(
        &b,
        &ResponseParams::for_range(DnRange::new(8.0, 250.0).unwrap()),
    )
    .unwrap();
    assert!(fit.response.g.iter().all(|g| g.is_finite()));
    let err = worst_relative_error(&fit.response, &inverse, 20.0, 240.0);
    assert!(err < 0.02, "worst error {err:.4}");
}

#[test]
fn a_channel_that_never_saturates_is_fit_where_it_is_observed() {
    // The blue channel of a warm lamp: never above 40 % of full scale.
    let response = |x: f64| 4095.0 * 0.4 * x;
    let inverse = |z: f64| z / 4095.0 / 0.4;
    let times: Vec<f64> = (0..8).map(|j| 2f64.powi(j - 14)).collect();
    let b = bracket(24, 2.0, &times, &response, 2.0, 4095.0);
    assert!(b.images.iter().all(|i| i.dn.iter().all(|&z| z < 1300)));
    let fit = solve_response(
        &b,
        &ResponseParams::for_range(DnRange::new(40.0, 4000.0).unwrap()),
    )
    .unwrap();
    assert!(fit.response.observed.hi < 1300.0);
    let err = worst_relative_error(&fit.response, &inverse, 100.0, fit.response.observed.hi);
    assert!(err < 0.01, "worst error {err:.4}");
    assert!(fit.response.g.iter().all(|g| g.is_finite()));
}

#[test]
fn ill_posed_brackets_are_reported_not_solved() {
    let response = |x: f64| 255.0 * x.min(1.0).powf(1.0 / 2.2);
    let range = DnRange::new(8.0, 250.0).unwrap();
    // One tone only: every pixel sits on one DN per exposure, too little to tie 256 levels.
    let flat = bracket(2, 0.0, &[0.01, 0.02], &response, 0.0, 255.0);
    assert!(matches!(
        solve_response(&flat, &ResponseParams::for_range(range)),
        Err(ProcessingError::TooFewSamples { .. } | ProcessingError::NarrowCoverage { .. })
    ));
    // All black.
    let black = bracket(24, 3.0, &[1e-9, 2e-9, 4e-9], &response, 0.0, 255.0);
    assert!(solve_response(&black, &ResponseParams::for_range(range)).is_err());
    // Bad parameters.
    let b = bracket(24, 3.0, &[0.01, 0.1], &response, 0.0, 255.0);
    let mut p = ResponseParams::for_range(range);
    p.smoothness = f64::NAN;
    assert!(matches!(
        solve_response(&b, &p),
        Err(ProcessingError::BadParameter {
            name: "smoothness",
            ..
        })
    ));
    p.smoothness = 1.0;
    p.levels = 2;
    assert!(matches!(
        solve_response(&b, &p),
        Err(ProcessingError::BadParameter { name: "levels", .. })
    ));
}
