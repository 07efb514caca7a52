//! HDR frames as OpenEXR: one RGB layer of **f32** samples, the frame metadata JSON in a
//! `stagehand` text attribute; uncompressed as a capture writes them ([`HDR_FRAME_COMPRESSION`]),
//! ZIP (16 scan lines per block) for products and conversions.
//!
//! Why f32 and not f16: radiance is in DN per second at gain 1, so a short exposure near full
//! scale reaches 10⁶–10⁸ (65535 DN / 1 ms ≈ 6.6·10⁷), far beyond f16's maximum of 65504, and
//! f16's 11-bit mantissa is coarser than a 12–16-bit sensor's DN step. Scaling into f16 range
//! would need a per-file factor every reader must know about; f32 avoids that.

use std::io::Cursor;

pub use exr::compression::Compression;
use exr::image::read::image::ReadLayers;
use exr::image::read::layers::ReadChannels;
use exr::image::read::read;
use exr::image::{Image, RgbChannels, SpecificChannels};
use exr::math::Vec2;

use crate::error::{Result, StorageError};
use crate::exr_file;
use crate::png16::rgb_samples;

pub use crate::exr_file::ATTRIBUTE;

/// A decoded stagehand OpenEXR file.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedExr {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved RGB samples.
    pub pixels: Vec<f32>,
    /// Text of the `stagehand` attribute, if present.
    pub metadata: Option<String>,
}

/// How a capture writes its merged HDR frames: uncompressed. `cargo bench --bench
/// frame_formats` on a 1024×768 bracket: ZIP16 takes 162 ms a frame for 89 % of the size,
/// PIZ 130 ms for 77 %, uncompressed 17.5 ms; ZIP16 took 41 % of the daemon's CPU in a
/// `btf.rhai` run. Every OpenEXR reader reads it.
pub const HDR_FRAME_COMPRESSION: Compression = Compression::Uncompressed;

/// Encodes interleaved RGB f32 `pixels` as OpenEXR (f32, ZIP16, increasing scan lines) with
/// `metadata_json` in the [`ATTRIBUTE`] text attribute. `name` is only used in errors.
pub fn encode_exr(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[f32],
    metadata_json: &str,
) -> Result<Vec<u8>> {
    encode_exr_with(
        name,
        width,
        height,
        pixels,
        metadata_json,
        Compression::ZIP16,
    )
}

/// [`encode_exr`] with another OpenEXR `compression` (the frame-format benchmark compares
/// them).
pub fn encode_exr_with(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[f32],
    metadata_json: &str,
    compression: Compression,
) -> Result<Vec<u8>> {
    let samples = rgb_samples(name, width, height)?;
    if pixels.len() != samples {
        return Err(StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!(
                "{} samples given, a {width}x{height} RGB image needs {samples}",
                pixels.len()
            ),
        });
    }
    let w = width as usize;
    let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let i = (pos.y() * w + pos.x()) * 3;
        (pixels[i], pixels[i + 1], pixels[i + 2])
    });
    let layer = exr_file::layer_with(width, height, channels, metadata_json, compression);
    let image = Image::from_layer(layer);
    exr_file::write(name, &image, samples * 2)
}

/// Pixel buffer used while decoding.
struct Rgb {
    width: usize,
    pixels: Vec<f32>,
}

/// Decodes the first RGB layer of an OpenEXR file (any sample type, converted to f32).
/// `name` is only used in errors.
pub fn decode_exr(name: &str, bytes: &[u8]) -> Result<DecodedExr> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size: Vec2<usize>, _: &RgbChannels| Rgb {
                width: size.width(),
                pixels: vec![0.0; size.width() * size.height() * 3],
            },
            |rgb: &mut Rgb, pos: Vec2<usize>, (r, g, b): (f32, f32, f32)| {
                let i = (pos.y() * rgb.width + pos.x()) * 3;
                rgb.pixels[i..i + 3].copy_from_slice(&[r, g, b]);
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(exr_file::exr_error("decode", name))?;
    let layer = image.layer_data;
    let (width, height) = exr_file::dimensions(name, layer.size)?;
    Ok(DecodedExr {
        width,
        height,
        metadata: exr_file::metadata_attribute(&layer.attributes),
        pixels: layer.channel_data.pixels.pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact() -> Result<()> {
        let (w, h) = (33u32, 21u32);
        let pixels: Vec<f32> = (0..(w * h * 3))
            .map(|i| match i % 5 {
                0 => 0.0,
                1 => 1.0e8 + i as f32,
                2 => 1.0e-6 * i as f32,
                3 => 0.1 * i as f32,
                _ => 12345.678,
            })
            .collect();
        let json = r#"{"camera":"cam2","kind":"hdr","note":"ü"}"#;
        let bytes = encode_exr("t.exr", w, h, &pixels, json)?;
        let back = decode_exr("t.exr", &bytes)?;
        assert_eq!((back.width, back.height), (w, h));
        assert_eq!(back.pixels, pixels);
        assert_eq!(back.metadata.as_deref(), Some(json));
        // deterministic bytes despite parallel compression
        assert_eq!(encode_exr("t.exr", w, h, &pixels, json)?, bytes);
        // As a capture writes them: uncompressed, every sample stored, the same image back.
        let plain = encode_exr_with("t.exr", w, h, &pixels, json, HDR_FRAME_COMPRESSION)?;
        assert!(plain.len() >= pixels.len() * 4, "{} bytes", plain.len());
        let back = decode_exr("t.exr", &plain)?;
        assert_eq!(back.pixels, pixels);
        assert_eq!(back.metadata.as_deref(), Some(json));
        Ok(())
    }

    #[test]
    fn wrong_sample_count_is_an_error() {
        assert!(matches!(
            encode_exr("bad.exr", 2, 2, &[0.0; 3], "{}"),
            Err(StorageError::InvalidFrame { .. })
        ));
    }
}
