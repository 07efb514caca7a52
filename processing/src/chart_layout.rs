//! The physical layout of the rig's colour checker: a 6×4 grid of square ColorChecker patches
//! on a black card, lying flat and centred on the turntable. Patch positions are a property of
//! the chart, not of any image, so colour calibration finds the patches by projecting this
//! layout through a camera's geometry (then refining the match, see [`crate::chart_locate`]).
//!
//! Chart frame: the sample frame (z up, origin on the turntable axis at the sample's top, x
//! along the turntable's 0°). The 6 patches of a row run along +y; the 4 rows run along +x
//! starting at −x, so patch 0 (dark skin) sits at the (−x, −y) corner and the neutral row
//! (white … black) along +x. Six pitches span 96 % of the chart's long side and each patch is
//! 0.82 pitch across (the mini ColorChecker's proportions).

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::white_balance::checker_reflectance;

/// Patch pitch as a fraction of the chart's long side (6 pitches take 96 % of it).
pub const PITCH_PER_SIZE: f64 = 0.96 / 6.0;
/// Patch side as a fraction of the pitch (the rest is black card between patches).
pub const PATCH_PER_PITCH: f64 = 0.82;
/// Reflectance of the black card around and between the patches.
pub const CARD_REFLECTANCE: f64 = 0.03;
/// Default long side of the chart, mm: the built-in rig's fixtures (`sample_size_mm`).
pub const DEFAULT_SIZE_MM: f64 = 80.0;
/// Patches of the chart.
pub const PATCHES: usize = 24;

/// How the chart lies on the turntable: as drawn (patch 0 at −x, −y) or turned half way
/// (patch 0 at +x, +y). The two are the only placements with the same footprint, so chart
/// location tries both rather than trusting the operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Orientation {
    /// Patch 0 at the (−x, −y) corner.
    AsDrawn,
    /// Turned by 180° about the turntable axis: patch 0 at (+x, +y).
    HalfTurn,
}

impl Orientation {
    /// A point of the chart's own frame in the sample frame (a half turn is its own inverse,
    /// so this maps sample-frame points to the chart frame too).
    pub fn apply(self, p: [f64; 2]) -> [f64; 2] {
        match self {
            Orientation::AsDrawn => p,
            Orientation::HalfTurn => [-p[0], -p[1]],
        }
    }
}

/// The size of the chart; everything else follows from the published layout.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChartLayout {
    /// Length of the chart's long side (along its rows of 6), mm.
    pub size_mm: f64,
}

impl Default for ChartLayout {
    fn default() -> ChartLayout {
        ChartLayout {
            size_mm: DEFAULT_SIZE_MM,
        }
    }
}

impl ChartLayout {
    /// Checks the size is finite and positive.
    pub fn check(&self) -> Result<(), ProcessingError> {
        if self.size_mm.is_finite() && self.size_mm > 0.0 {
            Ok(())
        } else {
            Err(ProcessingError::BadParameter {
                name: "chart size_mm",
                value: self.size_mm,
                why: "the chart's long side must be finite and positive",
            })
        }
    }

    /// Centre-to-centre spacing of the patches, mm.
    pub fn pitch_mm(&self) -> f64 {
        self.size_mm * PITCH_PER_SIZE
    }

    /// Side of one patch, mm.
    pub fn patch_mm(&self) -> f64 {
        self.pitch_mm() * PATCH_PER_PITCH
    }

    /// Centre of patch `index` (0..24) in the chart frame, mm.
    pub fn patch_centre(&self, index: usize) -> [f64; 2] {
        let (row, col) = ((index / 6) as f64, (index % 6) as f64);
        let p = self.pitch_mm();
        [(row - 1.5) * p, (col - 2.5) * p]
    }

    /// Half extent of the patch grid along x and y, mm: the grid spans ±2 pitches by ±3.
    pub fn half_extent_mm(&self) -> [f64; 2] {
        let p = self.pitch_mm();
        [2.0 * p, 3.0 * p]
    }

    /// The patch whose square holds chart-frame point `(x, y)`, if any.
    pub fn patch_at(&self, x: f64, y: f64) -> Option<usize> {
        let p = self.pitch_mm();
        let row = ((x + 2.0 * p) / p).floor();
        let col = ((y + 3.0 * p) / p).floor();
        if !((0.0..4.0).contains(&row) && (0.0..6.0).contains(&col)) {
            return None;
        }
        let index = row as usize * 6 + col as usize;
        let c = self.patch_centre(index);
        let half = 0.5 * self.patch_mm();
        ((x - c[0]).abs() <= half && (y - c[1]).abs() <= half).then_some(index)
    }

    /// Mean reflectance over the three channels at chart-frame point `(x, y)`: the patch's,
    /// or the card's between patches. The template chart location matches images against.
    pub fn luminance_at(&self, x: f64, y: f64) -> f64 {
        match self.patch_at(x, y) {
            Some(i) => checker_reflectance(i).iter().sum::<f64>() / 3.0,
            None => CARD_REFLECTANCE,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patches_sit_on_their_published_grid() {
        let chart = ChartLayout { size_mm: 80.0 };
        assert!((chart.pitch_mm() - 12.8).abs() < 1e-12);
        assert_eq!(chart.patch_centre(0), [-1.5 * 12.8, -2.5 * 12.8]);
        assert_eq!(chart.patch_centre(23), [1.5 * 12.8, 2.5 * 12.8]);
        for i in 0..PATCHES {
            let c = chart.patch_centre(i);
            assert_eq!(chart.patch_at(c[0], c[1]), Some(i));
            // Half a pitch off the centre is card.
            assert_eq!(chart.patch_at(c[0] + 6.4, c[1]), None);
        }
        assert_eq!(chart.luminance_at(100.0, 0.0), CARD_REFLECTANCE);
        let flipped = Orientation::HalfTurn.apply(chart.patch_centre(0));
        assert_eq!(flipped, chart.patch_centre(23));
        assert!(ChartLayout { size_mm: 0.0 }.check().is_err());
        assert!(ChartLayout { size_mm: f64::NAN }.check().is_err());
    }
}
