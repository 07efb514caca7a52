//! Procedural samples and fixtures on the turntable: their relief (a height field, or exactly
//! flat) and their materials (Lambert albedo, isotropic Ward lobe, transmittance).

use glam::Vec3A;
use rayon::prelude::*;

use super::heightfield::HeightGrid;
use super::rng::{mix64, unit_f32};

pub use stagehand_devices::rig::FIXTURES;

/// Finest relief and texel spacing, in mm (about one pixel of the light stage cameras).
const TEXEL_MM: f32 = 0.1;
/// Most cells per side, to bound memory and build time for large samples.
const MAX_CELLS: usize = 1024;

pub use super::material::Material;

/// Which procedural sample this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// z = 0, grey Lambert 0.5 with a weak Ward lobe.
    Flat,
    /// Smooth coloured bumps up to 3 mm.
    Bumps,
    /// Concentric square terraces.
    Steps,
    /// Over-under woven straw strands with see-through gaps.
    Weave,
    /// Flat 10 mm black and white squares.
    Checkerboard,
    /// Flat 6×4 colour checker.
    ColorChecker,
    /// Two matte white planes at 0 and 20 mm (y > 0 raised), for laser-plane calibration.
    Planes,
}

/// Per-texel material of a height-field sample, quantised to keep the grid small.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Texel {
    albedo: [u8; 3],
    trans: u8,
    ks: u8,
    alpha: u8,
}

impl Texel {
    fn encode(m: &Material) -> Texel {
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        let t = m.transmittance.max_element();
        Texel {
            albedo: [q(m.albedo.x), q(m.albedo.y), q(m.albedo.z)],
            trans: q(t),
            ks: q(m.ks),
            alpha: q(m.alpha),
        }
    }

    fn decode(&self) -> Material {
        let f = |v: u8| v as f32 * (1.0 / 255.0);
        let albedo = Vec3A::new(f(self.albedo[0]), f(self.albedo[1]), f(self.albedo[2]));
        // Transmitted light is tinted like the albedo (normalised), scaled by the stored maximum.
        let trans = if self.trans == 0 {
            Vec3A::ZERO
        } else {
            let tint = albedo / albedo.max_element().max(1.0e-3);
            tint.lerp(Vec3A::ONE, 0.5) * f(self.trans)
        };
        Material {
            transmittance: trans,
            ..Material::ward(albedo, f(self.ks), f(self.alpha).max(0.01))
        }
    }
}

/// A built sample: square, `size_mm` on a side, centred on the turntable.
#[derive(Debug)]
pub struct Sample {
    /// Fixture name.
    pub name: String,
    /// Which procedural model.
    pub kind: Kind,
    /// Edge length in mm.
    pub size_mm: f32,
    /// The relief; `None` for exactly flat samples (z = 0 everywhere, no shadow rays ever).
    pub grid: Option<HeightGrid>,
    texels: Vec<Texel>,
    tex_n: usize,
    tex_cell: f32,
    /// Largest Ward ρs anywhere on the sample.
    pub max_ks: f32,
    /// Largest transmittance anywhere on the sample.
    pub max_transmittance: f32,
}

impl Sample {
    /// Builds the named fixture with its relief and materials sampled every `step_mm` (at
    /// least 0.1 mm), or `None` if the name is unknown.
    pub fn build(name: &str, size_mm: f32, step_mm: f32) -> Option<Sample> {
        let kind = match name {
            "flat" => Kind::Flat,
            "bumps" => Kind::Bumps,
            "steps" => Kind::Steps,
            "weave" => Kind::Weave,
            "checkerboard" => Kind::Checkerboard,
            "colorchecker" => Kind::ColorChecker,
            "planes" => Kind::Planes,
            _ => return None,
        };
        let mut sample = Sample {
            name: name.to_string(),
            kind,
            size_mm,
            grid: None,
            texels: Vec::new(),
            tex_n: 0,
            tex_cell: 1.0,
            max_ks: 0.0,
            max_transmittance: 0.0,
        };
        match kind {
            Kind::Flat => sample.max_ks = FLAT.ks,
            Kind::Checkerboard | Kind::ColorChecker => {}
            Kind::Planes => {
                let n = cells(size_mm, step_mm);
                let raised = |_: f32, y: f32| if y > 0.0 { PLANE_STEP_MM } else { 0.0 };
                sample.grid = Some(HeightGrid::build(n, size_mm, raised));
            }
            Kind::Bumps | Kind::Steps | Kind::Weave => {
                let model = Procedural::new(kind, size_mm);
                let n = cells(size_mm, step_mm);
                let grid = HeightGrid::build(n, size_mm, |x, y| model.height(x, y));
                let tn = n;
                let cell = size_mm / tn as f32;
                let origin = -0.5 * size_mm;
                sample.texels = (0..tn * tn)
                    .into_par_iter()
                    .map(|k| {
                        let x = origin + ((k % tn) as f32 + 0.5) * cell;
                        let y = origin + ((k / tn) as f32 + 0.5) * cell;
                        Texel::encode(&model.material(x, y))
                    })
                    .collect();
                sample.tex_n = tn;
                sample.tex_cell = cell;
                let max = |f: fn(&Texel) -> u8| sample.texels.iter().map(f).max().unwrap_or(0);
                sample.max_ks = max(|t| t.ks) as f32 / 255.0;
                sample.max_transmittance = max(|t| t.trans) as f32 / 255.0;
                sample.grid = Some(grid);
            }
        }
        Some(sample)
    }

    /// Whether (x, y) lies on the sample's square footprint.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let h = 0.5 * self.size_mm;
        x.abs() <= h && y.abs() <= h
    }

    /// The material at (x, y) on the sample.
    pub fn material_at(&self, x: f32, y: f32) -> Material {
        match self.kind {
            Kind::Flat => FLAT,
            Kind::Planes => PLANE,
            Kind::Checkerboard => checkerboard(x, y),
            Kind::ColorChecker => colorchecker(self.size_mm, x, y),
            Kind::Bumps | Kind::Steps | Kind::Weave => {
                let h = 0.5 * self.size_mm;
                let last = self.tex_n.saturating_sub(1);
                let index = |c: f32| (((c + h) / self.tex_cell).max(0.0) as usize).min(last);
                self.texels
                    .get(index(y) * self.tex_n + index(x))
                    .map(Texel::decode)
                    .unwrap_or(FLAT)
            }
        }
    }

    /// Surface height at (x, y).
    pub fn height_at(&self, x: f32, y: f32) -> f32 {
        self.grid.as_ref().map_or(0.0, |g| g.height_at(x, y))
    }
}

/// Cells per side for a sample of `size` mm sampled every `step` mm.
fn cells(size: f32, step: f32) -> usize {
    ((size / step.max(TEXEL_MM)).ceil() as usize).clamp(16, MAX_CELLS)
}

const FLAT: Material = Material::ward(Vec3A::splat(0.5), 0.04, 0.15);
const PLANE: Material = Material::grey(0.8);
const PLANE_STEP_MM: f32 = 20.0;

/// Floor without a libm call (baseline x86-64 has no rounding instruction).
#[inline]
fn floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// A lattice value in [0, 1) for integer point (i, j).
#[inline]
fn lattice(seed: u64, i: i32, j: i32) -> f32 {
    unit_f32(mix64(seed ^ ((i as u32 as u64) << 32 | j as u32 as u64)))
}

/// Smooth value noise in [0, 1] on a lattice of `scale` mm (for albedo texture).
fn value_noise(seed: u64, x: f32, y: f32, scale: f32) -> f32 {
    let (u, v) = (x / scale, y / scale);
    let (fi, fj) = (floor(u), floor(v));
    let (a, b) = (u - fi, v - fj);
    let (a, b) = (a * a * (3.0 - 2.0 * a), b * b * (3.0 - 2.0 * b));
    let (i, j) = (fi as i32, fj as i32);
    let (v00, v10) = (lattice(seed, i, j), lattice(seed, i + 1, j));
    let (v01, v11) = (lattice(seed, i, j + 1), lattice(seed, i + 1, j + 1));
    let top = v00 + (v10 - v00) * a;
    let bottom = v01 + (v11 - v01) * a;
    top + (bottom - top) * b
}

/// Two octaves of value noise, the second rotated, to hide the lattice.
fn texture(seed: u64, x: f32, y: f32, scale: f32) -> f32 {
    let (rx, ry) = (0.8 * x - 0.6 * y, 0.6 * x + 0.8 * y);
    0.6 * value_noise(seed, x, y, scale) + 0.4 * value_noise(seed ^ 0x77, rx, ry, 0.45 * scale)
}

const BUMP_CELL_MM: f32 = 10.0;

/// One smooth bump H·(1 − r²/R²)³.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Bump {
    cx: f32,
    cy: f32,
    height: f32,
    inv_r2: f32,
    colour: Vec3A,
}

/// A height-field sample's procedural model, with its random layout drawn once.
struct Procedural {
    kind: Kind,
    size: f32,
    /// Bumps by lattice cell (row-major, `cols` per row), for `Kind::Bumps`.
    bumps: Vec<Option<Bump>>,
    cols: i32,
}

impl Procedural {
    fn new(kind: Kind, size: f32) -> Procedural {
        let cols = (size / BUMP_CELL_MM).ceil() as i32;
        let palette = [
            Vec3A::new(0.70, 0.25, 0.12),
            Vec3A::new(0.15, 0.45, 0.55),
            Vec3A::new(0.75, 0.60, 0.15),
            Vec3A::new(0.35, 0.55, 0.20),
            Vec3A::new(0.50, 0.30, 0.60),
        ];
        let mut bumps = Vec::new();
        if kind == Kind::Bumps {
            for j in 0..cols {
                for i in 0..cols {
                    let h = mix64(0xb0b5 ^ ((i as u64) << 32 | j as u64));
                    let r = |k: u32| unit_f32(h.rotate_left(8 * k));
                    let cx = (i as f32 + 0.5) * BUMP_CELL_MM + (r(1) - 0.5) * 4.0;
                    let cy = (j as f32 + 0.5) * BUMP_CELL_MM + (r(2) - 0.5) * 4.0;
                    // Keep the whole kernel on the sample so its edge meets the turntable at 0.
                    let radius = (5.0 + 3.0 * r(4))
                        .min(cx - 0.5)
                        .min(cy - 0.5)
                        .min(size - cx - 0.5)
                        .min(size - cy - 0.5);
                    let bump = (r(0) >= 0.12 && radius >= 2.0).then(|| Bump {
                        cx,
                        cy,
                        // Shrunk bumps at the edge stay gentle: H ≤ 0.45 R.
                        height: (1.2 + 1.8 * r(3)).min(0.45 * radius),
                        inv_r2: 1.0 / (radius * radius),
                        colour: palette[(h >> 56) as usize % palette.len()],
                    });
                    bumps.push(bump);
                }
            }
        }
        Procedural {
            kind,
            size,
            bumps,
            cols,
        }
    }

    fn height(&self, x: f32, y: f32) -> f32 {
        match self.kind {
            Kind::Bumps => self.bumps_at(x, y).0,
            Kind::Steps => steps(self.size, x, y).0,
            Kind::Weave => weave(self.size, x, y).0,
            _ => 0.0,
        }
    }

    fn material(&self, x: f32, y: f32) -> Material {
        match self.kind {
            Kind::Bumps => {
                let (_, weight, colour) = self.bumps_at(x, y);
                let base = Vec3A::new(0.62, 0.55, 0.45);
                let tex = 0.85 + 0.3 * texture(11, x, y, 1.5);
                let albedo =
                    (base.lerp(colour, weight.sqrt().min(1.0)) * tex).min(Vec3A::splat(0.95));
                Material::ward(albedo, 0.06, 0.2)
            }
            Kind::Steps => steps(self.size, x, y).1,
            Kind::Weave => weave(self.size, x, y).1,
            _ => FLAT,
        }
    }

    /// Bumps on a jittered 10 mm lattice (H ≤ 3 mm, R ≤ 8 mm, so only the 3×3 neighbouring
    /// cells reach a point): total height, the summed kernel weight (clamped to 1) and the
    /// weight-averaged bump colour, so overlapping bumps blend without seams.
    fn bumps_at(&self, x: f32, y: f32) -> (f32, f32, Vec3A) {
        let half = 0.5 * self.size;
        let (gx, gy) = (x + half, y + half);
        let ci = floor(gx / BUMP_CELL_MM) as i32;
        let cj = floor(gy / BUMP_CELL_MM) as i32;
        let mut height = 0.0f32;
        let (mut weight, mut colour) = (0.0f32, Vec3A::ZERO);
        for j in (cj - 1).max(0)..=(cj + 1).min(self.cols - 1) {
            for i in (ci - 1).max(0)..=(ci + 1).min(self.cols - 1) {
                let Some(b) = self.bumps[(j * self.cols + i) as usize] else {
                    continue;
                };
                let d2 = ((gx - b.cx) * (gx - b.cx) + (gy - b.cy) * (gy - b.cy)) * b.inv_r2;
                if d2 < 1.0 {
                    let k = (1.0 - d2) * (1.0 - d2) * (1.0 - d2);
                    height += b.height * k;
                    weight += k;
                    colour += b.colour * k;
                }
            }
        }
        let colour = if weight > 0.0 {
            colour / weight
        } else {
            colour
        };
        (height, weight.min(1.0), colour)
    }
}

/// Five concentric square terraces 1.5 mm apart, each painted a different colour.
fn steps(size: f32, x: f32, y: f32) -> (f32, Material) {
    let ring = 0.1 * size;
    let m = x.abs().max(y.abs());
    let level = (((0.5 * size - m) / ring).max(0.0) as usize).min(4);
    let colours = [
        Vec3A::new(0.60, 0.60, 0.62),
        Vec3A::new(0.25, 0.40, 0.65),
        Vec3A::new(0.65, 0.45, 0.25),
        Vec3A::new(0.30, 0.60, 0.35),
        Vec3A::new(0.75, 0.70, 0.60),
    ];
    let tex = 0.92 + 0.16 * texture(5, x, y, 0.8);
    let m = Material::ward(colours[level] * tex, 0.05, 0.12);
    (1.5 * (level as f32 + 1.0), m)
}

/// Woven straw: strands 5 mm wide on a 6 mm pitch along x (warp) and y (weft), passing over
/// and under each other; 1 mm gaps let the backlight through.
fn weave(size: f32, x: f32, y: f32) -> (f32, Material) {
    const PITCH: f32 = 6.0;
    const WIDTH: f32 = 5.0;
    const THICK: f32 = 1.2;
    const AMP: f32 = 0.35;
    let pi = std::f32::consts::PI;
    let half = 0.5 * size;
    let (gx, gy) = (x + half, y + half);
    let (i, j) = (floor(gx / PITCH), floor(gy / PITCH));
    let mid = AMP + 0.5 * THICK;
    // Warp strand j runs along x; it is on top where (i + j) is even.
    let dy = gy - (j + 0.5) * PITCH;
    let warp_prof = (1.0 - (2.0 * dy / WIDTH).powi(2)).max(0.0).sqrt();
    let warp = mid + AMP * (pi * (gx / PITCH - 0.5) - pi * j).cos() + 0.5 * THICK * warp_prof;
    let dx = gx - (i + 0.5) * PITCH;
    let weft_prof = (1.0 - (2.0 * dx / WIDTH).powi(2)).max(0.0).sqrt();
    let weft = mid - AMP * (pi * (gy / PITCH - 0.5) - pi * i).cos() + 0.5 * THICK * weft_prof;
    let on_warp = warp_prof > 0.0;
    let on_weft = weft_prof > 0.0;
    let straw = Vec3A::new(0.72, 0.57, 0.30);
    let strand = |index: f32, across: f32, along: f32, seed: u64| {
        let v = 0.85 + 0.25 * lattice(seed, index as i32, 0);
        let stripes = 0.10 * (across * 2.0 * pi / 0.6).sin();
        let fibre = 1.0 + stripes + 0.06 * (value_noise(seed, along, across, 2.0) - 0.5);
        let albedo = (straw * v * fibre).min(Vec3A::splat(0.95));
        Material {
            transmittance: albedo * 0.15,
            ..Material::ward(albedo, 0.10, 0.18)
        }
    };
    match (on_warp && (!on_weft || warp >= weft), on_weft) {
        (true, _) => (warp, strand(j, dy, gx, 21)),
        (false, true) => (weft, strand(i, dx, gy, 37)),
        (false, false) => {
            let gap = Material {
                transmittance: Vec3A::splat(0.85),
                ..Material::ward(Vec3A::splat(0.03), 0.0, 0.2)
            };
            (0.0, gap)
        }
    }
}

fn checkerboard(x: f32, y: f32) -> Material {
    let parity = (floor(x / 10.0) as i64 + floor(y / 10.0) as i64).rem_euclid(2);
    Material::grey(if parity == 0 { 0.85 } else { 0.03 })
}

/// Published sRGB values of the 24 ColorChecker patches (row by row, dark skin first).
const COLORCHECKER_SRGB: [[u8; 3]; 24] = [
    [115, 82, 68],
    [194, 150, 130],
    [98, 122, 157],
    [87, 108, 67],
    [133, 128, 177],
    [103, 189, 170],
    [214, 126, 44],
    [80, 91, 166],
    [193, 90, 99],
    [94, 60, 108],
    [157, 188, 64],
    [224, 163, 46],
    [56, 61, 150],
    [70, 148, 73],
    [175, 54, 60],
    [231, 199, 31],
    [187, 86, 149],
    [8, 133, 161],
    [243, 243, 242],
    [200, 200, 200],
    [160, 160, 160],
    [122, 122, 121],
    [85, 85, 85],
    [52, 52, 52],
];

/// sRGB transfer function inverse: encoded value in [0, 1] to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear reflectance of ColorChecker patch `index` (0..24).
pub fn colorchecker_patch(index: usize) -> Vec3A {
    let p = COLORCHECKER_SRGB[index.min(23)];
    Vec3A::new(
        srgb_to_linear(p[0] as f32 / 255.0),
        srgb_to_linear(p[1] as f32 / 255.0),
        srgb_to_linear(p[2] as f32 / 255.0),
    )
}

/// A 6×4 chart on a black card: columns run along +y (left to right for the camera arc at
/// azimuth 0), rows along +x starting at −x (the far side, top of those images).
fn colorchecker(size: f32, x: f32, y: f32) -> Material {
    let pitch = size * 0.96 / 6.0;
    let patch = 0.82 * pitch;
    let col = floor((y + 3.0 * pitch) / pitch);
    let row = floor((x + 2.0 * pitch) / pitch);
    if (0.0..6.0).contains(&col) && (0.0..4.0).contains(&row) {
        let cy = -3.0 * pitch + (col + 0.5) * pitch;
        let cx = -2.0 * pitch + (row + 0.5) * pitch;
        if (y - cy).abs() <= 0.5 * patch && (x - cx).abs() <= 0.5 * patch {
            let albedo = colorchecker_patch(row as usize * 6 + col as usize);
            return Material::ward(albedo, 0.0, 0.2);
        }
    }
    Material::grey(0.03)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_fixture_builds_and_unknown_does_not() {
        for name in FIXTURES {
            assert!(Sample::build(name, 80.0, 0.2).is_some(), "{name}");
        }
        assert!(Sample::build("teapot", 80.0, 0.2).is_none());
    }

    #[test]
    fn reliefs_have_the_documented_shape() {
        let flat = Sample::build("flat", 80.0, 0.1).expect("flat");
        assert!(flat.grid.is_none());
        let bumps = Sample::build("bumps", 80.0, 0.1).expect("bumps");
        let g = bumps.grid.as_ref().expect("grid");
        assert!(g.zmax() > 1.0 && g.zmax() < 6.0, "bumps zmax {}", g.zmax());
        assert_eq!(g.edge_max(), 0.0, "bumps meet the turntable at height 0");
        let planes = Sample::build("planes", 80.0, 0.2).expect("planes");
        assert_eq!(planes.height_at(0.0, 20.0), 20.0);
        assert_eq!(planes.height_at(0.0, -20.0), 0.0);
        let weave = Sample::build("weave", 80.0, 0.2).expect("weave");
        assert!(weave.max_transmittance > 0.5);
        let steps = Sample::build("steps", 80.0, 0.2).expect("steps");
        assert_eq!(steps.height_at(0.0, 0.0), 7.5);
        assert_eq!(steps.height_at(39.0, 0.0), 1.5);
    }

    #[test]
    fn colorchecker_white_and_black_patches() {
        let white = colorchecker_patch(18);
        let black = colorchecker_patch(23);
        assert!(white.min_element() > 0.85 && white.max_element() < 0.95);
        assert!(black.max_element() < 0.05);
        // Patch 0 (dark skin) sits at the −x, −y corner of the chart.
        let m = colorchecker(80.0, -2.0 * 12.8 + 6.4, -3.0 * 12.8 + 6.4);
        assert_eq!(m.albedo, colorchecker_patch(0));
    }
}
