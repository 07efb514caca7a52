//! Merging an exposure bracket of RGB frames into calibrated radiance: each channel's DNs go
//! through its recovered inverse response (tabulated once per DN for speed), the exposures are
//! combined with the fit's weights, and the white balance turns relative exposure into
//! reflectance-equivalent units (1 = a perfect white diffuser under that lamp). Pixels that no
//! exposure saw in range are flagged as bounds, never filled with a guess.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::response_curve::InverseResponse;

/// How exposures are weighted in the merge (ln E = Σ_j w_j (g(Z_j) − ln Δt_j) / Σ_j w_j).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MergeWeight {
    /// The response fit's weight of the DN (see [`crate::weight`]).
    Hat,
    /// That weight times the exposure time: longer exposures collect more photons, so with
    /// shot noise their estimate of E is better; the weight still drops clipped and black DNs.
    HatTimesExposure,
}

/// One exposure of an RGB frame: interleaved 16-bit DNs and the exposure time.
#[derive(Debug, Clone, Copy)]
pub struct RgbExposure<'a> {
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Interleaved RGB DNs, `width × height × 3`.
    pub dn: &'a [u16],
}

/// What is known of a merged pixel channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum PixelState {
    /// Measured.
    Measured = 0,
    /// Saturated in every exposure: the value is a lower bound.
    AtLeast = 1,
    /// Black in every exposure: the value is an upper bound.
    AtMost = 2,
}

/// A merged RGB frame.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrFrame {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Interleaved RGB radiance in white-diffuser units.
    pub rgb: Vec<f32>,
    /// Interleaved RGB state of each value.
    pub state: Vec<PixelState>,
}

/// A channel's inverse response tabulated per DN: g(z) and the weight of z.
struct Table {
    /// Per DN: g(z), the weight of z, and whether z is above the usable range, side by side
    /// so one lookup brings all three.
    entries: Vec<Entry>,
}

#[derive(Clone, Copy)]
struct Entry {
    g: f32,
    w: f32,
    high: bool,
}

impl Table {
    fn new(r: &InverseResponse, max_dn: usize) -> Table {
        let entries = (0..=max_dn)
            .map(|z| {
                let z = z as f64;
                Entry {
                    g: r.g(z) as f32,
                    w: r.range.weight(z) as f32,
                    high: r.range.is_high(z),
                }
            })
            .collect();
        Table { entries }
    }
}

/// Merges `bracket` (all frames `width × height`) through one inverse response per channel,
/// dividing by the white-balance `scale` per channel.
pub fn merge_rgb_frames(
    bracket: &[RgbExposure<'_>],
    width: usize,
    height: usize,
    responses: &[InverseResponse; 3],
    scale: [f64; 3],
    weight: MergeWeight,
) -> Result<HdrFrame, ProcessingError> {
    let n = width * height * 3;
    if bracket.is_empty() {
        return Err(ProcessingError::TooFewExposures { distinct: 0 });
    }
    for (index, e) in bracket.iter().enumerate() {
        if e.dn.len() != n {
            return Err(ProcessingError::SizeMismatch {
                index,
                expected: n,
                got: e.dn.len(),
            });
        }
        if !(e.exposure_s.is_finite() && e.exposure_s > 0.0) {
            return Err(ProcessingError::BadExposure {
                index,
                time_s: e.exposure_s,
            });
        }
    }
    for (c, s) in scale.iter().enumerate() {
        if !(s.is_finite() && *s > 0.0) {
            return Err(ProcessingError::BadParameter {
                name: ["scale.r", "scale.g", "scale.b"][c],
                value: *s,
                why: "a white-balance scale must be finite and positive",
            });
        }
    }
    let max_dn = bracket
        .iter()
        .flat_map(|e| e.dn.iter())
        .copied()
        .max()
        .unwrap_or(0) as usize;
    let tables: Vec<Table> = responses.iter().map(|r| Table::new(r, max_dn)).collect();
    let t_max = bracket.iter().map(|e| e.exposure_s).fold(0.0, f64::max);
    let t_min = bracket
        .iter()
        .map(|e| e.exposure_s)
        .fold(f64::MAX, f64::min);
    let exposures: Vec<(f32, f32)> = bracket
        .iter()
        .map(|e| {
            let w = match weight {
                MergeWeight::Hat => 1.0,
                MergeWeight::HatTimesExposure => e.exposure_s / t_max,
            };
            (e.exposure_s.ln() as f32, w as f32)
        })
        .collect();
    let bounds: Vec<(f32, f32)> = responses
        .iter()
        .zip(scale)
        .map(|(r, s)| {
            (
                ((r.g(r.range.hi) - t_min.ln()).exp() / s) as f32,
                ((r.g(r.range.lo) - t_max.ln()).exp() / s) as f32,
            )
        })
        .collect();
    let mut rgb = vec![0.0f32; n];
    let mut state = vec![PixelState::Measured; n];
    let inverse_scale: [f32; 3] = scale.map(|s| (1.0 / s) as f32);
    for (p, (out, states)) in rgb
        .chunks_exact_mut(3)
        .zip(state.chunks_exact_mut(3))
        .enumerate()
    {
        for c in 0..3 {
            let i = 3 * p + c;
            let t = &tables[c].entries;
            let (mut num, mut den, mut all_high) = (0.0f32, 0.0f32, true);
            for (e, &(ln_t, we)) in bracket.iter().zip(&exposures) {
                let entry = t[e.dn[i] as usize];
                let w = entry.w * we;
                num += w * (entry.g - ln_t);
                den += w;
                all_high &= entry.high;
            }
            if den > 0.0 {
                out[c] = (num / den).exp() * inverse_scale[c];
            } else if all_high {
                out[c] = bounds[c].0;
                states[c] = PixelState::AtLeast;
            } else {
                out[c] = bounds[c].1;
                states[c] = PixelState::AtMost;
            }
        }
    }
    Ok(HdrFrame {
        width,
        height,
        rgb,
        state,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::weight::DnRange;

    fn gamma_response() -> InverseResponse {
        let range = DnRange::new(4.0, 250.0).unwrap();
        let knots_dn: Vec<f64> = (4..=250).map(f64::from).collect();
        InverseResponse {
            range,
            g: knots_dn.iter().map(|z| 2.2 * (z / 255.0f64).ln()).collect(),
            knots_dn,
            observed: range,
        }
    }

    #[test]
    fn merges_through_the_response_and_the_white_balance() {
        let r = gamma_response();
        let responses = [r.clone(), r.clone(), r];
        // One pixel of relative exposure-rate (0.5, 0.2, 0.05) under a lamp with scales
        // (1, 0.5, 0.25): reflectance-equivalent (0.5, 0.4, 0.2).
        let rate = [0.5, 0.2, 0.05];
        let frames: Vec<(f64, Vec<u16>)> = [0.25, 1.0, 4.0]
            .iter()
            .map(|&t| {
                let dn = rate
                    .iter()
                    .map(|&e: &f64| (255.0 * (e * t).min(1.0).powf(1.0 / 2.2)).round() as u16)
                    .collect();
                (t, dn)
            })
            .collect();
        let bracket: Vec<RgbExposure> = frames
            .iter()
            .map(|(t, dn)| RgbExposure { exposure_s: *t, dn })
            .collect();
        let out = merge_rgb_frames(
            &bracket,
            1,
            1,
            &responses,
            [1.0, 0.5, 0.25],
            MergeWeight::Hat,
        )
        .unwrap();
        for (c, want) in [0.5, 0.4, 0.2].iter().enumerate() {
            assert_eq!(out.state[c], PixelState::Measured);
            assert!(
                (f64::from(out.rgb[c]) / want - 1.0).abs() < 0.02,
                "{c}: {}",
                out.rgb[c]
            );
        }
    }

    #[test]
    fn clipped_pixels_are_bounds_and_bad_scales_are_refused() {
        let r = gamma_response();
        let responses = [r.clone(), r.clone(), r];
        let sat = [255u16, 255, 0];
        let bracket = [
            RgbExposure {
                exposure_s: 1.0,
                dn: &sat,
            },
            RgbExposure {
                exposure_s: 2.0,
                dn: &sat,
            },
        ];
        let out = merge_rgb_frames(&bracket, 1, 1, &responses, [1.0; 3], MergeWeight::Hat).unwrap();
        assert_eq!(
            out.state,
            vec![PixelState::AtLeast, PixelState::AtLeast, PixelState::AtMost]
        );
        assert!(out.rgb.iter().all(|v| v.is_finite() && *v > 0.0));
        assert!(
            merge_rgb_frames(
                &bracket,
                1,
                1,
                &responses,
                [1.0, 0.0, 1.0],
                MergeWeight::Hat
            )
            .is_err()
        );
        assert!(merge_rgb_frames(&bracket, 2, 1, &responses, [1.0; 3], MergeWeight::Hat).is_err());
    }
}
