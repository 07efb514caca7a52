//! Raw frames as 16-bit RGB PNG with the frame metadata in an iTXt chunk.
//!
//! Samples are stored as the sensor's digital numbers, unscaled: a 12-bit sensor's values stay
//! in `0..=4095` (the image looks dark in a viewer, but every DN survives exactly). No sBIT
//! chunk is written, because sBIT would claim the values were scaled to the full 16 bits; the
//! sensor's bit depth is in the metadata instead. Encoding is deterministic: identical pixels
//! and metadata give identical bytes.

use std::io::Cursor;

use super::error::{Result, StorageError};

/// Keyword of the iTXt chunk holding the frame metadata JSON.
pub const ITXT_KEYWORD: &str = "stagehand";

/// A decoded stagehand PNG.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedPng {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved RGB samples.
    pub pixels: Vec<u16>,
    /// Text of the `stagehand` iTXt chunk, if present.
    pub metadata: Option<String>,
}

/// Number of interleaved RGB samples of a `width` × `height` image, or an error naming `name`.
pub(crate) fn rgb_samples(name: &str, width: u32, height: u32) -> Result<usize> {
    if width == 0 || height == 0 {
        return Err(StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!("image is {width}x{height}; both sides must be at least 1"),
        });
    }
    (width as usize)
        .checked_mul(height as usize)
        .and_then(|n| n.checked_mul(3))
        .ok_or_else(|| StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!("image size {width}x{height} overflows memory"),
        })
}

/// Encodes interleaved RGB `pixels` as a 16-bit PNG (fast compression) with `metadata_json`
/// in an iTXt chunk named [`ITXT_KEYWORD`]. `name` is only used in errors.
pub fn encode_png16(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    metadata_json: &str,
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
    let png_err = |source| StorageError::PngEncode {
        name: name.to_string(),
        source,
    };
    let mut data = Vec::with_capacity(samples * 2);
    for &v in pixels {
        data.extend_from_slice(&v.to_be_bytes());
    }
    let mut out = Vec::with_capacity(samples + 4096);
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Sixteen);
    encoder.set_compression(png::Compression::Fast);
    encoder
        .add_itxt_chunk(ITXT_KEYWORD.to_string(), metadata_json.to_string())
        .map_err(png_err)?;
    let mut writer = encoder.write_header().map_err(png_err)?;
    writer.write_image_data(&data).map_err(png_err)?;
    writer.finish().map_err(png_err)?;
    Ok(out)
}

/// Decodes a 16-bit RGB PNG written by [`encode_png16`]. `name` is only used in errors.
pub fn decode_png16(name: &str, bytes: &[u8]) -> Result<DecodedPng> {
    let png_err = |source| StorageError::PngDecode {
        name: name.to_string(),
        source,
    };
    let decoder = png::Decoder::new(Cursor::new(bytes));
    let mut reader = decoder.read_info().map_err(png_err)?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if info.color_type != png::ColorType::Rgb || info.bit_depth != png::BitDepth::Sixteen {
        return Err(StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!(
                "is {:?} {:?}, expected 16-bit RGB as stagehand writes",
                info.bit_depth, info.color_type
            ),
        });
    }
    let mut metadata = None;
    for chunk in &info.utf8_text {
        if chunk.keyword == ITXT_KEYWORD {
            metadata = Some(chunk.get_text().map_err(png_err)?);
        }
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| StorageError::InvalidFrame {
            name: name.to_string(),
            reason: "image too large to decode".to_string(),
        })?;
    let mut buf = vec![0u8; size];
    let out = reader.next_frame(&mut buf).map_err(png_err)?;
    let pixels = buf[..out.buffer_size()]
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    Ok(DecodedPng {
        width,
        height,
        pixels,
        metadata,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact() -> Result<()> {
        let (w, h) = (7u32, 5u32);
        let pixels: Vec<u16> = (0..(w * h * 3))
            .map(|i| (i.wrapping_mul(2654435761) >> 16) as u16)
            .collect();
        let mut with_extremes = pixels.clone();
        with_extremes[0] = 0;
        with_extremes[1] = u16::MAX;
        let json = r#"{"camera":"cam5","note":"ünïcode ✓"}"#;
        let bytes = encode_png16("t.png", w, h, &with_extremes, json)?;
        let back = decode_png16("t.png", &bytes)?;
        assert_eq!((back.width, back.height), (w, h));
        assert_eq!(back.pixels, with_extremes);
        assert_eq!(back.metadata.as_deref(), Some(json));
        Ok(())
    }

    #[test]
    fn wrong_sample_count_is_an_error() {
        let err = encode_png16("bad.png", 2, 2, &[0; 11], "{}");
        assert!(matches!(err, Err(StorageError::InvalidFrame { .. })));
        assert!(matches!(
            encode_png16("z.png", 0, 2, &[], "{}"),
            Err(StorageError::InvalidFrame { .. })
        ));
    }
}
