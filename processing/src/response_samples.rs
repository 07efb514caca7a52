//! The pixels a response fit uses (Debevec–Malik): spread over the scene's tones so every part
//! of the DN range is observed, each in a flat neighbourhood (edges turn misregistration and
//! blur into errors), each seen in range by at least two exposures (one says nothing about g).

use crate::error::ProcessingError;
use crate::weight::DnRange;

/// One channel of one exposure of a static scene.
#[derive(Debug, Clone, PartialEq)]
pub struct BracketImage {
    /// Exposure time in seconds (relative times suffice).
    pub exposure_s: f64,
    /// Digital numbers, row-major, `width × height`.
    pub dn: Vec<u16>,
}

/// One channel of a bracket: the same static view at several exposure times.
#[derive(Debug, Clone, PartialEq)]
pub struct Bracket {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// The exposures, in any order.
    pub images: Vec<BracketImage>,
}

impl Bracket {
    /// Checks sizes and exposure times, and that at least two times differ by 10 % or more.
    pub fn check(&self) -> Result<(), ProcessingError> {
        self.check_images()?;
        let mut times: Vec<f64> = self.images.iter().map(|i| i.exposure_s).collect();
        times.sort_by(f64::total_cmp);
        let mut distinct = 0;
        let mut last = 0.0;
        for t in times {
            if distinct == 0 || t > last * 1.1 {
                distinct += 1;
                last = t;
            }
        }
        if distinct < 2 {
            return Err(ProcessingError::TooFewExposures { distinct });
        }
        Ok(())
    }

    /// Checks that there is an image, every image has `width × height` pixels and a finite
    /// positive exposure time.
    pub fn check_images(&self) -> Result<(), ProcessingError> {
        if self.images.is_empty() {
            return Err(ProcessingError::TooFewExposures { distinct: 0 });
        }
        let n = self.width * self.height;
        for (index, image) in self.images.iter().enumerate() {
            if image.dn.len() != n {
                return Err(ProcessingError::SizeMismatch {
                    index,
                    expected: n,
                    got: image.dn.len(),
                });
            }
            if !(image.exposure_s.is_finite() && image.exposure_s > 0.0) {
                return Err(ProcessingError::BadExposure {
                    index,
                    time_s: image.exposure_s,
                });
            }
        }
        Ok(())
    }
}

/// Half-size of the square window a sample averages: 5×5 pixels, so noise and DN rounding
/// shrink fivefold while the window still fits inside a colour-checker patch.
pub const SAMPLE_RADIUS: usize = 2;

/// A flat window of the scene seen through every exposure: its mean DN per image.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Index of the window's centre pixel.
    pub pixel: usize,
    /// Mean DN of the window in each image of the bracket, in the bracket's order.
    pub dn: Vec<f64>,
}

/// Chooses up to `PER_BIN` flat windows in each of `count` tone bins of `bracket` for the response fit, spread evenly over
/// the scene's log radiance, the flattest of each bin, each in range in at least two
/// exposures. Deterministic.
pub fn select_samples(
    bracket: &Bracket,
    range: DnRange,
    count: usize,
) -> Result<Vec<Sample>, ProcessingError> {
    bracket.check()?;
    let (w, h, r) = (bracket.width, bracket.height, SAMPLE_RADIUS);
    // Longest exposures first: the first in range gives the best tone estimate.
    let mut order: Vec<usize> = (0..bracket.images.len()).collect();
    order.sort_by(|&a, &b| {
        bracket.images[b]
            .exposure_s
            .total_cmp(&bracket.images[a].exposure_s)
    });

    struct Candidate {
        pixel: usize,
        tone: f64,
        /// Largest minus smallest DN of the window in that exposure.
        spread: f64,
    }
    let window = |image: &BracketImage, x: usize, y: usize| {
        let (mut sum, mut lo, mut hi) = (0.0, f64::MAX, f64::MIN);
        for yy in y - r..=y + r {
            for xx in x - r..=x + r {
                let v = f64::from(image.dn[yy * w + xx]);
                sum += v;
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        (sum / ((2 * r + 1) * (2 * r + 1)) as f64, lo, hi)
    };
    // The window's noise from the median absolute difference of neighbouring pixels, which an
    // edge through the window barely moves (it changes a minority of the differences).
    let noise = |image: &BracketImage, x: usize, y: usize| {
        let mut diffs = Vec::with_capacity(4 * (2 * r + 1) * r);
        for yy in y - r..=y + r {
            for xx in x - r..=x + r {
                let v = i32::from(image.dn[yy * w + xx]);
                if xx < x + r {
                    diffs.push((i32::from(image.dn[yy * w + xx + 1]) - v).unsigned_abs());
                }
                if yy < y + r {
                    diffs.push((i32::from(image.dn[(yy + 1) * w + xx]) - v).unsigned_abs());
                }
            }
        }
        diffs.sort_unstable();
        // MAD of a difference → σ of a pixel: ×1.4826 (Gaussian), ÷√2 (a difference of two).
        f64::from(diffs[diffs.len() / 2]) * 1.4826 / std::f64::consts::SQRT_2
    };
    let mut candidates = Vec::new();
    let step = (r + 1).max(1);
    for y in (r..h.saturating_sub(r)).step_by(step) {
        for x in (r..w.saturating_sub(r)).step_by(step) {
            // The tone comes from the longest exposure that sees the window in range.
            let mut best: Option<(f64, f64, f64, bool)> = None; // mean, spread, time, flat
            let mut in_range = 0;
            for &i in &order {
                let image = &bracket.images[i];
                let (mean, lo, hi) = window(image, x, y);
                if range.weight(lo) > 0.0 && range.weight(hi) > 0.0 {
                    in_range += 1;
                    if best.is_none() {
                        // Flat: no wider than the window's own noise allows, plus rounding.
                        let flat = hi - lo <= FLAT_SIGMAS * noise(image, x, y) + 2.0;
                        best = Some((mean, hi - lo, image.exposure_s, flat));
                    }
                }
            }
            let Some((mean, spread, exposure_s, true)) = best else {
                continue;
            };
            if in_range < 2 {
                continue;
            }
            candidates.push(Candidate {
                pixel: y * w + x,
                tone: (mean - range.lo).max(1.0).ln() - exposure_s.ln(),
                spread,
            });
        }
    }
    if candidates.is_empty() || count == 0 {
        return Ok(Vec::new());
    }
    let (lo, hi) = candidates.iter().fold((f64::MAX, f64::MIN), |(lo, hi), c| {
        (lo.min(c.tone), hi.max(c.tone))
    });
    let span = (hi - lo).max(1e-12);
    let mut bins: Vec<Vec<&Candidate>> = vec![Vec::new(); count];
    for c in &candidates {
        let bin = (((c.tone - lo) / span) * count as f64).floor() as usize;
        bins[bin.min(count - 1)].push(c);
    }
    Ok(bins
        .into_iter()
        .flat_map(|mut bin| {
            bin.sort_by(|a, b| a.spread.total_cmp(&b.spread));
            bin.truncate(PER_BIN);
            bin
        })
        .map(|c| {
            let (x, y) = (c.pixel % w, c.pixel / w);
            Sample {
                pixel: c.pixel,
                dn: bracket.images.iter().map(|i| window(i, x, y).0).collect(),
            }
        })
        .collect())
}

/// Windows kept per tone bin (the flattest): several windows of one patch average its noise.
pub const PER_BIN: usize = 4;

/// A flat window's spread (largest minus smallest DN) stays within this many noise σ: the
/// range of 25 Gaussian samples exceeds 8σ with probability below 10⁻⁶.
const FLAT_SIGMAS: f64 = 8.0;

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp_bracket() -> Bracket {
        // Four flat patches of different radiance, each 10×10, side by side.
        let (w, h) = (40, 10);
        let radiance = |x: usize| [40.0, 200.0, 800.0, 3200.0][x / 10];
        let images = [0.25, 1.0, 4.0]
            .iter()
            .map(|&t| BracketImage {
                exposure_s: t,
                dn: (0..w * h)
                    .map(|i| (radiance(i % w) * t).min(4095.0) as u16)
                    .collect(),
            })
            .collect();
        Bracket {
            width: w,
            height: h,
            images,
        }
    }

    #[test]
    fn samples_cover_every_patch_seen_twice_and_avoid_edges() {
        let b = ramp_bracket();
        let range = DnRange::new(5.0, 4000.0).unwrap();
        let picked = select_samples(&b, range, 8).unwrap();
        let patches: std::collections::BTreeSet<usize> =
            picked.iter().map(|s| (s.pixel % b.width) / 10).collect();
        // Every patch is in range at two exposures at least (the brightest clips at 4 s).
        assert_eq!(patches, [0, 1, 2, 3].into_iter().collect());
        for s in picked {
            let x = s.pixel % b.width;
            assert!(
                (2..=7).contains(&(x % 10)),
                "window at {x} crosses a patch edge"
            );
            let patch: f64 = [40.0, 200.0, 800.0, 3200.0][x / 10];
            assert_eq!(s.dn, vec![patch * 0.25, patch, (patch * 4.0).min(4095.0)]);
        }
    }

    #[test]
    fn a_bracket_of_one_time_is_refused() {
        let mut b = ramp_bracket();
        for i in &mut b.images {
            i.exposure_s = 1.0;
        }
        assert_eq!(
            select_samples(&b, DnRange::new(10.0, 4000.0).unwrap(), 8),
            Err(ProcessingError::TooFewExposures { distinct: 1 })
        );
        b.images[1].exposure_s = f64::NAN;
        assert!(matches!(
            b.check(),
            Err(ProcessingError::BadExposure { index: 1, .. })
        ));
        b.images[1].dn.pop();
        assert!(matches!(
            b.check(),
            Err(ProcessingError::SizeMismatch { index: 1, .. })
        ));
    }
}
