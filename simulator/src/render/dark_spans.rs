//! The runs of pixels a frame lit by the laser alone leaves black. Most of a sweep's frame lies
//! beyond the sheet's reach, yet each of its samples still costs a ray, a distance test and a
//! bounce lookup. A kept [`HitTable`] bounds each run of [`SPAN`] pixels' hit points; a run
//! whose whole box lies farther from the sheet than the sheet can reach from any of them, and
//! where the bounce pass brought no light, is black, and the renderer skips it. The test is
//! conservative (a margin for rounding), so frames stay bit-identical.

use super::bounce::BounceMap;
use super::laser::LaserSheet;
use super::primary_hits::{HitTable, SPAN, SpanBounds};

/// Relative margin on distances against f32 rounding in the per-sample tests (mm per mm of the
/// coordinates involved): far above the few ulps the per-sample arithmetic can differ by.
const ROUNDING: f32 = 1.0e-4;

/// One flag per run of [`SPAN`] pixels of `table` (row-major, [`HitTable::spans_per_row`] a
/// row): true where every pixel is black in a frame lit by `sheet` alone, seen from the
/// table's eye with samples `angle` radians apart, with the indirect light `bounce`.
pub fn dark_spans(
    table: &HitTable,
    sheet: &LaserSheet,
    angle: f32,
    bounce: Option<&BounceMap>,
) -> Vec<bool> {
    table
        .spans()
        .iter()
        .map(|span| is_dark(span, sheet, angle, bounce))
        .collect()
}

/// Whether the pixel at (x, y) lies in a run `dark` marks black.
#[inline]
pub fn in_dark_span(dark: &[bool], spans_per_row: usize, x: u32, y: u32) -> bool {
    dark[y as usize * spans_per_row + (x / SPAN) as usize]
}

/// Whether no sample of `span` can receive light: nothing hit, or every hit point beyond the
/// sheet's reach (as `Scene::pixel_with` tests it) and, on the relief, no indirect light.
fn is_dark(span: &SpanBounds, sheet: &LaserSheet, angle: f32, bounce: Option<&BounceMap>) -> bool {
    if span.is_empty() {
        return true;
    }
    let centre = 0.5 * (span.lo + span.hi);
    let half = 0.5 * (span.hi - span.lo);
    // The sheet distance is linear in the point: over the box it stays within this of the
    // centre's.
    let spread = sheet.normal.abs().dot(half);
    let nearest = sheet.distance(centre).abs() - spread;
    // The reach grows with the distance from the eye and shrinks with the cosine: its
    // largest over the run.
    let reach = sheet.reach_from(span.far, angle, span.cos_min);
    let scale = 1.0
        + span
            .lo
            .abs()
            .max(span.hi.abs())
            .max(sheet.origin.abs())
            .max_element();
    let beyond = nearest > reach + ROUNDING * (scale + reach);
    if !beyond {
        return false;
    }
    match bounce {
        Some(b) if span.relief => b.dark_over((span.lo.x, span.hi.x), (span.lo.y, span.hi.y)),
        _ => true,
    }
}
