//! Ground-truth images as OpenEXR: any number of named **f32** channels (depth `Z`, normal
//! `X Y Z`, material `albedo.R …`), ZIP compression (16 scan lines per block), metadata JSON in
//! the same `stagehand` text attribute as HDR frames ([`crate::exr_file::ATTRIBUTE`]).
//!
//! OpenEXR stores channels sorted by name; [`decode_exr_planes`] returns them in file order,
//! so readers look channels up by name.

use std::io::Cursor;

use exr::image::read::image::ReadLayers;
use exr::image::read::layers::ReadChannels;
use exr::image::read::read;
use exr::image::{AnyChannel, AnyChannels, FlatSamples, Image};
use exr::meta::attribute::Text;
use exr::prelude::SmallVec;

use crate::error::{Result, StorageError};
use crate::exr_file;

/// A decoded multi-channel stagehand OpenEXR file.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedPlanes {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// (channel name, row-major samples) in file order (sorted by name).
    pub channels: Vec<(String, Vec<f32>)>,
    /// Text of the `stagehand` attribute, if present.
    pub metadata: Option<String>,
}

impl DecodedPlanes {
    /// The samples of channel `name`.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
}

/// Encodes `samples` (interleaved, `channels.len()` per pixel, row-major) as an OpenEXR file
/// of f32 channels named `channels`, ZIP16, with `metadata_json` in the `stagehand`
/// attribute. `name` is only used in errors.
pub fn encode_exr_planes(
    name: &str,
    width: u32,
    height: u32,
    channels: &[String],
    samples: &[f32],
    metadata_json: &str,
) -> Result<Vec<u8>> {
    let invalid = |reason: String| StorageError::InvalidFrame {
        name: name.to_string(),
        reason,
    };
    let pixels = (width as usize)
        .checked_mul(height as usize)
        .filter(|&p| p > 0)
        .ok_or_else(|| invalid(format!("image size {width}x{height} is empty or too large")))?;
    let count = channels.len();
    if count == 0 || Some(samples.len()) != pixels.checked_mul(count) {
        return Err(invalid(format!(
            "{} samples given, a {width}x{height} image of {count} channels needs {}",
            samples.len(),
            pixels.saturating_mul(count)
        )));
    }
    let mut names = channels.to_vec();
    names.sort();
    names.dedup();
    if names.len() != count || names.iter().any(|c| c.is_empty() || !c.is_ascii()) {
        return Err(invalid(format!(
            "channel names must be distinct non-empty ASCII, got {channels:?}"
        )));
    }
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = channels
        .iter()
        .enumerate()
        .map(|(c, channel)| {
            let plane: Vec<f32> = samples.iter().skip(c).step_by(count).copied().collect();
            AnyChannel {
                name: Text::from_slice_unchecked(channel.as_bytes()),
                sample_data: FlatSamples::F32(plane),
                quantize_linearly: true,
                sampling: exr::math::Vec2(1, 1),
            }
        })
        .collect();
    let image = Image::from_layer(exr_file::layer(
        width,
        height,
        AnyChannels::sort(list),
        metadata_json,
    ));
    exr_file::write(name, &image, samples.len() * 2)
}

/// Decodes the first layer of an OpenEXR file with all its channels (any sample type,
/// converted to f32). `name` is only used in errors.
pub fn decode_exr_planes(name: &str, bytes: &[u8]) -> Result<DecodedPlanes> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(exr_file::exr_error("decode", name))?;
    let layer = image.layer_data;
    let (width, height) = exr_file::dimensions(name, layer.size)?;
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            (
                c.name.to_string(),
                c.sample_data.values_as_f32().collect::<Vec<f32>>(),
            )
        })
        .collect();
    Ok(DecodedPlanes {
        width,
        height,
        channels,
        metadata: exr_file::metadata_attribute(&layer.attributes),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_round_trip_exactly_by_name() -> Result<()> {
        let (w, h) = (7u32, 5u32);
        let channels: Vec<String> = ["ks", "albedo.R", "Z"].map(String::from).to_vec();
        let samples: Vec<f32> = (0..w * h * 3).map(|i| i as f32 * 0.25 - 3.0).collect();
        let bytes = encode_exr_planes("t.exr", w, h, &channels, &samples, "{\"a\":1}")?;
        let back = decode_exr_planes("t.exr", &bytes)?;
        assert_eq!((back.width, back.height), (w, h));
        assert_eq!(back.metadata.as_deref(), Some("{\"a\":1}"));
        for (c, name) in channels.iter().enumerate() {
            let expect: Vec<f32> = samples.iter().skip(c).step_by(3).copied().collect();
            assert_eq!(back.channel(name), Some(expect.as_slice()), "{name}");
        }
        // Deterministic bytes despite parallel compression.
        assert_eq!(
            encode_exr_planes("t.exr", w, h, &channels, &samples, "{\"a\":1}")?,
            bytes
        );
        Ok(())
    }

    #[test]
    fn bad_planes_are_errors() {
        let one = vec!["Z".to_string()];
        assert!(encode_exr_planes("b.exr", 2, 2, &one, &[0.0; 3], "{}").is_err());
        let twice = vec!["Z".to_string(), "Z".to_string()];
        assert!(encode_exr_planes("b.exr", 1, 1, &twice, &[0.0; 2], "{}").is_err());
        assert!(encode_exr_planes("b.exr", 0, 1, &one, &[], "{}").is_err());
    }
}
