//! PNG images a scene file refers to: 16-bit greyscale height images and 8/16-bit material
//! maps, decoded to linear values in [0, 1] and sampled bilinearly over the sample's footprint.
//!
//! Orientation: the image covers the square sample as a camera at azimuth 0 sees it, top row
//! at −x (the far side), columns left to right along +y.

use std::io::BufReader;
use std::path::Path;

use png::{BitDepth, ColorType};

use crate::render::sample::srgb_to_linear;

/// What an image is used for, which decides the accepted formats and the decoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapKind {
    /// A relief: 16-bit greyscale only (8 bits give visible terraces).
    Height,
    /// An RGB colour (albedo): 8-bit values are sRGB-encoded, 16-bit are linear; greyscale is
    /// replicated to RGB.
    Colour,
    /// One scalar parameter: 8- or 16-bit greyscale, linear.
    Scalar,
}

/// A decoded image: `channels` (1 or 3) linear values in [0, 1] per pixel, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageMap {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl ImageMap {
    /// An image from raw values (used by tests and procedural maps).
    pub fn from_values(width: usize, height: usize, channels: usize, data: Vec<f32>) -> ImageMap {
        ImageMap {
            width,
            height,
            channels,
            data,
        }
    }

    /// Pixels per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The bilinearly interpolated value at (x, y) mm on a sample `size` mm across, as RGB
    /// (greyscale replicated). Outside the footprint the edge pixels extend.
    pub fn at(&self, x: f32, y: f32, size: f32) -> [f32; 3] {
        if self.width == 0 || self.height == 0 || self.data.is_empty() {
            return [0.0; 3];
        }
        let h = 0.5 * size;
        let u = ((y + h) / size * self.width as f32 - 0.5).clamp(0.0, (self.width - 1) as f32);
        let v = ((x + h) / size * self.height as f32 - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (c0, r0) = (u as usize, v as usize);
        let (c1, r1) = ((c0 + 1).min(self.width - 1), (r0 + 1).min(self.height - 1));
        let (a, b) = (u - c0 as f32, v - r0 as f32);
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let ch = k.min(self.channels - 1);
            let px = |c: usize, r: usize| self.data[(r * self.width + c) * self.channels + ch];
            let top = px(c0, r0) + (px(c1, r0) - px(c0, r0)) * a;
            let bottom = px(c0, r1) + (px(c1, r1) - px(c0, r1)) * a;
            *o = top + (bottom - top) * b;
        }
        out
    }

    /// The first channel at (x, y), for scalar maps.
    pub fn scalar_at(&self, x: f32, y: f32, size: f32) -> f32 {
        self.at(x, y, size)[0]
    }
}

/// What is wrong with an image file of a scene, and how to fix it (it does not name the scene
/// file; the caller adds that). `path` is the image's path as shown.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file cannot be opened.
    #[error("cannot open `{path}`: {source}; check the path (it is relative to the scene file)")]
    Open {
        /// The image's path.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// Its header is not a PNG's.
    #[error("`{path}` is not a readable PNG: {source}; re-export it as PNG")]
    NotPng {
        /// The image's path.
        path: String,
        /// Why.
        source: png::DecodingError,
    },
    /// A palette image.
    #[error("`{path}` is a palette image; save it as {wanted}")]
    Palette {
        /// The image's path.
        path: String,
        /// What the map needs.
        wanted: &'static str,
    },
    /// A colour type or bit depth the map cannot use.
    #[error("`{path}` is {bits}-bit {colour}; save it as {wanted}")]
    WrongFormat {
        /// The image's path.
        path: String,
        /// Its bit depth.
        bits: u8,
        /// Its colour type.
        colour: &'static str,
        /// What the map needs.
        wanted: &'static str,
    },
    /// Too large to hold in memory.
    #[error("`{path}` is too large to decode; scale it down")]
    TooLarge {
        /// The image's path.
        path: String,
    },
    /// The pixel data cannot be decoded.
    #[error("`{path}` could not be decoded: {source}; re-export it as PNG")]
    Undecodable {
        /// The image's path.
        path: String,
        /// Why.
        source: png::DecodingError,
    },
    /// No pixels, or fewer than the header says.
    #[error("`{path}` has no pixels or is truncated; re-export it")]
    Truncated {
        /// The image's path.
        path: String,
    },
}

/// Reads the PNG at `path` as a `kind` map.
pub fn read_png(path: &Path, kind: MapKind) -> Result<ImageMap, ImageError> {
    let shown = || path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| ImageError::Open {
        path: shown(),
        source,
    })?;
    let decoder = png::Decoder::new(BufReader::new(file));
    let mut reader = decoder.read_info().map_err(|source| ImageError::NotPng {
        path: shown(),
        source,
    })?;
    let info = reader.info();
    let (width, height) = (info.width as usize, info.height as usize);
    let (colour, depth) = (info.color_type, info.bit_depth);
    let (src_channels, rgb) = match colour {
        ColorType::Grayscale => (1, false),
        ColorType::GrayscaleAlpha => (2, false),
        ColorType::Rgb => (3, true),
        ColorType::Rgba => (4, true),
        ColorType::Indexed => {
            return Err(ImageError::Palette {
                path: shown(),
                wanted: wanted(kind),
            });
        }
    };
    let ok = match kind {
        MapKind::Height => !rgb && depth == BitDepth::Sixteen,
        MapKind::Colour => matches!(depth, BitDepth::Eight | BitDepth::Sixteen),
        MapKind::Scalar => !rgb && matches!(depth, BitDepth::Eight | BitDepth::Sixteen),
    };
    if !ok {
        return Err(ImageError::WrongFormat {
            path: shown(),
            bits: depth as u8,
            colour: describe(colour),
            wanted: wanted(kind),
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| ImageError::TooLarge { path: shown() })?;
    let mut buf = vec![0u8; size];
    let out = reader
        .next_frame(&mut buf)
        .map_err(|source| ImageError::Undecodable {
            path: shown(),
            source,
        })?;
    let bytes = &buf[..out.buffer_size()];
    let samples: Vec<f32> = if depth == BitDepth::Sixteen {
        bytes
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]) as f32 / 65535.0)
            .collect()
    } else {
        let srgb = kind == MapKind::Colour;
        bytes
            .iter()
            .map(|&b| {
                let v = b as f32 / 255.0;
                if srgb { srgb_to_linear(v) } else { v }
            })
            .collect()
    };
    let channels = if rgb { 3 } else { 1 };
    let data: Vec<f32> = samples
        .chunks_exact(src_channels)
        .flat_map(|px| px[..channels].to_vec())
        .collect();
    if width == 0 || height == 0 || data.len() != width * height * channels {
        return Err(ImageError::Truncated { path: shown() });
    }
    Ok(ImageMap {
        width,
        height,
        channels,
        data,
    })
}

fn describe(colour: ColorType) -> &'static str {
    match colour {
        ColorType::Grayscale => "greyscale",
        ColorType::GrayscaleAlpha => "greyscale with alpha",
        ColorType::Rgb => "RGB",
        ColorType::Rgba => "RGBA",
        ColorType::Indexed => "palette",
    }
}

fn wanted(kind: MapKind) -> &'static str {
    match kind {
        MapKind::Height => "a 16-bit greyscale PNG (height maps need 16 bits)",
        MapKind::Colour => "an 8-bit (sRGB) or 16-bit (linear) RGB or greyscale PNG",
        MapKind::Scalar => "an 8- or 16-bit greyscale PNG",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_sampling_follows_the_documented_orientation() {
        // 2×2 image: columns along +y, rows along +x (top row at −x).
        let map = ImageMap::from_values(2, 2, 1, vec![0.0, 1.0, 0.5, 0.25]);
        let size = 10.0;
        assert_eq!(map.scalar_at(-2.5, -2.5, size), 0.0);
        assert_eq!(map.scalar_at(-2.5, 2.5, size), 1.0);
        assert_eq!(map.scalar_at(2.5, -2.5, size), 0.5);
        assert_eq!(map.scalar_at(2.5, 2.5, size), 0.25);
        assert!((map.scalar_at(-2.5, 0.0, size) - 0.5).abs() < 1e-6);
        // Beyond the edge pixels the edge value extends.
        assert_eq!(map.scalar_at(-5.0, 5.0, size), 1.0);
    }

    #[test]
    fn missing_file_says_what_to_do() {
        let e = read_png(Path::new("/nonexistent/a.png"), MapKind::Scalar)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/nonexistent/a.png") && e.contains("check the path"),
            "{e}"
        );
    }
}
