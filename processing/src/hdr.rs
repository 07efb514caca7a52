//! Merging a bracket into relative radiance through a recovered inverse response
//! (Debevec–Malik): ln E = Σ_j w(Z_j)(g(Z_j) − ln Δt_j) / Σ_j w(Z_j). A pixel no exposure saw
//! in range is not given a made-up value: it is a lower bound (saturated in every exposure)
//! or an upper bound (black in every exposure).

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::response_curve::InverseResponse;
use crate::response_samples::Bracket;

/// How exposures are weighted in the merge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MergeWeight {
    /// The trapezoid weight of the DN (see [`crate::weight`]).
    Hat,
    /// That weight times the exposure time: longer exposures collect more photons, so with shot
    /// noise their estimate of E is better; the weight still drops clipped and black values.
    HatTimesExposure,
}

/// What is known of a merged pixel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "radiance", rename_all = "snake_case")]
pub enum HdrPixel {
    /// A measured relative radiance.
    Measured(f32),
    /// Saturated in every exposure: the radiance is at least this.
    AtLeast(f32),
    /// Black in every exposure: the radiance is at most this.
    AtMost(f32),
}

impl HdrPixel {
    /// The value: the measurement or the bound.
    pub fn value(self) -> f32 {
        match self {
            HdrPixel::Measured(v) | HdrPixel::AtLeast(v) | HdrPixel::AtMost(v) => v,
        }
    }
}

/// Merges one channel of `bracket` through `response`, pixel by pixel.
pub fn merge_bracket(
    bracket: &Bracket,
    response: &InverseResponse,
    weight: MergeWeight,
) -> Result<Vec<HdrPixel>, ProcessingError> {
    bracket.check_images()?;
    let range = response.range;
    let times: Vec<(f64, f64)> = bracket
        .images
        .iter()
        .map(|i| (i.exposure_s, i.exposure_s.ln()))
        .collect();
    let (t_min, t_max) = times.iter().fold((f64::MAX, 0.0f64), |(lo, hi), &(t, _)| {
        (lo.min(t), hi.max(t))
    });
    let (g_lo, g_hi) = (response.g(range.lo), response.g(range.hi));
    let n = bracket.width * bracket.height;
    let mut out = Vec::with_capacity(n);
    for p in 0..n {
        let (mut num, mut den) = (0.0, 0.0);
        let mut all_high = true;
        for (image, &(t, ln_t)) in bracket.images.iter().zip(&times) {
            let z = f64::from(image.dn[p]);
            all_high &= range.is_high(z);
            let mut w = range.weight(z);
            if weight == MergeWeight::HatTimesExposure {
                w *= t / t_max;
            }
            num += w * (response.g(z) - ln_t);
            den += w;
        }
        let pixel = if den > 0.0 {
            HdrPixel::Measured((num / den).exp() as f32)
        } else if all_high {
            HdrPixel::AtLeast((g_hi - t_min.ln()).exp() as f32)
        } else {
            HdrPixel::AtMost((g_lo - t_max.ln()).exp() as f32)
        };
        out.push(pixel);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::response_samples::BracketImage;
    use crate::weight::DnRange;

    /// A linear 8-bit camera's exact inverse response: g(z) = ln z on knots at every level.
    fn linear_response() -> InverseResponse {
        let range = DnRange::new(5.0, 250.0).unwrap();
        let knots_dn: Vec<f64> = (0..246).map(|k| 5.0 + k as f64).collect();
        InverseResponse {
            range,
            g: knots_dn.iter().map(|z| z.ln()).collect(),
            knots_dn,
            observed: range,
        }
    }

    fn one_pixel(dns: &[u16], times: &[f64]) -> Bracket {
        Bracket {
            width: 1,
            height: 1,
            images: dns
                .iter()
                .zip(times)
                .map(|(&z, &t)| BracketImage {
                    exposure_s: t,
                    dn: vec![z],
                })
                .collect(),
        }
    }

    #[test]
    fn consistent_exposures_merge_to_the_radiance() {
        let r = linear_response();
        let b = one_pixel(&[25, 50, 100, 200], &[0.25, 0.5, 1.0, 2.0]);
        for w in [MergeWeight::Hat, MergeWeight::HatTimesExposure] {
            let px = merge_bracket(&b, &r, w).unwrap()[0];
            let HdrPixel::Measured(v) = px else {
                panic!("{px:?}")
            };
            assert!((v - 100.0).abs() < 1e-3, "{v}");
        }
    }

    #[test]
    fn saturated_everywhere_is_a_lower_bound_and_black_an_upper_bound() {
        let r = linear_response();
        let times = [0.5, 1.0, 2.0];
        let sat =
            merge_bracket(&one_pixel(&[255, 255, 255], &times), &r, MergeWeight::Hat).unwrap();
        assert!(matches!(sat[0], HdrPixel::AtLeast(v) if (v - 500.0).abs() < 1e-3));
        let dark = merge_bracket(&one_pixel(&[0, 1, 3], &times), &r, MergeWeight::Hat).unwrap();
        assert!(matches!(dark[0], HdrPixel::AtMost(v) if (v - 2.5).abs() < 1e-4));
        // One exposure in range among clipped ones is a measurement from that exposure.
        let one = merge_bracket(&one_pixel(&[0, 100, 255], &times), &r, MergeWeight::Hat).unwrap();
        assert!(matches!(one[0], HdrPixel::Measured(v) if (v - 100.0).abs() < 1e-3));
    }
}
