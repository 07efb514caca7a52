//! The procedural height-field fixtures (bumps, steps, weave): relief and built-in spatially
//! varying materials from one model, with its random layout drawn once.

use glam::Vec3A;

use super::noise::{floor, lattice, texture, value_noise};
use crate::render::material::Material;
use crate::render::rng::{mix64, unit_f32};

/// The exactly flat fixture's material: grey Lambert 0.5 with a weak Ward lobe.
pub(super) const FLAT: Material = Material::ward(Vec3A::splat(0.5), 0.04, 0.15);
/// The calibration planes' matte white.
pub(super) const PLANE: Material = Material::grey(0.8);
/// Seed of the built-in bumps layout.
pub const BUMPS_SEED: u64 = 0xb0b5;
/// Tallest possible bump of the built-in layout, in mm.
const DEFAULT_BUMP_MAX_MM: f32 = 3.0;

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

/// Which procedural relief, with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Relief {
    /// Bumps on a jittered lattice; heights scaled so the tallest possible is `max_height_mm`.
    Bumps {
        /// Tallest possible bump in mm (3 for the built-in fixture).
        max_height_mm: f32,
        /// Layout seed.
        seed: u64,
    },
    /// Concentric terraces `step_height_mm` apart.
    Steps {
        /// Rise per terrace in mm.
        step_height_mm: f32,
    },
    /// Over-under woven strands.
    Weave,
}

/// A height-field sample's procedural model, with its random layout drawn once.
pub(super) struct Procedural {
    relief: Relief,
    size: f32,
    /// Bumps by lattice cell (row-major, `cols` per row), for `Relief::Bumps`.
    bumps: Vec<Option<Bump>>,
    cols: i32,
}

impl Procedural {
    /// The model of `relief` on a sample `size` mm across.
    pub(super) fn new(relief: Relief, size: f32) -> Procedural {
        let cols = (size / BUMP_CELL_MM).ceil() as i32;
        let palette = [
            Vec3A::new(0.70, 0.25, 0.12),
            Vec3A::new(0.15, 0.45, 0.55),
            Vec3A::new(0.75, 0.60, 0.15),
            Vec3A::new(0.35, 0.55, 0.20),
            Vec3A::new(0.50, 0.30, 0.60),
        ];
        let mut bumps = Vec::new();
        if let Relief::Bumps {
            max_height_mm,
            seed,
        } = relief
        {
            let scale = max_height_mm / DEFAULT_BUMP_MAX_MM;
            for j in 0..cols {
                for i in 0..cols {
                    let h = mix64(seed ^ ((i as u64) << 32 | j as u64));
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
                        height: (1.2 + 1.8 * r(3)).min(0.45 * radius) * scale,
                        inv_r2: 1.0 / (radius * radius),
                        colour: palette[(h >> 56) as usize % palette.len()],
                    });
                    bumps.push(bump);
                }
            }
        }
        Procedural {
            relief,
            size,
            bumps,
            cols,
        }
    }

    /// Surface height at (x, y) in mm.
    pub(super) fn height(&self, x: f32, y: f32) -> f32 {
        match self.relief {
            Relief::Bumps { .. } => self.bumps_at(x, y).0,
            Relief::Steps { step_height_mm } => steps(self.size, step_height_mm, x, y).0,
            Relief::Weave => weave(self.size, x, y).0,
        }
    }

    /// The built-in material at (x, y).
    pub(super) fn material(&self, x: f32, y: f32) -> Material {
        match self.relief {
            Relief::Bumps { .. } => {
                let (_, weight, colour) = self.bumps_at(x, y);
                let base = Vec3A::new(0.62, 0.55, 0.45);
                let tex = 0.85 + 0.3 * texture(11, x, y, 1.5);
                let albedo =
                    (base.lerp(colour, weight.sqrt().min(1.0)) * tex).min(Vec3A::splat(0.95));
                Material::ward(albedo, 0.06, 0.2)
            }
            Relief::Steps { step_height_mm } => steps(self.size, step_height_mm, x, y).1,
            Relief::Weave => weave(self.size, x, y).1,
        }
    }

    /// Bumps on a jittered 10 mm lattice (R ≤ 8 mm, so only the 3×3 neighbouring
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

/// Five concentric square terraces `rise` mm apart, each painted a different colour.
fn steps(size: f32, rise: f32, x: f32, y: f32) -> (f32, Material) {
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
    (rise * (level as f32 + 1.0), m)
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
        // 15% of the brightest channel gets through, tinted halfway from the albedo's hue
        // to white (as the fixture has always rendered).
        let tint = albedo / albedo.max_element().max(1.0e-3);
        Material {
            transmittance: tint.lerp(Vec3A::ONE, 0.5) * (albedo.max_element() * 0.15),
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
