//! The bytes of a 16-bit RGB PNG, made in one pass over a frame: each row is MSB-aligned,
//! converted to big-endian, Up-filtered and deflated while it is in the cache, straight into
//! the file's buffer. They are byte for byte what the `png` crate writes for the same image,
//! chunks and settings (`tests` below), at less CPU: the crate takes the whole frame already
//! converted, filters each row into a copy, and copies its compressed stream twice, into a
//! growing buffer and then into the file's (at 15 Hz on 8 full-size cameras the conversion,
//! the filter and those copies were 15–17 % of both cores, `perf record -a`).

use std::io::{self, Cursor};

use fdeflate::{Compressor, StoredOnlyCompressor};

use crate::png16::Deflate;

/// The PNG file signature.
const SIGNATURE: [u8; 8] = [137, 80, 78, 71, 13, 10, 26, 10];
/// PNG's filter type "Up": each byte minus the byte above it.
const FILTER_UP: u8 = 2;
/// PNG's filter type "None".
const FILTER_NONE: u8 = 0;

/// Why a frame could not be encoded.
#[derive(Debug)]
pub(crate) enum Rgb16Error {
    /// A sample above the largest the shift leaves room for (the first such sample).
    SampleTooLarge(u16),
    /// The buffer refused a write, or the image data would not fit one IDAT chunk (2 GiB).
    Io(io::Error),
}

impl From<io::Error> for Rgb16Error {
    fn from(e: io::Error) -> Self {
        Rgb16Error::Io(e)
    }
}

/// A 16-bit RGB image to encode: `pixels` interleaved, `width * 3` samples a row, each shifted
/// left by `shift` (0..=15) in the file.
pub(crate) struct Rgb16<'a> {
    pub width: u32,
    pub height: u32,
    pub pixels: &'a [u16],
    pub shift: u8,
}

/// Encodes `image` as a PNG: the signature, IHDR, the `chunks` given (type and data, in order),
/// the image data in one IDAT chunk, and IEND. With [`Deflate::Fastest`] rows are Up-filtered
/// and deflated with `fdeflate`, stored instead when that would be larger (as the `png` crate
/// does); with [`Deflate::Stored`] they are stored unfiltered. The caller checks that the
/// sample count matches the size.
pub(crate) fn encode_rgb16(
    image: &Rgb16<'_>,
    chunks: &[(&[u8; 4], &[u8])],
    deflate: Deflate,
) -> Result<Vec<u8>, Rgb16Error> {
    let row_samples = image.width as usize * 3;
    let rows = image.height as usize;
    debug_assert_eq!(image.pixels.len(), row_samples * rows);
    // The filtered rows, each with its filter byte: what the zlib stream holds.
    let filtered_len = (row_samples * 2 + 1) * rows;
    let stored_len = StoredOnlyCompressor::<()>::compressed_size(filtered_len);
    let chunk_bytes: usize = chunks.iter().map(|(_, d)| d.len() + 12).sum();
    // Room for the stored form, so the buffer never moves while it grows.
    let mut out = Vec::with_capacity(SIGNATURE.len() + 25 + chunk_bytes + stored_len + 24);
    out.extend_from_slice(&SIGNATURE);
    let mut ihdr = [0u8; 13];
    ihdr[..4].copy_from_slice(&image.width.to_be_bytes());
    ihdr[4..8].copy_from_slice(&image.height.to_be_bytes());
    ihdr[8] = 16; // bits per sample
    ihdr[9] = 2; // colour type RGB; compression, filter method and interlace all 0
    put_chunk(&mut out, b"IHDR", &ihdr);
    for (kind, data) in chunks {
        put_chunk(&mut out, kind, data);
    }
    let idat = out.len();
    out.extend_from_slice(&[0; 4]);
    out.extend_from_slice(b"IDAT");
    let data_start = out.len();
    match deflate {
        Deflate::Fastest => {
            deflate_up_filtered(&mut out, image)?;
            if out.len() - data_start > stored_len {
                out.truncate(data_start);
                store_unfiltered(&mut out, image)?;
            }
        }
        Deflate::Stored => store_unfiltered(&mut out, image)?,
    }
    let length = u32::try_from(out.len() - data_start)
        .ok()
        .filter(|&n| n <= i32::MAX as u32)
        .ok_or_else(|| {
            io::Error::other("the image data is over 2 GiB, more than one PNG IDAT chunk holds")
        })?;
    out[idat..data_start - 4].copy_from_slice(&length.to_be_bytes());
    let crc = crc32fast::hash(&out[data_start - 4..]);
    out.extend_from_slice(&crc.to_be_bytes());
    put_chunk(&mut out, b"IEND", &[]);
    Ok(out)
}

/// Appends a chunk: length, type, data, CRC of type and data.
fn put_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32fast::hash(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// The zlib stream of the Up-filtered rows, each row converted, filtered and deflated in one
/// loop that runs in vector lanes.
fn deflate_up_filtered(out: &mut Vec<u8>, image: &Rgb16<'_>) -> Result<(), Rgb16Error> {
    let row_samples = image.width as usize * 3;
    let limit = u16::MAX >> image.shift;
    // The row above, shifted (zeros above the first row, as PNG's Up filter defines).
    let mut above = vec![0u16; row_samples];
    // The filtered row as big-endian samples behind a lead sample whose second byte is the
    // filter type, so the bytes from 1 on are the row as the stream holds it.
    let mut line = vec![0u16; row_samples + 1];
    line[0] = u16::from_ne_bytes([0, FILTER_UP]);
    let mut z = Compressor::new(out)?;
    for row in image.pixels.chunks_exact(row_samples) {
        let mut largest = 0u16;
        for ((o, up), &v) in line[1..].iter_mut().zip(above.iter_mut()).zip(row) {
            largest = largest.max(v);
            let s = v << image.shift;
            // Each byte minus the byte above it, wrapping: the high bytes without the low
            // bytes' borrow, then the low bytes.
            let f = (s.wrapping_sub(*up & 0xff00) & 0xff00) | (s.wrapping_sub(*up) & 0x00ff);
            *o = f.to_be();
            *up = s;
        }
        if largest > limit {
            return Err(first_above(row, limit));
        }
        z.write_data(&bytemuck::cast_slice::<u16, u8>(&line)[1..])?;
    }
    z.finish()?;
    Ok(())
}

/// The zlib stream of the unfiltered rows in stored blocks.
fn store_unfiltered(out: &mut Vec<u8>, image: &Rgb16<'_>) -> Result<(), Rgb16Error> {
    let row_samples = image.width as usize * 3;
    let limit = u16::MAX >> image.shift;
    let mut line = vec![0u16; row_samples];
    let end = out.len() as u64;
    let mut cursor = Cursor::new(out);
    cursor.set_position(end);
    let mut z = StoredOnlyCompressor::new(cursor)?;
    for row in image.pixels.chunks_exact(row_samples) {
        let mut largest = 0u16;
        for (o, &v) in line.iter_mut().zip(row) {
            largest = largest.max(v);
            *o = (v << image.shift).to_be();
        }
        if largest > limit {
            return Err(first_above(row, limit));
        }
        z.write_data(&[FILTER_NONE])?;
        z.write_data(bytemuck::cast_slice(&line))?;
    }
    z.finish()?;
    Ok(())
}

/// The error naming the first sample of `row` above `limit` (searched only once one is known
/// to be there: the search runs one sample at a time).
fn first_above(row: &[u16], limit: u16) -> Rgb16Error {
    Rgb16Error::SampleTooLarge(row.iter().copied().find(|&v| v > limit).unwrap_or(limit))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same image through the `png` crate, as `png16` encoded frames until this writer.
    fn png_crate(
        image: &Rgb16<'_>,
        itxt: Option<&str>,
        sbit: Option<u8>,
        deflate: Deflate,
    ) -> Vec<u8> {
        let data: Vec<u8> = image
            .pixels
            .iter()
            .flat_map(|&v| (v << image.shift).to_be_bytes())
            .collect();
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Sixteen);
        match deflate {
            Deflate::Fastest => {
                encoder.set_compression(png::Compression::Fastest);
                encoder.set_filter(png::Filter::Up);
            }
            Deflate::Stored => {
                encoder.set_compression(png::Compression::NoCompression);
                encoder.set_filter(png::Filter::NoFilter);
            }
        }
        if let Some(text) = itxt {
            encoder
                .add_itxt_chunk("stagehand".to_string(), text.to_string())
                .unwrap();
        }
        let mut writer = encoder.write_header().unwrap();
        if let Some(bits) = sbit {
            writer.write_chunk(png::chunk::sBIT, &[bits; 3]).unwrap();
        }
        writer.write_image_data(&data).unwrap();
        writer.finish().unwrap();
        out
    }

    /// Our chunks for the same iTXt and sBIT.
    fn ours(image: &Rgb16<'_>, itxt: Option<&str>, sbit: Option<u8>, deflate: Deflate) -> Vec<u8> {
        let text = itxt.map(|t| [b"stagehand\0\0\0\0\0".as_slice(), t.as_bytes()].concat());
        let bits = sbit.map(|b| [b; 3]);
        let mut chunks: Vec<(&[u8; 4], &[u8])> = Vec::new();
        if let Some(t) = &text {
            chunks.push((b"iTXt", t));
        }
        if let Some(b) = &bits {
            chunks.push((b"sBIT", b));
        }
        encode_rgb16(image, &chunks, deflate).unwrap()
    }

    /// Pseudo-random samples below `1 << bits`, smooth (`noise` 0) or noisy, with runs of zeros.
    fn samples(w: u32, h: u32, bits: u8, noise: u32) -> Vec<u16> {
        let max = u32::from(u16::MAX >> (16 - bits));
        (0..w * h * 3)
            .map(|i| {
                let (x, y) = (i % (w * 3), i / (w * 3));
                if (x / 7 + y) % 5 == 0 {
                    return 0;
                }
                let smooth = (x * 37 + y * 11) % (max + 1);
                let hash = i.wrapping_mul(2654435761) >> 8;
                ((smooth + hash % (noise + 1)) % (max + 1)) as u16
            })
            .collect()
    }

    #[test]
    fn writes_the_bytes_the_png_crate_writes() {
        for (w, h) in [(1u32, 1u32), (2, 3), (7, 5), (64, 9), (333, 4)] {
            for (bits, noise) in [(16u8, 0u32), (16, 40_000), (12, 3), (8, 255), (1, 1)] {
                let pixels = samples(w, h, bits, noise);
                let image = Rgb16 {
                    width: w,
                    height: h,
                    pixels: &pixels,
                    shift: 16 - bits,
                };
                for deflate in [Deflate::Fastest, Deflate::Stored] {
                    for (itxt, sbit) in [
                        (Some(r#"{"camera":"cam5","note":"ünïcode ✓"}"#), Some(bits)),
                        (None, None),
                    ] {
                        assert_eq!(
                            ours(&image, itxt, sbit, deflate),
                            png_crate(&image, itxt, sbit, deflate),
                            "{w}x{h}, {bits} bits, noise {noise}, {deflate:?}, {itxt:?}"
                        );
                    }
                }
            }
        }
    }

    /// Noise that deflates to more than its stored size is stored, as the `png` crate does.
    #[test]
    fn incompressible_rows_are_stored_like_the_png_crate() {
        let pixels: Vec<u16> = (0u32..300 * 40 * 3)
            .map(|i| (i.wrapping_mul(2654435761) >> 13) as u16)
            .collect();
        let image = Rgb16 {
            width: 300,
            height: 40,
            pixels: &pixels,
            shift: 0,
        };
        let bytes = ours(&image, None, None, Deflate::Fastest);
        assert_eq!(bytes, png_crate(&image, None, None, Deflate::Fastest));
        assert_eq!(bytes, ours(&image, None, None, Deflate::Stored));
    }

    #[test]
    fn a_sample_above_the_shifted_range_is_named() {
        let mut pixels = vec![100u16; 4 * 3 * 3];
        pixels[20] = 5000;
        pixels[30] = 4096;
        let image = Rgb16 {
            width: 4,
            height: 3,
            pixels: &pixels,
            shift: 4,
        };
        for deflate in [Deflate::Fastest, Deflate::Stored] {
            assert!(matches!(
                encode_rgb16(&image, &[], deflate),
                Err(Rgb16Error::SampleTooLarge(5000))
            ));
        }
    }
}
