//! Flat calibration charts: the checkerboard and the 24-patch colour checker, evaluated
//! analytically (no texels) so their edges stay sharp.

use glam::Vec3A;

use super::noise::floor;
use crate::render::material::Material;

/// Squares of the calibration board along x and y: 9 × 8, so its 8 × 7 inner corners have
/// an odd sum and the board cannot be mistaken for itself turned half way.
pub const BOARD_SQUARES: [i64; 2] = [9, 8];

/// A calibration board: black (0.03) and white (0.85) matte squares `square` mm on a side,
/// [`BOARD_SQUARES`] of them centred on the origin, in a white margin. The square at the
/// board's −x, +y corner is black, so a detector that puts its first corner where the square
/// diagonally outside is dark, with board x then y turning clockwise in the image, finds board
/// x along +x (the turntable's 0°) on a board lying flat at turntable 0°.
pub(super) fn checkerboard(square: f32, x: f32, y: f32) -> Material {
    let [nx, ny] = BOARD_SQUARES;
    let i = floor(x / square + nx as f32 / 2.0) as i64;
    let j = floor(y / square + ny as f32 / 2.0) as i64;
    let on_board = (0..nx).contains(&i) && (0..ny).contains(&j);
    let dark = on_board && (i + j).rem_euclid(2) == 1;
    Material::grey(if dark { 0.03 } else { 0.85 })
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

/// Centre (x, y) in mm of patch `index` (0..24) of the colour checker on a `size` mm sample:
/// 6 columns a pitch of size·0.96/6 apart along +y, 4 rows along +x from −x.
pub fn colorchecker_patch_centre(size: f32, index: usize) -> (f32, f32) {
    let pitch = size * 0.96 / 6.0;
    let index = index.min(23);
    let (row, col) = ((index / 6) as f32, (index % 6) as f32);
    (
        -2.0 * pitch + (row + 0.5) * pitch,
        -3.0 * pitch + (col + 0.5) * pitch,
    )
}

/// A 6×4 chart on a black card: columns run along +y (left to right for the camera arc at
/// azimuth 0), rows along +x starting at −x (the far side, top of those images).
pub(super) fn colorchecker(size: f32, x: f32, y: f32) -> Material {
    let pitch = size * 0.96 / 6.0;
    let patch = 0.82 * pitch;
    let col = floor((y + 3.0 * pitch) / pitch);
    let row = floor((x + 2.0 * pitch) / pitch);
    if (0.0..6.0).contains(&col) && (0.0..4.0).contains(&row) {
        let index = row as usize * 6 + col as usize;
        let (cx, cy) = colorchecker_patch_centre(size, index);
        if (y - cy).abs() <= 0.5 * patch && (x - cx).abs() <= 0.5 * patch {
            return Material::ward(colorchecker_patch(index), 0.0, 0.2);
        }
    }
    Material::grey(0.03)
}

#[cfg(test)]
mod tests {
    use super::*;

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
