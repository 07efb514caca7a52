//! Debevec–Malik recovery of the inverse response g from a bracket of a static scene:
//! least squares over pixels i and exposures j of w(Z_ij)·(g(Z_ij) − ln E_i − ln Δt_j), plus
//! λ·w(z)·g''(z) at every knot, with g fixed to 0 at the middle knot.
//!
//! g is piecewise linear on `levels` knots, so 12- and 16-bit data need no 4096- or
//! 65536-unknown system. The unknown log radiances ln E_i enter only their own pixel's rows, so
//! they are eliminated from the normal equations (a Schur complement), leaving a banded
//! `levels × levels` system solved by Cholesky: the work grows with the observations, not
//! with their square.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::response_curve::{InverseResponse, locate};
use crate::response_samples::{Bracket, Sample, select_samples};
use crate::weight::DnRange;

/// The fit's settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ResponseParams {
    /// The DN range trusted (weights 0 at its ends).
    pub range: DnRange,
    /// Knots of g over the range (8-bit data: 256, one per level).
    pub levels: usize,
    /// Smoothness weight λ on the second difference of g at each knot, relative to the mean
    /// data weight per knot: 0 trusts the data alone (and leaves knots without data
    /// undetermined), large values straighten g. The default 100 was the best of 10, 30, 100
    /// and 300 on simulated colour-checker sweeps of 8 cameras (RMS error 0.3 % against the
    /// simulator's truth, `tests/integration/calibration.rs`), and keeps the noisy synthetic
    /// 8-bit and 12-bit brackets of `response_solve_tests` within 1 %.
    pub smoothness: f64,
    /// Tone bins of the sample selection (one flat pixel per bin).
    pub samples: usize,
}

impl ResponseParams {
    /// Defaults for `range`: a knot per DN up to 256 knots, 2 tone bins per knot, λ = 100.
    pub fn for_range(range: DnRange) -> ResponseParams {
        let levels = ((range.hi - range.lo).floor() as usize + 1).clamp(2, 256);
        ResponseParams {
            range,
            levels,
            smoothness: 100.0,
            samples: 2 * levels,
        }
    }
}

/// A recovered response with its quality figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResponseFit {
    /// The inverse response.
    pub response: InverseResponse,
    /// Pixels used.
    pub pixels: usize,
    /// In-range observations used.
    pub observations: usize,
    /// RMS of the data residual g(Z) − ln E − ln Δt over the observations, in ln units
    /// (0.01 ≈ 1 % exposure error).
    pub rms_residual: f64,
}

/// Recovers the inverse response of one channel from `bracket`.
pub fn solve_response(
    bracket: &Bracket,
    params: &ResponseParams,
) -> Result<ResponseFit, ProcessingError> {
    if params.levels < 3 {
        return Err(ProcessingError::BadParameter {
            name: "levels",
            value: params.levels as f64,
            why: "the response needs at least 3 knots",
        });
    }
    if !(params.smoothness.is_finite() && params.smoothness >= 0.0) {
        return Err(ProcessingError::BadParameter {
            name: "smoothness",
            value: params.smoothness,
            why: "it must be finite and not negative",
        });
    }
    let samples = select_samples(bracket, params.range, params.samples)?;
    let observations = observations(bracket, &samples, params.range);
    solve_observations(&observations, params)
}

/// One pixel's in-range observations: (DN, ln Δt).
type PixelObservations = Vec<(f64, f64)>;

/// Collects each sample's in-range observations, keeping samples seen at least twice.
fn observations(bracket: &Bracket, samples: &[Sample], range: DnRange) -> Vec<PixelObservations> {
    samples
        .iter()
        .map(|s| {
            s.dn.iter()
                .zip(&bracket.images)
                .map(|(&z, i)| (z, i.exposure_s.ln()))
                .filter(|&(z, _)| range.weight(z) > 0.0)
                .collect::<PixelObservations>()
        })
        .filter(|o| o.len() >= 2)
        .collect()
}

/// Solves the normal equations for g given each pixel's observations.
fn solve_observations(
    pixels: &[PixelObservations],
    params: &ResponseParams,
) -> Result<ResponseFit, ProcessingError> {
    let range = params.range;
    let knots = crate::response_curve::knots(range, params.levels);
    let k = knots.len();
    let constraints: usize = pixels.iter().map(|o| o.len() - 1).sum();
    if constraints < k / 2 {
        return Err(ProcessingError::TooFewSamples {
            usable: constraints,
            unknowns: k,
        });
    }
    let (mut z_lo, mut z_hi) = (f64::MAX, f64::MIN);
    for &(z, _) in pixels.iter().flatten() {
        z_lo = z_lo.min(z);
        z_hi = z_hi.max(z);
    }
    let needed = 0.25;
    if z_hi - z_lo < needed * (range.hi - range.lo) {
        return Err(ProcessingError::NarrowCoverage {
            lo: z_lo,
            hi: z_hi,
            needed_fraction: needed * 100.0,
        });
    }

    // Normal equations with every ln E_i eliminated: S g = r.
    let mut s = DMatrix::<f64>::zeros(k, k);
    let mut r = DVector::<f64>::zeros(k);
    let mut total_weight = 0.0;
    for obs in pixels {
        // Row of observation (z, ln Δt): w·(a g_k + b g_k+1 − ln E) = w·ln Δt.
        let mut cols: Vec<(usize, f64)> = Vec::with_capacity(2 * obs.len());
        let mut e_diag = 0.0; // Σ w²
        let mut e_rhs = 0.0; // Σ −w² ln Δt  (the ln E column has coefficient −w)
        for &(z, ln_t) in obs {
            let w = range.weight(z);
            let w2 = w * w;
            total_weight += w2;
            let (kk, a) = locate(&knots, z);
            let entries = [(kk, w * (1.0 - a)), (kk + 1, w * a)];
            for &(i, ci) in &entries {
                for &(j, cj) in &entries {
                    s[(i, j)] += ci * cj;
                }
                r[i] += ci * w * ln_t;
                cols.push((i, -ci * w)); // coupling g_i with ln E: ci·(−w)
            }
            e_diag += w2;
            e_rhs += -w2 * ln_t;
        }
        // Eliminate ln E: S −= u uᵀ / e_diag, r −= u e_rhs / e_diag, u = coupling column.
        let mut u: Vec<(usize, f64)> = Vec::new();
        for (i, c) in cols {
            match u.iter_mut().find(|(j, _)| *j == i) {
                Some((_, v)) => *v += c,
                None => u.push((i, c)),
            }
        }
        for &(i, ui) in &u {
            for &(j, uj) in &u {
                s[(i, j)] -= ui * uj / e_diag;
            }
            r[i] -= ui * e_rhs / e_diag;
        }
    }
    // Smoothness: λ·w(z_k)·(g_k−1 − 2g_k + g_k+1), the curvature in the knots' (warped)
    // coordinate, scaled to the mean data weight per knot.
    let lambda = params.smoothness * total_weight / k as f64;
    for (m, &knot) in knots.iter().enumerate().take(k - 1).skip(1) {
        let wz = range.weight(knot).max(0.05);
        let c = [(m - 1, 1.0), (m, -2.0), (m + 1, 1.0)];
        for &(i, ci) in &c {
            for &(j, cj) in &c {
                s[(i, j)] += lambda * wz * wz * ci * cj;
            }
        }
    }
    // g = 0 at the middle knot.
    let mid = k / 2;
    s[(mid, mid)] += total_weight.max(1.0);

    let g = s
        .cholesky()
        .ok_or_else(|| ProcessingError::IllPosed {
            what: "response fit",
            why: "its normal equations are singular; the bracket does not tie the DN levels together (add exposures that overlap in tone)".into(),
        })?
        .solve(&r);
    if g.iter().any(|v| !v.is_finite()) {
        return Err(ProcessingError::IllPosed {
            what: "response fit",
            why: "the solution is not finite".into(),
        });
    }
    let response = InverseResponse {
        range,
        knots_dn: knots,
        g: g.iter().copied().collect(),
        observed: DnRange { lo: z_lo, hi: z_hi },
    };
    if !response.rises_over_observed() {
        return Err(ProcessingError::IllPosed {
            what: "response fit",
            why: "the recovered response does not rise with DN; the scene moved or the frames are not of one static view".into(),
        });
    }

    // Residuals with each pixel's best ln E.
    let (mut sum, mut n) = (0.0, 0usize);
    for obs in pixels {
        let (mut num, mut den) = (0.0, 0.0);
        for &(z, ln_t) in obs {
            let w = range.weight(z);
            num += w * (response.g(z) - ln_t);
            den += w;
        }
        let ln_e = num / den;
        for &(z, ln_t) in obs {
            sum += (response.g(z) - ln_e - ln_t).powi(2);
            n += 1;
        }
    }
    Ok(ResponseFit {
        response,
        pixels: pixels.len(),
        observations: n,
        rms_residual: (sum / n.max(1) as f64).sqrt(),
    })
}

#[cfg(test)]
#[path = "response_solve_tests.rs"]
mod tests;
