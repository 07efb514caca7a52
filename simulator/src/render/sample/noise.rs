//! Smooth value noise for procedural textures, without libm calls in the hot path.

use crate::render::rng::{mix64, unit_f32};

/// Floor without a libm call (baseline x86-64 has no rounding instruction).
#[inline]
pub(super) fn floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// A lattice value in [0, 1) for integer point (i, j).
#[inline]
pub(super) fn lattice(seed: u64, i: i32, j: i32) -> f32 {
    unit_f32(mix64(seed ^ ((i as u32 as u64) << 32 | j as u32 as u64)))
}

/// Smooth value noise in [0, 1] on a lattice of `scale` mm (for albedo texture).
pub(super) fn value_noise(seed: u64, x: f32, y: f32, scale: f32) -> f32 {
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
pub(super) fn texture(seed: u64, x: f32, y: f32, scale: f32) -> f32 {
    let (rx, ry) = (0.8 * x - 0.6 * y, 0.6 * x + 0.8 * y);
    0.6 * value_noise(seed, x, y, scale) + 0.4 * value_noise(seed ^ 0x77, rx, ry, 0.45 * scale)
}
