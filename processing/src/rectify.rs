//! Rectification onto the reference plane: a square of the plane (the sample's top, z = 0 in
//! the sample frame) resampled into an N×N image through a calibrated camera. Each output pixel
//! averages k×k points spread over its own footprint, k following the footprint's size in the
//! input image, so a grazing view that squeezes many input pixels into one output pixel is
//! area-averaged instead of aliased (plain bilinear sampling would alias the BTF).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera_model::{CameraModel, Pose};
use crate::error::ProcessingError;

/// The square of the reference plane to resample, and the output size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RectifyGrid {
    /// Centre of the square on the plane, millimetres.
    pub centre_mm: (f64, f64),
    /// Side of the square, millimetres.
    pub size_mm: f64,
    /// Output pixels per side (the seed uses 128 or 256).
    pub pixels: usize,
}

impl RectifyGrid {
    /// Plane coordinates (mm) of output position `(i, j)` in output pixels (centres at +0.5):
    /// columns along +x, rows along +y.
    pub fn plane_point(&self, i: f64, j: f64) -> (f64, f64) {
        let step = self.size_mm / self.pixels as f64;
        (
            self.centre_mm.0 - 0.5 * self.size_mm + i * step,
            self.centre_mm.1 - 0.5 * self.size_mm + j * step,
        )
    }
}

/// An image of interleaved channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// Row-major interleaved values, `width × height × channels`.
    pub data: &'a [f32],
}

/// A rectified image and which of its pixels the camera saw.
#[derive(Debug, Clone, PartialEq)]
pub struct Rectified {
    /// Pixels per side.
    pub pixels: usize,
    /// Row-major interleaved values; 0 where not seen.
    pub data: Vec<f32>,
    /// Whether every sample of the pixel's footprint fell inside the input image.
    pub seen: Vec<bool>,
}

/// Largest supersampling per axis.
const MAX_SAMPLES: usize = 8;

/// Rectifies `image`, taken by `camera` at `pose` (plane → camera), onto `grid`.
pub fn rectify(
    image: &Image<'_>,
    camera: &CameraModel,
    pose: &Pose,
    grid: &RectifyGrid,
) -> Result<Rectified, ProcessingError> {
    if image.data.len() != image.width * image.height * image.channels || image.channels == 0 {
        return Err(ProcessingError::SizeMismatch {
            index: 0,
            expected: image.width * image.height * image.channels,
            got: image.data.len(),
        });
    }
    if !(grid.size_mm.is_finite() && grid.size_mm > 0.0) || grid.pixels == 0 {
        return Err(ProcessingError::BadParameter {
            name: "rectification size",
            value: grid.size_mm,
            why: "the square must have a positive size and at least one pixel",
        });
    }
    let n = grid.pixels;
    let ch = image.channels;
    let project = |i: f64, j: f64| {
        let (x, y) = grid.plane_point(i, j);
        camera
            .project(pose, &Vector3::new(x, y, 0.0))
            .map(|p| (p.x, p.y))
    };
    let mut data = vec![0.0f32; n * n * ch];
    let mut seen = vec![false; n * n];
    let mut acc = vec![0.0f64; ch];
    for j in 0..n {
        for i in 0..n {
            let (fi, fj) = (i as f64, j as f64);
            // The footprint's extent in input pixels decides the samples per axis.
            let corners = [
                project(fi, fj),
                project(fi + 1.0, fj),
                project(fi, fj + 1.0),
                project(fi + 1.0, fj + 1.0),
            ];
            let Some(c) = corners.iter().copied().collect::<Option<Vec<_>>>() else {
                continue;
            };
            let extent = (c[0].0 - c[3].0)
                .abs()
                .max((c[1].0 - c[2].0).abs())
                .max((c[0].1 - c[3].1).abs())
                .max((c[1].1 - c[2].1).abs());
            let k = (extent.ceil() as usize).clamp(1, MAX_SAMPLES);
            acc.iter_mut().for_each(|a| *a = 0.0);
            let mut inside = true;
            'samples: for sj in 0..k {
                for si in 0..k {
                    let (u, v) = match project(
                        fi + (si as f64 + 0.5) / k as f64,
                        fj + (sj as f64 + 0.5) / k as f64,
                    ) {
                        Some(p) => p,
                        None => {
                            inside = false;
                            break 'samples;
                        }
                    };
                    if !bilinear(image, u, v, &mut acc) {
                        inside = false;
                        break 'samples;
                    }
                }
            }
            if inside {
                let out = &mut data[(j * n + i) * ch..(j * n + i + 1) * ch];
                for (o, a) in out.iter_mut().zip(&acc) {
                    *o = (*a / (k * k) as f64) as f32;
                }
                seen[j * n + i] = true;
            }
        }
    }
    Ok(Rectified {
        pixels: n,
        data,
        seen,
    })
}

/// Adds the bilinear sample of `image` at `(u, v)` (pixel centres at integers) to `acc`;
/// false if the point is outside the image.
fn bilinear(image: &Image<'_>, u: f64, v: f64, acc: &mut [f64]) -> bool {
    let (w, h, ch) = (image.width, image.height, image.channels);
    if !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
        return false;
    }
    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (u - x0 as f64, v - y0 as f64);
    for (c, a) in acc.iter_mut().enumerate() {
        let p = |x: usize, y: usize| f64::from(image.data[(y * w + x) * ch + c]);
        let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
        let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
        *a += top * (1.0 - fy) + bottom * fy;
    }
    true
}

#[cfg(test)]
mod tests {
    use nalgebra::Rotation3;

    use super::*;
    use crate::camera_model::{Distortion, Intrinsics};

    fn camera() -> CameraModel {
        CameraModel {
            intrinsics: Intrinsics {
                fx: 800.0,
                fy: 800.0,
                cx: 200.0,
                cy: 150.0,
            },
            distortion: Distortion {
                k1: -0.1,
                ..Distortion::default()
            },
        }
    }

    /// An image of the plane texture f(x, y) = x + 2y (mm) seen through `camera` at `pose`,
    /// made by inverting the projection pixel by pixel.
    fn linear_texture_image(cam: &CameraModel, pose: &Pose, w: usize, h: usize) -> Vec<f32> {
        let r = pose.rotation_matrix();
        let rt_t = r.transpose() * Vector3::from(pose.translation);
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (nx, ny) = cam.normalise(x as f64, y as f64).unwrap();
                let d = r.transpose() * Vector3::new(nx, ny, 1.0);
                let lambda = rt_t.z / d.z;
                let (px, py) = (lambda * d.x - rt_t.x, lambda * d.y - rt_t.y);
                out[y * w + x] = (px + 2.0 * py) as f32;
            }
        }
        out
    }

    #[test]
    fn a_linear_texture_is_reproduced_at_an_oblique_view() {
        let cam = camera();
        // 50° from the normal, 400 mm away.
        let r = Rotation3::from_euler_angles(50f64.to_radians(), 0.0, 0.0);
        let pose = Pose::from_parts(&r, Vector3::new(0.0, 0.0, 400.0));
        let (w, h) = (400, 300);
        let img = linear_texture_image(&cam, &pose, w, h);
        let grid = RectifyGrid {
            centre_mm: (0.0, 0.0),
            size_mm: 40.0,
            pixels: 64,
        };
        let image = Image {
            width: w,
            height: h,
            channels: 1,
            data: &img,
        };
        let out = rectify(&image, &cam, &pose, &grid).unwrap();
        assert!(out.seen.iter().all(|&s| s));
        for j in 0..64 {
            for i in 0..64 {
                let (x, y) = grid.plane_point(i as f64 + 0.5, j as f64 + 0.5);
                let v = f64::from(out.data[j * 64 + i]);
                // A linear texture averages to its centre value over any symmetric footprint.
                assert!(
                    (v - (x + 2.0 * y)).abs() < 0.02,
                    "({i}, {j}): {v} vs {}",
                    x + 2.0 * y
                );
            }
        }
    }

    #[test]
    fn pixels_outside_the_view_are_marked_unseen_not_invented() {
        let cam = camera();
        let pose = Pose::from_parts(&Rotation3::identity(), Vector3::new(0.0, 0.0, 400.0));
        let img = vec![1.0f32; 400 * 300];
        let image = Image {
            width: 400,
            height: 300,
            channels: 1,
            data: &img,
        };
        // 300 mm square at 400 mm: far wider than the view.
        let grid = RectifyGrid {
            centre_mm: (0.0, 0.0),
            size_mm: 300.0,
            pixels: 32,
        };
        let out = rectify(&image, &cam, &pose, &grid).unwrap();
        assert!(!out.seen[0] && out.data[0] == 0.0);
        assert!(out.seen[16 * 32 + 16] && out.data[16 * 32 + 16] == 1.0);
        assert!(out.data.iter().all(|v| v.is_finite()));
        let bad = RectifyGrid {
            size_mm: f64::NAN,
            ..grid
        };
        assert!(rectify(&image, &cam, &pose, &bad).is_err());
    }
}
