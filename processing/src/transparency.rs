//! The sample's transparency map from the reflectometer's backlight frame (seed 004 §2.4,
//! Fig. 3.7(d)): the fraction of the panel's light that reaches the camera through the
//! sample, per pixel and channel, T = L / L_panel, with L_panel the panel's radiance seen
//! without a sample (its calibration). Clipped pixels and values above 1 (light the sample
//! reflects toward the camera, or a panel calibration too low) are flagged, never hidden.

use crate::error::ProcessingError;

/// Flag bit: the pixel clipped in the backlight frame (T is a lower bound).
pub const CLIPPED: u8 = 1;
/// Flag bit: T came out above 1 (clamped to 1), beyond f32 rounding.
pub const ABOVE_ONE: u8 = 2;
/// How far above 1 a T may be from f32 rounding alone.
const ROUNDING: f64 = 1e-6;

/// A transparency map, RGB interleaved, row-major, with a flag mask per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct TransparencyMap {
    /// Transmittance per channel, in [0, 1].
    pub rgb: Vec<f32>,
    /// [`CLIPPED`] and [`ABOVE_ONE`] bits.
    pub flags: Vec<u8>,
}

impl TransparencyMap {
    /// Pixels with `bit` set.
    pub fn count(&self, bit: u8) -> usize {
        self.flags.iter().filter(|f| **f & bit != 0).count()
    }
}

/// T from a backlight frame's linear radiance `rgb` (interleaved) and the panel's radiance
/// per channel; `clipped` marks pixels clipped in the frame. Errors on a panel radiance that
/// is not above 0, a mask of the wrong size, or a value that is not finite or is negative.
pub fn transparency(
    rgb: &[f32],
    clipped: Option<&[bool]>,
    panel_rgb: [f64; 3],
) -> Result<TransparencyMap, ProcessingError> {
    let ill = |why: String| ProcessingError::IllPosed {
        what: "transparency map",
        why,
    };
    if panel_rgb.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(ill(format!(
            "the backlight panel's radiance {panel_rgb:?} must be above 0 in every channel; calibrate it on a frame without the sample"
        )));
    }
    let n = rgb.len() / 3;
    if !rgb.len().is_multiple_of(3) || clipped.is_some_and(|c| c.len() != n) {
        return Err(ill(format!(
            "{} values and a mask of {} pixels are not one RGB image",
            rgb.len(),
            clipped.map_or(n, <[bool]>::len)
        )));
    }
    if let Some(i) = rgb.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(ill(format!(
            "pixel {} channel {} of the backlight frame is {}; check the frame and its response calibration",
            i / 3,
            i % 3,
            rgb[i]
        )));
    }
    let mut map = TransparencyMap {
        rgb: Vec::with_capacity(rgb.len()),
        flags: vec![0; n],
    };
    for (i, px) in rgb.chunks_exact(3).enumerate() {
        if clipped.is_some_and(|c| c[i]) {
            map.flags[i] |= CLIPPED;
        }
        for (v, panel) in px.iter().zip(panel_rgb) {
            let t = f64::from(*v) / panel;
            if t > 1.0 + ROUNDING {
                map.flags[i] |= ABOVE_ONE;
            }
            map.rgb.push(t.min(1.0) as f32);
        }
    }
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transmittance_is_the_fraction_of_the_panel_and_odd_pixels_are_flagged() {
        let panel = [0.3, 0.32, 0.31];
        // A leaf pixel, an opaque one, one brighter than the panel, one clipped.
        let rgb = [
            0.15, 0.032, 0.0, 0.0, 0.0, 0.0, 0.33, 0.32, 0.31, 0.3, 0.32, 0.31,
        ];
        let clipped = [false, false, false, true];
        let map = transparency(&rgb, Some(&clipped), panel).expect("a map");
        assert!((map.rgb[0] - 0.5).abs() < 1e-6 && (map.rgb[1] - 0.1).abs() < 1e-6);
        assert_eq!(&map.rgb[3..6], &[0.0; 3]);
        assert_eq!(map.rgb[6], 1.0);
        assert_eq!(map.flags, vec![0, 0, ABOVE_ONE, CLIPPED]);
        assert_eq!((map.count(ABOVE_ONE), map.count(CLIPPED)), (1, 1));
        for bad_panel in [[0.0, 1.0, 1.0], [f64::NAN, 1.0, 1.0]] {
            let e = transparency(&rgb, None, bad_panel).expect_err("no panel");
            assert!(e.to_string().contains("calibrate it"), "{e}");
        }
        let e = transparency(&[0.1, f32::NAN, 0.1], None, panel).expect_err("NaN");
        assert!(e.to_string().contains("pixel 0 channel 1"), "{e}");
        let e = transparency(&rgb, Some(&clipped[..2]), panel).expect_err("mask");
        assert!(e.to_string().contains("not one RGB image"), "{e}");
    }
}
