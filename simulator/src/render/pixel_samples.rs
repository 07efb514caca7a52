//! Where a camera's pixels are sampled, and the lens's undistorted coordinates of those points
//! computed once per camera. The sub-pixel pattern is fixed (hashed jitter), and undistorting a
//! point (the Newton inversion of `BrownConrady::undistort`) costs more than the rest of a
//! primary ray, yet depends only on the lens and the pixel grid, which no frame changes:
//! [`LensTables`] keeps each camera's coordinates within a memory budget. A table holds exactly
//! what [`CameraPose::undistorted`] returns, so frames are bit-identical with or without it.

use std::sync::Arc;

use rayon::prelude::*;

use super::geometry::CameraPose;
use super::kept::Kept;
use super::rng::{hash3, unit_f32};

/// Key for sub-pixel and light-sample jitter: fixed, so only the sensor noise depends on the
/// caller's seed.
pub const JITTER_KEY: u64 = 0x5a3e_11c0_77aa_0001;

/// Memory the tables of one renderer may hold: the light stage's eight cameras at 1024×768 and
/// 2×2 samples a pixel (25 MB each) fit.
const BUDGET_BYTES: usize = 256 << 20;

/// Position of sample `sub` of pixel (x, y) in a `width`-pixel row, in pixels from the top-left
/// corner: the pixel centre with one sample, else a jittered point in each cell of a
/// side × side grid.
#[inline]
pub fn sample_position(x: u32, y: u32, width: u32, sub: u32, side: u32) -> (f32, f32) {
    let pixel = y as u64 * width as u64 + x as u64;
    let step = 1.0 / side as f32;
    let (jx, jy) = if side == 1 {
        (0.5, 0.5)
    } else {
        let h = hash3(JITTER_KEY, pixel, sub as u64, 7);
        (unit_f32(h), unit_f32(h.rotate_left(24)))
    };
    (
        x as f32 + ((sub % side) as f32 + jx) * step,
        y as f32 + ((sub / side) as f32 + jy) * step,
    )
}

/// What a table is computed from: the lens, the pixel grid and the sampling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Key {
    lens: [u64; 5],
    focal_px: u32,
    principal: [u32; 2],
    width: u32,
    height: u32,
    side: u32,
    differentials: bool,
}

impl Key {
    fn of(pose: &CameraPose, side: u32, differentials: bool) -> Key {
        let l = pose.lens;
        Key {
            lens: [l.k1, l.k2, l.k3, l.p1, l.p2].map(f64::to_bits),
            focal_px: pose.focal_px.to_bits(),
            principal: [pose.principal_x.to_bits(), pose.principal_y.to_bits()],
            width: pose.width,
            height: pose.height,
            side,
            differentials,
        }
    }

    /// Points a sample keeps: itself, and with differentials its neighbours one sample step
    /// right and down (the laser's pixel footprint).
    fn points(&self) -> usize {
        if self.differentials { 3 } else { 1 }
    }

    fn bytes(&self) -> usize {
        let samples = self.width as usize
            * self.height as usize
            * self.side as usize
            * self.side as usize
            * self.points();
        samples.saturating_mul(std::mem::size_of::<[f32; 2]>())
    }
}

/// The undistorted normalised coordinates of every sample point of one camera.
#[derive(Debug)]
pub struct LensTable {
    key: Key,
    uv: Vec<[f32; 2]>,
}

impl LensTable {
    /// Computes the table of `pose` sampled side × side per pixel (rows in parallel).
    fn build(pose: &CameraPose, key: Key) -> LensTable {
        let side = key.side;
        let step = 1.0 / side as f32;
        let points = key.points();
        let row = pose.width as usize * (side * side) as usize * points;
        let mut uv = vec![[0.0f32; 2]; row * pose.height as usize];
        uv.par_chunks_mut(row.max(1))
            .enumerate()
            .for_each(|(y, out)| {
                let mut i = 0;
                for x in 0..pose.width {
                    for sub in 0..side * side {
                        let (px, py) = sample_position(x, y as u32, pose.width, sub, side);
                        out[i] = pose.undistorted(px, py);
                        if points == 3 {
                            out[i + 1] = pose.undistorted(px + step, py);
                            out[i + 2] = pose.undistorted(px, py + step);
                        }
                        i += points;
                    }
                }
            });
        LensTable { key, uv }
    }

    /// True when the table serves `side` × `side` sampling, with the neighbours the laser's
    /// footprint needs if `differentials`.
    pub fn covers(&self, side: u32, differentials: bool) -> bool {
        self.key.side == side && (self.key.differentials || !differentials)
    }

    /// Point `which` of sample `sub` of pixel index `pixel` (row-major): 0 the sample, 1 and 2
    /// its neighbours one sample step right and down (tables [`covers`](Self::covers) with
    /// differentials only).
    #[inline]
    pub fn uv(&self, pixel: u64, sub: u32, which: usize) -> [f32; 2] {
        let side2 = (self.key.side * self.key.side) as usize;
        self.uv[(pixel as usize * side2 + sub as usize) * self.key.points() + which]
    }
}

/// The lens tables of one renderer's cameras (see [`Kept`]).
#[derive(Debug)]
pub struct LensTables(Kept<Key, LensTable>);

impl Default for LensTables {
    fn default() -> Self {
        LensTables::with_budget(BUDGET_BYTES)
    }
}

impl LensTables {
    /// Tables within `budget_bytes`; one above an eighth of it is not kept (its rays are
    /// computed per frame instead), so that eight cameras' tables fit at once.
    pub fn with_budget(budget_bytes: usize) -> LensTables {
        LensTables(Kept::with_budget(budget_bytes))
    }

    /// The table of `pose` sampled side × side (with the laser footprint's neighbours when
    /// `differentials`), computed on first use; `None` for a pinhole camera (nothing to
    /// invert) or a table too large to keep.
    pub fn get(&self, pose: &CameraPose, side: u32, differentials: bool) -> Option<Arc<LensTable>> {
        if pose.lens.is_identity() {
            return None;
        }
        let key = Key::of(pose, side, differentials);
        self.0.get(key, key.bytes(), || LensTable::build(pose, key))
    }

    /// Tables held now.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// True when no table is held.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, CameraSpec, parse_rig};

    use super::*;
    use crate::render::geometry::ToSample;

    fn camera(k1: f64, width: u32, height: u32) -> CameraSpec {
        let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
        CameraSpec {
            k1,
            k2: 0.02,
            p1: 1e-4,
            cx: 3.5,
            cy: -2.25,
            width,
            height,
            ..rig.cameras[2].clone()
        }
    }

    /// Every sample point and both neighbours: the table's ray is the computed ray, bit for
    /// bit, at any turntable angle (the table depends on the lens alone).
    #[test]
    fn table_rays_are_the_computed_rays_bit_for_bit() {
        let spec = camera(-0.15, 40, 30);
        let tables = LensTables::default();
        for turntable_deg in [0.0, 137.5] {
            let pose = CameraPose::new(&spec, ToSample::new(turntable_deg));
            let table = tables
                .get(&pose, 2, true)
                .expect("a distorted lens is tabulated");
            assert!(table.covers(2, true) && table.covers(2, false) && !table.covers(1, false));
            let step = 0.5;
            for y in 0..pose.height {
                for x in 0..pose.width {
                    let pixel = y as u64 * pose.width as u64 + x as u64;
                    for sub in 0..4 {
                        let (px, py) = sample_position(x, y, pose.width, sub, 2);
                        for (which, (qx, qy)) in [(px, py), (px + step, py), (px, py + step)]
                            .into_iter()
                            .enumerate()
                        {
                            let want = pose.ray(qx, qy).to_array().map(f32::to_bits);
                            let got = pose
                                .ray_through(table.uv(pixel, sub, which))
                                .to_array()
                                .map(f32::to_bits);
                            assert_eq!(got, want, "({x}, {y}) sample {sub} point {which}");
                        }
                    }
                }
            }
        }
        assert_eq!(tables.len(), 1, "one lens, one table");
    }

    #[test]
    fn pinholes_and_oversized_tables_are_not_kept() {
        let tables = LensTables::default();
        let pinhole = CameraPose::new(
            &CameraSpec {
                k1: 0.0,
                k2: 0.0,
                p1: 0.0,
                ..camera(0.0, 40, 30)
            },
            ToSample::new(0.0),
        );
        assert!(tables.get(&pinhole, 1, false).is_none());
        let huge = CameraPose::new(&camera(-0.1, 4096, 4096), ToSample::new(0.0));
        assert!(tables.get(&huge, 2, true).is_none());
        assert!(tables.is_empty());
    }

    /// The same lens shares one table; past the budget the least recently used goes first.
    #[test]
    fn tables_are_shared_and_the_oldest_dropped_past_the_budget() {
        // 40 × 30 × 4 samples × 8 bytes = 38 400 bytes a table: ten fit, the eleventh drops
        // the first.
        let tables = LensTables::with_budget(10 * 38_400 + 100);
        let pose = |k1: f64| CameraPose::new(&camera(k1, 40, 30), ToSample::new(0.0));
        let a = tables.get(&pose(-0.10), 2, false).expect("table");
        let again = tables.get(&pose(-0.10), 2, false).expect("table");
        assert!(Arc::ptr_eq(&a, &again));
        for i in 1..=10 {
            tables.get(&pose(-0.10 - 0.001 * f64::from(i)), 2, false);
        }
        assert_eq!(tables.len(), 10);
        let fresh = tables.get(&pose(-0.10), 2, false).expect("table");
        assert!(
            !Arc::ptr_eq(&a, &fresh),
            "the first table was dropped and made again"
        );
    }
}
