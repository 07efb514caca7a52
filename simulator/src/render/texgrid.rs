//! A regular texel grid over the sample's square, holding one RGB value per texel, with
//! bilinear lookup between texel centres: the storage of the per-frame light-transport maps
//! (subsurface exitance, indirect irradiance).

use glam::Vec3A;

/// n × n texels of side `cell` mm covering [−size/2, size/2]², values at texel centres.
#[derive(Debug, Clone, PartialEq)]
pub struct TexGrid {
    n: usize,
    cell: f32,
    origin: f32,
    values: Vec<Vec3A>,
}

impl TexGrid {
    /// A grid of `n` (≥ 1) texels per side over a sample `size_mm` wide, every value zero.
    pub fn new(n: usize, size_mm: f32) -> TexGrid {
        let n = n.max(1);
        TexGrid {
            n,
            cell: size_mm / n as f32,
            origin: -0.5 * size_mm,
            values: vec![Vec3A::ZERO; n * n],
        }
    }

    /// Texels per side.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Texel side in mm.
    pub fn cell(&self) -> f32 {
        self.cell
    }

    /// Centre (x, y) in mm of texel (i, j).
    #[inline]
    pub fn centre(&self, i: usize, j: usize) -> (f32, f32) {
        (
            self.origin + (i as f32 + 0.5) * self.cell,
            self.origin + (j as f32 + 0.5) * self.cell,
        )
    }

    /// All values, row-major (index j·n + i).
    pub fn values(&self) -> &[Vec3A] {
        &self.values
    }

    /// All values, mutable, row-major.
    pub fn values_mut(&mut self) -> &mut [Vec3A] {
        &mut self.values
    }

    /// The value of texel (i, j).
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> Vec3A {
        self.values[j * self.n + i]
    }

    /// The four texels around (x, y) mm, clamped at the border (lower-left, lower-right,
    /// upper-left, upper-right), and the point's fractions (a, b) across them; `None` for NaN
    /// coordinates.
    #[inline]
    fn around(&self, x: f32, y: f32) -> Option<([Vec3A; 4], f32, f32)> {
        if x.is_nan() || y.is_nan() {
            return None;
        }
        let last = (self.n - 1) as f32;
        let u = ((x - self.origin) / self.cell - 0.5).clamp(0.0, last);
        let v = ((y - self.origin) / self.cell - 0.5).clamp(0.0, last);
        let (i, j) = (u as usize, v as usize);
        let (a, b) = (u - i as f32, v - j as f32);
        let (i1, j1) = ((i + 1).min(self.n - 1), (j + 1).min(self.n - 1));
        Some((
            [
                self.get(i, j),
                self.get(i1, j),
                self.get(i, j1),
                self.get(i1, j1),
            ],
            a,
            b,
        ))
    }

    /// Bilinear interpolation between texel centres at (x, y) mm, clamped at the border;
    /// zero for NaN coordinates.
    #[inline]
    pub fn at(&self, x: f32, y: f32) -> Vec3A {
        let Some(([q00, q10, q01, q11], a, b)) = self.around(x, y) else {
            return Vec3A::ZERO;
        };
        q00.lerp(q10, a).lerp(q01.lerp(q11, a), b)
    }

    /// Interpolation between texel centres at (x, y) mm in the logarithm, per channel, where
    /// the four texels around are all positive (bilinear otherwise), clamped at the border;
    /// zero for NaN coordinates. A falloff such as light spreading away from where it entered
    /// is convex: the bilinear chord overestimates it between texels (by h²·f″/8 at the
    /// midpoint, 1 % for a decay of 1.3/mm on 0.23 mm texels), while an exponential is exact
    /// in the logarithm.
    #[inline]
    pub fn at_geometric(&self, x: f32, y: f32) -> Vec3A {
        let Some((corners, a, b)) = self.around(x, y) else {
            return Vec3A::ZERO;
        };
        let weights = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
        let channel = |c: usize| {
            let values = corners.map(|q| q[c]);
            if values.iter().all(|q| *q > 0.0) {
                values
                    .iter()
                    .zip(weights)
                    .map(|(q, w)| w * q.ln())
                    .sum::<f32>()
                    .exp()
            } else {
                values.iter().zip(weights).map(|(q, w)| w * q).sum::<f32>()
            }
        };
        Vec3A::new(channel(0), channel(1), channel(2))
    }
}

/// Where a [`TexGrid`] holds light: a summed-area count of its non-zero texels, so that
/// whether a lookup anywhere in a rectangle can return non-zero is answered at once.
#[derive(Debug, Clone)]
pub struct LitTexels {
    n: usize,
    cell: f32,
    origin: f32,
    /// (n + 1)² running counts: entry (i, j) counts the non-zero texels left of column i
    /// and below row j.
    counts: Vec<u32>,
}

impl TexGrid {
    /// The summed-area count of this grid's non-zero texels.
    pub fn lit_texels(&self) -> LitTexels {
        let n = self.n;
        let mut counts = vec![0u32; (n + 1) * (n + 1)];
        for j in 0..n {
            let mut row = 0u32;
            for i in 0..n {
                row += u32::from(self.get(i, j) != Vec3A::ZERO);
                counts[(j + 1) * (n + 1) + i + 1] = counts[j * (n + 1) + i + 1] + row;
            }
        }
        LitTexels {
            n,
            cell: self.cell,
            origin: self.origin,
            counts,
        }
    }
}

impl LitTexels {
    /// True when [`TexGrid::at`] is exactly zero everywhere in [x0, x1] × [y0, y1] mm: every
    /// texel a lookup there reads, and one more on each side against rounding, is zero.
    /// False for bounds that are not finite.
    pub fn dark_over(&self, (x0, x1): (f32, f32), (y0, y1): (f32, f32)) -> bool {
        if ![x0, x1, y0, y1].iter().all(|v| v.is_finite()) {
            return false;
        }
        let last = (self.n - 1) as f32;
        let texel = |v: f32| ((v - self.origin) / self.cell - 0.5).clamp(0.0, last) as usize;
        let range = |a: f32, b: f32| (texel(a).saturating_sub(1), (texel(b) + 2).min(self.n - 1));
        let ((i0, i1), (j0, j1)) = (range(x0, x1), range(y0, y1));
        if i0 > i1 || j0 > j1 {
            return true;
        }
        let w = self.n + 1;
        let at = |i: usize, j: usize| self.counts[j * w + i];
        at(i1 + 1, j1 + 1) + at(i0, j0) == at(i0, j1 + 1) + at(i1 + 1, j0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_reproduces_a_linear_ramp_and_clamps() {
        let mut g = TexGrid::new(8, 16.0);
        for j in 0..8 {
            for i in 0..8 {
                let (x, y) = g.centre(i, j);
                g.values_mut()[j * 8 + i] = Vec3A::new(x, y, 1.0);
            }
        }
        let v = g.at(1.3, -2.7);
        assert!(
            (v - Vec3A::new(1.3, -2.7, 1.0)).abs().max_element() < 1e-5,
            "{v}"
        );
        assert_eq!(g.at(100.0, 100.0), g.get(7, 7));
        assert_eq!(g.at(f32::NAN, 0.0), Vec3A::ZERO);
        assert_eq!(g.n(), 8);
        assert!((g.cell() - 2.0).abs() < 1e-6);
    }

    #[test]
    fn geometric_lookup_follows_an_exponential_and_falls_back_at_zeros() {
        let mut g = TexGrid::new(16, 16.0);
        for j in 0..16 {
            for i in 0..16 {
                let (x, _) = g.centre(i, j);
                let zero = if i == 12 { 0.0 } else { 1.0 };
                g.values_mut()[j * 16 + i] = Vec3A::new((-1.3 * x).exp(), 2.0, zero);
            }
        }
        for x in [-3.3f32, -0.25, 0.5, 2.71] {
            let got = g.at_geometric(x, 0.4);
            let want = (-1.3 * x).exp();
            assert!(
                (got.x / want - 1.0).abs() < 1e-5,
                "{x}: {} vs {want}",
                got.x
            );
            assert!((got.y - 2.0).abs() < 1e-6);
            // The bilinear chord is above the curve there.
            assert!(g.at(x, 0.4).x >= got.x);
        }
        // Beside a zero texel: bilinear.
        let (x12, _) = g.centre(12, 0);
        assert!((g.at_geometric(x12 - 0.5, 0.0).z - 0.5).abs() < 1e-6);
        assert_eq!(g.at_geometric(f32::NAN, 0.0), Vec3A::ZERO);
    }

    /// A lit texel darkens no rectangle it cannot reach and lights every one it can.
    #[test]
    fn lit_texels_answer_for_rectangles_exactly_where_lookups_read() {
        let mut g = TexGrid::new(16, 32.0);
        g.values_mut()[5 * 16 + 9] = Vec3A::new(0.0, 0.0, 2.0);
        let lit = g.lit_texels();
        let (cx, cy) = g.centre(9, 5);
        for (x, y) in [(cx, cy), (cx - 1.9, cy), (cx + 1.9, cy + 1.9)] {
            assert!(g.at(x, y) != Vec3A::ZERO);
            assert!(!lit.dark_over((x, x), (y, y)), "({x}, {y})");
        }
        assert!(!lit.dark_over((-16.0, 16.0), (-16.0, 16.0)));
        for (x, y) in [(cx - 6.1, cy), (cx, cy + 6.1), (-16.0, -16.0), (40.0, 40.0)] {
            assert_eq!(g.at(x, y), Vec3A::ZERO);
            assert!(lit.dark_over((x - 1.0, x), (y - 1.0, y)), "({x}, {y})");
        }
        assert!(!lit.dark_over((f32::NAN, 0.0), (0.0, 0.0)));
        assert!(
            TexGrid::new(4, 8.0)
                .lit_texels()
                .dark_over((-9.0, 9.0), (-9.0, 9.0))
        );
    }
}
