//! DSLRs and mirrorless cameras through libgphoto2 (feature `cam-gphoto2`).
//!
//! Exposure and gain are the `shutterspeed` and `iso` config widgets (nearest choice within a
//! third of a stop, else an error). Software mode captures on `expect` (`capture_image`);
//! hardware mode (a remote-release cable on the trigger line) waits for the camera's new-file
//! events. The frame counter is ours: one per image received. Images are decoded only from
//! PPM (P6); JPEG and raw files are reported as unsupported.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::Duration;

use gphoto2::camera::CameraEvent;
use gphoto2::file::CameraFilePath;
use gphoto2::widget::RadioWidget;
use gphoto2::{Camera, Context};

use super::HardwareCamera;
use super::config::{self, Gphoto2Target, TriggerMode};
use super::worker::{Blocking, Image, Link, RawFrame};
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::CameraSpec;

/// A libgphoto2 camera driven from its own thread.
pub struct Gphoto2Camera;

impl Gphoto2Camera {
    /// Opens the camera named by `spec.port` (`usb:BUS,DEV` or a unique model name).
    pub fn open(spec: &CameraSpec, mode: TriggerMode) -> DeviceResult<HardwareCamera> {
        let target = config::gphoto2_target(spec)?;
        let spec = spec.clone();
        let link = Link::spawn(&spec.id.clone(), mode, move || {
            Worker::open(spec, target, mode)
        })?;
        Ok(link)
    }
}

/// The blocking side, owned by the worker thread.
struct Worker {
    spec: CameraSpec,
    port: String,
    mode: TriggerMode,
    context: Context,
    camera: Camera,
    /// A captured image waiting for `grab` (software mode).
    ready: Option<RawFrame>,
    /// Images received since arming.
    count: u64,
}

impl Worker {
    fn open(spec: CameraSpec, target: Gphoto2Target, mode: TriggerMode) -> DeviceResult<Self> {
        let shown = match &target {
            Gphoto2Target::Port(p) | Gphoto2Target::Model(p) => p.clone(),
        };
        let unavailable = |reason: String| {
            DeviceError::new(
                spec.id.clone(),
                DeviceErrorKind::PortUnavailable {
                    port: shown.clone(),
                    reason,
                },
            )
        };
        let context = Context::new().map_err(|e| unavailable(e.to_string()))?;
        let found: Vec<_> = context
            .list_cameras()
            .wait()
            .map_err(|e| unavailable(e.to_string()))?
            .filter(|d| match &target {
                Gphoto2Target::Port(p) => &d.port == p,
                Gphoto2Target::Model(m) => &d.model == m,
            })
            .collect();
        let desc = match found.as_slice() {
            [one] => one.clone(),
            [] => {
                return Err(unavailable(
                    "no such camera (see `gphoto2 --auto-detect`)".into(),
                ));
            }
            many => {
                return Err(unavailable(format!(
                    "{} cameras match; name one by its port (usb:BUS,DEV)",
                    many.len()
                )));
            }
        };
        let camera = context
            .get_camera(&desc)
            .wait()
            .map_err(|e| unavailable(e.to_string()))?;
        Ok(Self {
            spec,
            port: desc.port,
            mode,
            context,
            camera,
            ready: None,
            count: 0,
        })
    }

    fn err(&self, what: &str, e: impl std::fmt::Display) -> DeviceError {
        DeviceError::new(
            self.spec.id.clone(),
            DeviceErrorKind::Other {
                message: format!("{what} on {}: {e}", self.port),
            },
        )
    }

    /// Reads a radio widget and its choices (the crate panics on some library errors; that
    /// is contained here).
    fn radio(&self, key: &str) -> DeviceResult<(RadioWidget, Vec<String>)> {
        let w = self
            .camera
            .config_key::<RadioWidget>(key)
            .wait()
            .map_err(|e| self.err(&format!("read `{key}`"), e))?;
        let choices = catch_unwind(AssertUnwindSafe(|| w.choices_iter().collect::<Vec<_>>()))
            .map_err(|_| self.err(&format!("read the choices of `{key}`"), "library error"))?;
        Ok((w, choices))
    }

    fn set_radio(&self, key: &str, widget: &RadioWidget, choice: &str) -> DeviceResult<()> {
        widget
            .set_choice(choice)
            .map_err(|e| self.err(&format!("choose {choice} for `{key}`"), e))?;
        self.camera
            .set_config(widget)
            .wait()
            .map_err(|e| self.err(&format!("set `{key}`"), e))
    }

    fn fetch(&mut self, path: &CameraFilePath) -> RawFrame {
        self.count += 1;
        let file = self
            .camera
            .fs()
            .download(&path.folder(), &path.name())
            .wait()
            .map_err(|e| self.err("download the image", e));
        let data = file.and_then(|f| {
            f.get_data(&self.context)
                .wait()
                .map_err(|e| self.err("read the image", e))
        });
        RawFrame {
            sequence: self.count,
            image: data.and_then(|d| {
                decode(&d).map_err(|e| {
                    DeviceError::new(
                        self.spec.id.clone(),
                        DeviceErrorKind::Other {
                            message: e.to_string(),
                        },
                    )
                })
            }),
        }
    }
}

/// Why an image from the camera could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PpmError {
    /// Not a binary PPM (`JPEG` or `raw or unknown`).
    #[error(
        "the camera delivered a {0} file, which is not decoded; set the camera's image format to one libgphoto2 delivers as PPM, or use a V4L2/GenICam camera"
    )]
    NotPpm(&'static str),
    /// The header is not `P6 width height maxval`.
    #[error("malformed PPM header")]
    MalformedHeader,
    /// A zero size or a maximum beyond 16 bits.
    #[error("PPM header out of range: {width}×{height}, max {max}")]
    OutOfRange {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Largest sample value.
        max: u32,
    },
    /// Fewer samples than the header says.
    #[error("PPM data is truncated")]
    Truncated,
}

/// Decodes a binary PPM (P6, 8 or 16 bit); anything else is reported as unsupported.
pub fn decode(data: &[u8]) -> Result<Image, PpmError> {
    if !data.starts_with(b"P6") {
        let kind = if data.starts_with(&[0xff, 0xd8]) {
            "JPEG"
        } else {
            "raw or unknown"
        };
        return Err(PpmError::NotPpm(kind));
    }
    // Header: P6 <ws> width <ws> height <ws> maxval <one ws> data; `#` comments.
    let mut fields = Vec::new();
    let mut i = 2;
    while fields.len() < 3 {
        while i < data.len() && (data[i].is_ascii_whitespace() || data[i] == b'#') {
            if data[i] == b'#' {
                while i < data.len() && data[i] != b'\n' {
                    i += 1;
                }
            } else {
                i += 1;
            }
        }
        let start = i;
        while i < data.len() && data[i].is_ascii_digit() {
            i += 1;
        }
        let n: u32 = std::str::from_utf8(&data[start..i])
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or(PpmError::MalformedHeader)?;
        fields.push(n);
    }
    if i >= data.len() || !data[i].is_ascii_whitespace() {
        return Err(PpmError::MalformedHeader);
    }
    let body = &data[i + 1..];
    let (w, h, max) = (fields[0], fields[1], fields[2]);
    if w == 0 || h == 0 || max == 0 || max > 65535 {
        return Err(PpmError::OutOfRange {
            width: w,
            height: h,
            max,
        });
    }
    let samples = w as usize * h as usize * 3;
    let pixels: Vec<u16> = if max < 256 {
        body.get(..samples)
            .ok_or(PpmError::Truncated)?
            .iter()
            .map(|&v| u16::from(v))
            .collect()
    } else {
        body.get(..samples * 2)
            .ok_or(PpmError::Truncated)?
            .chunks_exact(2)
            .map(|p| u16::from_be_bytes([p[0], p[1]]))
            .collect()
    };
    Ok(Image {
        width: w,
        height: h,
        bit_depth: (32 - max.leading_zeros()) as u8,
        pixels,
    })
}

impl Blocking for Worker {
    fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        let id = self.spec.id.clone();
        let (w, choices) = self.radio("shutterspeed")?;
        let choice = config::shutter_choice(&id, &choices, exposure_s)?.to_string();
        self.set_radio("shutterspeed", &w, &choice)?;
        let (w, choices) = self.radio("iso")?;
        let choice = config::iso_choice(&id, &choices, gain)?.to_string();
        self.set_radio("iso", &w, &choice)
    }

    fn arm(&mut self) -> DeviceResult<Option<u64>> {
        self.ready = None;
        self.count = 0;
        // The next image is number 1.
        Ok(Some(1))
    }

    fn disarm(&mut self) -> DeviceResult<()> {
        self.ready = None;
        Ok(())
    }

    fn software_trigger(&mut self) -> DeviceResult<()> {
        let path = self
            .camera
            .capture_image()
            .wait()
            .map_err(|e| self.err("capture", e))?;
        self.ready = Some(self.fetch(&path));
        Ok(())
    }

    fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>> {
        if let Some(raw) = self.ready.take() {
            return Ok(Some(raw));
        }
        let event = self
            .camera
            .wait_event(timeout)
            .wait()
            .map_err(|e| self.err("wait for camera events", e))?;
        match (self.mode, event) {
            (TriggerMode::Hardware, CameraEvent::NewFile(path)) => Ok(Some(self.fetch(&path))),
            _ => Ok(None),
        }
    }

    fn readout_s(&self) -> f64 {
        self.spec.readout_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_ppm_8_and_16_bit() {
        let img = decode(b"P6\n# comment\n2 1\n255\n\x01\x02\x03\x04\x05\x06").expect("8-bit");
        assert_eq!((img.width, img.height, img.bit_depth), (2, 1, 8));
        assert_eq!(img.pixels, vec![1, 2, 3, 4, 5, 6]);
        let img = decode(b"P6 1 1 4095 \x0f\xff\x00\x01\x08\x00").expect("12-bit");
        assert_eq!(img.bit_depth, 12);
        assert_eq!(img.pixels, vec![4095, 1, 2048]);
    }

    #[test]
    fn rejects_jpeg_and_broken_ppm() {
        assert!(
            decode(&[0xff, 0xd8, 0xff])
                .err()
                .is_some_and(|e| e.to_string().contains("JPEG"))
        );
        assert!(decode(b"P6 2 2 255 \x00").is_err());
        assert!(decode(b"P6 0 2 255 ").is_err());
        assert!(decode(b"P6 x").is_err());
        assert!(decode(b"P6 1 1 255").is_err());
    }
}
