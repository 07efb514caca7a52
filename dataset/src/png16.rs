//! Raw frames as 16-bit RGB PNG with the frame metadata in an iTXt chunk.
//!
//! Samples are stored MSB-aligned, the convention of machine-vision SDKs: a 12-bit sensor's
//! DN `d` is stored as `d << 4`, so any image viewer shows the frame at its true brightness,
//! and the PNG `sBIT` chunk names the sensor's bits (12, 12, 12) so a reader knows how many
//! low bits are padding. [`decode_png16`] shifts back and returns every DN exactly. Files
//! written before this layout (stagehand datasets with index schema < 3) have no sBIT chunk
//! and hold the DN unshifted; they decode with a shift of 0. Encoding is deterministic:
//! identical pixels and metadata give identical bytes.

use std::io::Cursor;

use crate::error::{Result, StorageError};
use crate::png_rgb16::{Rgb16, Rgb16Error, encode_rgb16};

/// Keyword of the iTXt chunk holding the frame metadata JSON.
pub const ITXT_KEYWORD: &str = "stagehand";

/// A decoded stagehand PNG.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedPng {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved RGB samples as the sensor's digital numbers (shifted back by `shift`).
    pub pixels: Vec<u16>,
    /// Significant bits per sample: the `sBIT` chunk's value, or 16 when the file has none.
    pub significant_bits: u8,
    /// Left shift the file's samples carry (`16 - significant_bits`; 0 for old files).
    pub shift: u8,
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

/// The left shift that MSB-aligns the samples of a `sensor_bits`-bit sensor in 16 bits
/// (`16 - sensor_bits`), or an error naming `name` when the depth is not 1..=16.
pub fn msb_shift(name: &str, sensor_bits: u8) -> Result<u8> {
    if (1..=16).contains(&sensor_bits) {
        Ok(16 - sensor_bits)
    } else {
        Err(StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!(
                "the sensor has {sensor_bits} bits per sample; a 16-bit PNG holds 1 to 16"
            ),
        })
    }
}

/// Encodes interleaved RGB `pixels` (DN of a `sensor_bits`-bit sensor) as a 16-bit PNG (the
/// fastest deflate, Up filter): samples MSB-aligned, an `sBIT` chunk naming `sensor_bits`, and
/// `metadata_json` in an iTXt chunk named [`ITXT_KEYWORD`]. A DN above the sensor's range is
/// an error. `name` is only used in errors.
pub fn encode_png16(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    sensor_bits: u8,
    metadata_json: &str,
) -> Result<Vec<u8>> {
    encode_png16_with(
        name,
        width,
        height,
        pixels,
        sensor_bits,
        metadata_json,
        Deflate::Fastest,
    )
}

/// How a raw frame's PNG compresses its image data. Both are plain PNG that every reader
/// opens; they differ only in size and in the CPU they take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Deflate {
    /// The fastest deflate with the Up filter: about 55 % of the raw size on sensor frames.
    Fastest,
    /// Stored deflate blocks, no filter: the raw size, at about half the CPU of `Fastest`
    /// (`cargo bench --bench frame_formats`). The writer uses it when it falls behind.
    Stored,
}

/// [`encode_png16`] with the compression given.
pub fn encode_png16_with(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    sensor_bits: u8,
    metadata_json: &str,
    deflate: Deflate,
) -> Result<Vec<u8>> {
    encode(
        name,
        width,
        height,
        pixels,
        Some(sensor_bits),
        metadata_json,
        deflate,
    )
}

/// A raw frame in the layout of datasets before MSB alignment (index schema < 3: DN unshifted,
/// no sBIT chunk), so tests and tools can build old datasets that readers must still decode.
pub fn encode_png16_unshifted(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    metadata_json: &str,
) -> Result<Vec<u8>> {
    encode(
        name,
        width,
        height,
        pixels,
        None,
        metadata_json,
        Deflate::Fastest,
    )
}

/// [`encode_png16`]; with `sensor_bits` `None`, the layout before MSB alignment (DN unshifted,
/// no sBIT).
fn encode(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    sensor_bits: Option<u8>,
    metadata_json: &str,
    deflate: Deflate,
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
    let shift = sensor_bits.map(|bits| msb_shift(name, bits)).transpose()?;
    let shift = shift.unwrap_or(0);
    // The iTXt chunk: keyword, then no compression, no language tag, no translated keyword.
    let itxt = [ITXT_KEYWORD.as_bytes(), &[0; 5], metadata_json.as_bytes()].concat();
    let sbit = sensor_bits.map(|bits| [bits; 3]);
    let mut chunks: Vec<(&[u8; 4], &[u8])> = vec![(b"iTXt", &itxt[..])];
    if let Some(sbit) = &sbit {
        // sBIT goes before the image data (PNG spec 11.3.3.4); readers parse it.
        chunks.push((b"sBIT", sbit));
    }
    let image = Rgb16 {
        width,
        height,
        pixels,
        shift,
    };
    encode_rgb16(&image, &chunks, deflate).map_err(|e| match e {
        Rgb16Error::SampleTooLarge(v) => StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!(
                "sample {v} is above the largest DN {} of a {}-bit sensor",
                u16::MAX >> shift,
                16 - shift
            ),
        },
        Rgb16Error::Io(e) => StorageError::PngEncode {
            name: name.to_string(),
            source: e.into(),
        },
    })
}

/// Decodes a 16-bit RGB PNG written by [`encode_png16`] (or by a stagehand before MSB
/// alignment) back to the sensor's DN. Differing sBIT values per channel, or padding bits that
/// are not zero, are errors (the samples would not be the DN that were written). `name` is
/// only used in errors.
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
    let significant_bits = match info.sbit.as_deref() {
        None => 16,
        Some(&[r, g, b]) if r == g && g == b => r,
        Some(other) => {
            return Err(StorageError::InvalidFrame {
                name: name.to_string(),
                reason: format!(
                    "its sBIT chunk is {other:?}; stagehand writes one depth for R, G and B"
                ),
            });
        }
    };
    let shift = 16 - significant_bits.min(16);
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
    let padding = (1u16 << shift) - 1;
    let mut pixels = Vec::with_capacity(out.buffer_size() / 2);
    for b in buf[..out.buffer_size()].chunks_exact(2) {
        let v = u16::from_be_bytes([b[0], b[1]]);
        if v & padding != 0 {
            return Err(StorageError::InvalidFrame {
                name: name.to_string(),
                reason: format!(
                    "sample {v:#06x} has non-zero padding bits below its sBIT depth of \
                     {significant_bits}; the file is damaged"
                ),
            });
        }
        pixels.push(v >> shift);
    }
    Ok(DecodedPng {
        width,
        height,
        pixels,
        significant_bits,
        shift,
        metadata,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random DN of a `bits`-bit sensor, with both extremes.
    fn dn(w: u32, h: u32, bits: u8) -> Vec<u16> {
        let max = u16::MAX >> (16 - bits);
        let mut px: Vec<u16> = (0..(w * h * 3))
            .map(|i| ((i.wrapping_mul(2654435761) >> 16) as u16) & max)
            .collect();
        px[0] = 0;
        px[1] = max;
        px
    }

    #[test]
    fn round_trip_is_exact() -> Result<()> {
        let (w, h) = (7u32, 5u32);
        let json = r#"{"camera":"cam5","note":"ünïcode ✓"}"#;
        for bits in [8u8, 10, 12, 14, 16] {
            let pixels = dn(w, h, bits);
            let bytes = encode_png16("t.png", w, h, &pixels, bits, json)?;
            let back = decode_png16("t.png", &bytes)?;
            assert_eq!((back.width, back.height), (w, h));
            assert_eq!(back.pixels, pixels, "{bits} bits");
            assert_eq!((back.significant_bits, back.shift), (bits, 16 - bits));
            assert_eq!(back.metadata.as_deref(), Some(json));
        }
        Ok(())
    }

    #[test]
    fn samples_are_msb_aligned_with_sbit_for_viewers() -> Result<()> {
        let pixels = vec![4095u16, 1, 0, 2048, 7, 100];
        let bytes = encode_png16("t.png", 2, 1, &pixels, 12, "{}")?;
        // What any PNG reader sees: the DN scaled to 16 bits, and the sBIT chunk.
        let mut reader = png::Decoder::new(Cursor::new(&bytes))
            .read_info()
            .map_err(|source| StorageError::PngDecode {
                name: "t.png".into(),
                source,
            })?;
        assert_eq!(reader.info().sbit.as_deref(), Some(&[12u8, 12, 12][..]));
        let mut buf = vec![0u8; 12];
        reader
            .next_frame(&mut buf)
            .map_err(|source| StorageError::PngDecode {
                name: "t.png".into(),
                source,
            })?;
        let raw: Vec<u16> = buf
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(raw, vec![0xfff0, 0x0010, 0, 0x8000, 0x0070, 0x0640]);
        Ok(())
    }

    #[test]
    fn old_files_without_sbit_read_unshifted() -> Result<()> {
        let pixels = dn(3, 2, 12);
        let bytes = encode_png16_unshifted("old.png", 3, 2, &pixels, "{}")?;
        let back = decode_png16("old.png", &bytes)?;
        assert_eq!(back.pixels, pixels);
        assert_eq!((back.significant_bits, back.shift), (16, 0));
        Ok(())
    }

    #[test]
    fn out_of_range_dn_and_bad_depths_are_errors() {
        assert!(matches!(
            encode_png16("big.png", 1, 1, &[4096, 0, 0], 12, "{}"),
            Err(StorageError::InvalidFrame { .. })
        ));
        for bits in [0u8, 17, 32] {
            assert!(matches!(
                encode_png16("d.png", 1, 1, &[0, 0, 0], bits, "{}"),
                Err(StorageError::InvalidFrame { .. })
            ));
        }
    }

    #[test]
    fn wrong_sample_count_is_an_error() {
        let err = encode_png16("bad.png", 2, 2, &[0; 11], 12, "{}");
        assert!(matches!(err, Err(StorageError::InvalidFrame { .. })));
        assert!(matches!(
            encode_png16("z.png", 0, 2, &[], 12, "{}"),
            Err(StorageError::InvalidFrame { .. })
        ));
    }
}
