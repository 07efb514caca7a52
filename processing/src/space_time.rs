//! Space-time analysis of a laser sweep (Curless & Levoy 1995, cited by seed 004 §4.4): as
//! the laser sheet steps across the sample, every pixel sees the light rise and fall; the
//! time of its peak, placed between frames, says which sheet lit the surface point the pixel
//! sees, independently of the point's reflectance or the line's width in the image. Frames
//! stream through one at a time, so memory is a few values per pixel whatever the sweep's
//! length. A pixel never lit above its background by the frame noise's threshold has no
//! time (−1: occluded or out of the sweep), as has one whose peak is the sweep's first or
//! last frame (half a profile cannot be placed).

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::laser_line::noise_sigma;

/// The time a pixel without a measured peak gets.
pub const NO_TIME: f32 = -1.0;

/// Settings of the peak-time search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpaceTimeOptions {
    /// How many noise σ above its background a pixel's peak must stand.
    pub threshold_sigmas: f64,
    /// The sensor's clipping level in the frames' units, if known.
    pub saturation: Option<f32>,
    /// A peak dimmer than this fraction of the brightest within [`DIM_WINDOW_PX`] pixels is
    /// light from elsewhere, not the line ([`drop_dim_peaks`]); 0 keeps every peak.
    pub relative_floor: f32,
}

impl Default for SpaceTimeOptions {
    fn default() -> SpaceTimeOptions {
        SpaceTimeOptions {
            threshold_sigmas: 8.0,
            saturation: None,
            relative_floor: 0.25,
        }
    }
}

/// Half the side of the window [`drop_dim_peaks`] compares a peak with, pixels.
pub const DIM_WINDOW_PX: usize = 15;

/// Unsets the peaks dimmer than `floor` times the brightest peak within `half` pixels (a
/// square window): a point in the laser's shadow lit by the line's reflection from a facing
/// wall (a groove, a cavity) peaks when the line is elsewhere, and no threshold on the
/// noise can tell it, however short the shutter; beside the directly lit surface it is dim.
/// The seed suppresses such light by underexposing it; this is that in relative terms.
/// Returns the peaks unset.
pub fn drop_dim_peaks(times: &mut PeakTimes, half: usize, floor: f32) -> usize {
    let (w, h) = (times.width, times.height);
    if floor.is_nan() || floor <= 0.0 || w == 0 || h == 0 {
        return 0;
    }
    // The window maximum, separably: along rows, then along columns.
    let mut rows = vec![0.0f32; w * h];
    for y in 0..h {
        let line = &times.height_above[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(half), (x + half).min(w - 1));
            rows[y * w + x] = line[a..=b].iter().copied().fold(0.0, f32::max);
        }
    }
    let mut dropped = 0;
    for x in 0..w {
        for y in 0..h {
            let i = y * w + x;
            if times.time[i] == NO_TIME {
                continue;
            }
            let (a, b) = (y.saturating_sub(half), (y + half).min(h - 1));
            let brightest = (a..=b).map(|yy| rows[yy * w + x]).fold(0.0, f32::max);
            if times.height_above[i] < floor * brightest {
                times.time[i] = NO_TIME;
                times.height_above[i] = 0.0;
                times.saturated[i] = false;
                dropped += 1;
            }
        }
    }
    dropped
}

/// Per pixel, the state of the running search.
#[derive(Debug, Clone, Copy, Default)]
struct Running {
    max: f32,
    at: u32,
    before: f32,
    after: f32,
    sum: f64,
    /// Frames at the saturation level in the run through the maximum (0: not saturated).
    saturated_run: u32,
    /// Whether the run of saturated frames is still going.
    in_run: bool,
}

/// The peak times of a sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct PeakTimes {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Frame index of each pixel's peak, fractional; [`NO_TIME`] where unknown.
    pub time: Vec<f32>,
    /// The peak's height above the pixel's background; 0 where unknown.
    pub height_above: Vec<f32>,
    /// Whether the peak was saturated (placed at the middle of its saturated frames).
    pub saturated: Vec<bool>,
    /// Noise σ of the frames (median over frames of each frame's spatial estimate).
    pub noise: f64,
}

/// A sweep being analysed: push its frames in order, then [`SpaceTime::finish`].
#[derive(Debug, Clone)]
pub struct SpaceTime {
    width: usize,
    height: usize,
    options: SpaceTimeOptions,
    pixels: Vec<Running>,
    previous: Vec<f32>,
    frames: u32,
    noises: Vec<f64>,
}

impl SpaceTime {
    /// A sweep of `width × height` frames.
    pub fn new(
        width: usize,
        height: usize,
        options: SpaceTimeOptions,
    ) -> Result<SpaceTime, ProcessingError> {
        if !(options.threshold_sigmas.is_finite() && options.threshold_sigmas > 0.0) {
            return Err(ProcessingError::BadParameter {
                name: "space-time threshold",
                value: options.threshold_sigmas,
                why: "the threshold must be a positive number of noise σ",
            });
        }
        Ok(SpaceTime {
            width,
            height,
            options,
            pixels: vec![Running::default(); width * height],
            previous: vec![0.0; width * height],
            frames: 0,
            noises: Vec::new(),
        })
    }

    /// Adds the sweep's next frame (the laser channel's intensities, row-major).
    pub fn push(&mut self, frame: &[f32]) -> Result<(), ProcessingError> {
        if frame.len() != self.width * self.height {
            return Err(ProcessingError::SizeMismatch {
                index: self.frames as usize,
                expected: self.width * self.height,
                got: frame.len(),
            });
        }
        let t = self.frames;
        let saturation = self.options.saturation;
        for ((r, &raw), prev) in self.pixels.iter_mut().zip(frame).zip(&mut self.previous) {
            let v = if raw.is_finite() { raw } else { 0.0 };
            r.sum += f64::from(v);
            let saturated = saturation.is_some_and(|s| v >= s);
            if t > 0 && r.at == t - 1 {
                r.after = v;
            }
            if r.in_run {
                if saturated {
                    r.saturated_run += 1;
                } else {
                    r.in_run = false;
                }
            }
            if t == 0 || v > r.max {
                r.max = v;
                r.at = t;
                r.before = *prev;
                r.after = v;
                r.saturated_run = u32::from(saturated);
                r.in_run = saturated;
            }
            *prev = v;
        }
        self.noises.push(noise_sigma(frame, self.width));
        self.frames += 1;
        Ok(())
    }

    /// Each pixel's peak time. A sweep of fewer than 3 frames cannot place a peak.
    pub fn finish(self) -> Result<PeakTimes, ProcessingError> {
        if self.frames < 3 {
            return Err(ProcessingError::IllPosed {
                what: "space-time analysis",
                why: format!(
                    "the sweep has {} frames; a peak needs a frame on each side",
                    self.frames
                ),
            });
        }
        let mut noises = self.noises;
        noises.sort_by(f64::total_cmp);
        let noise = noises[noises.len() / 2];
        let threshold = (self.options.threshold_sigmas * noise) as f32;
        let n = self.width * self.height;
        let mut out = PeakTimes {
            width: self.width,
            height: self.height,
            time: vec![NO_TIME; n],
            height_above: vec![0.0; n],
            saturated: vec![false; n],
            noise,
        };
        let last = self.frames - 1;
        let others = f64::from(self.frames - 3);
        for (i, r) in self.pixels.iter().enumerate() {
            // The background: the mean of the frames away from the peak.
            let background = if others > 0.0 {
                ((r.sum - f64::from(r.max) - f64::from(r.before) - f64::from(r.after)) / others)
                    as f32
            } else {
                r.before.min(r.after)
            };
            let height = r.max - background;
            if height.is_nan() || height <= threshold.max(1e-6) {
                continue;
            }
            let time = if r.saturated_run > 0 {
                // The middle of the saturated frames from the first one on.
                out.saturated[i] = true;
                r.at as f32 + 0.5 * (r.saturated_run - 1) as f32
            } else if r.at == 0 || r.at == last {
                continue;
            } else {
                // A Gaussian in time: a parabola through the logarithms above background.
                let floor = 1e-6 * height;
                let (a, b, c) = (
                    (r.before - background).max(floor).ln(),
                    height.ln(),
                    (r.after - background).max(floor).ln(),
                );
                let curvature = a - 2.0 * b + c;
                let offset = if curvature < 0.0 {
                    (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                r.at as f32 + offset
            };
            out.time[i] = time;
            out.height_above[i] = height;
        }
        Ok(out)
    }
}

#[cfg(test)]
#[path = "space_time_tests.rs"]
mod tests;
