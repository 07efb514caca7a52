//! The first surface every sample ray of a camera meets, kept while the camera and the sample
//! stay put. During a laser sweep or a lamp sequence only the light changes, yet marching the
//! height field for each primary ray is the largest part of a frame: a [`HitTable`] keeps, per
//! sub-pixel sample, the distance to the hit, what was hit and the cosine of the view there
//! (which bounds where the laser can light it), keyed on everything the
//! intersection depends on (sample, relief, camera pose with the turntable angle and fixture
//! pose, sampling, the tube's body). A lamp frame records its view's table as it shades (the
//! march it does anyway, so a view seen once costs only the stores); a frame lit by the laser
//! alone builds it before shading, to skip what the sheet cannot reach from its first frame
//! on. The shading point is rebuilt from the kept distance by the same code as an uncached
//! frame, so frames are bit-identical with or without the table.
//! Each run of [`SPAN`] pixels along a row also keeps the bounds of its hit points
//! ([`SpanBounds`]), so a laser frame can skip the runs the sheet cannot reach
//! (`dark_spans.rs`). A lamp frame's table also keeps each sample's shading normal where
//! it fits the budget (the preview preset): every point of a lamp frame is shaded, and
//! interpolating the relief's normal is a tenth of its cost.

use std::sync::Arc;

use glam::Vec3A;
use rayon::prelude::*;

use super::kept::Kept;

/// Memory the tables of one renderer may hold: the light stage's eight cameras at 1024×768 and
/// 2×2 samples a pixel (38 MB each) fit; a table above an eighth of it is not kept.
const BUDGET_BYTES: usize = 320 << 20;

/// What a primary ray met, compactly: enough to rebuild the hit exactly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PackedHit {
    /// Distance along the unit ray, mm (unused for [`HitKind::Nothing`]).
    pub t: f32,
    /// |n·ω_o| at the hit, the cosine between the shading normal and the view: how wide a
    /// strip the laser's pixel footprint covers there. 0 until known (a hit not yet shaded).
    pub cos_view: f32,
    /// What was hit.
    pub kind: HitKind,
}

/// The surfaces a primary ray can meet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitKind {
    /// Void, or the tube's body in front of everything: black.
    Nothing,
    /// The top of the sample's relief.
    Relief,
    /// A vertical side of the relief, facing −x, +x, −y or +y (the outward normal).
    Wall(WallFacing),
    /// The sample's plane (no relief grid hit there).
    SamplePlane,
    /// The turntable around the sample.
    Turntable,
}

/// Outward normal of a relief side wall: the march only reports these four.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WallFacing {
    /// Normal −x.
    MinusX,
    /// Normal +x.
    PlusX,
    /// Normal −y.
    MinusY,
    /// Normal +y.
    PlusY,
}

impl PackedHit {
    /// No surface.
    pub const NOTHING: PackedHit = PackedHit {
        t: 0.0,
        cos_view: 0.0,
        kind: HitKind::Nothing,
    };
}

/// Pixels along a row that share one [`SpanBounds`].
pub const SPAN: u32 = 16;

/// The hit points of one run of [`SPAN`] pixels (fewer at a row's end), all their samples:
/// where they lie, how far from the eye and how obliquely seen, which bounds how close a
/// laser sheet must pass to light any of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpanBounds {
    /// Corner of the box holding every hit point (sample frame, mm); +∞ when nothing was hit.
    pub lo: Vec3A,
    /// Opposite corner; −∞ when nothing was hit.
    pub hi: Vec3A,
    /// Largest distance from the eye to a hit point, mm.
    pub far: f32,
    /// Smallest `cos_view` of a hit.
    pub cos_min: f32,
    /// Whether a sample hit the relief (the only surface the bounce pass lights).
    pub relief: bool,
}

impl SpanBounds {
    /// A run with no hit yet.
    const EMPTY: SpanBounds = SpanBounds {
        lo: Vec3A::INFINITY,
        hi: Vec3A::NEG_INFINITY,
        far: 0.0,
        cos_min: f32::INFINITY,
        relief: false,
    };

    /// Whether no sample of the run hit a surface (its pixels are black under any light).
    pub fn is_empty(&self) -> bool {
        self.lo.x > self.hi.x
    }

    /// Takes hit `hit` at point `p`, seen from `eye`, into the bounds.
    fn include(&mut self, hit: &PackedHit, p: Vec3A, eye: Vec3A) {
        if hit.kind == HitKind::Nothing {
            return;
        }
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
        self.far = self.far.max((p - eye).length());
        self.cos_min = self.cos_min.min(hit.cos_view);
        self.relief |= hit.kind == HitKind::Relief;
    }
}

/// Every sample's primary hit for one camera view, `side`² samples per pixel, row-major, the
/// bounds of each run of [`SPAN`] pixels and, when kept, each sample's shading normal.
#[derive(Debug)]
pub struct HitTable {
    side: u32,
    width: u32,
    hits: Vec<PackedHit>,
    /// Per sample, the shading normal at its hit (zero where nothing was hit); empty when not
    /// kept.
    normals: Vec<[f32; 3]>,
    spans: Vec<SpanBounds>,
}

/// One row of a [`HitTable`] being filled (see [`HitTable::rows`]).
pub struct RowRecorder<'t> {
    per_pixel: usize,
    eye: Vec3A,
    hits: &'t mut [PackedHit],
    /// Empty when the table keeps no normals.
    normals: &'t mut [[f32; 3]],
    spans: &'t mut [SpanBounds],
}

impl RowRecorder<'_> {
    /// Records sample `sub` of pixel `x` of this row: its hit, the hit's point `p` and its
    /// shading normal `n` (zero where nothing is hit).
    #[inline]
    pub fn record(&mut self, x: u32, sub: u32, hit: PackedHit, p: Vec3A, n: Vec3A) {
        self.spans[(x / SPAN) as usize].include(&hit, p, self.eye);
        let i = x as usize * self.per_pixel + sub as usize;
        self.hits[i] = hit;
        if let Some(slot) = self.normals.get_mut(i) {
            *slot = n.to_array();
        }
    }
}

impl HitTable {
    /// A table for a `width` × `height` camera sampled `side` × `side` where nothing is hit
    /// yet, keeping normals when `normals` is true: filled row by row ([`Self::rows`]).
    pub fn empty(width: u32, height: u32, side: u32, normals: bool) -> HitTable {
        let samples = width as usize * height as usize * (side * side) as usize;
        HitTable {
            side,
            width,
            hits: vec![PackedHit::NOTHING; samples],
            normals: vec![[0.0; 3]; if normals { samples } else { 0 }],
            spans: vec![SpanBounds::EMPTY; spans_per_row(width) * height as usize],
        }
    }

    /// The table's rows, top first, for filling in parallel with the hits of samples seen
    /// from `eye`.
    pub fn rows(&mut self, eye: Vec3A) -> impl IndexedParallelIterator<Item = RowRecorder<'_>> {
        let per_pixel = (self.side * self.side) as usize;
        let row = (self.width as usize * per_pixel).max(1);
        let height = self.hits.len() / row;
        // Without normals each row gets an empty slice to write none into.
        let normal_rows: Vec<&mut [[f32; 3]]> = if self.normals.is_empty() {
            (0..height).map(|_| <&mut [[f32; 3]]>::default()).collect()
        } else {
            self.normals.chunks_mut(row).collect()
        };
        let spans_per_row = spans_per_row(self.width).max(1);
        self.hits
            .par_chunks_mut(row)
            .zip(self.spans.par_chunks_mut(spans_per_row))
            .zip(normal_rows)
            .map(move |((hits, spans), normals)| RowRecorder {
                per_pixel,
                eye,
                hits,
                normals,
                spans,
            })
    }

    /// Computes the table for a `width` × `height` camera at `eye` sampled `side` × `side`,
    /// rows in parallel; `locate(x, y, sub)` is the primary hit of sample `sub` of pixel
    /// (x, y), its point and its shading normal, computed as the renderer rebuilds them from
    /// the kept distance. The normals are kept when `normals` is true.
    pub fn build(
        width: u32,
        height: u32,
        side: u32,
        eye: Vec3A,
        normals: bool,
        locate: impl Fn(u32, u32, u32) -> (PackedHit, Vec3A, Vec3A) + Sync,
    ) -> HitTable {
        let mut table = HitTable::empty(width, height, side, normals);
        table.rows(eye).enumerate().for_each(|(y, mut row)| {
            for x in 0..width {
                for sub in 0..side * side {
                    let (hit, p, n) = locate(x, y as u32, sub);
                    row.record(x, sub, hit, p, n);
                }
            }
        });
        table
    }

    /// The bounds of every run of [`SPAN`] pixels, row-major ([`Self::spans_per_row`] a row).
    pub fn spans(&self) -> &[SpanBounds] {
        &self.spans
    }

    /// Runs of [`SPAN`] pixels a row holds (the last may be shorter).
    pub fn spans_per_row(&self) -> usize {
        spans_per_row(self.width)
    }

    /// Where sample `sub` of pixel (x, y) sits in the per-sample vectors.
    #[inline]
    fn index(&self, x: u32, y: u32, sub: u32) -> usize {
        let per_pixel = (self.side * self.side) as usize;
        (y as usize * self.width as usize + x as usize) * per_pixel + sub as usize
    }

    /// The hit of sample `sub` of pixel (x, y).
    #[inline]
    pub fn get(&self, x: u32, y: u32, sub: u32) -> PackedHit {
        self.hits[self.index(x, y, sub)]
    }

    /// The shading normal at the hit of sample `sub` of pixel (x, y), when the table keeps
    /// normals.
    #[inline]
    pub fn normal(&self, x: u32, y: u32, sub: u32) -> Option<Vec3A> {
        self.normals
            .get(self.index(x, y, sub))
            .map(|&n| Vec3A::from_array(n))
    }

    /// Bytes this table holds: what [`table_bytes`] counts for its size.
    fn bytes(&self) -> usize {
        self.hits.len() * std::mem::size_of::<PackedHit>()
            + self.normals.len() * std::mem::size_of::<[f32; 3]>()
            + self.spans.len() * std::mem::size_of::<SpanBounds>()
    }

    /// Samples per pixel side this table holds.
    pub fn side(&self) -> u32 {
        self.side
    }

    /// Whether `self` and `other` hold the same hits and bounds (normals aside).
    #[cfg(test)]
    pub fn same_hits(&self, other: &HitTable) -> bool {
        self.hits == other.hits && self.spans == other.spans && self.side == other.side
    }
}

/// Runs of [`SPAN`] pixels in a row `width` pixels wide.
fn spans_per_row(width: u32) -> usize {
    width.div_ceil(SPAN) as usize
}

/// Bytes a table of `width` × `height` pixels at `side`² samples holds, with or without
/// `normals`.
fn table_bytes(width: u32, height: u32, side: u32, normals: bool) -> usize {
    let per_sample = std::mem::size_of::<PackedHit>()
        + if normals {
            std::mem::size_of::<[f32; 3]>()
        } else {
            0
        };
    (width as usize * height as usize)
        .saturating_mul((side * side) as usize)
        .saturating_mul(per_sample)
        .saturating_add(
            (spans_per_row(width) * height as usize)
                .saturating_mul(std::mem::size_of::<SpanBounds>()),
        )
}

/// The hit tables of one renderer's camera views, keyed on an exact description of each view.
#[derive(Debug)]
pub struct PrimaryHits {
    tables: Kept<String, HitTable>,
}

impl Default for PrimaryHits {
    fn default() -> Self {
        PrimaryHits::with_budget(BUDGET_BYTES)
    }
}

impl PrimaryHits {
    /// Tables within `budget_bytes` (see [`Kept`]).
    pub fn with_budget(budget_bytes: usize) -> PrimaryHits {
        PrimaryHits {
            tables: Kept::with_budget(budget_bytes),
        }
    }

    /// Whether a table of `width` × `height` pixels sampled `side` × `side` is kept
    /// (`None`: too large, the caller intersects per frame), and whether with normals: when
    /// `normals` are wanted and the table still fits with them.
    pub fn keeps(&self, (width, height, side): (u32, u32, u32), normals: bool) -> Option<bool> {
        let with_normals = normals && self.tables.keeps(table_bytes(width, height, side, true));
        self.tables
            .keeps(table_bytes(width, height, side, with_normals))
            .then_some(with_normals)
    }

    /// The table for the view described exactly by `key`, `width` × `height` pixels sampled
    /// `side` × `side`, built now by `build(normals)` unless kept (normals as
    /// [`Self::keeps`] decides); `None` when too large to keep.
    pub fn get(
        &self,
        key: String,
        (width, height, side): (u32, u32, u32),
        normals: bool,
        build: impl FnOnce(bool) -> HitTable,
    ) -> Option<Arc<HitTable>> {
        let normals = self.keeps((width, height, side), normals)?;
        let bytes = table_bytes(width, height, side, normals);
        self.tables.get(key, bytes, || build(normals))
    }

    /// The kept table for the view `key`, if any.
    pub fn kept(&self, key: &String) -> Option<Arc<HitTable>> {
        self.tables.peek(key)
    }

    /// Keeps `table`, recorded by a frame of the view `key` as it shaded (a table kept
    /// meanwhile for the same view stays instead).
    pub fn keep(&self, key: String, table: HitTable) {
        self.tables.get(key, table.bytes(), || table);
    }

    /// Every table held, by key (tests).
    #[cfg(test)]
    pub fn held(&self) -> Vec<(String, Arc<HitTable>)> {
        let held = self.tables.held().into_iter();
        held.filter_map(|(key, table)| Some((key, table?)))
            .collect()
    }

    /// Tables held now.
    pub fn len(&self) -> usize {
        self.tables.len()
    }

    /// True when no table is held.
    pub fn is_empty(&self) -> bool {
        self.tables.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(w: u32, h: u32, side: u32) -> HitTable {
        table_with(w, h, side, false)
    }

    /// A test table, keeping the normals (x, y, sub) when `normals`.
    fn table_with(w: u32, h: u32, side: u32, normals: bool) -> HitTable {
        HitTable::build(w, h, side, Vec3A::ZERO, normals, located)
    }

    /// The test tables' hit of sample `sub` of pixel (x, y): nothing on row 0.
    fn located(x: u32, y: u32, sub: u32) -> (PackedHit, Vec3A, Vec3A) {
        let hit = PackedHit {
            t: (x * 1000 + y * 10 + sub) as f32,
            cos_view: 1.0 / (1 + x) as f32,
            kind: if y == 0 {
                HitKind::Nothing
            } else {
                HitKind::Relief
            },
        };
        let n = Vec3A::new(x as f32, y as f32, sub as f32 + 0.5);
        (hit, Vec3A::new(x as f32, y as f32, sub as f32), n)
    }

    #[test]
    fn a_table_holds_each_samples_hit_where_it_was_located() {
        let t = table(5, 3, 2);
        assert_eq!(t.side(), 2);
        for (x, y, sub) in [(0, 0, 0), (4, 2, 3), (2, 1, 1)] {
            assert_eq!(t.get(x, y, sub).t, (x * 1000 + y * 10 + sub) as f32);
        }
        assert_eq!(t.normal(4, 2, 3), None, "no normals asked for");
        assert_eq!(t.bytes(), table_bytes(5, 3, 2, false));
        assert_eq!(
            table_with(5, 3, 2, true).bytes(),
            table_bytes(5, 3, 2, true)
        );
        let t = table_with(5, 3, 2, true);
        for (x, y, sub) in [(0, 0, 0), (4, 2, 3), (2, 1, 1)] {
            let n = Vec3A::new(x as f32, y as f32, sub as f32 + 0.5);
            assert_eq!(t.normal(x, y, sub), Some(n));
        }
    }

    /// Normals are kept when wanted (a lamp view's table) and the table still fits with
    /// them; a table too large with normals is kept without them; one too large even
    /// without is not kept.
    #[test]
    fn normals_are_kept_when_wanted_and_within_the_budget() {
        let dims = (5, 3, 1);
        let with_normals = table_bytes(5, 3, 1, true);
        let hits = PrimaryHits::with_budget(8 * with_normals);
        assert_eq!(hits.keeps(dims, true), Some(true));
        assert_eq!(hits.keeps(dims, false), Some(false));
        let build = |normals| table_with(5, 3, 1, normals);
        let lamp = hits.get("lamp".into(), dims, true, build).expect("kept");
        assert!(lamp.normal(0, 0, 0).is_some());
        let laser = hits.get("laser".into(), dims, false, build).expect("kept");
        assert!(laser.normal(0, 0, 0).is_none());
        let tight = PrimaryHits::with_budget(8 * with_normals - 8);
        assert_eq!(tight.keeps(dims, true), Some(false));
        let lamp = tight.get("lamp".into(), dims, true, build).expect("kept");
        assert!(lamp.normal(0, 0, 0).is_none());
        let none = PrimaryHits::with_budget(8 * table_bytes(5, 3, 1, false) - 8);
        assert_eq!(none.keeps(dims, false), None);
        assert!(none.get("lamp".into(), dims, true, build).is_none());
    }

    /// A table recorded row by row holds what one built from the same hits holds.
    #[test]
    fn a_recorded_table_equals_a_built_one() {
        let built = table_with(20, 3, 2, true);
        let mut recorded = HitTable::empty(20, 3, 2, true);
        recorded
            .rows(Vec3A::ZERO)
            .enumerate()
            .for_each(|(y, mut row)| {
                for x in (0..20).rev() {
                    for sub in 0..4 {
                        let (hit, p, n) = located(x, y as u32, sub);
                        row.record(x, sub, hit, p, n);
                    }
                }
            });
        assert_eq!(recorded.hits, built.hits);
        assert_eq!(recorded.normals, built.normals);
        assert_eq!(recorded.spans, built.spans);
    }

    /// Each run of SPAN pixels bounds its own hits; a row that hit nothing is empty.
    #[test]
    fn each_span_bounds_its_hit_points() {
        let t = table(20, 3, 2);
        assert_eq!(t.spans_per_row(), 2);
        assert_eq!(t.spans().len(), 6);
        assert!(t.spans()[0].is_empty() && t.spans()[1].is_empty());
        let [a, b] = [t.spans()[4], t.spans()[5]];
        assert_eq!(
            (a.lo, a.hi),
            (Vec3A::new(0.0, 2.0, 0.0), Vec3A::new(15.0, 2.0, 3.0))
        );
        assert_eq!(
            (b.lo, b.hi),
            (Vec3A::new(16.0, 2.0, 0.0), Vec3A::new(19.0, 2.0, 3.0))
        );
        assert_eq!(b.cos_min, 1.0 / 20.0);
        assert_eq!(a.far, Vec3A::new(15.0, 2.0, 3.0).length());
        assert!(a.relief && !a.is_empty());
    }

    /// A table is built once and shared; a table a frame recorded is found again and a
    /// second recording of the same view does not replace it.
    #[test]
    fn a_table_is_built_or_recorded_once_and_found_again() {
        let hits = PrimaryHits::default();
        let dims = (5, 3, 1);
        assert!(hits.kept(&"a".into()).is_none());
        let a = hits
            .get("a".into(), dims, false, |_| table(5, 3, 1))
            .expect("built");
        let again = hits
            .get("a".into(), dims, false, |_| panic!("built twice"))
            .expect("kept");
        assert!(Arc::ptr_eq(&a, &again));
        assert!(Arc::ptr_eq(&a, &hits.kept(&"a".into()).expect("kept")));
        hits.keep("b".into(), table(5, 3, 1));
        let b = hits.kept(&"b".into()).expect("recorded");
        hits.keep("b".into(), table(5, 3, 2));
        assert!(Arc::ptr_eq(&b, &hits.kept(&"b".into()).expect("kept")));
        assert_eq!(hits.len(), 2);
    }
}
