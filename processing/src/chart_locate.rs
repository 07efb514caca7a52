//! Finding the colour checker in an image from where a camera's geometry says it is. The chart
//! layout ([`ChartLayout`]) is projected through the geometry at the capture's turntable angle;
//! a nominal geometry (the rig file's) can be off by tens of pixels (a camera half a degree off
//! its mount), and at grazing views a patch is a few pixels tall, so the projection is then
//! corrected in the image: the chart's reflectance pattern, sampled on a grid of chart points,
//! is matched against the image by normalised cross-correlation (NCC), first over integer
//! shifts within a search window for both orientations the chart can lie in, then refined to an
//! affine correction about the projected chart centre (shift, scale, shear, roll: what a small
//! pose error does to a small chart) by pattern search. With a calibrated geometry the
//! correction comes out near the identity, and its size is a quality figure of the geometry.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera_model::{CameraModel, Pose};
use crate::chart_layout::{ChartLayout, Orientation};
use crate::error::ProcessingError;
use crate::gray_image::GrayImage;

/// Settings of chart location.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LocateOptions {
    /// Largest shift searched between the projected and the imaged chart, as a fraction of
    /// the image width.
    pub search_fraction: f64,
    /// Lowest normalised cross-correlation between the chart's pattern and the image that
    /// counts as found.
    pub min_ncc: f64,
}

/// Search window for a nominal geometry: ±12 % of the image width (±1.3° on the built-in
/// rig's 11° lenses, beyond the ±0.5° and ±3 mm a camera sits off its mount).
pub const NOMINAL_SEARCH_FRACTION: f64 = 0.12;
/// Search window for a calibrated geometry: ±3 % of the image width (its residual error is
/// a fraction of a pixel; the window only guards against a camera knocked since).
pub const CALIBRATED_SEARCH_FRACTION: f64 = 0.03;

impl Default for LocateOptions {
    /// The settings for a nominal geometry.
    fn default() -> LocateOptions {
        LocateOptions {
            search_fraction: NOMINAL_SEARCH_FRACTION,
            min_ncc: 0.6,
        }
    }
}

impl LocateOptions {
    /// The settings for a calibrated geometry: a narrower search.
    pub fn calibrated() -> LocateOptions {
        LocateOptions {
            search_fraction: CALIBRATED_SEARCH_FRACTION,
            ..LocateOptions::default()
        }
    }
}

/// Where the chart was found: the correction that takes the geometry's projection onto the
/// image, `q' = centre + linear·(q − centre) + offset`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChartFit {
    /// How the chart lies on the turntable.
    pub orientation: Orientation,
    /// Where the geometry projects the chart's centre, pixels.
    pub centre_px: [f64; 2],
    /// Shift of the imaged chart from the projection, pixels.
    pub offset_px: [f64; 2],
    /// Linear part of the correction (the identity when the geometry is exact).
    pub linear: [[f64; 2]; 2],
    /// Normalised cross-correlation of the chart's pattern with the image at the fit.
    pub ncc: f64,
}

impl ChartFit {
    /// The corrected image position of projected point `q`.
    pub fn correct(&self, q: [f64; 2]) -> [f64; 2] {
        correct(self.centre_px, self.offset_px, &self.linear, q)
    }
}

fn correct(centre: [f64; 2], offset: [f64; 2], m: &[[f64; 2]; 2], q: [f64; 2]) -> [f64; 2] {
    let d = [q[0] - centre[0], q[1] - centre[1]];
    [
        centre[0] + m[0][0] * d[0] + m[0][1] * d[1] + offset[0],
        centre[1] + m[1][0] * d[0] + m[1][1] * d[1] + offset[1],
    ]
}

/// Image position of chart-plane point `p` (sample frame, z = 0).
fn project(model: &CameraModel, pose: &Pose, p: [f64; 2]) -> Option<[f64; 2]> {
    let q = model.project(pose, &Vector3::new(p[0], p[1], 0.0))?;
    (q.x.is_finite() && q.y.is_finite()).then_some([q.x, q.y])
}

/// Chart points on a grid `per_pitch` to a pitch over the patch grid, projected, with the
/// template value of each orientation.
struct Samples {
    image: Vec<[f64; 2]>,
    template: [Vec<f64>; 2],
}

fn samples(
    layout: &ChartLayout,
    model: &CameraModel,
    pose: &Pose,
    per_pitch: usize,
) -> Result<Samples, ProcessingError> {
    let [hx, hy] = layout.half_extent_mm();
    let step = layout.pitch_mm() / per_pitch as f64;
    let (nx, ny) = (
        (2.0 * hx / step).round() as usize,
        (2.0 * hy / step).round() as usize,
    );
    let mut out = Samples {
        image: Vec::with_capacity((nx + 1) * (ny + 1)),
        template: [Vec::new(), Vec::new()],
    };
    for i in 0..=nx {
        for j in 0..=ny {
            let p = [-hx + i as f64 * step, -hy + j as f64 * step];
            let q = project(model, pose, p).ok_or_else(|| ProcessingError::IllPosed {
                what: "chart location",
                why: "the chart lies behind the camera in the given geometry".into(),
            })?;
            out.image.push(q);
            for (k, o) in [Orientation::AsDrawn, Orientation::HalfTurn]
                .into_iter()
                .enumerate()
            {
                let c = o.apply(p);
                out.template[k].push(layout.luminance_at(c[0], c[1]));
            }
        }
    }
    Ok(out)
}

/// NCC of `template` with `image` sampled at the corrected `points`; −1 when fewer than 90 %
/// of the points fall inside the image or either side is flat.
fn ncc(
    image: &GrayImage,
    points: &[[f64; 2]],
    template: &[f64],
    centre: [f64; 2],
    offset: [f64; 2],
    m: &[[f64; 2]; 2],
) -> f64 {
    let (w, h) = (image.width as f64 - 1.0, image.height as f64 - 1.0);
    let (mut n, mut sv, mut svv, mut st, mut stt, mut svt) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (q, &t) in points.iter().zip(template) {
        let [x, y] = correct(centre, offset, m, *q);
        if !(x >= 0.0 && y >= 0.0 && x <= w && y <= h) {
            continue;
        }
        let v = f64::from(image.sample(x, y));
        if !v.is_finite() {
            continue;
        }
        n += 1;
        sv += v;
        svv += v * v;
        st += t;
        stt += t * t;
        svt += v * t;
    }
    finish_ncc(points.len(), n, [sv, svv, st, stt, svt])
}

/// Bilinear taps of projected points, for NCC at integer shifts: shifting by whole pixels
/// keeps each point's interpolation weights, so they are computed once.
struct Taps {
    /// Top-left pixel of each point's 2×2 neighbourhood.
    base: Vec<(i64, i64)>,
    /// Weights of the four neighbours (top-left, top-right, bottom-left, bottom-right).
    weights: Vec<[f32; 4]>,
    /// Smallest and largest base x and y.
    bounds: [i64; 4],
}

impl Taps {
    fn new(points: &[[f64; 2]]) -> Taps {
        let mut bounds = [i64::MAX, i64::MIN, i64::MAX, i64::MIN];
        let (base, weights) = points
            .iter()
            .map(|q| {
                let (x0, y0) = (q[0].floor(), q[1].floor());
                let (fx, fy) = ((q[0] - x0) as f32, (q[1] - y0) as f32);
                let b = (x0 as i64, y0 as i64);
                bounds = [
                    bounds[0].min(b.0),
                    bounds[1].max(b.0),
                    bounds[2].min(b.1),
                    bounds[3].max(b.1),
                ];
                let w = [
                    (1.0 - fx) * (1.0 - fy),
                    fx * (1.0 - fy),
                    (1.0 - fx) * fy,
                    fx * fy,
                ];
                (b, w)
            })
            .unzip();
        Taps {
            base,
            weights,
            bounds,
        }
    }

    /// NCC of `template` with `image` at the points shifted by `(dx, dy)` pixels; −1 as for
    /// [`ncc`].
    fn ncc(&self, image: &GrayImage, template: &[f64], dx: i64, dy: i64) -> f64 {
        let (w, h) = (image.width as i64, image.height as i64);
        let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x + 1 < w && y + 1 < h;
        let all_inside = inside(self.bounds[0] + dx, self.bounds[2] + dy)
            && inside(self.bounds[1] + dx, self.bounds[3] + dy);
        let data = &image.data;
        let (mut n, mut sv, mut svv, mut st, mut stt, mut svt) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
        for ((b, wt), &t) in self.base.iter().zip(&self.weights).zip(template) {
            let (x, y) = (b.0 + dx, b.1 + dy);
            if !all_inside && !inside(x, y) {
                continue;
            }
            let i = (y * w + x) as usize;
            let j = i + image.width;
            let v = f64::from(
                wt[0] * data[i] + wt[1] * data[i + 1] + wt[2] * data[j] + wt[3] * data[j + 1],
            );
            if !v.is_finite() {
                continue;
            }
            n += 1;
            sv += v;
            svv += v * v;
            st += t;
            stt += t * t;
            svt += v * t;
        }
        finish_ncc(self.base.len(), n, [sv, svv, st, stt, svt])
    }
}

/// The NCC from its sums `[Σv, Σv², Σt, Σt², Σvt]` over `n` of `total` points.
fn finish_ncc(total: usize, n: usize, sums: [f64; 5]) -> f64 {
    let [sv, svv, st, stt, svt] = sums;
    if (n as f64) < 0.9 * total as f64 || n < 2 {
        return -1.0;
    }
    let nf = n as f64;
    let var_v = svv - sv * sv / nf;
    let var_t = stt - st * st / nf;
    if !(var_v > 0.0 && var_t > 0.0) {
        return -1.0;
    }
    (svt - sv * st / nf) / (var_v * var_t).sqrt()
}

/// Largest departure of the linear correction from the identity the refinement may reach.
const MAX_LINEAR: f64 = 0.25;

/// Finds the chart in `image` (a luminance image of the capture, pixel centres at integers)
/// for a camera of `model` whose chart → camera pose is `pose`.
pub fn locate_chart(
    image: &GrayImage,
    model: &CameraModel,
    pose: &Pose,
    layout: &ChartLayout,
    options: &LocateOptions,
) -> Result<ChartFit, ProcessingError> {
    layout.check()?;
    if !(options.search_fraction.is_finite() && options.search_fraction >= 0.0) {
        return Err(ProcessingError::BadParameter {
            name: "search_fraction",
            value: options.search_fraction,
            why: "the chart search window must be a finite, non-negative fraction of the image width",
        });
    }
    if !(options.min_ncc.is_finite() && options.min_ncc <= 1.0) {
        return Err(ProcessingError::BadParameter {
            name: "min_ncc",
            value: options.min_ncc,
            why: "the lowest correlation accepted must be a finite number up to 1",
        });
    }
    let centre = project(model, pose, [0.0, 0.0]).ok_or_else(|| ProcessingError::IllPosed {
        what: "chart location",
        why: "the chart lies behind the camera in the given geometry".into(),
    })?;
    let coarse = samples(layout, model, pose, 8)?;
    let fine = samples(layout, model, pose, 16)?;
    let radius = (options.search_fraction * image.width as f64).ceil() as i64;
    // Integer shifts over the whole window, both orientations, on the coarse grid.
    let taps = Taps::new(&coarse.image);
    let mut best = (-2.0, 0usize, [0.0, 0.0]);
    for k in 0..2 {
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let s = taps.ncc(image, &coarse.template[k], dx, dy);
                if s > best.0 {
                    best = (s, k, [dx as f64, dy as f64]);
                }
            }
        }
    }
    let (_, k, start) = best;
    let score = |p: &[f64; 6]| {
        let m = [[1.0 + p[2], p[3]], [p[4], 1.0 + p[5]]];
        if p[2..].iter().any(|v| v.abs() > MAX_LINEAR) {
            return -2.0;
        }
        ncc(
            image,
            &fine.image,
            &fine.template[k],
            centre,
            [p[0], p[1]],
            &m,
        )
    };
    // Pattern search: each parameter a step either way, steps halved when none helps.
    let mut p = [start[0], start[1], 0.0, 0.0, 0.0, 0.0];
    let mut value = score(&p);
    let mut step = [1.0, 1.0, 0.004, 0.004, 0.004, 0.004];
    for _ in 0..2000 {
        let mut improved = false;
        for i in 0..6 {
            for sign in [1.0, -1.0] {
                let mut q = p;
                q[i] += sign * step[i];
                let v = score(&q);
                if v > value {
                    (p, value, improved) = (q, v, true);
                    break;
                }
            }
        }
        if !improved {
            step.iter_mut().for_each(|s| *s *= 0.5);
            if step[0] < 0.01 {
                break;
            }
        }
    }
    if value < options.min_ncc {
        return Err(ProcessingError::IllPosed {
            what: "chart location",
            why: format!(
                "the best match of the chart's pattern has correlation {value:.2} (at least {:.2} is needed), {:.0} px from where the geometry puts it; check that the chart lies flat and centred in view and has the size given, or widen the search",
                options.min_ncc,
                p[0].hypot(p[1])
            ),
        });
    }
    Ok(ChartFit {
        orientation: [Orientation::AsDrawn, Orientation::HalfTurn][k],
        centre_px: centre,
        offset_px: [p[0], p[1]],
        linear: [[1.0 + p[2], p[3]], [p[4], 1.0 + p[5]]],
        ncc: value,
    })
}

/// A located chart in one camera's image: the geometry's projection and its correction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedChart<'a> {
    /// The camera's intrinsics and distortion.
    pub model: &'a CameraModel,
    /// Chart → camera pose from the geometry ([`crate::rig_frame::sample_to_camera`]).
    pub pose: Pose,
    /// The chart's layout.
    pub layout: ChartLayout,
    /// The correction [`locate_chart`] found.
    pub fit: ChartFit,
}

impl PlacedChart<'_> {
    /// Image position of chart-frame point `p` (the chart's own frame, before orientation).
    pub fn image_of(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        project(self.model, &self.pose, self.fit.orientation.apply(p)).map(|q| self.fit.correct(q))
    }

    /// Indices (`y·width + x`) of the pixels of a `width × height` image whose centres lie
    /// in the central `core_fraction` (by side) of patch `index`.
    pub fn patch_pixels(
        &self,
        index: usize,
        core_fraction: f64,
        width: usize,
        height: usize,
    ) -> Vec<usize> {
        let c = self.layout.patch_centre(index);
        let h = 0.5 * core_fraction * self.layout.patch_mm();
        let mut quad = [[0.0; 2]; 4];
        for (corner, (sx, sy)) in
            quad.iter_mut()
                .zip([(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)])
        {
            match self.image_of([c[0] + sx * h, c[1] + sy * h]) {
                Some(q) => *corner = q,
                None => return Vec::new(),
            }
        }
        let lo = |a: usize| quad.iter().map(|q| q[a]).fold(f64::INFINITY, f64::min);
        let hi = |a: usize| quad.iter().map(|q| q[a]).fold(f64::NEG_INFINITY, f64::max);
        let (x0, x1) = (lo(0).ceil().max(0.0), hi(0).floor().min(width as f64 - 1.0));
        let (y0, y1) = (
            lo(1).ceil().max(0.0),
            hi(1).floor().min(height as f64 - 1.0),
        );
        if !(x0 <= x1 && y0 <= y1) {
            return Vec::new();
        }
        // Inside a convex quad: on the same side of all four edges.
        let side = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        let mut out = Vec::new();
        for y in (y0 as usize)..=(y1 as usize) {
            for x in (x0 as usize)..=(x1 as usize) {
                let p = [x as f64, y as f64];
                let s = [0, 1, 2, 3].map(|i| side(quad[i], quad[(i + 1) % 4], p));
                if s.iter().all(|v| *v >= 0.0) || s.iter().all(|v| *v <= 0.0) {
                    out.push(y * width + x);
                }
            }
        }
        out
    }
}
