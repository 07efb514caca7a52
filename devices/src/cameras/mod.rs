//! Real camera backends (V4L2, GenICam through aravis, DSLRs through gphoto2), each behind its
//! Cargo feature, plus what they share and what is tested without hardware: exact trigger
//! accounting ([`accounting`]), rig-file parsing and unit conversion ([`config`]) and pixel
//! format conversion ([`pixels`]).
//!
//! Every backend runs its blocking library on a dedicated std thread fed by a channel
//! ([`worker`], built and tested without any camera feature); the async `CameraDriver` side
//! only sends commands and receives frames.

pub mod accounting;
pub mod config;
pub(crate) mod wiring;
pub mod worker;

#[cfg(feature = "cam-aravis")]
// The only unsafe in the crate: aravis-sys calls the safe `aravis` wrapper does not cover.
#[allow(unsafe_code)]
pub mod aravis;
#[cfg(feature = "cam-gphoto2")]
pub mod gphoto2;
#[cfg(feature = "cam-v4l")]
pub mod v4l;

/// Conversion of the simple uncompressed pixel formats to [`crate::Frame`]'s interleaved RGB
/// u16 samples. Compressed (MJPEG) and mosaic (Bayer) formats are not converted here.
pub mod pixels {
    use thiserror::Error;

    /// Why a frame's bytes could not be converted.
    #[derive(Debug, Clone, PartialEq, Eq, Error)]
    pub enum PixelError {
        /// A width or height of zero.
        #[error("empty image {width}×{height}")]
        Empty {
            /// Width in pixels.
            width: u32,
            /// Height in pixels.
            height: u32,
        },
        /// Rows closer together than a row is long.
        #[error("row stride {stride} is less than a row ({row_bytes} bytes)")]
        StrideTooSmall {
            /// Bytes from one row to the next.
            stride: usize,
            /// Bytes of one row's pixels.
            row_bytes: usize,
        },
        /// Fewer bytes than the image needs.
        #[error("frame of {len} bytes is too short for {width}×{height} ({need} bytes needed)")]
        TooShort {
            /// Bytes delivered.
            len: usize,
            /// Width in pixels.
            width: u32,
            /// Height in pixels.
            height: u32,
            /// Bytes needed.
            need: usize,
        },
        /// YUYV pairs pixels, so its width is even.
        #[error("YUYV needs an even width, got {0}")]
        OddYuyvWidth(u32),
        /// A format not converted here; `advice` says why and what to set instead.
        #[error("pixel format {format} is not supported {advice}")]
        Unsupported {
            /// The format as the camera library names it.
            format: String,
            /// Why it is not converted and what to set instead.
            advice: &'static str,
        },
    }

    /// Checks that `data` holds `height` rows of `stride` bytes with `row_bytes` used each.
    fn check(
        width: u32,
        height: u32,
        stride: usize,
        row_bytes: usize,
        data: &[u8],
    ) -> Result<(), PixelError> {
        if width == 0 || height == 0 {
            return Err(PixelError::Empty { width, height });
        }
        if stride < row_bytes {
            return Err(PixelError::StrideTooSmall { stride, row_bytes });
        }
        let need = stride * (height as usize - 1) + row_bytes;
        if data.len() < need {
            return Err(PixelError::TooShort {
                len: data.len(),
                width,
                height,
                need,
            });
        }
        Ok(())
    }

    /// Rows of `data`, each cut to `row_bytes`.
    fn rows(
        data: &[u8],
        height: u32,
        stride: usize,
        row_bytes: usize,
    ) -> impl Iterator<Item = &[u8]> {
        (0..height as usize).map(move |y| &data[y * stride..y * stride + row_bytes])
    }

    /// 8-bit grey (V4L2 `GREY`, GenICam `Mono8`) to RGB with equal channels (bit depth 8).
    pub fn mono8(
        width: u32,
        height: u32,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<u16>, PixelError> {
        let row = width as usize;
        check(width, height, stride, row, data)?;
        Ok(rows(data, height, stride, row)
            .flat_map(|r| r.iter().flat_map(|&v| [u16::from(v); 3]))
            .collect())
    }

    /// 16-bit little-endian grey (V4L2 `Y16 `, GenICam `Mono16`, also Mono10/12 unpacked) to
    /// RGB with equal channels.
    pub fn mono16le(
        width: u32,
        height: u32,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<u16>, PixelError> {
        let row = width as usize * 2;
        check(width, height, stride, row, data)?;
        Ok(rows(data, height, stride, row)
            .flat_map(|r| {
                r.chunks_exact(2)
                    .flat_map(|p| [u16::from_le_bytes([p[0], p[1]]); 3])
            })
            .collect())
    }

    /// Packed 8-bit RGB (V4L2 `RGB3`, GenICam `RGB8`) to RGB u16 (bit depth 8).
    pub fn rgb24(
        width: u32,
        height: u32,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<u16>, PixelError> {
        let row = width as usize * 3;
        check(width, height, stride, row, data)?;
        Ok(rows(data, height, stride, row)
            .flat_map(|r| r.iter().map(|&v| u16::from(v)))
            .collect())
    }

    /// Packed 8-bit BGR (V4L2 `BGR3`, GenICam `BGR8`) to RGB u16 (bit depth 8).
    pub fn bgr24(
        width: u32,
        height: u32,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<u16>, PixelError> {
        let row = width as usize * 3;
        check(width, height, stride, row, data)?;
        Ok(rows(data, height, stride, row)
            .flat_map(|r| {
                r.chunks_exact(3)
                    .flat_map(|p| [p[2], p[1], p[0]].map(u16::from))
            })
            .collect())
    }

    /// YUYV 4:2:2 (V4L2 `YUYV`, most UVC webcams) to RGB, BT.601 limited range (bit depth 8).
    pub fn yuyv(
        width: u32,
        height: u32,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<u16>, PixelError> {
        if !width.is_multiple_of(2) {
            return Err(PixelError::OddYuyvWidth(width));
        }
        let row = width as usize * 2;
        check(width, height, stride, row, data)?;
        let mut out = Vec::with_capacity(width as usize * height as usize * 3);
        for r in rows(data, height, stride, row) {
            for q in r.chunks_exact(4) {
                let (y0, u, y1, v) = (q[0], q[1], q[2], q[3]);
                out.extend(yuv_to_rgb(y0, u, v));
                out.extend(yuv_to_rgb(y1, u, v));
            }
        }
        Ok(out)
    }

    /// One BT.601 limited-range YCbCr sample to 8-bit RGB.
    pub fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u16; 3] {
        let c = (f32::from(y) - 16.0) * 1.164_383;
        let d = f32::from(u) - 128.0;
        let e = f32::from(v) - 128.0;
        let to = |x: f32| x.round().clamp(0.0, 255.0) as u16;
        [
            to(c + 1.596_027 * e),
            to(c - 0.391_762 * d - 0.812_968 * e),
            to(c + 2.017_232 * d),
        ]
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn mono_and_rgb() {
            assert_eq!(mono8(2, 1, 2, &[0, 255]), Ok(vec![0, 0, 0, 255, 255, 255]));
            // Stride padding is skipped.
            assert_eq!(mono8(1, 2, 4, &[7, 9, 9, 9, 8]), Ok(vec![7, 7, 7, 8, 8, 8]));
            assert_eq!(mono16le(1, 1, 2, &[0x34, 0x12]), Ok(vec![0x1234; 3]));
            assert_eq!(rgb24(1, 1, 3, &[1, 2, 3]), Ok(vec![1, 2, 3]));
            assert_eq!(bgr24(1, 1, 3, &[1, 2, 3]), Ok(vec![3, 2, 1]));
        }

        #[test]
        fn yuyv_primaries() {
            // Black, white and mid grey.
            assert_eq!(yuv_to_rgb(16, 128, 128), [0, 0, 0]);
            assert_eq!(yuv_to_rgb(235, 128, 128), [255, 255, 255]);
            assert_eq!(yuv_to_rgb(126, 128, 128), [128, 128, 128]);
            // BT.601 red: Y=81 Cb=90 Cr=240.
            let [r, g, b] = yuv_to_rgb(81, 90, 240);
            assert!(r >= 250 && g <= 3 && b <= 3, "{r} {g} {b}");
            let px = yuyv(2, 1, 4, &[16, 128, 235, 128]).expect("valid");
            assert_eq!(px, vec![0, 0, 0, 255, 255, 255]);
        }

        #[test]
        fn short_or_odd_buffers_are_errors() {
            assert!(
                mono8(4, 4, 4, &[0; 15])
                    .unwrap_err()
                    .to_string()
                    .contains("too short")
            );
            assert!(
                rgb24(2, 1, 5, &[0; 6])
                    .unwrap_err()
                    .to_string()
                    .contains("stride")
            );
            assert!(
                yuyv(3, 1, 6, &[0; 6])
                    .unwrap_err()
                    .to_string()
                    .contains("even width")
            );
            assert!(mono16le(0, 1, 0, &[]).is_err());
        }
    }
}

/// A real camera: the async side of a backend's worker thread. Every backend's `open` returns
/// one; they differ only in the blocking code on the thread.
pub use worker::Link as HardwareCamera;
