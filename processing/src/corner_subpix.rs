//! Sub-pixel refinement of a checkerboard corner (the principle of OpenCV's cornerSubPix):
//! at the true corner q every image gradient ∇I(p) in a window is orthogonal to p − q, so q
//! solves Σ ∇I∇Iᵀ q = Σ ∇I∇Iᵀ p, a 2×2 system iterated until q stops moving.

use crate::gray_image::GrayImage;

/// Refines `start` within a window of `radius` pixels; `None` if the window holds no corner
/// structure (singular system) or the estimate leaves the window.
pub fn refine_corner(image: &GrayImage, start: (f64, f64), radius: usize) -> Option<(f64, f64)> {
    let r = radius as isize;
    let sigma2 = (radius as f64 * 0.5).powi(2) * 2.0;
    let (mut qx, mut qy) = start;
    for _ in 0..30 {
        let (mut a, mut b, mut c, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for dy in -r..=r {
            for dx in -r..=r {
                let (px, py) = (qx + dx as f64, qy + dy as f64);
                let gx = f64::from(image.sample(px + 1.0, py) - image.sample(px - 1.0, py)) * 0.5;
                let gy = f64::from(image.sample(px, py + 1.0) - image.sample(px, py - 1.0)) * 0.5;
                let w = (-((dx * dx + dy * dy) as f64) / sigma2).exp();
                let (gxx, gxy, gyy) = (w * gx * gx, w * gx * gy, w * gy * gy);
                a += gxx;
                b += gxy;
                c += gyy;
                bx += gxx * px + gxy * py;
                by += gxy * px + gyy * py;
            }
        }
        let det = a * c - b * b;
        let solvable = det.abs() > 1e-12 * (a * c).abs().max(1e-30); // false for NaN
        if !solvable {
            return None;
        }
        let nx = (c * bx - b * by) / det;
        let ny = (a * by - b * bx) / det;
        if !(nx.is_finite() && ny.is_finite()) {
            return None;
        }
        let shift = ((nx - qx).powi(2) + (ny - qy).powi(2)).sqrt();
        (qx, qy) = (nx, ny);
        if ((qx - start.0).powi(2) + (qy - start.1).powi(2)).sqrt() > radius as f64 {
            return None;
        }
        if shift < 1e-4 {
            break;
        }
    }
    Some((qx, qy))
}
