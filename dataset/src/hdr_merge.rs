//! Debevec-style merge of a bracket of linear raw exposures into HDR radiance.
//!
//! The sensor is linear, so every unclipped sample `z` of an exposure `t` at gain `g` estimates
//! the radiance `(z − black) / (t·g)` in DN per second at gain 1. The merge is the average of
//! those estimates weighted by a hat function over the valid range: `w(z) = min(z − black,
//! max − z)` for `black < z < max`, else 0, where `max` is the sensor's largest DN
//! ([`stagehand_devices::Frame::max_value`]). Samples at or above `max` are saturated, samples
//! at or below the black level are dark; both carry no weight.
//!
//! When no exposure gives a valid sample:
//! - every exposure saturated: the shortest exposure's clipped value `(z − black)/(t·g)`, a
//!   lower bound of the radiance; counted in [`HdrImage::saturated_samples`];
//! - some saturated, the rest dark (a bracket with too wide a gap): the shortest saturated
//!   exposure's clipped value, again a lower bound (not counted: not saturated everywhere);
//! - every exposure dark: the longest exposure's value, clamped to ≥ 0.
//!
//! "Shortest" and "longest" compare the effective exposure `t·g`. The result is never NaN,
//! infinite or negative, and is monotone in the true radiance up to the quantisation of the
//! sensor (one DN of the shortest exposure, from rounding inside the weighted average).

use rayon::prelude::*;
use stagehand_devices::Frame;

use crate::error::{Result, StorageError};

/// A merged HDR image.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved RGB linear radiance in DN per second at gain 1; finite and ≥ 0.
    pub pixels: Vec<f32>,
    /// Samples saturated in every exposure of the bracket (their value is a lower bound).
    pub saturated_samples: u64,
}

/// Samples per parallel work item.
const CHUNK: usize = 1 << 14;

/// One exposure of the bracket, prepared for the merge.
struct Exposure<'a> {
    pixels: &'a [u16],
    /// 1 / (t·g).
    scale: f64,
}

/// Merges a bracket of raw frames of ONE camera into linear HDR radiance (DN per second at
/// gain 1). See the module documentation for the weighting and the clipped cases.
///
/// Errors when the bracket is empty, mixes cameras, sizes or bit depths, a frame's pixel count
/// does not match its size, an exposure or gain is not a positive finite number, or the black
/// level is not in `0..max DN`.
pub fn merge_bracket(frames: &[&Frame], black_level_dn: f64) -> Result<HdrImage> {
    let Some(first) = frames.first() else {
        return Err(StorageError::Merge("the bracket has no frames".into()));
    };
    let max = f64::from(first.max_value());
    if !(black_level_dn.is_finite() && black_level_dn >= 0.0 && black_level_dn < max) {
        return Err(StorageError::Merge(format!(
            "black level {black_level_dn} DN is outside 0..{max} for camera {}; check the rig's \
             camera black level",
            first.camera
        )));
    }
    let samples = (first.width as usize)
        .checked_mul(first.height as usize)
        .and_then(|n| n.checked_mul(3))
        .ok_or_else(|| {
            StorageError::Merge(format!(
                "frame size {}x{} overflows",
                first.width, first.height
            ))
        })?;
    let mut exposures = Vec::with_capacity(frames.len());
    for f in frames {
        if f.camera != first.camera {
            return Err(StorageError::Merge(format!(
                "frames of cameras {} and {} cannot be merged; merge each camera's bracket separately",
                first.camera, f.camera
            )));
        }
        if (f.width, f.height, f.bit_depth) != (first.width, first.height, first.bit_depth) {
            return Err(StorageError::Merge(format!(
                "camera {}: frame of trigger {} is {}x{} at {} bits, the first is {}x{} at {} bits",
                f.camera,
                f.trigger_id,
                f.width,
                f.height,
                f.bit_depth,
                first.width,
                first.height,
                first.bit_depth
            )));
        }
        if f.pixels.len() != samples {
            return Err(StorageError::Merge(format!(
                "camera {}: frame of trigger {} has {} samples, {}x{} RGB needs {samples}",
                f.camera,
                f.trigger_id,
                f.pixels.len(),
                f.width,
                f.height
            )));
        }
        let tg = f.exposure_s * f.gain;
        let usable = f.exposure_s.is_finite()
            && f.exposure_s > 0.0
            && f.gain.is_finite()
            && f.gain > 0.0
            && tg.is_normal();
        if !usable {
            return Err(StorageError::Merge(format!(
                "camera {}: frame of trigger {} has exposure {} s and gain {}; both must be \
                 positive and finite",
                f.camera, f.trigger_id, f.exposure_s, f.gain
            )));
        }
        exposures.push(Exposure {
            pixels: &f.pixels,
            scale: 1.0 / tg,
        });
    }
    // Shortest effective exposure has the largest scale; longest the smallest.
    let shortest = index_by(&exposures, |a, b| a > b);
    let longest = index_by(&exposures, |a, b| a < b);
    let black = black_level_dn;

    let merge_sample = |i: usize| -> (f32, bool) {
        let mut sum_w = 0.0;
        let mut sum_wr = 0.0;
        let mut all_saturated = true;
        // Scale and value of the shortest saturated exposure.
        let mut saturated_short: Option<(f64, f64)> = None;
        for e in &exposures {
            let z = f64::from(e.pixels[i]);
            if z >= max {
                if saturated_short.is_none_or(|(s, _)| e.scale > s) {
                    saturated_short = Some((e.scale, z));
                }
                continue;
            }
            all_saturated = false;
            if z > black {
                let w = (z - black).min(max - z);
                sum_w += w;
                sum_wr += w * (z - black) * e.scale;
            }
        }
        if sum_w > 0.0 {
            (sane(sum_wr / sum_w), false)
        } else if all_saturated {
            let e = &exposures[shortest];
            (sane((f64::from(e.pixels[i]) - black) * e.scale), true)
        } else if let Some((scale, z)) = saturated_short {
            (sane((z - black) * scale), false)
        } else {
            let e = &exposures[longest];
            (sane((f64::from(e.pixels[i]) - black) * e.scale), false)
        }
    };

    let mut pixels = vec![0.0f32; samples];
    let saturated_samples = pixels
        .par_chunks_mut(CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let base = c * CHUNK;
            let mut saturated = 0u64;
            for (k, out) in chunk.iter_mut().enumerate() {
                let (v, s) = merge_sample(base + k);
                *out = v;
                saturated += u64::from(s);
            }
            saturated
        })
        .sum();
    Ok(HdrImage {
        width: first.width,
        height: first.height,
        pixels,
        saturated_samples,
    })
}

/// Index of the exposure whose scale wins `better` against all others (first on ties).
fn index_by(exposures: &[Exposure<'_>], better: impl Fn(f64, f64) -> bool) -> usize {
    let mut best = 0;
    for (i, e) in exposures.iter().enumerate() {
        if better(e.scale, exposures[best].scale) {
            best = i;
        }
    }
    best
}

/// Clamps a radiance to a finite, non-negative f32 (NaN → 0, too large → `f32::MAX`).
fn sane(v: f64) -> f32 {
    if v.is_nan() || v <= 0.0 {
        0.0
    } else if v >= f64::from(f32::MAX) {
        f32::MAX
    } else {
        v as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame(camera: &str, w: u32, h: u32, bits: u8, t: f64, gain: f64, pixels: Vec<u16>) -> Frame {
        Frame {
            camera: camera.into(),
            trigger_id: 1,
            width: w,
            height: h,
            bit_depth: bits,
            pixels,
            exposure_s: t,
            gain,
            rig_time_s: 0.0,
            notes: serde_json::Value::Null,
            ground_truth: None,
        }
    }

    /// What a linear sensor records for radiance `l`.
    fn expose(l: f64, t: f64, gain: f64, black: f64, max: u16) -> u16 {
        (black + l * t * gain).round().clamp(0.0, f64::from(max)) as u16
    }

    #[test]
    fn exact_on_linear_data() -> Result<()> {
        let black = 64.0;
        let radiances = [2560.0, 640.0, 12800.0, 128.0, 25600.0, 0.0];
        let ts = [1.0 / 128.0, 1.0 / 64.0, 1.0 / 32.0];
        let frames: Vec<Frame> = ts
            .iter()
            .map(|&t| {
                let px = radiances
                    .iter()
                    .map(|&l| expose(l, t, 2.0, black, 4095))
                    .collect();
                frame("cam1", 2, 1, 12, t, 2.0, px)
            })
            .collect();
        let refs: Vec<&Frame> = frames.iter().collect();
        let hdr = merge_bracket(&refs, black)?;
        let want: Vec<f32> = radiances.iter().map(|&l| l as f32).collect();
        assert_eq!(hdr.pixels, want);
        assert_eq!(hdr.saturated_samples, 0);
        Ok(())
    }

    #[test]
    fn saturated_and_dark_samples() -> Result<()> {
        let black = 64.0;
        // sample 0 saturated everywhere, 1 zero everywhere, 2 at black, 3 dark in the short
        // and saturated in the long exposure
        let short = frame(
            "c",
            4,
            1,
            12,
            0.001,
            1.0,
            vec![4095, 0, 64, 10, 0, 0, 0, 0, 0, 0, 0, 0],
        );
        let long = frame(
            "c",
            4,
            1,
            12,
            0.1,
            1.0,
            vec![4095, 0, 64, 4095, 0, 0, 0, 0, 0, 0, 0, 0],
        );
        let hdr = merge_bracket(&[&long, &short], black)?;
        assert_eq!(hdr.pixels[0], ((4095.0 - 64.0) / 0.001) as f32);
        assert_eq!(hdr.pixels[1], 0.0);
        assert_eq!(hdr.pixels[2], 0.0);
        assert_eq!(hdr.pixels[3], ((4095.0 - 64.0) / 0.1) as f32);
        assert_eq!(hdr.saturated_samples, 1);
        Ok(())
    }

    #[test]
    fn mismatched_frames_are_errors() {
        let a = frame("cam1", 1, 1, 12, 0.01, 1.0, vec![1, 2, 3]);
        let b = frame("cam2", 1, 1, 12, 0.02, 1.0, vec![1, 2, 3]);
        let c = frame("cam1", 2, 1, 12, 0.02, 1.0, vec![1, 2, 3, 4, 5, 6]);
        let d = frame("cam1", 1, 1, 12, 0.0, 1.0, vec![1, 2, 3]);
        let short = frame("cam1", 1, 1, 12, 0.02, 1.0, vec![1, 2]);
        for bad in [
            vec![&a, &b],
            vec![&a, &c],
            vec![&a, &d],
            vec![&a, &short],
            vec![],
        ] {
            assert!(matches!(
                merge_bracket(&bad, 0.0),
                Err(StorageError::Merge(_))
            ));
        }
        assert!(matches!(
            merge_bracket(&[&a], 4095.0),
            Err(StorageError::Merge(_))
        ));
        assert!(matches!(
            merge_bracket(&[&a], f64::NAN),
            Err(StorageError::Merge(_))
        ));
    }

    proptest! {
        #[test]
        fn random_brackets_are_sane_and_monotone(
            bits in prop::sample::select(vec![8u8, 12, 16]),
            black_frac in 0.0f64..0.1,
            exposures in prop::collection::vec((1.0e-5f64..1.0, 1.0f64..16.0), 1..6),
            mut fractions in prop::collection::vec(0.0f64..1.0, 1..200),
        ) {
            let max = if bits >= 16 { u16::MAX } else { ((1u32 << bits) - 1) as u16 };
            let black = (black_frac * f64::from(max)).floor();
            let min_tg = exposures.iter().map(|(t, g)| t * g).fold(f64::INFINITY, f64::min);
            // radiances from dark to twice the shortest exposure's saturation, ascending
            fractions.sort_by(f64::total_cmp);
            let l_top = 2.0 * (f64::from(max) - black) / min_tg;
            let radiances: Vec<f64> = fractions.iter().map(|u| u * u * u * l_top).collect();
            let n = radiances.len();
            let frames: Vec<Frame> = exposures
                .iter()
                .map(|&(t, g)| {
                    let px = radiances
                        .iter()
                        .flat_map(|&l| [expose(l, t, g, black, max); 3])
                        .collect();
                    frame("cam", n as u32, 1, bits, t, g, px)
                })
                .collect();
            let refs: Vec<&Frame> = frames.iter().collect();
            let hdr = merge_bracket(&refs, black).map_err(|e| TestCaseError::fail(e.to_string()))?;
            for v in &hdr.pixels {
                prop_assert!(v.is_finite() && *v >= 0.0, "bad value {v}");
            }
            // where some exposure is in range, the merge is within half a DN of the truth
            for (k, &l) in radiances.iter().enumerate() {
                let valid = exposures.iter().any(|&(t, g)| {
                    let z = f64::from(expose(l, t, g, black, max));
                    z > black && z < f64::from(max)
                });
                if valid {
                    let v = f64::from(hdr.pixels[3 * k]);
                    prop_assert!(
                        (v - l).abs() <= 0.5 / min_tg + 1e-6 * l,
                        "L {l} merged to {v}"
                    );
                }
            }
            // monotone up to one DN of the shortest exposure (quantisation inside the average)
            let tolerance = 1.0 / min_tg;
            for k in 1..n {
                let (a, b) = (f64::from(hdr.pixels[3 * (k - 1)]), f64::from(hdr.pixels[3 * k]));
                prop_assert!(
                    b >= a - tolerance - 1e-6 * a,
                    "not monotone: L {} -> {a}, L {} -> {b}", radiances[k - 1], radiances[k]
                );
            }
        }
    }
}
