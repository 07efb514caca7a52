//! A view's depth images merged over laser directions (seed 004 eqs 4.44–4.45): at each pixel
//! D = Σ τᵢ Dᵢ / Σ τᵢ with τᵢ = 0 where direction i knows no depth and τᵢ = νᵢ (the
//! triangulation volume, [`crate::laser_sheet::triangulation_volume`]) elsewhere. One change
//! to the seed's average, for the pixels a direction gets wrong (a point in the laser's shadow
//! lit by a neighbour's reflection has a peak, at the wrong time): only the directions within
//! `agree_footprints` pixel footprints of the weighted median are averaged, and a pixel where
//! those hold no more than half the weight, or where just two directions disagree, is a
//! conflict: unknown, like a pixel no direction saw. Small islands of depth cut off from the
//! measured surface are dropped too (the same reflections, where no direction contradicts
//! them). Unknown pixels inside the sample are then filled from their neighbours
//! (inpainting), and the hole fraction says how many there were.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::ray_plane::NO_DEPTH;

/// One laser direction's depth image of the view and its weight ν.
#[derive(Debug, Clone, Copy)]
pub struct DepthLayer<'a> {
    /// Distance along each pixel's ray, mm; negative where unknown.
    pub depth: &'a [f32],
    /// ν of the direction, mm³ (≤ 0: the direction cannot triangulate and is left out).
    pub nu: f64,
}

/// Settings of the merge.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MergeOptions {
    /// Directions within this many pixel footprints of the weighted median agree.
    pub agree_footprints: f64,
}

impl Default for MergeOptions {
    fn default() -> MergeOptions {
        MergeOptions {
            agree_footprints: 2.0,
        }
    }
}

/// Where a merged pixel's depth came from.
pub mod source {
    /// No depth: no direction saw it, they conflicted, or it lies outside the sample.
    pub const NONE: u8 = 0;
    /// Filled from its neighbours.
    pub const INPAINTED: u8 = 1;
    /// Measured by one direction or more that agreed.
    pub const MEASURED: u8 = 2;
}

/// The merged depth of a view.
#[derive(Debug, Clone, PartialEq)]
pub struct MergedDepth {
    /// Image width, pixels.
    pub width: usize,
    /// Distance along each pixel's ray, mm; [`NO_DEPTH`] where unknown.
    pub depth: Vec<f32>,
    /// [`source`] of each pixel.
    pub source: Vec<u8>,
    /// Directions averaged at each pixel.
    pub agreeing: Vec<u8>,
    /// Σ τ of the directions averaged, mm³.
    pub weight: Vec<f32>,
    /// Pixels where directions saw a depth but did not agree.
    pub conflicts: usize,
}

/// Merges `layers` (each `width`×`height`); `fx` is the camera's focal length in pixels (a
/// pixel footprint at distance d is d / fx).
pub fn merge_layers(
    width: usize,
    height: usize,
    layers: &[DepthLayer<'_>],
    fx: f64,
    options: &MergeOptions,
) -> Result<MergedDepth, ProcessingError> {
    let n = width * height;
    if let Some((index, layer)) = layers.iter().enumerate().find(|(_, l)| l.depth.len() != n) {
        return Err(ProcessingError::SizeMismatch {
            index,
            expected: n,
            got: layer.depth.len(),
        });
    }
    if !(fx.is_finite() && fx > 0.0) {
        return Err(ProcessingError::BadParameter {
            name: "focal length",
            value: fx,
            why: "the merge needs the camera's focal length in pixels, > 0",
        });
    }
    if !(options.agree_footprints.is_finite() && options.agree_footprints > 0.0) {
        return Err(ProcessingError::BadParameter {
            name: "agree_footprints",
            value: options.agree_footprints,
            why: "directions agree within a positive number of pixel footprints",
        });
    }
    let mut merged = MergedDepth {
        width,
        depth: vec![NO_DEPTH; n],
        source: vec![source::NONE; n],
        agreeing: vec![0; n],
        weight: vec![0.0; n],
        conflicts: 0,
    };
    let mut seen: Vec<(f64, f64)> = Vec::with_capacity(layers.len());
    for i in 0..n {
        seen.clear();
        seen.extend(
            layers
                .iter()
                .filter(|l| l.nu > 0.0 && l.nu.is_finite())
                .map(|l| (f64::from(l.depth[i]), l.nu))
                .filter(|(d, _)| *d >= 0.0 && d.is_finite()),
        );
        if seen.is_empty() {
            continue;
        }
        seen.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = seen.iter().map(|s| s.1).sum();
        let mut running = 0.0;
        let median = seen
            .iter()
            .find(|s| {
                running += s.1;
                running >= 0.5 * total
            })
            .map_or(seen[0].0, |s| s.0);
        let tolerance = options.agree_footprints * median / fx;
        let (mut sum, mut weight, mut count) = (0.0, 0.0, 0u8);
        for &(d, nu) in &seen {
            if (d - median).abs() <= tolerance {
                sum += nu * d;
                weight += nu;
                count = count.saturating_add(1);
            }
        }
        let two_disagree = seen.len() == 2 && count < 2;
        if weight <= 0.5 * total || two_disagree {
            merged.conflicts += 1;
            continue;
        }
        merged.depth[i] = (sum / weight) as f32;
        merged.source[i] = source::MEASURED;
        merged.agreeing[i] = count;
        merged.weight[i] = weight as f32;
    }
    Ok(merged)
}

/// Unmeasures the specks: connected groups (8-neighbours) of measured pixels smaller than
/// `min_pixels`, cut off from the measured surface. A point in the laser's shadow lit by a
/// neighbour's reflection has a peak at the wrong time, and such points come in small islands
/// away from the swept surface; left in, they would also seed the inpainting with their wrong
/// depths. Returns the pixels dropped.
pub fn drop_specks(merged: &mut MergedDepth, min_pixels: usize) -> usize {
    let width = merged.width;
    let n = merged.depth.len();
    if width == 0 {
        return 0;
    }
    let height = n / width;
    let mut seen = vec![false; n];
    let mut dropped = 0;
    let mut stack = Vec::new();
    let mut group = Vec::new();
    for start in 0..n {
        if seen[start] || merged.source[start] != source::MEASURED {
            continue;
        }
        group.clear();
        stack.push(start);
        seen[start] = true;
        while let Some(i) = stack.pop() {
            group.push(i);
            let (x, y) = (i % width, i / width);
            for ny in y.saturating_sub(1)..=(y + 1).min(height - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(width - 1) {
                    let j = ny * width + nx;
                    if !seen[j] && merged.source[j] == source::MEASURED {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        if group.len() < min_pixels {
            for &i in &group {
                merged.depth[i] = NO_DEPTH;
                merged.source[i] = source::NONE;
                merged.agreeing[i] = 0;
                merged.weight[i] = 0.0;
            }
            dropped += group.len();
        }
    }
    dropped
}

/// Unmeasures the spikes: measured pixels that fewer than a third of their measured neighbours
/// in the 5×5 window around them agree with (within `agree_footprints` pixel footprints, the
/// footprint being d / `fx`). A surface is continuous at the pixel scale but for its occluding
/// edges, where a pixel still agrees with its own side; a wrong peak next to the swept
/// surface agrees with nothing. Returns the pixels dropped.
pub fn drop_spikes(merged: &mut MergedDepth, fx: f64, agree_footprints: f64) -> usize {
    let width = merged.width;
    let n = merged.depth.len();
    if width == 0 || fx.is_nan() || fx <= 0.0 {
        return 0;
    }
    let height = n / width;
    let mut spikes = Vec::new();
    for i in 0..n {
        if merged.source[i] != source::MEASURED {
            continue;
        }
        let (x, y) = (i % width, i / width);
        let d = f64::from(merged.depth[i]);
        let tolerance = agree_footprints * d / fx;
        let (mut neighbours, mut agree) = (0u32, 0u32);
        for ny in y.saturating_sub(2)..=(y + 2).min(height - 1) {
            for nx in x.saturating_sub(2)..=(x + 2).min(width - 1) {
                let j = ny * width + nx;
                if j == i || merged.source[j] != source::MEASURED {
                    continue;
                }
                neighbours += 1;
                if (f64::from(merged.depth[j]) - d).abs() <= tolerance {
                    agree += 1;
                }
            }
        }
        if neighbours > 0 && 3 * agree < neighbours {
            spikes.push(i);
        }
    }
    for &i in &spikes {
        merged.depth[i] = NO_DEPTH;
        merged.source[i] = source::NONE;
        merged.agreeing[i] = 0;
        merged.weight[i] = 0.0;
    }
    spikes.len()
}

/// Relaxation passes of [`inpaint`] at most (successive over-relaxation, [`RELAX_OMEGA`]).
pub const RELAX_PASSES: usize = 200;

/// Over-relaxation factor of [`inpaint`]'s smoothing.
pub const RELAX_OMEGA: f32 = 1.8;

/// Fills the unknown pixels of `merged` where `region` is true; returns the pixels filled.
/// A first guess ring by ring inward (each pass gives every unknown pixel next to a known one
/// the mean of its known 8-neighbours) is relaxed to the smooth (harmonic) surface the known
/// pixels around the hole bound: the ring-by-ring guess alone carries the border's values
/// straight inward and leaves streaks across a large hole. Pixels of the region with no known
/// pixel anywhere in reach stay unknown.
pub fn inpaint(merged: &mut MergedDepth, region: &[bool]) -> usize {
    let filled = onion_peel(merged, region);
    relax_inpainted(merged);
    filled
}

/// [`inpaint`]'s first guess.
fn onion_peel(merged: &mut MergedDepth, region: &[bool]) -> usize {
    let width = merged.width;
    let n = merged.depth.len();
    if width == 0 || region.len() != n {
        return 0;
    }
    let height = n / width;
    let mut holes: Vec<usize> = (0..n)
        .filter(|&i| region[i] && merged.source[i] == source::NONE)
        .collect();
    let mut filled = 0;
    loop {
        let mut next = Vec::new();
        let mut fills = Vec::new();
        for &i in &holes {
            let (x, y) = (i % width, i / width);
            let (mut sum, mut count) = (0.0f64, 0u32);
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if (dx, dy) == (0, 0) || nx < 0 || ny < 0 {
                        continue;
                    }
                    let (nx, ny) = (nx as usize, ny as usize);
                    if nx >= width || ny >= height {
                        continue;
                    }
                    let j = ny * width + nx;
                    if merged.source[j] != source::NONE {
                        sum += f64::from(merged.depth[j]);
                        count += 1;
                    }
                }
            }
            if count > 0 {
                fills.push((i, (sum / f64::from(count)) as f32));
            } else {
                next.push(i);
            }
        }
        if fills.is_empty() {
            break;
        }
        for (i, d) in fills {
            merged.depth[i] = d;
            merged.source[i] = source::INPAINTED;
            filled += 1;
        }
        holes = next;
    }
    filled
}

/// Relaxes the inpainted pixels of `merged` towards the mean of their 4-neighbours (measured
/// pixels held fixed) until the largest change falls below a millionth of the depths, or
/// [`RELAX_PASSES`]: Laplace's equation with the measured border as its boundary.
fn relax_inpainted(merged: &mut MergedDepth) {
    let width = merged.width;
    let n = merged.depth.len();
    let filled: Vec<usize> = (0..n)
        .filter(|&i| merged.source[i] == source::INPAINTED)
        .collect();
    if filled.is_empty() || width == 0 {
        return;
    }
    let height = n / width;
    let (lo, hi) = merged
        .depth
        .iter()
        .zip(&merged.source)
        .filter(|(_, s)| **s != source::NONE)
        .fold((f32::MAX, f32::MIN), |(lo, hi), (d, _)| {
            (lo.min(*d), hi.max(*d))
        });
    // A millionth of the depths' size: below that, f32 rounding is all that changes.
    let tolerance = (hi.abs().max(lo.abs()) * 1e-6).max(1e-6);
    for _ in 0..RELAX_PASSES {
        let mut largest = 0.0f32;
        for &i in &filled {
            let (x, y) = (i % width, i / width);
            let (mut sum, mut count) = (0.0f32, 0u32);
            let mut take = |j: usize| {
                if merged.source[j] != source::NONE {
                    sum += merged.depth[j];
                    count += 1;
                }
            };
            if x > 0 {
                take(i - 1);
            }
            if x + 1 < width {
                take(i + 1);
            }
            if y > 0 {
                take(i - width);
            }
            if y + 1 < height {
                take(i + width);
            }
            if count == 0 {
                continue;
            }
            let change = RELAX_OMEGA * (sum / count as f32 - merged.depth[i]);
            merged.depth[i] += change;
            largest = largest.max(change.abs());
        }
        if largest < tolerance {
            break;
        }
    }
}

/// Of the pixels where `region` is true, the fraction no direction measured (the seed's hole
/// fraction, before inpainting); 0 for an empty region.
pub fn hole_fraction(merged: &MergedDepth, region: &[bool]) -> f64 {
    let inside = region.iter().filter(|r| **r).count();
    if inside == 0 {
        return 0.0;
    }
    let holes = region
        .iter()
        .zip(&merged.source)
        .filter(|(r, s)| **r && **s != source::MEASURED)
        .count();
    holes as f64 / inside as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(depth: &[f32], nu: f64) -> DepthLayer<'_> {
        DepthLayer { depth, nu }
    }

    #[test]
    fn agreeing_directions_average_by_weight_and_an_outlier_is_left_out() {
        // fx 1000: at 500 mm a footprint is 0.5 mm, so directions within 1 mm agree.
        let a = [500.0, 500.0, 500.0, -1.0];
        let b = [500.6, 500.3, 500.0, -1.0];
        let c = [480.0, 500.6, 520.0, 500.0];
        let layers = [layer(&a, 1.0), layer(&b, 3.0), layer(&c, 1.0)];
        let m = merge_layers(2, 2, &layers, 1000.0, &MergeOptions::default()).unwrap();
        // Pixel 0: c is 20 mm off (a reflection's peak); a and b average 1:3.
        assert!((m.depth[0] - 500.45).abs() < 1e-4, "{}", m.depth[0]);
        assert_eq!(m.agreeing[0], 2);
        // Pixel 1: all three agree.
        assert_eq!(m.agreeing[1], 3);
        assert!((m.depth[1] - (500.0 + 3.0 * 500.3 + 500.6) / 5.0).abs() < 1e-3);
        // Pixel 3: one direction alone is measured.
        assert_eq!(m.source[3], source::MEASURED);
        assert_eq!(m.depth[3], 500.0);
        assert_eq!(m.conflicts, 0);
    }

    #[test]
    fn two_directions_that_disagree_are_a_conflict_not_a_guess() {
        let a = [500.0, 500.0];
        let b = [510.0, 500.2];
        let m = merge_layers(
            2,
            1,
            &[layer(&a, 1.0), layer(&b, 5.0)],
            1000.0,
            &MergeOptions::default(),
        )
        .unwrap();
        assert_eq!(m.source[0], source::NONE);
        assert_eq!(m.depth[0], NO_DEPTH);
        assert_eq!(m.conflicts, 1);
        assert_eq!(m.source[1], source::MEASURED);
        // A direction of zero weight cannot triangulate: it is left out entirely.
        let m = merge_layers(
            2,
            1,
            &[layer(&a, 1.0), layer(&b, 0.0)],
            1000.0,
            &MergeOptions::default(),
        )
        .unwrap();
        assert_eq!(m.depth[0], 500.0);
        assert!(
            merge_layers(
                2,
                1,
                &[layer(&a[..1], 1.0)],
                1000.0,
                &MergeOptions::default()
            )
            .is_err()
        );
        assert!(merge_layers(2, 1, &[layer(&a, 1.0)], 0.0, &MergeOptions::default()).is_err());
    }

    #[test]
    fn small_islands_of_depth_are_dropped_and_the_surface_kept() {
        // A 6×4 image: a 3×4 surface on the left, a one-pixel speck and a two-pixel speck.
        let mut d = vec![-1.0f32; 24];
        for y in 0..4 {
            for x in 0..3 {
                d[y * 6 + x] = 100.0;
            }
        }
        d[5] = 300.0;
        d[2 * 6 + 5] = 300.0;
        d[3 * 6 + 5] = 300.0;
        let mut m =
            merge_layers(6, 4, &[layer(&d, 1.0)], 1000.0, &MergeOptions::default()).unwrap();
        assert_eq!(drop_specks(&mut m, 4), 3);
        assert_eq!(
            m.source.iter().filter(|s| **s == source::MEASURED).count(),
            12
        );
        assert!(m.depth.iter().all(|d| *d == NO_DEPTH || *d == 100.0));
    }

    #[test]
    fn a_spike_is_dropped_and_an_occluding_edge_kept() {
        // 7×5: a step from 500 to 520 mm between columns 2 and 3, and one wrong pixel.
        let mut d = vec![0.0f32; 35];
        for y in 0..5 {
            for x in 0..7 {
                d[y * 7 + x] = if x < 3 { 500.0 } else { 520.0 };
            }
        }
        d[2 * 7 + 5] = 509.0;
        let mut m =
            merge_layers(7, 5, &[layer(&d, 1.0)], 1000.0, &MergeOptions::default()).unwrap();
        assert_eq!(drop_spikes(&mut m, 1000.0, 2.0), 1);
        assert_eq!(m.source[2 * 7 + 5], source::NONE);
        assert_eq!(
            m.source.iter().filter(|s| **s == source::MEASURED).count(),
            34
        );
    }

    #[test]
    fn corners_one_direction_cannot_see_come_from_the_others_or_are_inpainted() {
        // 8×8 view of a tilted plane; direction A is occluded at all four 2×2 corners.
        let (w, h) = (8, 8);
        let truth: Vec<f32> = (0..w * h).map(|i| 500.0 + 0.1 * (i % w) as f32).collect();
        let corner = |i: usize| {
            let (x, y) = (i % w, i / w);
            (x < 2 || x >= w - 2) && (y < 2 || y >= h - 2)
        };
        let a: Vec<f32> = (0..w * h)
            .map(|i| if corner(i) { NO_DEPTH } else { truth[i] })
            .collect();
        let options = MergeOptions::default();
        let region = vec![true; w * h];
        // With two more directions that see the corners, every pixel is measured.
        let both = [layer(&a, 2.0), layer(&truth, 1.0), layer(&truth, 1.0)];
        let m = merge_layers(w, h, &both, 1000.0, &options).unwrap();
        assert_eq!(hole_fraction(&m, &region), 0.0);
        assert!(
            m.depth
                .iter()
                .zip(&truth)
                .all(|(d, t)| (d - t).abs() < 1e-3)
        );
        assert_eq!(m.agreeing[0], 2);
        // Alone, A leaves the corners as holes (16 of 64), inpainted from their neighbours.
        let mut m = merge_layers(w, h, &[layer(&a, 2.0)], 1000.0, &options).unwrap();
        assert_eq!(hole_fraction(&m, &region), 0.25);
        assert_eq!(inpaint(&mut m, &region), 16);
        for i in 0..w * h {
            assert!(m.depth[i].is_finite() && m.depth[i] > 499.0 && m.depth[i] < 501.0);
        }
    }

    #[test]
    fn a_large_hole_in_a_slope_is_filled_with_the_slope_without_streaks() {
        // A 40×40 view of a plane sloping both ways, a 24×24 hole in its middle: the filled
        // surface is the plane (a harmonic function), where the ring-by-ring guess alone is
        // off by up to 0.6 and streaked along the diagonals.
        let (w, h) = (40, 40);
        let plane = |i: usize| 500.0 + 0.3 * (i % w) as f32 + 0.1 * (i / w) as f32;
        let hole = |i: usize| (8..32).contains(&(i % w)) && (8..32).contains(&(i / w));
        let d: Vec<f32> = (0..w * h)
            .map(|i| if hole(i) { NO_DEPTH } else { plane(i) })
            .collect();
        let region = vec![true; w * h];
        let options = MergeOptions::default();
        let mut guess = merge_layers(w, h, &[layer(&d, 1.0)], 1000.0, &options).unwrap();
        assert_eq!(onion_peel(&mut guess, &region), 576);
        let guess_error = (0..w * h)
            .map(|i| (guess.depth[i] - plane(i)).abs())
            .fold(0.0f32, f32::max);
        let mut m = merge_layers(w, h, &[layer(&d, 1.0)], 1000.0, &options).unwrap();
        assert_eq!(inpaint(&mut m, &region), 576);
        let error = (0..w * h)
            .map(|i| (m.depth[i] - plane(i)).abs())
            .fold(0.0f32, f32::max);
        assert!(guess_error > 0.3, "{guess_error}");
        assert!(error < 0.01, "{error} (the first guess: {guess_error})");
    }

    #[test]
    fn holes_inside_the_region_are_filled_and_counted() {
        // A 5×3 image, measured on its left column and right column only.
        let mut d = vec![-1.0f32; 15];
        for y in 0..3 {
            d[y * 5] = 100.0;
            d[y * 5 + 4] = 200.0;
        }
        let mut m =
            merge_layers(5, 3, &[layer(&d, 1.0)], 1000.0, &MergeOptions::default()).unwrap();
        let mut region = vec![true; 15];
        region[2] = false; // one pixel outside the sample stays unknown
        assert!((hole_fraction(&m, &region) - 8.0 / 14.0).abs() < 1e-12);
        let filled = inpaint(&mut m, &region);
        assert_eq!(filled, 8);
        assert_eq!(m.source[2], source::NONE);
        assert_eq!(m.source[7], source::INPAINTED);
        for (i, inside) in region.iter().enumerate() {
            if *inside {
                assert!(
                    m.depth[i] >= 100.0 && m.depth[i] <= 200.0,
                    "{i}: {}",
                    m.depth[i]
                );
            }
        }
        // Nothing known: nothing to fill from.
        let none = vec![-1.0f32; 15];
        let mut m =
            merge_layers(5, 3, &[layer(&none, 1.0)], 1000.0, &MergeOptions::default()).unwrap();
        assert_eq!(inpaint(&mut m, &region), 0);
        assert_eq!(hole_fraction(&m, &region), 1.0);
    }
}
