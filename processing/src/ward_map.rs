//! A reflectometer sweep's Ward maps over one camera's pixels (Gardner et al. 2003; seed 004
//! §2.4): each pixel's ray meets the flat sample (z = 0), and its samples over the cart stops,
//! in radiance over the tube's calibrated intensity per millimetre, are fitted by
//! [`fit_ward`] on every core. Every pixel gets numbers and a flag mask; nothing is left NaN.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::ray_plane::pixel_ray;
use crate::ward_fit::{
    WardFit, WardFitOptions, WardFlag, WardSample, combine_turned_scans, fit_ward,
};
use crate::ward_tube::{Tube, ViewPoint};

/// Flag bit of a pixel whose ray misses the sample plane (or cannot be undistorted).
pub const UNSEEN: u16 = 1 << 14;
/// Flag bit of a pixel whose fit was refused (too few unclipped samples; every sample is
/// finite by then); its numbers are 0.
pub const REFUSED: u16 = 1 << 15;

/// Flag bit of a pixel whose point of the sample the turned scan did not see (its numbers are
/// the first scan's alone, and anisotropy was not tested).
pub const NOT_TURNED: u16 = 1 << 13;

/// Every [`WardFlag`], in bit order.
const WARD_FLAGS: [WardFlag; 8] = [
    WardFlag::Black,
    WardFlag::NoSpecular,
    WardFlag::SpecularPeakOutsideSweep,
    WardFlag::AlphaBelowStopSpacing,
    WardFlag::AlphaAtSearchEnd,
    WardFlag::Saturated,
    WardFlag::PoorFit,
    WardFlag::Anisotropic,
];

impl WardFlag {
    /// The flags set in `mask`.
    pub fn from_mask(mask: u16) -> Vec<WardFlag> {
        WARD_FLAGS
            .into_iter()
            .filter(|f| mask & f.bit() != 0)
            .collect()
    }

    /// This flag's bit in a [`WardMaps`] flag mask.
    pub fn bit(self) -> u16 {
        1 << match self {
            WardFlag::Black => 0,
            WardFlag::NoSpecular => 1,
            WardFlag::SpecularPeakOutsideSweep => 2,
            WardFlag::AlphaBelowStopSpacing => 3,
            WardFlag::AlphaAtSearchEnd => 4,
            WardFlag::Saturated => 5,
            WardFlag::PoorFit => 6,
            WardFlag::Anisotropic => 7,
        }
    }
}

/// One frame of the sweep: where the tube was and the camera's linear radiance there.
#[derive(Debug, Clone, Copy)]
pub struct SweepFrame<'a> {
    /// The tube's x (cart position less half the travel), mm.
    pub tube_x_mm: f64,
    /// Radiance, RGB interleaved, row-major, `width × height × 3`.
    pub rgb: &'a [f32],
    /// Pixels clipped in this frame (any channel), `width × height`; `None`: none.
    pub clipped: Option<&'a [bool]>,
}

/// Per-pixel Ward parameters of one camera, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct WardMaps {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Diffuse albedo, RGB interleaved.
    pub rho_d: Vec<f32>,
    /// Specular albedo.
    pub rho_s: Vec<f32>,
    /// Roughness α.
    pub alpha: Vec<f32>,
    /// Relative RMS residual of each fit.
    pub relative_rms: Vec<f32>,
    /// [`WardFlag::bit`]s, [`UNSEEN`] and [`REFUSED`].
    pub flags: Vec<u16>,
}

impl WardMaps {
    /// Pixels with `bit` set.
    pub fn count(&self, bit: u16) -> usize {
        self.flags.iter().filter(|f| **f & bit != 0).count()
    }

    /// Pixel `i`'s fit.
    fn fit(&self, i: usize) -> WardFit {
        WardFit {
            rho_d: [0, 1, 2].map(|c| f64::from(self.rho_d[i * 3 + c])),
            rho_s: f64::from(self.rho_s[i]),
            alpha: f64::from(self.alpha[i]),
            relative_rms: f64::from(self.relative_rms[i]),
            samples: 0,
            flags: WardFlag::from_mask(self.flags[i]),
        }
    }

    /// Sets pixel `i` to `fit`, keeping its bits outside the Ward flags.
    fn set(&mut self, i: usize, fit: &WardFit) {
        for c in 0..3 {
            self.rho_d[i * 3 + c] = fit.rho_d[c] as f32;
        }
        self.rho_s[i] = fit.rho_s as f32;
        self.alpha[i] = fit.alpha as f32;
        self.relative_rms[i] = fit.relative_rms as f32;
        let others = self.flags[i] & !WARD_FLAGS.iter().fold(0, |m, f| m | f.bit());
        self.flags[i] = others | fit.flags.iter().fold(0, |m, f| m | f.bit());
    }
}

/// The maps of a scan and of a second scan of the same camera with the sample turned by
/// `turn_deg` about its normal (z through the origin) since, combined per point of the sample
/// ([`combine_turned_scans`]: means, [`WardFlag::Anisotropic`] where the two α differ by more
/// than `tolerance`), on the first scan's pixels. A pixel finds its point in the turned scan
/// by projecting the point, turned, into the camera (nearest pixel); where that pixel saw no
/// fit, it keeps the first scan's and is flagged [`NOT_TURNED`].
pub fn combine_turned_maps(
    first: &WardMaps,
    turned: &WardMaps,
    camera: &CameraGeometry,
    turn_deg: f64,
    tolerance: f64,
) -> WardMaps {
    let (s, c) = turn_deg.to_radians().sin_cos();
    let mut out = first.clone();
    let (w, h) = (first.width, first.height);
    for i in 0..w * h {
        if first.flags[i] & (UNSEEN | REFUSED) != 0 {
            continue;
        }
        let j = pixel_view(camera, (i % w, i / w)).and_then(|v| {
            let p = Vector3::new(c * v.p.x - s * v.p.y, s * v.p.x + c * v.p.y, v.p.z);
            let px = camera.model.project(&camera.rig_to_camera, &p)?;
            let (x, y) = (px.x.round(), px.y.round());
            let inside =
                x >= 0.0 && y >= 0.0 && x < turned.width as f64 && y < turned.height as f64;
            inside.then(|| y as usize * turned.width + x as usize)
        });
        match j.filter(|j| turned.flags[*j] & (UNSEEN | REFUSED) == 0) {
            Some(j) => out.set(
                i,
                &combine_turned_scans(&first.fit(i), &turned.fit(j), tolerance),
            ),
            None => out.flags[i] |= NOT_TURNED,
        }
    }
    out
}

/// Where pixel `(x, y)`'s ray meets the sample plane (z = 0) and the direction back to the
/// camera; `None` when it misses the plane from above or cannot be undistorted.
pub fn pixel_view(camera: &CameraGeometry, (x, y): (usize, usize)) -> Option<ViewPoint> {
    pixel_ray(&camera.model, &camera.rig_to_camera, (x as f64, y as f64))
        .and_then(|(c, d)| (d.z < -1e-9).then(|| (c, c - d * (c.z / d.z))))
        .and_then(|(c, p)| ViewPoint::seen_from(p, c))
}

/// Fits every pixel of `camera` (`width × height`) to `frames`. `tube_rgb` is the tube's
/// intensity per millimetre in each channel, in the frames' radiance units (its calibration),
/// so each sample is radiance over it. Errors, naming the frame and pixel, on frames of the
/// wrong size or holding a value that is not finite, and on a bad intensity.
pub fn ward_maps(
    tube: &Tube,
    camera: &CameraGeometry,
    (width, height): (usize, usize),
    frames: &[SweepFrame<'_>],
    tube_rgb: [f64; 3],
    options: &WardFitOptions,
) -> Result<WardMaps, ProcessingError> {
    let ill = |why: String| ProcessingError::IllPosed {
        what: "Ward map",
        why,
    };
    if tube_rgb.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(ill(format!(
            "the tube's intensity {tube_rgb:?} must be finite and above 0 in every channel; calibrate it"
        )));
    }
    let n = width * height;
    for (k, f) in frames.iter().enumerate() {
        if f.rgb.len() != n * 3 || f.clipped.is_some_and(|c| c.len() != n) {
            return Err(ill(format!(
                "frame {k} (tube at {} mm) holds {} values where a {width}×{height} RGB image holds {}",
                f.tube_x_mm,
                f.rgb.len(),
                n * 3
            )));
        }
        if !f.tube_x_mm.is_finite() {
            return Err(ill(format!(
                "frame {k}'s tube position {} is not a number",
                f.tube_x_mm
            )));
        }
        if let Some(i) = f.rgb.iter().position(|v| !v.is_finite()) {
            return Err(ill(format!(
                "frame {k} (tube at {} mm): pixel ({}, {}) channel {} is {}; check the frame and its response calibration",
                f.tube_x_mm,
                (i / 3) % width,
                (i / 3) / width,
                i % 3,
                f.rgb[i]
            )));
        }
    }
    let pixels: Vec<(u16, [f32; 6])> = (0..n)
        .into_par_iter()
        .map(|i| {
            let Some(view) = pixel_view(camera, (i % width, i / width)) else {
                return (UNSEEN, [0.0; 6]);
            };
            // Stops where the tube stands between the point and the camera show the tube.
            let samples: Vec<WardSample> = frames
                .iter()
                .filter(|f| !tube.hides(&view, f.tube_x_mm))
                .map(|f| WardSample {
                    tube_x_mm: f.tube_x_mm,
                    rgb: [0, 1, 2].map(|c| f64::from(f.rgb[i * 3 + c]) / tube_rgb[c]),
                    saturated: f.clipped.is_some_and(|m| m[i]),
                })
                .collect();
            match fit_ward(tube, &view, &samples, options) {
                Ok(fit) => (
                    fit.flags.iter().fold(0, |m, f| m | f.bit()),
                    [
                        fit.rho_d[0] as f32,
                        fit.rho_d[1] as f32,
                        fit.rho_d[2] as f32,
                        fit.rho_s as f32,
                        fit.alpha as f32,
                        fit.relative_rms as f32,
                    ],
                ),
                Err(_) => (REFUSED, [0.0; 6]),
            }
        })
        .collect();
    let mut maps = WardMaps {
        width,
        height,
        rho_d: Vec::with_capacity(n * 3),
        rho_s: Vec::with_capacity(n),
        alpha: Vec::with_capacity(n),
        relative_rms: Vec::with_capacity(n),
        flags: Vec::with_capacity(n),
    };
    for (flags, v) in pixels {
        maps.rho_d.extend_from_slice(&v[..3]);
        maps.rho_s.push(v[3]);
        maps.alpha.push(v[4]);
        maps.relative_rms.push(v[5]);
        maps.flags.push(flags);
    }
    Ok(maps)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::camera_model::Distortion;
    use crate::nominal_geometry::{NominalCamera, nominal_geometry};

    /// The reflectometer rig's camera, shrunk to 32×24.
    pub(crate) fn camera() -> CameraGeometry {
        nominal_geometry(&NominalCamera {
            id: "cam1".into(),
            width: 32,
            height: 24,
            azimuth_deg: 180.0,
            elevation_deg: 60.0,
            distance_mm: 400.0,
            fov_deg: 14.0,
            principal_offset_px: [0.0, 0.0],
            distortion: Distortion::default(),
        })
        .expect("a camera")
    }

    #[test]
    fn a_uniform_glossy_sample_is_mapped_and_clipped_and_black_pixels_are_flagged() {
        let tube = Tube {
            height_mm: 60.0,
            length_mm: 300.0,
            radius_mm: 13.0,
        };
        let cam = camera();
        let (w, h) = (32usize, 24usize);
        let tube_rgb = [0.9, 1.0, 0.95];
        let (rho_d, rho_s, alpha) = ([0.3, 0.2, 0.1], 0.1, 0.08);
        let stops: Vec<f64> = (0..61).map(|k| -120.0 + 4.0 * k as f64).collect();
        // Rendered from the model; pixel 0 black, pixel 1 clipped at its brightest frames.
        let images: Vec<Vec<f32>> = stops
            .iter()
            .map(|&x| {
                (0..w * h)
                    .flat_map(|i| {
                        let (c, d) = pixel_ray(
                            &cam.model,
                            &cam.rig_to_camera,
                            ((i % w) as f64, (i / w) as f64),
                        )
                        .expect("a ray");
                        let p = c - d * (c.z / d.z);
                        let view = ViewPoint::seen_from(p, c).expect("above");
                        let dd = tube.diffuse(&view, x) / std::f64::consts::PI;
                        let s = tube.specular(&view, x, alpha);
                        let black = i == 0;
                        [0, 1, 2].map(move |ch| {
                            if black {
                                0.0
                            } else {
                                ((rho_d[ch] * dd + rho_s * s) * tube_rgb[ch]) as f32
                            }
                        })
                    })
                    .collect()
            })
            .collect();
        let peak1 = images.iter().map(|im| im[3]).fold(0.0f32, f32::max);
        let masks: Vec<Vec<bool>> = images
            .iter()
            .map(|im| (0..w * h).map(|i| i == 1 && im[3] > 0.9 * peak1).collect())
            .collect();
        let frames: Vec<SweepFrame> = stops
            .iter()
            .zip(&images)
            .zip(&masks)
            .map(|((x, rgb), m)| SweepFrame {
                tube_x_mm: *x,
                rgb,
                clipped: Some(m),
            })
            .collect();
        let maps = ward_maps(
            &tube,
            &cam,
            (w, h),
            &frames,
            tube_rgb,
            &WardFitOptions::default(),
        )
        .expect("maps");
        assert_eq!(maps.flags[0], WardFlag::Black.bit());
        assert!(
            maps.flags[1] & WardFlag::Saturated.bit() != 0,
            "{}",
            maps.flags[1]
        );
        for i in 1..w * h {
            for (got, truth) in maps.rho_d[i * 3..i * 3 + 3].iter().zip(rho_d) {
                let got = f64::from(*got);
                assert!((got / truth - 1.0).abs() < 1e-3, "pixel {i}: ρd {got}");
            }
            assert!(
                (f64::from(maps.rho_s[i]) / rho_s - 1.0).abs() < 1e-3,
                "pixel {i}"
            );
            assert!(
                (f64::from(maps.alpha[i]) / alpha - 1.0).abs() < 1e-3,
                "pixel {i}"
            );
        }
        let all = [&maps.rho_d, &maps.rho_s, &maps.alpha, &maps.relative_rms];
        assert!(all.iter().all(|m| m.iter().all(|v| v.is_finite())));
        // Wrong sizes and an uncalibrated tube are refused with the reason.
        let short = [SweepFrame {
            tube_x_mm: 0.0,
            rgb: &images[0][..10],
            clipped: None,
        }];
        let e = ward_maps(
            &tube,
            &cam,
            (w, h),
            &short,
            tube_rgb,
            &WardFitOptions::default(),
        )
        .expect_err("short frame");
        assert!(e.to_string().contains("frame 0"), "{e}");
        let e = ward_maps(
            &tube,
            &cam,
            (w, h),
            &frames,
            [0.0, 1.0, 1.0],
            &WardFitOptions::default(),
        )
        .expect_err("no intensity");
        assert!(e.to_string().contains("calibrate it"), "{e}");
        let mut broken = images[3].clone();
        broken[(2 * w + 5) * 3 + 1] = f32::NAN;
        let mut with_nan = frames.clone();
        with_nan[3].rgb = &broken;
        let e = ward_maps(
            &tube,
            &cam,
            (w, h),
            &with_nan,
            tube_rgb,
            &WardFitOptions::default(),
        )
        .expect_err("a NaN in a frame");
        assert!(
            e.to_string().contains("frame 3") && e.to_string().contains("pixel (5, 2) channel 1"),
            "{e}"
        );
    }

    #[test]
    fn a_turned_scan_that_disagrees_flags_anisotropy_per_point_of_the_sample() {
        let cam = camera();
        let (w, h) = (32usize, 24usize);
        let maps = |alpha: f32| WardMaps {
            width: w,
            height: h,
            rho_d: vec![0.3; w * h * 3],
            rho_s: vec![0.1; w * h],
            alpha: vec![alpha; w * h],
            relative_rms: vec![0.01; w * h],
            flags: vec![0; w * h],
        };
        let mut turned = maps(0.2);
        // The turned scan saw nothing at the pixel where the centre's point went.
        let centre = 12 * w + 16;
        let went = pixel_view(&cam, (16, 12))
            .and_then(|v| {
                let p = Vector3::new(-v.p.y, v.p.x, 0.0);
                cam.model.project(&cam.rig_to_camera, &p)
            })
            .expect("projects");
        let j = went.y.round() as usize * w + went.x.round() as usize;
        turned.flags[j] = UNSEEN;
        let combined = combine_turned_maps(&maps(0.1), &turned, &cam, 90.0, 0.25);
        assert_ne!(combined.flags[centre] & NOT_TURNED, 0);
        assert_eq!(combined.alpha[centre], 0.1, "the first scan's alone");
        // Elsewhere in the middle: both scans, α averaged, anisotropic.
        let other = 10 * w + 14;
        assert_eq!(combined.flags[other], WardFlag::Anisotropic.bit());
        assert!((combined.alpha[other] - 0.15).abs() < 1e-6);
        // The view is wider than tall: a quarter turn takes its corners out of view.
        assert_ne!(combined.flags[0] & NOT_TURNED, 0);
        // Scans that agree flag nothing.
        let same = combine_turned_maps(&maps(0.1), &maps(0.11), &cam, 90.0, 0.25);
        assert_eq!(same.flags[other], 0);
    }
}
