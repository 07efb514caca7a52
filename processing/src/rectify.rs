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

/// One bilinear sample of the input: the index of its top-left pixel and its fractions in
/// 1/65536 of a pixel (8 bytes a sample: a view's map stays a few MB).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tap {
    pixel: u32,
    fx: u16,
    fy: u16,
}

/// The unit of a [`Tap`]'s fractions.
const FRACTION: f64 = 65536.0;

/// Where every output pixel of a rectification samples the input image. It depends only on
/// the camera, its pose and the grid, so it is computed once per view and applied to every
/// capture of that view (a BTF view has one capture per light).
#[derive(Debug, Clone, PartialEq)]
pub struct RectifyMap {
    pixels: usize,
    width: usize,
    height: usize,
    /// Output pixel `p`'s samples are `taps[starts[p]..starts[p + 1]]`; none if unseen.
    starts: Vec<u32>,
    taps: Vec<Tap>,
}

impl RectifyMap {
    /// The map of a `width × height` image taken by `camera` at `pose` (plane → camera) onto
    /// `grid`: each output pixel averages k×k points spread over its footprint, k following
    /// the footprint's extent in input pixels (1 to 8); a pixel any of whose points falls
    /// outside the image is unseen.
    pub fn new(
        camera: &CameraModel,
        pose: &Pose,
        grid: &RectifyGrid,
        width: usize,
        height: usize,
    ) -> Result<RectifyMap, ProcessingError> {
        if !(grid.size_mm.is_finite() && grid.size_mm > 0.0) || grid.pixels == 0 {
            return Err(ProcessingError::BadParameter {
                name: "rectification size",
                value: grid.size_mm,
                why: "the square must have a positive size and at least one pixel",
            });
        }
        if width == 0 || height == 0 || width.saturating_mul(height) > u32::MAX as usize {
            return Err(ProcessingError::BadParameter {
                name: "image size",
                value: (width * height) as f64,
                why: "the image must have pixels, fewer than 2³²",
            });
        }
        let n = grid.pixels;
        let project = |i: f64, j: f64| {
            let (x, y) = grid.plane_point(i, j);
            camera
                .project(pose, &Vector3::new(x, y, 0.0))
                .map(|p| (p.x, p.y))
        };
        let mut starts = Vec::with_capacity(n * n + 1);
        let mut taps = Vec::new();
        let mut pixel_taps = Vec::with_capacity(MAX_SAMPLES * MAX_SAMPLES);
        starts.push(0u32);
        for j in 0..n {
            for i in 0..n {
                let (fi, fj) = (i as f64, j as f64);
                pixel_taps.clear();
                // The footprint's extent in input pixels decides the samples per axis.
                let corners = [
                    project(fi, fj),
                    project(fi + 1.0, fj),
                    project(fi, fj + 1.0),
                    project(fi + 1.0, fj + 1.0),
                ];
                if let [Some(c0), Some(c1), Some(c2), Some(c3)] = corners {
                    let extent = (c0.0 - c3.0)
                        .abs()
                        .max((c1.0 - c2.0).abs())
                        .max((c0.1 - c3.1).abs())
                        .max((c1.1 - c2.1).abs());
                    let k = (extent.ceil() as usize).clamp(1, MAX_SAMPLES);
                    'samples: for sj in 0..k {
                        for si in 0..k {
                            let tap = project(
                                fi + (si as f64 + 0.5) / k as f64,
                                fj + (sj as f64 + 0.5) / k as f64,
                            )
                            .and_then(|(u, v)| tap(u, v, width, height));
                            match tap {
                                Some(t) => pixel_taps.push(t),
                                None => {
                                    pixel_taps.clear();
                                    break 'samples;
                                }
                            }
                        }
                    }
                }
                taps.extend_from_slice(&pixel_taps);
                starts.push(u32::try_from(taps.len()).map_err(|_| {
                    ProcessingError::BadParameter {
                        name: "rectification size",
                        value: n as f64,
                        why: "the grid needs more than 2³² samples; use fewer pixels",
                    }
                })?);
            }
        }
        Ok(RectifyMap {
            pixels: n,
            width,
            height,
            starts,
            taps,
        })
    }

    /// Which output pixels the camera saw (every sample of the footprint inside the image).
    pub fn seen(&self) -> Vec<bool> {
        self.starts.windows(2).map(|w| w[1] > w[0]).collect()
    }

    /// Rectifies `image` (of the size the map was made for).
    pub fn apply(&self, image: &Image<'_>) -> Result<Rectified, ProcessingError> {
        let ch = image.channels;
        if image.data.len() != image.width * image.height * ch
            || ch == 0
            || (image.width, image.height) != (self.width, self.height)
        {
            return Err(ProcessingError::SizeMismatch {
                index: 0,
                expected: self.width * self.height * ch.max(1),
                got: image.data.len(),
            });
        }
        let n = self.pixels;
        let w = self.width;
        let mut data = vec![0.0f32; n * n * ch];
        let mut acc = vec![0.0f64; ch];
        for (p, out) in data.chunks_exact_mut(ch).enumerate() {
            let taps = &self.taps[self.starts[p] as usize..self.starts[p + 1] as usize];
            if taps.is_empty() {
                continue;
            }
            acc.iter_mut().for_each(|a| *a = 0.0);
            for t in taps {
                let base = t.pixel as usize;
                let (x0, y0) = (base % w, base / w);
                let dx = usize::from(x0 + 1 < w);
                let dy = if y0 + 1 < self.height { w } else { 0 };
                let (fx, fy) = (f64::from(t.fx) / FRACTION, f64::from(t.fy) / FRACTION);
                let weights = [
                    (base, (1.0 - fx) * (1.0 - fy)),
                    (base + dx, fx * (1.0 - fy)),
                    (base + dy, (1.0 - fx) * fy),
                    (base + dx + dy, fx * fy),
                ];
                for (c, a) in acc.iter_mut().enumerate() {
                    *a += weights
                        .iter()
                        .map(|&(q, wt)| wt * f64::from(image.data[q * ch + c]))
                        .sum::<f64>();
                }
            }
            for (o, a) in out.iter_mut().zip(&acc) {
                *o = (*a / taps.len() as f64) as f32;
            }
        }
        Ok(Rectified {
            pixels: n,
            data,
            seen: self.seen(),
        })
    }
}

/// The bilinear tap at `(u, v)` (pixel centres at integers) of a `width × height` image;
/// `None` outside it.
fn tap(u: f64, v: f64, width: usize, height: usize) -> Option<Tap> {
    if !(u >= 0.0 && v >= 0.0 && u <= (width - 1) as f64 && v <= (height - 1) as f64) {
        return None;
    }
    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
    let fraction = |f: f64| (f * FRACTION).round().min(FRACTION - 1.0) as u16;
    Some(Tap {
        pixel: (y0 * width + x0) as u32,
        fx: fraction(u - x0 as f64),
        fy: fraction(v - y0 as f64),
    })
}

/// Rectifies `image`, taken by `camera` at `pose` (plane → camera), onto `grid` (a
/// [`RectifyMap`] made and applied once).
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
    RectifyMap::new(camera, pose, grid, image.width, image.height)?.apply(image)
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

    #[test]
    fn one_map_serves_every_capture_of_a_view_and_refuses_another_size() {
        let cam = camera();
        let r = Rotation3::from_euler_angles(30f64.to_radians(), 0.0, 0.0);
        let pose = Pose::from_parts(&r, Vector3::new(0.0, 0.0, 400.0));
        let grid = RectifyGrid {
            centre_mm: (0.0, 0.0),
            size_mm: 40.0,
            pixels: 32,
        };
        let map = RectifyMap::new(&cam, &pose, &grid, 400, 300).unwrap();
        let texture = linear_texture_image(&cam, &pose, 400, 300);
        for scale in [1.0f32, 3.0] {
            let img: Vec<f32> = texture.iter().map(|v| v * scale).collect();
            let image = Image {
                width: 400,
                height: 300,
                channels: 1,
                data: &img,
            };
            let out = map.apply(&image).unwrap();
            assert_eq!(out, rectify(&image, &cam, &pose, &grid).unwrap());
            let (x, y) = grid.plane_point(16.5, 16.5);
            let v = out.data[16 * 32 + 16];
            assert!((v - scale * (x + 2.0 * y) as f32).abs() < 0.05, "{v}");
        }
        let small = vec![0.0f32; 200 * 150];
        let image = Image {
            width: 200,
            height: 150,
            channels: 1,
            data: &small,
        };
        assert!(map.apply(&image).is_err());
        assert!(RectifyMap::new(&cam, &pose, &grid, 0, 300).is_err());
    }
}
