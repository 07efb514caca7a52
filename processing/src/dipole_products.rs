//! `stagehand process --products dipole`: the dipole's α′ and σ′t per laser colour from a
//! quasi-homogeneous run (`sequences/quasi_homogeneous.rhai`, seed 004 Ch. 5):
//! - the laser's power per unit length φ, per camera, from the line on a reference of known
//!   albedo (Lambert: ∫L ds = ρ/π·φ across the line), with the line's own width;
//! - step 2's lines at normal incidence on the sample: each pixel near the sample's centre is
//!   placed on the sample plane by the camera's geometry, at its distance from the line (whose
//!   centre and direction are measured in the frame), and its radiance turned into the line
//!   profile's units, π·c(η)·L / (F_t(η, 1)·F_t(η, cosθo)·φ) (the simulator's exit lobe,
//!   `simulator/src/render/subsurface.rs`);
//! - the pixels of every camera and view pooled into bins across the line, the clipped core
//!   left out, and [`fit_dipole`] run on them (and on each camera alone, for a spread).
//!
//! The product is one JSON per colour (`dipole/<nm>nm.json`): the fit, the profile it was fitted
//! to, the reference's φ per camera and the frames left out with the reason.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::FrameMeta;
use stagehand_dataset::exr_planes::encode_exr_planes;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::calibrate_geometry::CameraGeometry;
use crate::dipole::{DipoleMedium, fresnel_transmittance, hemispherical_transmittance};
use crate::dipole_fit::{DipoleFit, DipoleFitOptions, ProfileSample, blurred_profile, fit_dipole};
use crate::error::ProcessingError;
use crate::hdr_frame::PixelState;
use crate::laser_sheet::laser_channel;
use crate::ray_plane::pixel_ray;
use crate::reflectometer_products::{NOMINAL, camera_response};
use crate::response_calibration::ResponseSet;
use crate::rig_frame::sample_to_camera;
use crate::run_frames::{
    BracketKey, axis_angle, bracket_keys, dataset_err, merge_capture, open_run,
};

/// The reference sample that calibrates the laser's power: a fixture of known Lambert albedo.
#[derive(Debug, Clone, Copy)]
pub struct DipoleReference<'a> {
    /// Its fixture name in the frames (`opal_reference`).
    pub fixture: &'a str,
    /// Its albedo per RGB channel.
    pub albedo: [f64; 3],
}

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

/// What the dipole products are made with.
#[derive(Debug, Clone, Copy)]
pub struct DipoleSetup<'a> {
    /// The response calibration and its id.
    pub response: (&'a ResponseSet, &'a str),
    /// Each camera's geometry, and where it comes from (a calibration id, or [`NOMINAL`]).
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The turntable's axis id, if the rig has one.
    pub turntable_axis: Option<&'a str>,
    /// The reference sample.
    pub reference: DipoleReference<'a>,
    /// How the profile is read.
    pub options: DipoleOptions,
    /// Only these cameras (`None`: every camera).
    pub cameras: Option<&'a [String]>,
    /// Also the exit function of each view ([`exit_maps`]).
    pub exit: bool,
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

/// The laser on the reference, as one camera saw it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferenceLine {
    /// The laser's power per unit length, in the camera's radiance units × mm.
    pub phi: f64,
    /// The line's width across (standard deviation), mm.
    pub width_mm: f64,
}

/// A frame left out, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeftOut {
    /// The frame's path.
    pub frame: String,
    /// Why.
    pub why: String,
}

/// The fitted medium re-rendered at every pixel beside the line it was fitted to: each
/// pixel's radiance predicted from α′, σ′t, the laser's power and the Fresnel factors, against
/// the captured radiance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rerender {
    /// Pixels compared: outside the core, neither clipped nor black, within the window.
    pub pixels: usize,
    /// √(Σ(L − L̂)² / ΣL̂²) over them.
    pub relative_rms: f64,
    /// Median of |L − L̂| / L̂.
    pub median_relative: f64,
}

/// One colour's product.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DipoleProduct {
    /// The laser's wavelength, nm.
    pub colour_nm: u32,
    /// The RGB channel read.
    pub channel: usize,
    /// The sample's fixture.
    pub fixture: String,
    /// The reference's fixture and albedo in the channel read.
    pub reference: (String, f64),
    /// The reference line per camera.
    pub reference_lines: BTreeMap<String, ReferenceLine>,
    /// η assumed.
    pub eta: f64,
    /// The line width the model was blurred by (the median of the cameras'), mm.
    pub line_width_mm: f64,
    /// The core left out, mm.
    pub core_mm: f64,
    /// The pooled profile.
    pub profile: Vec<ProfileBin>,
    /// The fit of the pooled profile.
    pub fit: DipoleFit,
    /// Each camera's own fit, or why it has none.
    pub cameras: BTreeMap<String, Result<DipoleFit, String>>,
    /// The fit re-rendered against the captured pixels.
    pub rerender: Rerender,
    /// Sample frames used.
    pub frames_used: usize,
    /// Frames left out.
    pub left_out: Vec<LeftOut>,
}

/// What a dipole pass did.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DipoleSummary {
    /// Colours written now.
    pub written: usize,
    /// Colours already current.
    pub skipped: usize,
    /// Exit-function maps written now (one per camera and view).
    pub exit_written: usize,
    /// The fits written and their re-render, by colour.
    pub fits: Vec<(u32, DipoleFit, Rerender)>,
}

/// A pixel on the sample plane.
#[derive(Debug, Clone, Copy)]
struct PlanePixel {
    /// Index in the image.
    index: usize,
    /// Position on the sample plane (sample frame), mm.
    p: [f64; 2],
    /// Cosine of the view direction with the normal.
    cos_out: f64,
    /// The plane position's change per pixel step in x and in y, mm.
    dx: [f64; 2],
    dy: [f64; 2],
}

/// Where the pixels of a camera at a turntable angle meet the sample plane, for those that
/// meet it within `radius_mm` of the centre (the rest are not kept: a full-size camera's
/// frame would hold tens of megabytes of them).
fn plane_pixels(
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
struct LinePixel {
    /// Index in the image.
    index: usize,
    /// Signed distance from the line's centre, mm.
    s: f64,
    /// Radiance in the laser's channel.
    radiance: f64,
    /// Clipped in that channel.
    clipped: bool,
    /// Black in that channel (below what the response can read; the radiance an upper bound).
    black: bool,
    cos_out: f64,
    /// Its extent across the line, mm.
    across_mm: f64,
    /// Its area on the plane, mm².
    area_mm2: f64,
}

/// The line in one frame: its pixels within the strip about the sample's centre.
struct LineFrame {
    pixels: Vec<LinePixel>,
}

/// Finds the line in a frame's radiance (channel `channel`) by the weighted principal axis of
/// its bright pixels, and places the pixels about it; an error says why there is no usable
/// line.
fn line_frame(
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
fn reference_line(line: &LineFrame, options: &DipoleOptions) -> Result<(f64, f64), String> {
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
struct BinSums {
    n: usize,
    s: f64,
    v: f64,
    vv: f64,
    clipped: usize,
    black: usize,
}

/// Accumulates profile values into bins across the line.
#[derive(Debug, Clone, Default)]
struct Bins {
    bins: BTreeMap<i64, BinSums>,
}

impl Bins {
    /// Adds a pixel at `s` of value `v`: a clipped one is only counted; a black one enters
    /// the mean at its bound and is counted.
    fn add(&mut self, bin_mm: f64, s: f64, v: f64, p: &LinePixel) {
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

    fn profile(&self, bin_mm: f64) -> Vec<ProfileBin> {
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
const MIN_BIN_PIXELS: usize = 3;

/// Fits the profile in `bins`: the core is the options' or the clipped bins' reach, whichever
/// is wider; each side ends before the first bin holding a black pixel (the tail has sunk
/// into the sensor's floor there, and a bound is no measurement); the noise floor is the
/// median standard error of the outer half.
fn fit_bins(
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

/// True when the camera sees the sample's centre at a cosine of `min_cos` or more: the
/// cameras whose views can have an exit map.
fn sees_steeply(geometry: Option<&CameraGeometry>, min_cos: f64) -> bool {
    geometry.is_some_and(|g| {
        let [x, y, z] = g.centre_mm;
        z / (x * x + y * y + z * z).sqrt().max(1e-9) >= min_cos
    })
}

/// One view's pixels beside the lines of its sweep.
#[derive(Debug, Clone)]
struct ExitView {
    size: (usize, usize),
    table_deg: f64,
    truth_frame: String,
    /// (pixel index, distance from the line, value) over every line of the sweep.
    pixels: Vec<(usize, f64, f64)>,
}

/// Lines contribute to a point's exit function only while they light it at least this much of
/// the best-lit point's light (dark points are left at 0: the seed's threshold).
const EXIT_MIN_WEIGHT: f64 = 0.05;

/// A view's exit function, interleaved (exit, weight) per pixel: the light each point sent
/// over what the fitted homogeneous medium sends, summed over the lines (so each line weighs
/// by how well it lit the point); the clipped core left out.
fn exit_maps(view: &ExitView, medium: &DipoleMedium, width_mm: f64, core_mm: f64) -> Vec<f32> {
    let n = view.size.0 * view.size.1;
    let (mut seen, mut model) = (vec![0.0f64; n], vec![0.0f64; n]);
    for &(i, s, v) in view.pixels.iter().filter(|(_, s, _)| s.abs() > core_mm) {
        if i < n {
            seen[i] += v;
            model[i] += blurred_profile(medium, s, width_mm);
        }
    }
    let top = model.iter().copied().fold(0.0f64, f64::max);
    (0..n)
        .flat_map(|i| {
            let weight = if top > 0.0 { model[i] / top } else { 0.0 };
            let exit = if weight >= EXIT_MIN_WEIGHT {
                seen[i] / model[i]
            } else {
                0.0
            };
            [exit as f32, weight as f32]
        })
        .collect()
}

/// Compares the fitted profile with every pixel's value outside the core.
fn rerender(
    seen: &[(f64, f64)],
    fit: &DipoleFit,
    eta: f64,
    line_width_mm: f64,
    core_mm: f64,
) -> Rerender {
    let medium = DipoleMedium {
        alpha_p: fit.alpha_p,
        sigma_t_p: fit.sigma_t_p,
        eta,
    };
    let (mut num, mut den, mut rel) = (0.0, 0.0, Vec::new());
    for &(s, v) in seen.iter().filter(|(s, _)| s.abs() > core_mm) {
        let model = blurred_profile(&medium, s, line_width_mm);
        if model > 0.0 {
            num += (v - model).powi(2);
            den += model * model;
            rel.push(((v - model) / model).abs());
        }
    }
    rel.sort_by(f64::total_cmp);
    Rerender {
        pixels: rel.len(),
        relative_rms: if den > 0.0 { (num / den).sqrt() } else { 0.0 },
        median_relative: rel.get(rel.len() / 2).copied().unwrap_or(0.0),
    }
}

/// Each camera's plane pixels at its latest view: (turntable key, frame size, pixels).
type Planes = BTreeMap<String, (i64, (usize, usize), Vec<PlanePixel>)>;

/// A capture's view: its camera and turntable angle (in thousandths of a degree, a map key),
/// and the angle.
fn view_of(
    run_dir: &std::path::Path,
    key: &BracketKey,
    turntable_axis: Option<&str>,
) -> Result<((String, i64), f64), ProcessingError> {
    let table = axis_angle(run_dir, &key.meta, &key.frames[0].path, turntable_axis)?;
    Ok(((key.camera.clone(), (table * 1000.0).round() as i64), table))
}

/// True for a frame of step 2: the laser on, mounted for normal incidence.
fn overhead(meta: &FrameMeta, options: &DipoleOptions) -> bool {
    meta.laser_on
        && meta
            .laser_mount_deg
            .is_some_and(|m| (m - options.mount_deg).abs() <= 0.5)
}

/// Writes the dipole product of every laser colour of the run into `store`;
/// `progress(done, total)` after each colour.
pub fn dipole_products(
    store: &mut ProductStore,
    setup: DipoleSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<DipoleSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let options = setup.options;
    if !(1.0..=3.0).contains(&options.eta) {
        return Err(ProcessingError::BadParameter {
            name: "eta",
            value: options.eta,
            why: "the dipole's diffuse Fresnel fit holds for η in 1–3",
        });
    }
    let reader = open_run(&run_dir)?;
    let keep = |camera: &str| setup.cameras.is_none_or(|c| c.iter().any(|x| x == camera));
    let keys = bracket_keys(&reader, |m| overhead(m, &options) && keep(&m.camera))?;
    let mut by_colour: BTreeMap<u32, (Vec<&BracketKey>, Vec<&BracketKey>)> = BTreeMap::new();
    for k in &keys {
        let e = by_colour.entry(k.meta.laser_colour_nm).or_default();
        if k.meta.fixture == setup.reference.fixture {
            e.0.push(k);
        } else {
            e.1.push(k);
        }
    }
    by_colour.retain(|_, (_, sample)| !sample.is_empty());
    if by_colour.is_empty() {
        return Err(ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!(
                "the run has no laser line at normal incidence (laser mounted at {}°) on a sample; record one with sequences/quasi_homogeneous.rhai (step 2)",
                options.mount_deg
            ),
        });
    }
    let (geometries, geometry_id) = setup.geometry;
    let calibrations: Vec<String> = [setup.response.1, geometry_id]
        .into_iter()
        .filter(|id| *id != NOMINAL)
        .map(String::from)
        .collect();
    let mut planes = Planes::new();
    let radius = options
        .strip_mm
        .hypot(options.window_mm.max(options.reference_mm + 2.0))
        + 2.0;
    let mut summary = DipoleSummary::default();
    let total = by_colour.len();
    for (done, (nm, (references, samples))) in by_colour.iter().enumerate() {
        progress(done, total);
        let nm = *nm;
        let channel = laser_channel(nm);
        let mut fixtures: Vec<&str> = samples.iter().map(|k| k.meta.fixture.as_str()).collect();
        fixtures.sort_unstable();
        fixtures.dedup();
        if fixtures.len() > 1 {
            return Err(ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!(
                    "the {nm} nm lines at normal incidence fall on {} fixtures ({}), and none is the reference `{}`; a run holds one sample beside its reference: name the reference with --reference-fixture",
                    fixtures.len(),
                    fixtures.join(", "),
                    setup.reference.fixture
                ),
            });
        }
        let fixture = fixtures[0].to_string();
        if references.is_empty() {
            return Err(ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: format!(
                    "capture of the {nm} nm laser on the reference `{}`",
                    setup.reference.fixture
                ),
                hint: "record step 2 with its reference (sequences/quasi_homogeneous.rhai, reference=opal_reference), or name the reference's fixture (--reference-fixture)",
            });
        }
        let albedo = setup.reference.albedo[channel];
        let new = NewProduct {
            kind: "dipole".into(),
            key: format!("dipole/{nm}"),
            file_name: format!("{nm}nm.json"),
            inputs: references
                .iter()
                .chain(samples.iter())
                .flat_map(|k| k.frames.iter().map(|f| f.path.clone()))
                .collect(),
            calibrations: calibrations.clone(),
            software: software.to_string(),
            parameters: json!({
                "colour_nm": nm,
                "channel": channel,
                "geometry": geometry_id,
                "reference": {"fixture": setup.reference.fixture, "albedo": albedo},
                "options": options,
            }),
        };
        // One exit map per camera and turntable angle (a view: its pixels stay on the same
        // points of the sample through the sweep).
        let mut views: BTreeMap<(String, i64), ExitView> = BTreeMap::new();
        if setup.exit {
            for key in samples
                .iter()
                .filter(|k| sees_steeply(geometries.get(&k.camera), options.min_cos_out))
            {
                let (view, table) = view_of(&run_dir, key, setup.turntable_axis)?;
                views.entry(view).or_insert_with(|| ExitView {
                    size: (key.meta.width as usize, key.meta.height as usize),
                    table_deg: table,
                    truth_frame: key.frames[0].path.clone(),
                    pixels: Vec::new(),
                });
            }
        }
        let exit_new = |(camera, _): &(String, i64), view: &ExitView| NewProduct {
            kind: "exit".into(),
            key: format!("exit/{nm}/{camera}/{:.3}", view.table_deg),
            file_name: format!("{nm}nm_{camera}_{:.0}deg.exr", view.table_deg),
            inputs: new.inputs.clone(),
            calibrations: new.calibrations.clone(),
            software: software.to_string(),
            parameters: json!({
                "colour_nm": nm,
                "camera": camera,
                "turntable_deg": view.table_deg,
                "truth_frame": view.truth_frame,
                "dipole": new.parameters,
            }),
        };
        let mut all_current = store.is_current(&new).map_err(dataset_err(&run_dir))?;
        for (k, v) in &views {
            all_current &= store
                .is_current(&exit_new(k, v))
                .map_err(dataset_err(&run_dir))?;
        }
        if all_current {
            summary.skipped += 1;
            continue;
        }
        let mut left_out = Vec::new();
        let line_of = |key: &BracketKey,
                       planes: &mut Planes|
         -> Result<Result<LineFrame, String>, ProcessingError> {
            let geometry = geometries.get(&key.camera).ok_or_else(|| {
                ProcessingError::CalibrationMismatch {
                    id: geometry_id.to_string(),
                    why: format!("it has no geometry for camera `{}`", key.camera),
                }
            })?;
            let ((camera, table_key), table) = view_of(&run_dir, key, setup.turntable_axis)?;
            let size = (key.meta.width as usize, key.meta.height as usize);
            // One view per camera is kept: a view's frames come one after another.
            let cached = planes
                .entry(camera)
                .or_insert_with(|| (i64::MIN, (0, 0), Vec::new()));
            if (cached.0, cached.1) != (table_key, size) {
                *cached = (table_key, size, plane_pixels(geometry, table, size, radius));
            }
            let plane = &cached.2;
            let response = camera_response(setup.response, &key.camera)?;
            let (hdr, _) =
                merge_capture(&reader, key, response).map_err(|e| ProcessingError::Dataset {
                    run: run_dir.display().to_string(),
                    message: format!(
                        "capture {} (camera {}): {e}",
                        key.frames[0].path, key.camera
                    ),
                })?;
            Ok(line_frame(&hdr.rgb, &hdr.state, plane, channel, &options))
        };
        // The reference: φ and the line's width per camera.
        let mut reference_lines = BTreeMap::new();
        for key in references {
            let found = line_of(key, &mut planes)?.and_then(|l| reference_line(&l, &options));
            match found {
                Ok((integral, width)) => {
                    reference_lines.insert(
                        key.camera.clone(),
                        ReferenceLine {
                            phi: std::f64::consts::PI / albedo * integral,
                            width_mm: width,
                        },
                    );
                }
                Err(why) => left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: format!("reference: {why}"),
                }),
            }
        }
        let mut widths: Vec<f64> = reference_lines.values().map(|r| r.width_mm).collect();
        widths.sort_by(f64::total_cmp);
        let Some(&line_width_mm) = widths.get(widths.len() / 2) else {
            return Err(ProcessingError::IllPosed {
                what: "laser power calibration",
                why: format!(
                    "no camera saw the {nm} nm line on the reference `{}`: {}",
                    setup.reference.fixture,
                    left_out
                        .iter()
                        .map(|l| format!("{}: {}", l.frame, l.why))
                        .collect::<Vec<_>>()
                        .join("; ")
                ),
            });
        };
        // The sample's lines, pooled and per camera.
        let c_eta = hemispherical_transmittance(options.eta);
        let t_in = fresnel_transmittance(1.0, options.eta);
        let mut pooled = Bins::default();
        let mut per_camera: BTreeMap<String, Bins> = BTreeMap::new();
        let mut frames_used = 0;
        // Every usable pixel's (distance, value), for the re-render.
        let mut seen: Vec<(f64, f64)> = Vec::new();
        for key in samples {
            let Some(reference) = reference_lines.get(&key.camera) else {
                left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: "its camera has no reference line".into(),
                });
                continue;
            };
            let line = match line_of(key, &mut planes)? {
                Ok(l) => l,
                Err(why) => {
                    left_out.push(LeftOut {
                        frame: key.frames[0].path.clone(),
                        why,
                    });
                    continue;
                }
            };
            frames_used += 1;
            let mut view = if setup.exit {
                views.get_mut(&view_of(&run_dir, key, setup.turntable_axis)?.0)
            } else {
                None
            };
            let bins = per_camera.entry(key.camera.clone()).or_default();
            for p in &line.pixels {
                if p.s.abs() > options.window_mm || p.across_mm > options.max_footprint_mm {
                    continue;
                }
                let t_out = fresnel_transmittance(p.cos_out, options.eta);
                let v = std::f64::consts::PI * c_eta * p.radiance / (t_in * t_out * reference.phi);
                pooled.add(options.bin_mm, p.s, v, p);
                bins.add(options.bin_mm, p.s, v, p);
                if !(p.clipped || p.black) {
                    seen.push((p.s, v));
                    if let Some(view) = view.as_mut() {
                        view.pixels.push((p.index, p.s, v));
                    }
                }
            }
        }
        let profile = pooled.profile(options.bin_mm);
        let (fit, core_mm) =
            fit_bins(&profile, &options, line_width_mm).map_err(|e| ProcessingError::IllPosed {
                what: "dipole fit",
                why: format!("{nm} nm on `{fixture}`: {e}"),
            })?;
        let cameras = per_camera
            .iter()
            .map(|(camera, bins)| {
                let fit = fit_bins(&bins.profile(options.bin_mm), &options, line_width_mm)
                    .map(|(f, _)| f)
                    .map_err(|e| e.to_string());
                (camera.clone(), fit)
            })
            .collect();
        let rerender = rerender(&seen, &fit, options.eta, line_width_mm, core_mm);
        let product = DipoleProduct {
            colour_nm: nm,
            channel,
            fixture,
            reference: (setup.reference.fixture.to_string(), albedo),
            reference_lines,
            eta: options.eta,
            line_width_mm,
            core_mm,
            profile,
            fit: fit.clone(),
            cameras,
            rerender,
            frames_used,
            left_out,
        };
        let bytes = serde_json::to_vec_pretty(&product).map_err(|e| ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!("dipole product of {nm} nm: {e}"),
        })?;
        let medium = DipoleMedium {
            alpha_p: fit.alpha_p,
            sigma_t_p: fit.sigma_t_p,
            eta: options.eta,
        };
        for (k, view) in &views {
            let maps = exit_maps(view, &medium, line_width_mm, core_mm);
            let made = exit_new(k, view);
            let metadata = json!({
                "camera": k.0,
                "colour_nm": nm,
                "channels": {
                    "exit": "light leaving each point over what the fitted homogeneous medium sends (the mesostructure's exit function); 0 where no line lit it",
                    "weight": "the fitted medium's light summed over the lines, over its largest in the map: how well the point was lit",
                },
            })
            .to_string();
            let (w, h) = view.size;
            let exr = encode_exr_planes(
                &made.file_name,
                w as u32,
                h as u32,
                &["exit".to_string(), "weight".to_string()],
                &maps,
                &metadata,
            )
            .map_err(dataset_err(&run_dir))?;
            store.write(made, &exr).map_err(dataset_err(&run_dir))?;
            summary.exit_written += 1;
        }
        store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
        summary.written += 1;
        summary.fits.push((nm, fit, rerender));
    }
    progress(total, total);
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn the_exit_function_is_the_light_sent_over_the_fitted_medium_s() {
        // Pixel k sits 0.1·k mm from one line and 0.1·k + 3 mm from another; it sends 70 % of
        // what the medium predicts. Beyond the core and where lit, the exit function is 0.7.
        let medium = DipoleMedium {
            alpha_p: 0.6,
            sigma_t_p: 1.2,
            eta: 1.3,
        };
        let mut pixels = Vec::new();
        for k in 0..100 {
            for offset in [0.0, 3.0] {
                let s = 0.1 * k as f64 + offset;
                pixels.push((k, s, 0.7 * blurred_profile(&medium, s, 0.2)));
            }
        }
        let view = ExitView {
            size: (100, 1),
            table_deg: 0.0,
            truth_frame: String::new(),
            pixels,
        };
        let maps = exit_maps(&view, &medium, 0.2, 0.8);
        for k in 0..100 {
            let (exit, weight) = (maps[2 * k], maps[2 * k + 1]);
            assert!((0.0..=1.0).contains(&weight), "{k}: {weight}");
            if weight >= EXIT_MIN_WEIGHT as f32 {
                assert!((exit - 0.7).abs() < 1e-5, "{k}: {exit}");
            } else {
                assert_eq!(exit, 0.0, "{k}: unlit, {weight}");
            }
        }
        // Inside the core only the far line lights the pixel; far out, nothing does.
        assert!(maps[1] > 0.0 && maps[2 * 99 + 1] < EXIT_MIN_WEIGHT as f32);
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
