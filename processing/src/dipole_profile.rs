//! A laser line's falloff read from frames, for the dipole fit: each pixel near the sample's
//! centre placed on the sample plane by its camera's geometry, the line's centre and direction
//! measured in the frame, the pixels at their distance from it; the reference line's integral
//! and width; the pixels pooled into bins across the line, and the bins fitted with the clipped
//! core and the black tails left out ([`crate::dipole_products`] drives it).

use std::collections::BTreeMap;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibrate_geometry::CameraGeometry;
use crate::dipole_fit::{DipoleFit, DipoleFitOptions, ProfileSample, fit_dipole};
use crate::error::ProcessingError;
use crate::hdr_frame::PixelState;
use crate::ray_plane::pixel_ray;
use crate::rig_frame::sample_to_camera;

/// How the profile is read from the frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DipoleOptions {
    /// The sample's relative index of refraction η.
    pub eta: f64,
    /// The laser mount of normal incidence (the frames of step 2), degrees of elevation.
    pub mount_deg: f64,
    /// Half-width of the profile across the line, mm.
    pub window_mm: f64,
    /// Half-length of the line's stretch used, about the sample's centre, mm (the seed uses
    /// the centre only: the sample's edges leak light).
    pub strip_mm: f64,
    /// Lines passing further than this from the sample's centre are left out, mm.
    pub max_offset_mm: f64,
    /// Width of the profile's bins, mm.
    pub bin_mm: f64,
    /// Pixels seen at a lower cosine are left out (F_t(θo) is steep near grazing).
    pub min_cos_out: f64,
    /// Pixels wider than this across the line are left out (they blur the profile), mm.
    pub max_footprint_mm: f64,
    /// Half-width of the reference line's integral, mm (its background is read just beyond).
    pub reference_mm: f64,
    /// The sensor's relative noise, for the fit's weights.
    pub relative_noise: f64,
}

impl Default for DipoleOptions {
    fn default() -> Self {
        DipoleOptions {
            eta: 1.3,
            mount_deg: 90.0,
            window_mm: 10.0,
            strip_mm: 10.0,
            max_offset_mm: 10.0,
            bin_mm: 0.2,
            min_cos_out: 0.34,
            max_footprint_mm: 0.5,
            reference_mm: 3.0,
            relative_noise: 0.02,
        }
    }
}

/// One bin of the profile across the line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProfileBin {
    /// Mean distance from the line's centre of its pixels, mm.
    pub x_mm: f64,
    /// Mean light per unit line power, mm⁻¹.
    pub value: f64,
    /// Standard error of the mean, mm⁻¹.
    pub std_error: f64,
    /// Pixels in it.
    pub pixels: usize,
    /// Pixels clipped in the laser's channel (not in the mean).
    pub clipped: usize,
    /// Pixels black in that channel (in the mean at the response's floor, an upper bound).
    pub black: usize,
}

/// A pixel on the sample plane.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PlanePixel {
    /// Index in the image.
    pub(crate) index: usize,
    /// Position on the sample plane (sample frame), mm.
    pub(crate) p: [f64; 2],
    /// Cosine of the view direction with the normal.
    pub(crate) cos_out: f64,
    /// The plane position's change per pixel step in x and in y, mm.
    pub(crate) dx: [f64; 2],
    pub(crate) dy: [f64; 2],
}

/// Where the pixels of a camera at a turntable angle meet the sample plane, for those that
/// meet it within `radius_mm` of the centre (the rest are not kept: a full-size camera's
/// frame would hold tens of megabytes of them).
pub(crate) fn plane_pixels(
    geometry: &CameraGeometry,
    table_deg: f64,
    (w, h): (usize, usize),
    radius_mm: f64,
) -> Vec<PlanePixel> {
    let pose = sample_to_camera(&geometry.rig_to_camera, table_deg);
    let hit = |x: f64, y: f64| -> Option<(Vector3<f64>, f64)> {
        let (c, d) = pixel_ray(&geometry.model, &pose, (x, y))?;
        (d.z < -1e-9).then(|| (c - d * (c.z / d.z), -d.z))
    };
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let hit = &hit;
            (0..w).filter_map(move |x| {
                let (xf, yf) = (x as f64, y as f64);
                let (p, cos_out) = hit(xf, yf)?;
                if p.x.hypot(p.y) > radius_mm {
                    return None;
                }
                let (px, _) = hit(xf + 0.5, yf)?;
                let (mx, _) = hit(xf - 0.5, yf)?;
                let (py, _) = hit(xf, yf + 0.5)?;
                let (my, _) = hit(xf, yf - 0.5)?;
                Some(PlanePixel {
                    index: y * w + x,
                    p: [p.x, p.y],
                    cos_out,
                    dx: [px.x - mx.x, px.y - mx.y],
                    dy: [py.x - my.x, py.y - my.y],
                })
            })
        })
        .collect()
}

/// A pixel placed across and along a measured line.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LinePixel {
    /// Index in the image.
    pub(crate) index: usize,
    /// Signed distance from the line's centre, mm.
    pub(crate) s: f64,
    /// Radiance in the laser's channel.
    pub(crate) radiance: f64,
    /// Clipped in that channel.
    pub(crate) clipped: bool,
    /// Black in that channel (below what the response can read; the radiance an upper bound).
    pub(crate) black: bool,
    pub(crate) cos_out: f64,
    /// Its extent across the line, mm.
    pub(crate) across_mm: f64,
    /// Its area on the plane, mm².
    pub(crate) area_mm2: f64,
}

/// The line in one frame: its pixels within the strip about the sample's centre.
pub(crate) struct LineFrame {
    pub(crate) pixels: Vec<LinePixel>,
}

/// Finds the line in a frame's radiance (channel `channel`) by the weighted principal axis of
/// its bright pixels, and places the pixels about it; an error says why there is no usable
/// line.
pub(crate) fn line_frame(
    radiance: &[f32],
    state: &[PixelState],
    plane: &[PlanePixel],
    channel: usize,
    options: &DipoleOptions,
) -> Result<LineFrame, String> {
    let n = radiance.len().min(state.len()) / 3;
    if let Some(q) = plane.iter().find(|q| q.index >= n) {
        return Err(format!(
            "pixel {} is beyond the frame's {n} pixels: the frame is smaller than its camera's others",
            q.index
        ));
    }
    let seen = |q: &PlanePixel| {
        (q.cos_out >= options.min_cos_out)
            .then(|| (*q, state[q.index * 3 + channel] == PixelState::AtLeast))
    };
    let value = |q: &PlanePixel| f64::from(radiance[q.index * 3 + channel]);
    let peak = plane
        .iter()
        .filter_map(|q| seen(q).filter(|(_, c)| !c).map(|_| value(q)))
        .fold(0.0f64, f64::max);
    if !(peak > 0.0 && peak.is_finite()) {
        return Err("no laser light near the sample's centre".into());
    }
    // Weighted moments of the pixels above half the peak.
    let (mut sw, mut sx, mut sy, mut sxx, mut syy, mut sxy, mut count) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    for q in plane {
        let Some((q, clipped)) = seen(q) else {
            continue;
        };
        let v = if clipped { peak } else { value(&q) };
        let w = v - 0.5 * peak;
        if w <= 0.0 {
            continue;
        }
        let [x, y] = q.p;
        sw += w;
        sx += w * x;
        sy += w * y;
        sxx += w * x * x;
        syy += w * y * y;
        sxy += w * x * y;
        count += 1;
    }
    if count < 10 {
        return Err(format!(
            "only {count} pixels above half the line's peak: no line to locate"
        ));
    }
    let (cx, cy) = (sx / sw, sy / sw);
    let (vxx, vyy, vxy) = (sxx / sw - cx * cx, syy / sw - cy * cy, sxy / sw - cx * cy);
    let angle = 0.5 * (2.0 * vxy).atan2(vxx - vyy);
    let (dir, normal) = ([angle.cos(), angle.sin()], [-angle.sin(), angle.cos()]);
    let along = |p: [f64; 2]| (p[0] - cx) * dir[0] + (p[1] - cy) * dir[1];
    let across = |p: [f64; 2]| (p[0] - cx) * normal[0] + (p[1] - cy) * normal[1];
    let offset = across([0.0, 0.0]).abs();
    if offset > options.max_offset_mm {
        return Err(format!(
            "the line passes {offset:.1} mm from the sample's centre (more than {} mm)",
            options.max_offset_mm
        ));
    }
    let centre_along = along([0.0, 0.0]);
    let reach = options.window_mm.max(options.reference_mm + 2.0) + options.bin_mm;
    let pixels = plane
        .iter()
        .filter_map(|q| {
            let (q, clipped) = seen(q)?;
            let (s, u) = (across(q.p), along(q.p) - centre_along);
            if u.abs() > options.strip_mm || s.abs() > reach {
                return None;
            }
            let dot = |d: [f64; 2]| (d[0] * normal[0] + d[1] * normal[1]).abs();
            Some(LinePixel {
                index: q.index,
                s,
                radiance: value(&q),
                clipped,
                black: state[q.index * 3 + channel] == PixelState::AtMost,
                cos_out: q.cos_out,
                across_mm: dot(q.dx) + dot(q.dy),
                area_mm2: (q.dx[0] * q.dy[1] - q.dx[1] * q.dy[0]).abs(),
            })
        })
        .collect();
    Ok(LineFrame { pixels })
}

/// The reference line's power per unit length (before the albedo) and width: the area-weighted
/// mean radiance over ±`reference_mm` less the background just beyond, times the band's width.
pub(crate) fn reference_line(
    line: &LineFrame,
    options: &DipoleOptions,
) -> Result<(f64, f64), String> {
    let r = options.reference_mm;
    let band = |lo: f64, hi: f64| {
        line.pixels
            .iter()
            .filter(move |p| p.s.abs() >= lo && p.s.abs() <= hi)
    };
    if let Some(p) = band(0.0, r).find(|p| p.clipped) {
        return Err(format!(
            "the reference line is clipped {:.2} mm from its centre; capture it with a shorter exposure",
            p.s
        ));
    }
    let mean = |lo: f64, hi: f64| {
        let (sa, sv) = band(lo, hi).fold((0.0, 0.0), |(a, v), p| {
            (a + p.area_mm2, v + p.area_mm2 * p.radiance)
        });
        (sa > 0.0).then(|| sv / sa)
    };
    let (Some(inner), Some(background)) = (mean(0.0, r), mean(r, r + 2.0)) else {
        return Err(format!(
            "no pixels within {r} mm of the reference line and beyond it"
        ));
    };
    let integral = (inner - background) * 2.0 * r;
    if !(integral > 0.0 && integral.is_finite()) {
        return Err("the reference line is no brighter than its background".into());
    }
    let (mut m0, mut m2) = (0.0, 0.0);
    for p in band(0.0, r) {
        let v = (p.radiance - background) * p.area_mm2;
        m0 += v;
        m2 += v * p.s * p.s;
    }
    // The pixels' own width across (a box of `across` mm: variance a²/12) is in the sample's
    // profile too, through the same cameras; only the laser's own width is the model's.
    Ok((integral, (m2 / m0).max(0.0).sqrt()))
}

/// One bin's sums: pixels, Σs, Σv, Σv², clipped and black pixels.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct BinSums {
    n: usize,
    s: f64,
    v: f64,
    vv: f64,
    clipped: usize,
    black: usize,
}

/// Accumulates profile values into bins across the line.
#[derive(Debug, Clone, Default)]
pub(crate) struct Bins {
    bins: BTreeMap<i64, BinSums>,
}

impl Bins {
    /// Adds a pixel at `s` of value `v`: a clipped one is only counted; a black one enters
    /// the mean at its bound and is counted.
    pub(crate) fn add(&mut self, bin_mm: f64, s: f64, v: f64, p: &LinePixel) {
        let e = self.bins.entry((s / bin_mm).round() as i64).or_default();
        if p.clipped {
            e.clipped += 1;
            return;
        }
        e.black += usize::from(p.black);
        e.n += 1;
        e.s += s;
        e.v += v;
        e.vv += v * v;
    }

    pub(crate) fn profile(&self, bin_mm: f64) -> Vec<ProfileBin> {
        self.bins
            .iter()
            .map(|(k, b)| {
                let nf = b.n.max(1) as f64;
                let mean = b.v / nf;
                let var = (b.vv / nf - mean * mean).max(0.0);
                ProfileBin {
                    x_mm: if b.n > 0 {
                        b.s / nf
                    } else {
                        *k as f64 * bin_mm
                    },
                    value: mean,
                    std_error: (var / nf).sqrt(),
                    pixels: b.n,
                    clipped: b.clipped,
                    black: b.black,
                }
            })
            .collect()
    }
}

/// Least pixels in a bin for it to be fitted.
pub(crate) const MIN_BIN_PIXELS: usize = 3;

/// Fits the profile in `bins`: the core is the options' or the clipped bins' reach, whichever
/// is wider; each side ends before the first bin holding a black pixel (the tail has sunk
/// into the sensor's floor there, and a bound is no measurement); the noise floor is the
/// median standard error of the outer half.
pub(crate) fn fit_bins(
    profile: &[ProfileBin],
    options: &DipoleOptions,
    line_width_mm: f64,
) -> Result<(DipoleFit, f64), ProcessingError> {
    let bin = options.bin_mm;
    let clipped_reach = profile
        .iter()
        .filter(|b| b.clipped > 0)
        .map(|b| b.x_mm.abs() + bin)
        .fold(0.0f64, f64::max);
    let core_mm = clipped_reach.max(2.5 * bin);
    let floor_at = |side: f64| {
        profile
            .iter()
            .filter(|b| b.black > 0 && b.x_mm * side > core_mm)
            .map(|b| b.x_mm.abs())
            .fold(f64::INFINITY, f64::min)
    };
    let (left, right) = (floor_at(-1.0), floor_at(1.0));
    let used: Vec<&ProfileBin> = profile
        .iter()
        .filter(|b| {
            let reach = if b.x_mm < 0.0 { left } else { right };
            b.pixels >= MIN_BIN_PIXELS && b.x_mm.abs() <= options.window_mm && b.x_mm.abs() < reach
        })
        .collect();
    let mut outer: Vec<f64> = used
        .iter()
        .filter(|b| b.x_mm.abs() > 0.5 * options.window_mm)
        .map(|b| b.std_error)
        .collect();
    outer.sort_by(f64::total_cmp);
    let top = used.iter().map(|b| b.value).fold(0.0f64, f64::max);
    let floor = outer
        .get(outer.len() / 2)
        .copied()
        .unwrap_or(0.0)
        .max(1e-9 * top)
        .max(f64::MIN_POSITIVE.sqrt());
    let samples: Vec<ProfileSample> = used
        .iter()
        .map(|b| ProfileSample {
            x_mm: b.x_mm,
            value: b.value,
        })
        .collect();
    let fit = fit_dipole(
        &samples,
        &DipoleFitOptions {
            eta: options.eta,
            core_mm,
            relative_noise: options.relative_noise,
            noise_floor: floor,
            line_width_mm,
            ..DipoleFitOptions::default()
        },
    )?;
    Ok((
        fit,
        core_mm.max(crate::dipole_fit::CORE_WIDTHS * line_width_mm),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dipole::DipoleMedium;

    /// A flat field of pixels 0.1 mm apart, seen from straight above.
    fn grid(half_mm: f64) -> (Vec<PlanePixel>, usize) {
        let n = (2.0 * half_mm / 0.1) as usize + 1;
        let plane = (0..n * n)
            .map(|i| {
                let (x, y) = (
                    (i % n) as f64 * 0.1 - half_mm,
                    (i / n) as f64 * 0.1 - half_mm,
                );
                PlanePixel {
                    index: i,
                    p: [x, y],
                    cos_out: 1.0,
                    dx: [0.1, 0.0],
                    dy: [0.0, 0.1],
                }
            })
            .collect();
        (plane, n)
    }

    /// Radiance of a line along direction `angle` through `(ox, oy)` with cross profile `f`.
    fn render(
        plane: &[PlanePixel],
        (ox, oy): (f64, f64),
        angle: f64,
        f: impl Fn(f64) -> f64,
    ) -> (Vec<f32>, Vec<PixelState>) {
        let normal = [-angle.sin(), angle.cos()];
        let mut rgb = vec![0.0f32; plane.len() * 3];
        for q in plane {
            let s = (q.p[0] - ox) * normal[0] + (q.p[1] - oy) * normal[1];
            rgb[q.index * 3] = f(s) as f32;
        }
        let state = vec![PixelState::Measured; rgb.len()];
        (rgb, state)
    }

    fn options() -> DipoleOptions {
        DipoleOptions {
            window_mm: 6.0,
            strip_mm: 5.0,
            bin_mm: 0.1,
            ..DipoleOptions::default()
        }
    }

    #[test]
    fn a_reference_line_gives_its_integral_and_width() {
        let (plane, _) = grid(12.0);
        let sigma = 0.2;
        let gauss = |s: f64| {
            (-0.5 * (s / sigma).powi(2)).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt())
        };
        // 7 units per mm of line, on a background of 0.01.
        let (rgb, state) = render(&plane, (0.7, -0.4), 0.3, |s| 7.0 * gauss(s) + 0.01);
        let line = line_frame(&rgb, &state, &plane, 0, &options()).expect("a line");
        let (integral, width) = reference_line(&line, &options()).expect("reference");
        assert!((integral / 7.0 - 1.0).abs() < 5e-3, "{integral}");
        // The pixels' 0.1 mm box adds its variance a²/12 to the line's.
        let expected = (sigma * sigma + 0.01 / 12.0).sqrt();
        assert!(
            (width / expected - 1.0).abs() < 0.03,
            "{width} against {expected}"
        );
    }

    #[test]
    fn a_falloff_beside_a_line_fits_back_to_its_medium() {
        let (plane, _) = grid(12.0);
        let medium = DipoleMedium {
            alpha_p: 0.8,
            sigma_t_p: 1.5,
            eta: 1.3,
        };
        let (rgb, state) = render(&plane, (-0.3, 0.5), -1.1, |s| medium.line_profile(s));
        let line = line_frame(&rgb, &state, &plane, 0, &options()).expect("a line");
        let mut bins = Bins::default();
        for p in &line.pixels {
            if p.s.abs() <= 6.0 {
                bins.add(0.1, p.s, p.radiance, p);
            }
        }
        let (fit, _) = fit_bins(&bins.profile(0.1), &options(), 0.0).expect("fit");
        assert!((fit.alpha_p / 0.8 - 1.0).abs() < 5e-3, "{fit:?}");
        assert!((fit.sigma_t_p / 1.5 - 1.0).abs() < 1e-2, "{fit:?}");
    }

    #[test]
    fn a_tail_sunk_into_the_sensor_floor_is_left_out() {
        // Below 1 % of the peak the camera reads its floor (black: an upper bound), as a
        // single short exposure does; read as light, that floor pulls σ′t far down.
        let (plane, _) = grid(12.0);
        let medium = DipoleMedium {
            alpha_p: 0.4248,
            sigma_t_p: 1.0,
            eta: 1.3,
        };
        let (mut rgb, mut state) = render(&plane, (0.2, 0.1), 0.4, |s| medium.line_profile(s));
        let floor = 0.01 * medium.line_profile(0.0) as f32;
        for (i, v) in rgb.chunks_exact_mut(3).enumerate() {
            if v[0] < floor {
                v[0] = floor;
                state[i * 3] = PixelState::AtMost;
            }
        }
        let line = line_frame(&rgb, &state, &plane, 0, &options()).expect("a line");
        let mut bins = Bins::default();
        for p in &line.pixels {
            if p.s.abs() <= 6.0 {
                bins.add(0.1, p.s, p.radiance, p);
            }
        }
        let profile = bins.profile(0.1);
        let (fit, _) = fit_bins(&profile, &options(), 0.0).expect("fit");
        assert!((fit.alpha_p / 0.4248 - 1.0).abs() < 1e-2, "{fit:?}");
        assert!((fit.sigma_t_p - 1.0).abs() < 2e-2, "{fit:?}");
        assert!(fit.samples < profile.len() / 2, "{fit:?}");
    }

    #[test]
    fn a_clipped_core_widens_what_is_left_out() {
        let (plane, _) = grid(12.0);
        let medium = DipoleMedium {
            alpha_p: 0.95,
            sigma_t_p: 1.0,
            eta: 1.3,
        };
        let (rgb, mut state) = render(&plane, (0.0, 0.0), 0.0, |s| medium.line_profile(s));
        let limit = medium.line_profile(0.8) as f32;
        for (i, v) in rgb.chunks_exact(3).enumerate() {
            if v[0] > limit {
                state[i * 3] = PixelState::AtLeast;
            }
        }
        let line = line_frame(&rgb, &state, &plane, 0, &options()).expect("a line");
        let mut bins = Bins::default();
        for p in &line.pixels {
            bins.add(0.1, p.s, p.radiance, p);
        }
        let (fit, core) = fit_bins(&bins.profile(0.1), &options(), 0.0).expect("fit");
        assert!(core >= 0.8, "{core}");
        assert!((fit.alpha_p / 0.95 - 1.0).abs() < 5e-3, "{fit:?}");
        assert!((fit.sigma_t_p - 1.0).abs() < 1e-2, "{fit:?}");
        // A saturated reference is refused, not integrated.
        let e = reference_line(&line, &options()).unwrap_err();
        assert!(e.contains("clipped"), "{e}");
    }

    #[test]
    fn no_line_and_a_line_off_centre_are_said_so() {
        let (plane, _) = grid(12.0);
        let (rgb, state) = render(&plane, (0.0, 0.0), 0.0, |_| 0.0);
        let e = line_frame(&rgb, &state, &plane, 0, &options())
            .err()
            .expect("no line");
        assert!(e.contains("no laser light"), "{e}");
        let off = DipoleOptions {
            max_offset_mm: 2.0,
            ..options()
        };
        let (rgb, state) = render(&plane, (0.0, 5.0), 0.0, |s| (-s * s * 10.0).exp());
        let e = line_frame(&rgb, &state, &plane, 0, &off)
            .err()
            .expect("off centre");
        assert!(e.contains("from the sample's centre"), "{e}");
    }
}
