//! The OpenEXR conventions shared by HDR frames ([`crate::exr_hdr`]) and ground-truth planes
//! ([`crate::exr_planes`]): one layer, ZIP compression (16 scan lines per block) unless told
//! otherwise, increasing scan lines, `stagehand` as the software name and the frame metadata
//! JSON in the [`ATTRIBUTE`] text attribute; and the errors of encoding and decoding.

use std::io::Cursor;

use exr::compression::Compression;
use exr::image::write::WritableImage;
use exr::image::write::channels::WritableChannels;
use exr::image::{Blocks, Encoding, Image, Layer};
use exr::math::Vec2;
use exr::meta::attribute::{AttributeValue, LineOrder, Text};
use exr::meta::header::LayerAttributes;

use crate::error::{Result, StorageError};

/// Name of the text attribute holding the frame metadata JSON.
pub const ATTRIBUTE: &str = "stagehand";

/// One layer of `width`×`height` pixels of `channels`, with `metadata_json` in the
/// [`ATTRIBUTE`] text attribute, ZIP16, increasing scan lines.
pub(crate) fn layer<'c, C>(width: u32, height: u32, channels: C, metadata_json: &str) -> Layer<C>
where
    C: WritableChannels<'c> + 'c,
{
    layer_with(width, height, channels, metadata_json, Compression::ZIP16)
}

/// [`layer`] with another `compression`.
pub(crate) fn layer_with<'c, C>(
    width: u32,
    height: u32,
    channels: C,
    metadata_json: &str,
    compression: Compression,
) -> Layer<C>
where
    C: WritableChannels<'c> + 'c,
{
    let mut attributes = LayerAttributes {
        software_name: Some(Text::from_slice_unchecked(b"stagehand")),
        ..LayerAttributes::default()
    };
    attributes.other.insert(
        Text::from_slice_unchecked(ATTRIBUTE.as_bytes()),
        AttributeValue::Text(Text::from_slice_unchecked(metadata_json.as_bytes())),
    );
    let encoding = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    Layer::new(
        (width as usize, height as usize),
        attributes,
        encoding,
        channels,
    )
}

/// The bytes of the OpenEXR file holding `image`; `capacity` is a guess of its size and
/// `name` is only used in errors.
pub(crate) fn write<'img, C>(
    name: &str,
    image: &'img Image<Layer<C>>,
    capacity: usize,
) -> Result<Vec<u8>>
where
    C: WritableChannels<'img>,
{
    let mut out = Cursor::new(Vec::with_capacity(capacity));
    image
        .write()
        .to_buffered(&mut out)
        .map_err(exr_error("encode", name))?;
    Ok(out.into_inner())
}

/// Turns an `exr` error of `op` (`encode`, `decode`) on file `name` into a [`StorageError`].
pub(crate) fn exr_error(
    op: &'static str,
    name: &str,
) -> impl FnOnce(exr::error::Error) -> StorageError {
    let name = name.to_string();
    move |source| StorageError::Exr { op, name, source }
}

/// The [`ATTRIBUTE`] text attribute of a decoded layer, if present.
pub(crate) fn metadata_attribute(attributes: &LayerAttributes) -> Option<String> {
    match attributes
        .other
        .get(&Text::from_slice_unchecked(ATTRIBUTE.as_bytes()))
    {
        Some(AttributeValue::Text(text)) => {
            Some(String::from_utf8_lossy(text.as_slice()).into_owned())
        }
        _ => None,
    }
}

/// A decoded image's size as the frame's u32 width and height, or an error naming `name`.
pub(crate) fn dimensions(name: &str, size: Vec2<usize>) -> Result<(u32, u32)> {
    match (u32::try_from(size.width()), u32::try_from(size.height())) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(StorageError::InvalidFrame {
            name: name.to_string(),
            reason: format!(
                "image size {}x{} does not fit in u32",
                size.width(),
                size.height()
            ),
        }),
    }
}
