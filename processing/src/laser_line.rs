//! Finding a laser line in a frame (seed 004 §3.3, §4.4): the image is smoothed by a small
//! Gaussian, every column (or row) is scanned across the line for its brightest sample, and
//! a sample counts as the line only where it stands above the frame's background by a
//! multiple of the frame's own noise (measured from neighbouring-pixel differences, so a dim
//! frame and a noisy one get the thresholds they need, not a fixed number). The peak is then
//! placed to a fraction of a pixel by one of three methods, compared in the tests and the
//! benchmark: the intensity centroid, a Gaussian through the three samples about the maximum
//! (a parabola through their logarithms; on a broad
//! line the three samples are spread over its half-width), or a parabola through the samples themselves.
//! A line that saturates the sensor has a flat top whose maximum says nothing: its peak is
//! the middle of the saturated run, whatever the method.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::gray_image::GrayImage;

/// Which way the image is scanned across the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ScanAxis {
    /// Each column is scanned along y: for a line that runs roughly along x.
    Columns,
    /// Each row is scanned along x: for a line that runs roughly along y.
    Rows,
}

/// How the peak is placed between pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PeakMethod {
    /// Intensity-weighted mean over the samples above half the line's height.
    Centroid,
    /// A Gaussian through three samples about the maximum (neighbours, or on a broad line
    /// samples half its half-width apart).
    Gaussian,
    /// A parabola through the three samples about the maximum.
    Parabolic,
}

/// Settings of the line search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LineOptions {
    /// σ of the Gaussian smoothing, pixels (0: none).
    pub smoothing_px: f64,
    /// How many noise σ above the background a sample must stand to count as the line.
    pub threshold_sigmas: f64,
    /// How the peak is placed between pixels.
    pub method: PeakMethod,
    /// The sensor's clipping level in the image's units, if known: samples at or above it
    /// are saturated.
    pub saturation: Option<f32>,
}

impl Default for LineOptions {
    fn default() -> LineOptions {
        LineOptions {
            smoothing_px: 1.0,
            threshold_sigmas: 8.0,
            method: PeakMethod::Gaussian,
            saturation: None,
        }
    }
}

/// The line's position in one column (or row).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LinePoint {
    /// The column (or row) index.
    pub along: usize,
    /// The peak's position across the line, pixels (pixel centres at integers).
    pub across: f64,
    /// The peak's height above the background (smoothed image).
    pub height: f32,
    /// Whether the raw samples at the peak were saturated.
    pub saturated: bool,
}

/// The line found in a frame and the thresholds it was found with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LineDetection {
    /// One point per column (or row) where the line stands above the threshold.
    pub points: Vec<LinePoint>,
    /// Background level (median of the frame).
    pub background: f64,
    /// Noise σ of the raw frame.
    pub noise: f64,
    /// Height above the background a smoothed sample needed to count as the line.
    pub threshold: f64,
}

/// Noise σ of a row-major image `width` wide from the median absolute difference of horizontal neighbours (robust
/// to the line and to edges, which touch few pixels): σ = 1.4826 · MAD / √2.
pub fn noise_sigma(data: &[f32], width: usize) -> f64 {
    let diffs = data
        .chunks_exact(width.max(1))
        .flat_map(|row| row.windows(2).map(|w| (w[1] - w[0]).abs()));
    median_of(diffs) * 1.4826 / std::f64::consts::SQRT_2
}

/// The median of the finite values of `values`; 0 when there are none.
fn median_of(values: impl Iterator<Item = f32>) -> f64 {
    let mut values: Vec<f32> = values.filter(|v| v.is_finite()).collect();
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

/// How much a Gaussian of `sigma` pixels lowers white noise's σ (2-D, as [`GrayImage::gaussian`]
/// applies it): the root of the sum of the squared kernel weights.
fn smoothing_gain(sigma: f64) -> f64 {
    if sigma <= 0.0 {
        return 1.0;
    }
    let radius = (3.0 * sigma).ceil().max(1.0) as i64;
    let k: Vec<f64> = (-radius..=radius)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    // Separable: the 2-D kernel's Σw² is the 1-D one's squared; its root is the 1-D Σw².
    k.iter().map(|v| (v / sum).powi(2)).sum::<f64>()
}

/// Finds the line in `image` scanning along `axis`. A frame without a line gives no points
/// (not an error); non-finite settings are an error.
pub fn detect_line(
    image: &GrayImage,
    axis: ScanAxis,
    options: &LineOptions,
) -> Result<LineDetection, ProcessingError> {
    let bad = |name, value, why| ProcessingError::BadParameter { name, value, why };
    if !(options.smoothing_px.is_finite() && (0.0..=20.0).contains(&options.smoothing_px)) {
        return Err(bad(
            "line smoothing",
            options.smoothing_px,
            "σ must be between 0 and 20 pixels",
        ));
    }
    if !(options.threshold_sigmas.is_finite() && options.threshold_sigmas > 0.0) {
        return Err(bad(
            "line threshold",
            options.threshold_sigmas,
            "the threshold must be a positive number of noise σ",
        ));
    }
    if image.data.len() != image.width * image.height {
        return Err(ProcessingError::SizeMismatch {
            index: 0,
            expected: image.width * image.height,
            got: image.data.len(),
        });
    }
    let smooth = if options.smoothing_px > 0.0 {
        image.gaussian(options.smoothing_px)
    } else {
        image.clone()
    };
    let background = median_of(image.data.iter().copied());
    let noise = noise_sigma(&image.data, image.width);
    // At least a hundredth of a unit, so a noise-free frame still needs the line to show.
    let threshold = (options.threshold_sigmas * noise * smoothing_gain(options.smoothing_px))
        .max(1e-2 * (1.0 + background.abs()));
    let (lines, length) = match axis {
        ScanAxis::Columns => (image.width, image.height),
        ScanAxis::Rows => (image.height, image.width),
    };
    let index = |line: usize, i: usize| match axis {
        ScanAxis::Columns => i * image.width + line,
        ScanAxis::Rows => line * image.width + i,
    };
    let mut points = Vec::new();
    let mut profile = vec![0.0f64; length];
    for line in 0..lines {
        for (i, p) in profile.iter_mut().enumerate() {
            let v = f64::from(smooth.data[index(line, i)]) - background;
            *p = if v.is_finite() { v } else { 0.0 };
        }
        let Some((peak, height)) = profile
            .iter()
            .copied()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            continue;
        };
        if height < threshold {
            continue;
        }
        let saturated_at = |i: usize| {
            options
                .saturation
                .is_some_and(|s| image.data[index(line, i)] >= s)
        };
        let saturated = saturated_at(peak);
        let across = if saturated {
            // The middle of the saturated run through the peak.
            let (mut lo, mut hi) = (peak, peak);
            while lo > 0 && saturated_at(lo - 1) {
                lo -= 1;
            }
            while hi + 1 < length && saturated_at(hi + 1) {
                hi += 1;
            }
            let raw: Vec<f64> = (0..length)
                .map(|i| f64::from(image.data[index(line, i)]) - background)
                .collect();
            saturated_centre(&raw, lo, hi)
        } else {
            match sub_pixel(&profile, peak, options.method) {
                Some(a) => a,
                None => continue,
            }
        };
        points.push(LinePoint {
            along: line,
            across,
            height: height as f32,
            saturated,
        });
    }
    Ok(LineDetection {
        points,
        background,
        noise,
        threshold,
    })
}

/// The centre of a line clipped over samples `lo..=hi` of the raw profile `p` (background
/// removed, not smoothed, so its flanks are the line's own): midway
/// between where its flanks cross half the clipped height, interpolated between samples, so
/// a symmetric line is placed to a fraction of a pixel however wide its plateau; the middle
/// of the plateau when a flank runs off the image.
fn saturated_centre(p: &[f64], lo: usize, hi: usize) -> f64 {
    let level = 0.5 * p[lo..=hi].iter().copied().fold(f64::INFINITY, f64::min);
    let middle = 0.5 * (lo + hi) as f64;
    if !(level.is_finite() && level > 0.0) {
        return middle;
    }
    // Where the flank crosses `level` between samples valued `a` (below) and `b` (above),
    // as a fraction of the step from `a`: in logarithms, in which a Gaussian tail is nearly
    // straight, when both are positive.
    let cross = |a: f64, b: f64| {
        if a > 0.0 {
            (level.ln() - a.ln()) / (b.ln() - a.ln())
        } else {
            (level - a) / (b - a)
        }
    };
    let left = (1..=lo)
        .rev()
        .find(|&i| p[i - 1] < level)
        .map(|i| (i - 1) as f64 + cross(p[i - 1], p[i]));
    let right = (hi..p.len() - 1)
        .find(|&i| p[i + 1] < level)
        .map(|i| (i + 1) as f64 - cross(p[i + 1], p[i]));
    match (left, right) {
        (Some(l), Some(r)) if (l + r).is_finite() => 0.5 * (l + r),
        _ => middle,
    }
}

/// The peak of `p` (background removed) about its maximum at `k`, by `method`; `None` at
/// the border, where one side of the line is missing.
fn sub_pixel(p: &[f64], k: usize, method: PeakMethod) -> Option<f64> {
    if k == 0 || k + 1 >= p.len() {
        return None;
    }
    let (a, b, c) = (p[k - 1], p[k], p[k + 1]);
    let offset = match method {
        PeakMethod::Parabolic => vertex(a, b, c),
        PeakMethod::Gaussian => {
            // The logarithm of a Gaussian is a parabola at any spacing: on a broad line,
            // samples half its half-width apart see more curvature than neighbours do, and
            // the noise moves the vertex less.
            let half = 0.5 * b;
            let (mut lo, mut hi) = (k, k);
            while lo > 0 && p[lo - 1] > half {
                lo -= 1;
            }
            while hi + 1 < p.len() && p[hi + 1] > half {
                hi += 1;
            }
            let step = ((k - lo).min(hi - k) / 2).max(1);
            if k < step || k + step >= p.len() {
                return None;
            }
            let (a, c) = (p[k - step], p[k + step]);
            let floor = 1e-6 * b.abs().max(1e-12);
            let offset = vertex(a.max(floor).ln(), b.max(floor).ln(), c.max(floor).ln());
            return Some(k as f64 + (step as f64 * offset).clamp(-0.5, 0.5));
        }
        PeakMethod::Centroid => {
            // The run of samples above half the maximum around it.
            let half = 0.5 * b;
            let mut lo = k;
            while lo > 0 && p[lo - 1] > half {
                lo -= 1;
            }
            let mut hi = k;
            while hi + 1 < p.len() && p[hi + 1] > half {
                hi += 1;
            }
            let (mut sum, mut moment) = (0.0, 0.0);
            for (i, &v) in p.iter().enumerate().take(hi + 1).skip(lo) {
                let w = v - half;
                sum += w;
                moment += w * i as f64;
            }
            if sum > 0.0 {
                moment / sum - k as f64
            } else {
                0.0
            }
        }
    };
    Some(k as f64 + offset.clamp(-0.5, 0.5))
}

/// The offset of the vertex of the parabola through (−1, a), (0, b), (1, c); 0 when flat.
fn vertex(a: f64, b: f64, c: f64) -> f64 {
    let curvature = a - 2.0 * b + c;
    if curvature < 0.0 && curvature.is_finite() {
        0.5 * (a - c) / curvature
    } else {
        0.0
    }
}

#[cfg(test)]
#[path = "laser_line_tests.rs"]
mod tests;
