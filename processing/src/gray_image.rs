//! A single-channel f32 image and the Gaussian smoothing that corner detection needs.

/// A grayscale image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixel values, `width × height`.
    pub data: Vec<f32>,
}

impl GrayImage {
    /// A `width × height` image of zeros.
    pub fn new(width: usize, height: usize) -> GrayImage {
        GrayImage {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// The pixel at `(x, y)`, clamped to the border.
    pub fn at(&self, x: isize, y: isize) -> f32 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.data[y * self.width + x]
    }

    /// Bilinear sample at `(x, y)` (pixel centres at integers), clamped to the border.
    pub fn sample(&self, x: f64, y: f64) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as isize, y0 as isize);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The image smoothed by a Gaussian of `sigma` pixels (separable, kernel to 3σ, border
    /// clamped).
    pub fn gaussian(&self, sigma: f64) -> GrayImage {
        let radius = (3.0 * sigma).ceil().max(1.0) as isize;
        let kernel: Vec<f32> = {
            let k: Vec<f64> = (-radius..=radius)
                .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
                .collect();
            let sum: f64 = k.iter().sum();
            k.iter().map(|v| (v / sum) as f32).collect()
        };
        let (w, h) = (self.width as isize, self.height as isize);
        let mut rows = GrayImage::new(self.width, self.height);
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (i, k) in kernel.iter().enumerate() {
                    acc += k * self.at(x + i as isize - radius, y);
                }
                rows.data[(y * w + x) as usize] = acc;
            }
        }
        let mut out = GrayImage::new(self.width, self.height);
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (i, k) in kernel.iter().enumerate() {
                    acc += k * rows.at(x, y + i as isize - radius);
                }
                out.data[(y * w + x) as usize] = acc;
            }
        }
        out
    }
}
