//! The reflectometer's two light sources calibrated on a reference sample of known diffuse
//! albedo and transmittance (an opal diffuser; Gardner et al. 2003 calibrate on a diffuse
//! reference the same way): the tube's intensity per millimetre in each channel, in the
//! frames' radiance units, from a sweep over the reference, and the backlight panel's radiance
//! from one backlight frame through it. Ward maps and transparency maps made with them are in
//! absolute albedo and transmittance.
//!
//! The tube: each pixel of the reference square sees L = ρ/π·D(x) per unit intensity at each
//! stop x ([`Tube::diffuse`], closed form), so its own least-squares intensity is
//! Σ L·m / Σ m² with m = ρ/π·D; the calibration is the median over pixels (robust to dust and
//! to pixels at the square's edge), and the spread between pixels is reported. The panel: the
//! median over the square of L_backlight / T.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::ward_map::{SweepFrame, pixel_view};
use crate::ward_tube::Tube;

/// The reference sample: what is known of it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferenceSample {
    /// Diffuse albedo per channel, (0, 1].
    pub albedo: [f64; 3],
    /// Fraction of the backlight it passes per channel, (0, 1].
    pub transmittance: [f64; 3],
    /// Side of the square of the sample plane it covers, centred on the origin, mm.
    pub square_mm: f64,
}

/// One camera's calibration of the two sources.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceCalibration {
    /// Camera id.
    pub camera: String,
    /// The tube's intensity per millimetre per channel, radiance units.
    pub tube_rgb: [f64; 3],
    /// Relative spread of the per-pixel intensities (half the 10–90 % range over the median),
    /// per channel: how uniform the reference and the fit are.
    pub tube_spread: [f64; 3],
    /// Pixels of the square that measured the tube.
    pub tube_pixels: usize,
    /// The backlight panel's radiance per channel, radiance units; `None` without a
    /// backlight frame.
    pub panel_rgb: Option<[f64; 3]>,
    /// Pixels of the square that measured the panel.
    pub panel_pixels: usize,
}

/// Pixels of a square that saw the tube with less than this fraction of their best stop's
/// Lambert response are not used for the tube (their samples are mostly noise).
const MIN_RESPONSE: f64 = 0.05;

fn ill(why: String) -> ProcessingError {
    ProcessingError::IllPosed {
        what: "reflectometer calibration",
        why,
    }
}

/// Checks the reference's numbers.
fn check(reference: &ReferenceSample) -> Result<(), ProcessingError> {
    let fraction = |v: &[f64; 3]| v.iter().all(|x| x.is_finite() && *x > 0.0 && *x <= 1.0);
    if !fraction(&reference.albedo) || !fraction(&reference.transmittance) {
        return Err(ill(format!(
            "the reference's albedo {:?} and transmittance {:?} must be in (0, 1] per channel",
            reference.albedo, reference.transmittance
        )));
    }
    if !(reference.square_mm.is_finite() && reference.square_mm > 0.0) {
        return Err(ill(format!(
            "the reference's side {} mm must be above 0",
            reference.square_mm
        )));
    }
    Ok(())
}

/// The pixels of `camera` (`width × height`) whose ray meets the reference's square.
fn square_pixels(
    camera: &CameraGeometry,
    (width, height): (usize, usize),
    square_mm: f64,
) -> Vec<(usize, crate::ward_tube::ViewPoint)> {
    let half = 0.5 * square_mm;
    (0..width * height)
        .filter_map(|i| {
            let view = pixel_view(camera, (i % width, i / width))?;
            (view.p.x.abs() <= half && view.p.y.abs() <= half).then_some((i, view))
        })
        .collect()
}

/// The 10th, 50th and 90th percentiles of `v` (sorted in place; not empty).
fn percentiles(v: &mut [f64]) -> [f64; 3] {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    [at(0.1), at(0.5), at(0.9)]
}

/// Calibrates camera `id`'s view of the tube from `sweep` (the reference lit by the tube at
/// each stop) and of the panel from `backlight` (its radiance, RGB interleaved, and clipped
/// pixels), on the reference's square. Errors when no pixel measured a source.
pub fn calibrate_sources(
    id: &str,
    tube: &Tube,
    camera: &CameraGeometry,
    size: (usize, usize),
    sweep: &[SweepFrame<'_>],
    backlight: Option<(&[f32], Option<&[bool]>)>,
    reference: &ReferenceSample,
) -> Result<SourceCalibration, ProcessingError> {
    check(reference)?;
    let n = size.0 * size.1;
    if let Some(k) = sweep.iter().position(|f| {
        f.rgb.len() != n * 3 || f.clipped.is_some_and(|c| c.len() != n) || !f.tube_x_mm.is_finite()
    }) {
        return Err(ill(format!(
            "camera `{id}`: sweep frame {k} is not a {}×{} RGB image at a known tube position",
            size.0, size.1
        )));
    }
    let pixels = square_pixels(camera, size, reference.square_mm);
    if pixels.is_empty() {
        return Err(ill(format!(
            "camera `{id}` sees none of the reference's {} mm square; check the camera geometry",
            reference.square_mm
        )));
    }
    // Each pixel's own intensity per channel, where it saw the tube well enough.
    let per_pixel: Vec<[f64; 3]> = pixels
        .par_iter()
        .filter_map(|(i, view)| {
            let d: Vec<f64> = sweep
                .iter()
                .map(|f| tube.diffuse(view, f.tube_x_mm))
                .collect();
            let best = d.iter().copied().fold(0.0, f64::max);
            let mut k = [0.0; 3];
            for (c, kc) in k.iter_mut().enumerate() {
                let (mut lm, mut mm) = (0.0, 0.0);
                for (f, d) in sweep.iter().zip(&d) {
                    let value = f64::from(f.rgb[i * 3 + c]);
                    if *d < MIN_RESPONSE * best
                        || tube.hides(view, f.tube_x_mm)
                        || f.clipped.is_some_and(|m| m[*i])
                        || !value.is_finite()
                    {
                        continue;
                    }
                    let m = reference.albedo[c] / std::f64::consts::PI * d;
                    lm += value * m;
                    mm += m * m;
                }
                if mm <= 0.0 {
                    return None;
                }
                *kc = lm / mm;
            }
            k.iter().all(|v| *v > 0.0).then_some(k)
        })
        .collect();
    if per_pixel.is_empty() {
        return Err(ill(format!(
            "camera `{id}`: no pixel of the reference measured the tube (every sample clipped, dark or missing); lower the exposure or check the tube"
        )));
    }
    let mut tube_rgb = [0.0; 3];
    let mut tube_spread = [0.0; 3];
    for c in 0..3 {
        let mut v: Vec<f64> = per_pixel.iter().map(|k| k[c]).collect();
        let [p10, p50, p90] = percentiles(&mut v);
        tube_rgb[c] = p50;
        tube_spread[c] = 0.5 * (p90 - p10) / p50;
    }
    let (panel_rgb, panel_pixels) = match backlight {
        None => (None, 0),
        Some((rgb, clipped)) => {
            if rgb.len() != n * 3 || clipped.is_some_and(|c| c.len() != n) {
                return Err(ill(format!(
                    "camera `{id}`: the backlight frame is not a {}×{} RGB image",
                    size.0, size.1
                )));
            }
            let seen: Vec<usize> = pixels
                .iter()
                .map(|(i, _)| *i)
                .filter(|i| !clipped.is_some_and(|m| m[*i]))
                .collect();
            if seen.is_empty() {
                return Err(ill(format!(
                    "camera `{id}`: every pixel of the reference clipped in the backlight frame; lower its exposure"
                )));
            }
            let mut panel = [0.0; 3];
            for (c, p) in panel.iter_mut().enumerate() {
                let mut v: Vec<f64> = seen
                    .iter()
                    .map(|i| f64::from(rgb[i * 3 + c]) / reference.transmittance[c])
                    .filter(|v| v.is_finite())
                    .collect();
                if v.is_empty() {
                    return Err(ill(format!(
                        "camera `{id}`: the backlight frame holds no finite value on the reference"
                    )));
                }
                *p = percentiles(&mut v)[1];
            }
            if panel.iter().any(|p| *p <= 0.0) {
                return Err(ill(format!(
                    "camera `{id}`: the backlight frame is black on the reference ({panel:?}); is the backlight on?"
                )));
            }
            (Some(panel), seen.len())
        }
    };
    Ok(SourceCalibration {
        camera: id.to_string(),
        tube_rgb,
        tube_spread,
        tube_pixels: per_pixel.len(),
        panel_rgb,
        panel_pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ward_fit::tests::TUBE;
    use crate::ward_map::tests::camera;

    /// A Lambert reference of `albedo` under a tube of `intensity`, at 41 stops over ±120 mm,
    /// with the pixels whose radiance exceeds `clip` clipped; off the 60 mm square the
    /// background is a brighter white (it must not count).
    fn sweep(albedo: f64, intensity: [f64; 3], clip: f64) -> Vec<(f64, Vec<f32>, Vec<bool>)> {
        let cam = camera();
        (0..41)
            .map(|k| {
                let x = -120.0 + 6.0 * k as f64;
                let mut rgb = Vec::new();
                let mut clipped = Vec::new();
                for i in 0..32 * 24 {
                    let view = pixel_view(&cam, (i % 32, i / 32)).expect("seen");
                    let a = if view.p.x.abs() <= 30.0 && view.p.y.abs() <= 30.0 {
                        albedo
                    } else {
                        0.95
                    };
                    let l: Vec<f64> = intensity
                        .iter()
                        .map(|s| s * a / std::f64::consts::PI * TUBE.diffuse(&view, x))
                        .collect();
                    clipped.push(l.iter().any(|v| *v > clip));
                    rgb.extend(l.iter().map(|v| v.min(clip) as f32));
                }
                (x, rgb, clipped)
            })
            .collect()
    }

    fn frames(s: &[(f64, Vec<f32>, Vec<bool>)]) -> Vec<SweepFrame<'_>> {
        s.iter()
            .map(|(x, rgb, clipped)| SweepFrame {
                tube_x_mm: *x,
                rgb,
                clipped: Some(clipped),
            })
            .collect()
    }

    const REFERENCE: ReferenceSample = ReferenceSample {
        albedo: [0.8; 3],
        transmittance: [0.5; 3],
        square_mm: 60.0,
    };

    #[test]
    fn the_tube_and_panel_come_back_from_a_reference_with_clipped_stops() {
        let intensity = [20.0, 30.0, 10.0];
        // The brightest stops clip in green (under the tube D ≈ π/2h, so the peak radiance
        // is about 0.8/π·30·0.026 ≈ 0.2).
        let s = sweep(0.8, intensity, 0.15);
        assert!(
            s.iter().any(|(_, _, c)| c.iter().any(|c| *c)),
            "some stops clip"
        );
        let backlight: Vec<f32> = (0..32 * 24 * 3)
            .map(|i| [0.3f32, 0.2, 0.1][i % 3] * 0.5)
            .collect();
        let cal = calibrate_sources(
            "cam1",
            &TUBE,
            &camera(),
            (32, 24),
            &frames(&s),
            Some((&backlight, None)),
            &REFERENCE,
        )
        .expect("calibrates");
        for ((got, want), spread) in cal.tube_rgb.iter().zip(intensity).zip(cal.tube_spread) {
            assert!((got / want - 1.0).abs() < 1e-5, "{cal:?}");
            assert!(spread < 1e-5, "{cal:?}");
        }
        let panel = cal.panel_rgb.expect("a panel");
        for (c, want) in [0.3, 0.2, 0.1].iter().enumerate() {
            assert!((panel[c] / want - 1.0).abs() < 1e-6, "{panel:?}");
        }
        assert!(cal.tube_pixels > 100 && cal.panel_pixels >= cal.tube_pixels);
    }

    #[test]
    fn a_reference_never_measured_is_refused_with_what_to_do() {
        let s = sweep(0.8, [20.0; 3], 0.0);
        let e = calibrate_sources(
            "cam1",
            &TUBE,
            &camera(),
            (32, 24),
            &frames(&s),
            None,
            &REFERENCE,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("cam1") && e.contains("lower the exposure"),
            "{e}"
        );
        let bad = ReferenceSample {
            albedo: [0.0, 0.8, 0.8],
            ..REFERENCE
        };
        let e = calibrate_sources("cam1", &TUBE, &camera(), (32, 24), &frames(&s), None, &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("albedo"), "{e}");
        let short = [SweepFrame {
            tube_x_mm: 0.0,
            rgb: &[0.5; 30],
            clipped: None,
        }];
        let e = calibrate_sources("cam1", &TUBE, &camera(), (32, 24), &short, None, &REFERENCE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("sweep frame 0 is not a 32×24"), "{e}");
    }
}
