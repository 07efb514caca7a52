//! Frame format conversion for downloads and thumbnails.
//!
//! Raw frames are 16-bit RGB PNG on disk (sensor DN MSB-aligned with an sBIT chunk, or
//! unshifted in old datasets; [`decode_png16`] gives the DN back either way) and convert
//! losslessly to a 16-bit RGB TIFF or a 32-bit float EXR (the DN, unshifted, as floats). HDR frames are 32-bit float
//! EXR (DN per second at gain 1) and convert losslessly to a 32-bit float TIFF; a PNG of an
//! HDR frame is refused ([`ConvertError::WouldClip`]): 16 bits cannot hold the range, and a
//! silently tone-mapped file would look like data. Thumbnails are 8-bit sRGB PNG previews.
//!
//! Thumbnail tone mapping (always finite: NaN/Inf/negative samples count as 0):
//! - raw: subtract the camera's black level (`notes.black_level_dn` of the embedded metadata,
//!   0 if unknown), divide by the white point, clamp to [0, 1], sRGB gamma;
//! - HDR (already black-subtracted): exposure-normalise by the white point, then the extended
//!   Reinhard curve `y = x (1 + x/4) / (1 + x)` with `x = 2 v / white` (the white point maps to
//!   white, shadows are lifted, highlights above it clip), sRGB gamma.
//!
//! The white point is the 99.5th percentile of the downscaled samples, but at least a quarter
//! of the way from black to the brightest sample: a dark frame with a thin laser line shows the
//! line rather than noise stretched to full scale, and an all-zero image stays black.

use std::io::Cursor;

use tiff::encoder::{Compression, DeflateLevel, Predictor, TiffEncoder, colortype};
use tiff::tags::Tag;

use crate::storage::FrameKind;
use crate::storage::exr_hdr::{decode_exr, encode_exr};
use crate::storage::png16::decode_png16;

/// Smallest and largest thumbnail edge in pixels.
pub const THUMBNAIL_MIN: u32 = 16;
pub const THUMBNAIL_MAX: u32 = 1024;
/// Thumbnail edge when the request does not say.
pub const THUMBNAIL_DEFAULT: u32 = 256;

/// A download format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// 16-bit RGB PNG (raw frames only).
    Png,
    /// TIFF: 16-bit RGB (raw) or 32-bit float RGB (HDR), deflate-compressed.
    Tiff,
    /// OpenEXR, 32-bit float RGB, ZIP-compressed.
    Exr,
}

impl ImageFormat {
    /// The MIME type of the format.
    pub fn content_type(self) -> &'static str {
        match self {
            ImageFormat::Png => "image/png",
            ImageFormat::Tiff => "image/tiff",
            ImageFormat::Exr => "image/x-exr",
        }
    }

    /// The file extension (without dot).
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Tiff => "tiff",
            ImageFormat::Exr => "exr",
        }
    }

    /// The format a frame of `kind` is stored in.
    pub fn stored(kind: FrameKind) -> ImageFormat {
        match kind {
            FrameKind::Hdr => ImageFormat::Exr,
            FrameKind::Raw => ImageFormat::Png,
        }
    }
}

/// Why a conversion failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// The requested format cannot hold the frame without losing data (client's choice: 422).
    #[error("{0}")]
    WouldClip(String),
    /// The stored file could not be decoded (the dataset is damaged: 500).
    #[error("cannot decode {name}: {reason}")]
    Decode { name: String, reason: String },
    /// Encoding failed (500).
    #[error("cannot encode {name}: {reason}")]
    Encode { name: String, reason: String },
}

/// Interleaved RGB pixels of a decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// Raw sensor DN.
    Raw(Vec<u16>),
    /// HDR radiance.
    Hdr(Vec<f32>),
}

/// A decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub width: u32,
    pub height: u32,
    pub pixels: Pixels,
    /// The stagehand metadata JSON embedded in the file.
    pub metadata: Option<String>,
}

/// Decodes a stored frame (`raw` → 16-bit PNG, otherwise EXR). `name` is only used in errors.
pub fn decode(kind: FrameKind, name: &str, bytes: &[u8]) -> Result<Decoded, ConvertError> {
    let decode_err = |e: crate::storage::StorageError| ConvertError::Decode {
        name: name.to_string(),
        reason: e.to_string(),
    };
    match ImageFormat::stored(kind) {
        ImageFormat::Exr => {
            let d = decode_exr(name, bytes).map_err(decode_err)?;
            Ok(Decoded {
                width: d.width,
                height: d.height,
                pixels: Pixels::Hdr(d.pixels),
                metadata: d.metadata,
            })
        }
        _ => {
            let d = decode_png16(name, bytes).map_err(decode_err)?;
            Ok(Decoded {
                width: d.width,
                height: d.height,
                pixels: Pixels::Raw(d.pixels),
                metadata: d.metadata,
            })
        }
    }
}

/// The stored file `bytes` of a frame of `kind` in `format`: the bytes as they are when the
/// format is the stored one, otherwise decoded and re-encoded (with the embedded metadata
/// carried over: TIFF ImageDescription, EXR `stagehand` attribute).
pub fn convert(
    kind: FrameKind,
    name: &str,
    bytes: Vec<u8>,
    format: ImageFormat,
) -> Result<Vec<u8>, ConvertError> {
    let stored = ImageFormat::stored(kind);
    if format == stored {
        return Ok(bytes);
    }
    if stored == ImageFormat::Exr && format == ImageFormat::Png {
        return Err(ConvertError::WouldClip(format!(
            "{name} is an HDR frame (32-bit float radiance); a PNG would clip and quantise it"
        )));
    }
    let d = decode(kind, name, &bytes)?;
    let meta = d.metadata.as_deref().unwrap_or("{}");
    let ascii = ascii_json(meta);
    match (&d.pixels, format) {
        (Pixels::Raw(p), ImageFormat::Tiff) => tiff_rgb16(name, d.width, d.height, p, &ascii),
        (Pixels::Hdr(p), ImageFormat::Tiff) => tiff_rgb32f(name, d.width, d.height, p, &ascii),
        (Pixels::Raw(p), ImageFormat::Exr) => {
            let f: Vec<f32> = p.iter().map(|&v| f32::from(v)).collect();
            encode_exr(name, d.width, d.height, &f, meta).map_err(|e| ConvertError::Encode {
                name: name.to_string(),
                reason: e.to_string(),
            })
        }
        // Same format as stored was answered above; HDR to PNG was refused.
        (_, f) => Err(ConvertError::Encode {
            name: name.to_string(),
            reason: format!("no conversion to {}", f.extension()),
        }),
    }
}

/// JSON text with every non-ASCII character (and NUL) escaped as `\uXXXX`, so it fits a TIFF
/// ASCII tag and still parses to the same value (such characters only occur inside strings).
pub fn ascii_json(json: &str) -> String {
    let mut out = String::with_capacity(json.len());
    for c in json.chars() {
        if c.is_ascii() && c != '\0' {
            out.push(c);
        } else {
            let mut units = [0u16; 2];
            for u in c.encode_utf16(&mut units) {
                out.push_str(&format!("\\u{u:04x}"));
            }
        }
    }
    out
}

fn tiff_err(name: &str) -> impl Fn(tiff::TiffError) -> ConvertError + '_ {
    move |e| ConvertError::Encode {
        name: name.to_string(),
        reason: e.to_string(),
    }
}

/// 16-bit RGB TIFF (deflate, horizontal predictor) with `description` as ImageDescription.
pub fn tiff_rgb16(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[u16],
    description: &str,
) -> Result<Vec<u8>, ConvertError> {
    let err = tiff_err(name);
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out)
        .map_err(&err)?
        .with_compression(Compression::Deflate(DeflateLevel::Fast))
        .with_predictor(Predictor::Horizontal);
    let mut image = enc
        .new_image::<colortype::RGB16>(width, height)
        .map_err(&err)?;
    image
        .encoder()
        .write_tag(Tag::ImageDescription, description)
        .map_err(&err)?;
    image
        .encoder()
        .write_tag(Tag::Software, "stagehand")
        .map_err(&err)?;
    image.write_data(pixels).map_err(&err)?;
    Ok(out.into_inner())
}

/// 32-bit float RGB TIFF (deflate) with `description` as ImageDescription.
pub fn tiff_rgb32f(
    name: &str,
    width: u32,
    height: u32,
    pixels: &[f32],
    description: &str,
) -> Result<Vec<u8>, ConvertError> {
    let err = tiff_err(name);
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out)
        .map_err(&err)?
        .with_compression(Compression::Deflate(DeflateLevel::Fast));
    let mut image = enc
        .new_image::<colortype::RGB32Float>(width, height)
        .map_err(&err)?;
    image
        .encoder()
        .write_tag(Tag::ImageDescription, description)
        .map_err(&err)?;
    image
        .encoder()
        .write_tag(Tag::Software, "stagehand")
        .map_err(&err)?;
    image.write_data(pixels).map_err(&err)?;
    Ok(out.into_inner())
}

/// Width and height of a thumbnail of a `w`×`h` image whose longer side is `size`.
pub fn thumbnail_size(w: u32, h: u32, size: u32) -> (u32, u32) {
    let (w, h, size) = (
        u64::from(w.max(1)),
        u64::from(h.max(1)),
        u64::from(size.max(1)),
    );
    let short = |s: u64, l: u64| ((s * size + l / 2) / l).clamp(1, size) as u32;
    if w >= h {
        (size as u32, short(h, w))
    } else {
        (short(w, h), size as u32)
    }
}

/// Box-filters interleaved RGB `src` (`w`×`h`) to `ow`×`oh`: each output pixel averages the
/// source pixels its footprint covers (at least one, so upscaling repeats pixels). Non-finite
/// and negative samples count as 0.
pub fn resample(src: &[f32], w: u32, h: u32, ow: u32, oh: u32) -> Vec<f32> {
    let (w, h, ow, oh) = (w as usize, h as usize, ow as usize, oh as usize);
    let span = |o: usize, n: usize, on: usize| {
        let a = o * n / on;
        let b = ((o + 1) * n / on).max(a + 1).min(n);
        (a.min(n.saturating_sub(1)), b)
    };
    let mut out = vec![0.0f32; ow * oh * 3];
    if src.len() < w * h * 3 || w == 0 || h == 0 {
        return out;
    }
    for oy in 0..oh {
        let (y0, y1) = span(oy, h, oh);
        for ox in 0..ow {
            let (x0, x1) = span(ox, w, ow);
            let mut acc = [0.0f64; 3];
            for y in y0..y1 {
                let row = &src[(y * w + x0) * 3..(y * w + x1) * 3];
                for px in row.chunks_exact(3) {
                    for c in 0..3 {
                        acc[c] += f64::from(sanitize(px[c]));
                    }
                }
            }
            let n = ((y1 - y0) * (x1 - x0)) as f64;
            let o = (oy * ow + ox) * 3;
            for c in 0..3 {
                out[o + c] = (acc[c] / n) as f32;
            }
        }
    }
    out
}

/// A sample as a finite non-negative value (NaN, negative → 0; +Inf → f32::MAX).
fn sanitize(v: f32) -> f32 {
    if v.is_nan() || v <= 0.0 {
        0.0
    } else {
        v.min(f32::MAX)
    }
}

/// The `q`-quantile (0..1) of `values` (sanitised, non-empty).
fn quantile(values: &[f32], q: f64) -> f64 {
    let mut v = values.to_vec();
    let k = ((v.len().saturating_sub(1)) as f64 * q).round() as usize;
    let (_, p, _) = v.select_nth_unstable_by(k.min(values.len() - 1), f32::total_cmp);
    f64::from(*p)
}

/// The white point of a thumbnail's linear samples above `black`: the 99.5th percentile, but
/// at least a quarter of the way from black to the brightest sample, so a dark frame with a
/// few bright pixels (a laser line) shows them instead of stretching the sensor noise to full
/// scale. Always above `black`.
fn white_point(values: &[f32], black: f64) -> f64 {
    if values.is_empty() {
        return black + 1.0;
    }
    let p = quantile(values, 0.995);
    let max = f64::from(values.iter().copied().fold(0.0f32, f32::max));
    let white = p.max(black + 0.25 * (max - black));
    if white > black { white } else { black + 1.0 }
}

/// The camera's black level from a frame's embedded metadata (`notes.black_level_dn`), or 0.
fn black_level(metadata: Option<&str>) -> f64 {
    metadata
        .and_then(|m| serde_json::from_str::<serde_json::Value>(m).ok())
        .and_then(|v| v.pointer("/notes/black_level_dn")?.as_f64())
        .filter(|b| b.is_finite() && *b >= 0.0)
        .unwrap_or(0.0)
}

/// The sRGB transfer function of a linear value in [0, 1].
fn srgb(linear: f64) -> f64 {
    let l = if linear.is_finite() {
        linear.clamp(0.0, 1.0)
    } else {
        0.0
    };
    if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

/// An 8-bit sRGB RGB PNG of a decoded frame whose longer side is `size` pixels, tone-mapped
/// as described in the module documentation.
pub fn thumbnail(d: &Decoded, size: u32) -> Result<Vec<u8>, ConvertError> {
    let size = size.clamp(THUMBNAIL_MIN, THUMBNAIL_MAX);
    let (ow, oh) = thumbnail_size(d.width, d.height, size);
    let (linear, hdr) = match &d.pixels {
        Pixels::Raw(p) => {
            let f: Vec<f32> = p.iter().map(|&v| f32::from(v)).collect();
            (resample(&f, d.width, d.height, ow, oh), false)
        }
        Pixels::Hdr(p) => (resample(p, d.width, d.height, ow, oh), true),
    };
    // HDR radiance is black-subtracted by the merge; raw DN carry the sensor's black level.
    let black = if hdr {
        0.0
    } else {
        black_level(d.metadata.as_deref())
    };
    let white = white_point(&linear, black);
    let rgb8: Vec<u8> = linear
        .iter()
        .map(|&v| {
            let x = (f64::from(v) - black).max(0.0) / (white - black);
            let y = if hdr {
                let x = 2.0 * x;
                x * (1.0 + x / 4.0) / (1.0 + x)
            } else {
                x
            };
            (srgb(y) * 255.0).round().clamp(0.0, 255.0) as u8
        })
        .collect();
    png8(ow, oh, &rgb8)
}

/// Encodes interleaved 8-bit RGB as a PNG tagged sRGB.
pub fn png8(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, ConvertError> {
    let err = |e: png::EncodingError| ConvertError::Encode {
        name: "thumbnail".into(),
        reason: e.to_string(),
    };
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header().map_err(err)?;
    writer.write_image_data(rgb).map_err(err)?;
    writer.finish().map_err(err)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::storage::png16::encode_png16;

    fn decode_png8(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
        let mut reader = png::Decoder::new(Cursor::new(bytes))
            .read_info()
            .expect("valid png");
        let info = reader.info();
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        assert_eq!(info.color_type, png::ColorType::Rgb);
        let (w, h) = (info.width, info.height);
        let mut buf = vec![0; reader.output_buffer_size().expect("size")];
        let n = reader.next_frame(&mut buf).expect("frame").buffer_size();
        buf.truncate(n);
        (w, h, buf)
    }

    fn raw(w: u32, h: u32, f: impl Fn(usize) -> u16) -> Decoded {
        Decoded {
            width: w,
            height: h,
            pixels: Pixels::Raw((0..(w * h * 3) as usize).map(f).collect()),
            metadata: None,
        }
    }

    fn hdr(w: u32, h: u32, f: impl Fn(usize) -> f32) -> Decoded {
        Decoded {
            width: w,
            height: h,
            pixels: Pixels::Hdr((0..(w * h * 3) as usize).map(f).collect()),
            metadata: None,
        }
    }

    #[test]
    fn thumbnail_sizes_keep_the_aspect() {
        assert_eq!(thumbnail_size(1024, 768, 256), (256, 192));
        assert_eq!(thumbnail_size(768, 1024, 256), (192, 256));
        assert_eq!(thumbnail_size(32, 24, 64), (64, 48));
        assert_eq!(thumbnail_size(10_000, 1, 16), (16, 1));
        assert_eq!(thumbnail_size(0, 0, 16), (16, 16));
    }

    #[test]
    fn zero_and_saturated_frames_give_finite_thumbnails() {
        for (d, want) in [
            (raw(40, 30, |_| 0), Some(0u8)),
            (raw(40, 30, |_| u16::MAX), Some(255)),
            (hdr(40, 30, |_| 0.0), Some(0)),
            (hdr(40, 30, |_| f32::MAX), Some(255)),
            (hdr(40, 30, |_| 1.0e8), Some(255)),
            (
                hdr(40, 30, |i| match i % 4 {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => f32::NEG_INFINITY,
                    _ => -1.0,
                }),
                None,
            ),
        ] {
            let png = thumbnail(&d, 64).expect("thumbnail");
            let (w, h, px) = decode_png8(&png);
            assert_eq!((w, h), (64, 48));
            assert_eq!(px.len(), 64 * 48 * 3);
            if let Some(v) = want {
                assert!(px.iter().all(|&p| p == v), "expected all {v}");
            }
        }
    }

    #[test]
    fn raw_thumbnail_scales_by_the_percentile() {
        // A gradient: brighter pixels map brighter; the top 0.5 % is white.
        let d = raw(100, 100, |i| (i / 3) as u16);
        let (_, _, px) = decode_png8(&thumbnail(&d, 100).expect("thumbnail"));
        assert_eq!(px[0], 0);
        assert_eq!(*px.last().expect("pixels"), 255);
        assert!(px.windows(6).step_by(3).all(|w| w[3] >= w[0]));
    }

    #[test]
    fn a_laser_line_on_black_shows_the_line_not_the_noise() {
        // 64×64, black level 82 with up to 8 DN of noise, and 8 bright pixels (0.2 %: fewer
        // than the 0.5 % above the percentile).
        let mut d = raw(64, 64, |i| 82 + ((i * 7919) % 9) as u16);
        if let Pixels::Raw(p) = &mut d.pixels {
            for x in 0..8 {
                for c in 0..3 {
                    p[(32 * 64 + x) * 3 + c] = 4000;
                }
            }
        }
        d.metadata = Some(r#"{"notes":{"black_level_dn":82.0}}"#.into());
        let (w, _, px) = decode_png8(&thumbnail(&d, 64).expect("thumbnail"));
        assert_eq!(w, 64);
        let at = |x: usize, y: usize| px[(y * 64 + x) * 3];
        assert_eq!(at(0, 32), 255, "the line is white");
        assert!(at(40, 10) < 40, "the background stays dark: {}", at(40, 10));
        assert_eq!(black_level(d.metadata.as_deref()), 82.0);
        assert_eq!(black_level(Some("not json")), 0.0);
    }

    #[test]
    fn resample_averages_boxes() {
        // 4x2 → 2x1: each output averages a 2x2 block.
        let src: Vec<f32> = [1.0, 3.0, 5.0, 7.0, 1.0, 3.0, 5.0, 7.0]
            .iter()
            .flat_map(|&v| [v, v, v])
            .collect();
        assert_eq!(
            resample(&src, 4, 2, 2, 1),
            vec![2.0, 2.0, 2.0, 6.0, 6.0, 6.0]
        );
        // upscaling repeats
        assert_eq!(resample(&[4.0, 4.0, 4.0], 1, 1, 2, 1), vec![4.0; 6]);
    }

    #[test]
    fn conversions_round_trip() -> Result<(), Box<dyn std::error::Error>> {
        let (w, h) = (5u32, 3u32);
        // 12-bit DN, stored MSB-aligned: every conversion gives the DN back.
        let px: Vec<u16> = (0..w * h * 3).map(|i| ((i * 271) % 4096) as u16).collect();
        let png = encode_png16("t.png", w, h, &px, 12, r#"{"camera":"c"}"#)?;
        assert_eq!(
            convert(FrameKind::Raw, "t", png.clone(), ImageFormat::Png)?,
            png
        );
        // A frame of an old dataset (DN unshifted, no sBIT) converts to the same DN.
        let old =
            crate::storage::png16::encode_png16_unshifted("t.png", w, h, &px, r#"{"camera":"c"}"#)?;
        assert_eq!(
            convert(FrameKind::Raw, "t", old.clone(), ImageFormat::Tiff)?,
            convert(FrameKind::Raw, "t", png.clone(), ImageFormat::Tiff)?
        );
        let tif = convert(FrameKind::Raw, "t", png.clone(), ImageFormat::Tiff)?;
        let mut dec = tiff::decoder::Decoder::new(Cursor::new(tif))?;
        assert_eq!(dec.dimensions()?, (w, h));
        assert_eq!(
            dec.get_tag_ascii_string(Tag::ImageDescription)?,
            r#"{"camera":"c"}"#
        );
        match dec.read_image()? {
            tiff::decoder::DecodingResult::U16(v) => assert_eq!(v, px),
            other => panic!("not 16-bit: {other:?}"),
        }
        let exr = convert(FrameKind::Raw, "t", png, ImageFormat::Exr)?;
        let back = decode_exr("t", &exr)?;
        assert_eq!(
            back.pixels,
            px.iter().map(|&v| f32::from(v)).collect::<Vec<_>>()
        );

        let f: Vec<f32> = (0..w * h * 3).map(|i| i as f32 * 1.5e6).collect();
        let exr = encode_exr("h.exr", w, h, &f, "{}")?;
        assert!(matches!(
            convert(FrameKind::Hdr, "h", exr.clone(), ImageFormat::Png),
            Err(ConvertError::WouldClip(_))
        ));
        let tif = convert(FrameKind::Hdr, "h", exr, ImageFormat::Tiff)?;
        let mut dec = tiff::decoder::Decoder::new(Cursor::new(tif))?;
        match dec.read_image()? {
            tiff::decoder::DecodingResult::F32(v) => assert_eq!(v, f),
            other => panic!("not f32: {other:?}"),
        }
        Ok(())
    }

    #[test]
    fn tiff_descriptions_are_ascii_json() {
        let text = r#"{"a":"20°C ✓ 😀","b":1}"#;
        let ascii = ascii_json(text);
        assert!(ascii.is_ascii());
        let back: serde_json::Value = serde_json::from_str(&ascii).expect("json");
        let want: serde_json::Value = serde_json::from_str(text).expect("json");
        assert_eq!(back, want);
    }

    #[test]
    fn garbage_is_a_decode_error() {
        assert!(matches!(
            convert(
                FrameKind::Raw,
                "x",
                b"not a png".to_vec(),
                ImageFormat::Tiff
            ),
            Err(ConvertError::Decode { .. })
        ));
        assert!(matches!(
            convert(
                FrameKind::Hdr,
                "x",
                b"not an exr".to_vec(),
                ImageFormat::Tiff
            ),
            Err(ConvertError::Decode { .. })
        ));
    }
}
