//! V4L2 / UVC cameras through the `v4l` crate (feature `cam-v4l`).
//!
//! Hardware trigger mode expects a camera that produces a frame only per trigger pulse and
//! matches frames by the V4L2 buffer sequence. Software mode is for free-running webcams: after
//! `expect` the driver skips the frame already in flight and takes the next one; frames nobody
//! asked for are discarded.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::PathBuf;
use std::time::Duration;

use v4l::buffer::Type as BufType;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::{CaptureStream, Stream as _};
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

use super::HardwareCamera;
use super::config::{self, TriggerMode};
use super::pixels::{self, PixelError};
use super::worker::{Blocking, Image, Link, RawFrame};
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::CameraSpec;

/// V4L2 control ids (linux/v4l2-controls.h).
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_AUTOGAIN: u32 = 0x0098_0912;
const CID_GAIN: u32 = 0x0098_0913;
/// `V4L2_EXPOSURE_MANUAL` of the exposure-auto menu.
const EXPOSURE_MANUAL: i64 = 1;

/// Pixel formats we convert, in order of preference (most bits first).
const FORMATS: [&[u8; 4]; 5] = [b"Y16 ", b"GREY", b"RGB3", b"BGR3", b"YUYV"];

/// A V4L2 camera driven from its own thread.
pub struct V4lCamera;

impl V4lCamera {
    /// Opens the device named by `spec.port` and negotiates a format we can convert.
    pub fn open(spec: &CameraSpec, mode: TriggerMode) -> DeviceResult<HardwareCamera> {
        let path = config::v4l_device_path(spec)?;
        let spec = spec.clone();
        let link = Link::spawn(&spec.id.clone(), mode, move || {
            Worker::open(spec, path, mode)
        })?;
        Ok(link)
    }
}

/// Range of one V4L2 control.
#[derive(Debug, Clone, Copy)]
struct Range {
    min: i64,
    max: i64,
}

/// The blocking side, owned by the worker thread.
struct Worker {
    spec: CameraSpec,
    path: PathBuf,
    mode: TriggerMode,
    dev: Device,
    format: Format,
    exposure: Option<Range>,
    gain: Option<Range>,
    stream: Option<Stream<'static>>,
    /// Software mode: frames still to skip (1) or to take (0) before the next is wanted;
    /// `None` when no frame is wanted.
    skip: Option<u32>,
    /// Software mode: our own count of delivered frames.
    taken: u64,
}

impl Worker {
    fn open(spec: CameraSpec, path: PathBuf, mode: TriggerMode) -> DeviceResult<Self> {
        let dev = Device::with_path(&path).map_err(|e| {
            DeviceError::new(
                spec.id.clone(),
                DeviceErrorKind::PortUnavailable {
                    port: path.display().to_string(),
                    reason: e.to_string(),
                },
            )
        })?;
        let format = negotiate(&dev, &spec, &path)?;
        // `query_controls` unwraps on control types it does not know; a panic here only means
        // we cannot read the ranges.
        let controls = catch_unwind(AssertUnwindSafe(|| dev.query_controls()))
            .ok()
            .and_then(Result::ok)
            .unwrap_or_default();
        let range = |id| {
            controls.iter().find(|c| c.id == id).map(|c| Range {
                min: c.minimum,
                max: c.maximum,
            })
        };
        let (exposure, gain) = (range(CID_EXPOSURE_ABSOLUTE), range(CID_GAIN));
        Ok(Self {
            spec,
            path,
            mode,
            dev,
            format,
            exposure,
            gain,
            stream: None,
            skip: None,
            taken: 0,
        })
    }

    fn err(&self, message: impl Into<String>) -> DeviceError {
        DeviceError::new(
            self.spec.id.clone(),
            DeviceErrorKind::Other {
                message: message.into(),
            },
        )
    }

    fn lost(&self, e: std::io::Error) -> DeviceError {
        DeviceError::new(
            self.spec.id.clone(),
            DeviceErrorKind::Disconnected {
                port: self.path.display().to_string(),
                reason: e.to_string(),
            },
        )
    }

    fn set(&self, id: u32, value: Value, what: &str) -> DeviceResult<()> {
        self.dev
            .set_control(Control { id, value })
            .map_err(|e| self.err(format!("cannot set {what}: {e}")))
    }

    fn convert(&self, data: &[u8]) -> DeviceResult<Image> {
        let f = &self.format;
        let stride = f.stride as usize;
        let (w, h) = (f.width, f.height);
        let (pixels, bit_depth) = match &f.fourcc.repr {
            b"Y16 " => (pixels::mono16le(w, h, stride, data), 16),
            b"GREY" => (pixels::mono8(w, h, stride, data), 8),
            b"RGB3" => (pixels::rgb24(w, h, stride, data), 8),
            b"BGR3" => (pixels::bgr24(w, h, stride, data), 8),
            b"YUYV" => (pixels::yuyv(w, h, stride, data), 8),
            other => (Err(unsupported(other)), 8),
        };
        Ok(Image {
            width: w,
            height: h,
            bit_depth,
            pixels: pixels.map_err(|e| self.err(e.to_string()))?,
        })
    }

    fn stop(&mut self) {
        if let Some(mut s) = self.stream.take() {
            let _ = s.stop();
            // The stream's Drop panics on some errors; contain it to this call.
            let _ = catch_unwind(AssertUnwindSafe(move || drop(s)));
        }
    }
}

fn unsupported(fourcc: &[u8; 4]) -> PixelError {
    PixelError::Unsupported {
        format: String::from_utf8_lossy(fourcc).into_owned(),
        advice: "(MJPEG and Bayer are not converted); set the camera to YUYV, GREY, Y16, RGB3 or BGR3, e.g. `v4l2-ctl --set-fmt-video=pixelformat=YUYV`",
    }
}

/// Asks for the rig's size in each format we convert, taking the first the device accepts.
fn negotiate(dev: &Device, spec: &CameraSpec, path: &std::path::Path) -> DeviceResult<Format> {
    let mut last = None;
    for fourcc in FORMATS {
        let want = Format::new(spec.width, spec.height, FourCC::new(fourcc));
        match dev.set_format(&want) {
            Ok(got) if &got.fourcc.repr == fourcc => {
                if (got.width, got.height) != (spec.width, spec.height) {
                    tracing::warn!(
                        device = %spec.id,
                        "camera gives {}×{} instead of the rig's {}×{}",
                        got.width, got.height, spec.width, spec.height
                    );
                }
                return Ok(got);
            }
            Ok(got) => last = Some(got.fourcc.repr),
            Err(e) => {
                return Err(DeviceError::new(
                    spec.id.clone(),
                    DeviceErrorKind::PortUnavailable {
                        port: path.display().to_string(),
                        reason: format!("cannot set the pixel format: {e}"),
                    },
                ));
            }
        }
    }
    Err(DeviceError::new(
        spec.id.clone(),
        DeviceErrorKind::Other {
            message: unsupported(&last.unwrap_or(*b"????")).to_string(),
        },
    ))
}

impl Blocking for Worker {
    fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        let id = self.spec.id.clone();
        match self.exposure {
            Some(r) => {
                let units = config::v4l_exposure_units(&id, exposure_s, r.min, r.max)?;
                // Manual exposure first; cameras without the menu reject it harmlessly.
                let _ = self.set(
                    CID_EXPOSURE_AUTO,
                    Value::Integer(EXPOSURE_MANUAL),
                    "manual exposure",
                );
                self.set(
                    CID_EXPOSURE_ABSOLUTE,
                    Value::Integer(units),
                    "exposure_time_absolute",
                )?;
            }
            None => {
                tracing::warn!(device = %id, "no exposure_time_absolute control; exposure left to the camera")
            }
        }
        match self.gain {
            Some(r) => {
                let v = config::v4l_gain_value(&id, gain, self.spec.max_gain, r.min, r.max)?;
                let _ = self.set(CID_AUTOGAIN, Value::Boolean(false), "manual gain");
                self.set(CID_GAIN, Value::Integer(v), "gain")?;
            }
            None if gain != 1.0 => {
                return Err(self.err("the camera has no gain control; use gain 1"));
            }
            None => {}
        }
        Ok(())
    }

    fn arm(&mut self) -> DeviceResult<Option<u64>> {
        self.stop();
        let mut stream =
            Stream::with_buffers(&self.dev, BufType::VideoCapture, 4).map_err(|e| self.lost(e))?;
        stream.set_timeout(super::worker::POLL);
        self.stream = Some(stream);
        self.skip = None;
        Ok(None)
    }

    fn disarm(&mut self) -> DeviceResult<()> {
        self.stop();
        self.skip = None;
        Ok(())
    }

    fn software_trigger(&mut self) -> DeviceResult<()> {
        // The frame being exposed now started before the trigger: skip it, take the next.
        self.skip = Some(1);
        Ok(())
    }

    fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>> {
        let Some(stream) = self.stream.as_mut() else {
            std::thread::sleep(timeout);
            return Ok(None);
        };
        let (data, meta) = match CaptureStream::next(stream) {
            Ok(x) => x,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return Ok(None),
            Err(e) => return Err(self.lost(e)),
        };
        let used = (meta.bytesused as usize).min(data.len());
        let data = if used == 0 { data } else { &data[..used] };
        let sequence = u64::from(meta.sequence);
        let image = data.to_vec();
        let sequence = match self.mode {
            TriggerMode::Hardware => sequence,
            TriggerMode::Software => match self.skip {
                None => return Ok(None),
                Some(n) if n > 0 => {
                    self.skip = Some(n - 1);
                    return Ok(None);
                }
                Some(_) => {
                    self.skip = None;
                    self.taken += 1;
                    self.taken
                }
            },
        };
        Ok(Some(RawFrame {
            sequence,
            image: self.convert(&image),
        }))
    }

    fn readout_s(&self) -> f64 {
        self.spec.readout_s()
    }

    fn sequence_wrap(&self) -> u64 {
        match self.mode {
            TriggerMode::Hardware => 1 << 32,
            TriggerMode::Software => 0,
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unsupported_format_names_the_fix() {
        let m = unsupported(b"MJPG").to_string();
        assert!(m.contains("MJPG") && m.contains("YUYV"), "{m}");
    }

    #[test]
    fn opening_a_missing_device_is_port_unavailable() {
        let spec: CameraSpec = toml::from_str(
            "id = \"c\"\nbackend = \"v4l\"\nport = \"/dev/video987\"\nwidth = 8\nheight = 8\nfps = 10.0\nazimuth_deg = 0.0\nelevation_deg = 0.0\ndistance_mm = 1.0\nfov_deg = 30.0\n",
        )
        .expect("spec");
        match V4lCamera::open(&spec, TriggerMode::Software) {
            Err(DeviceError {
                kind: DeviceErrorKind::PortUnavailable { port, .. },
                ..
            }) => assert_eq!(port, "/dev/video987"),
            Err(e) => panic!("wrong error {e}"),
            Ok(_) => panic!("opened a device that does not exist"),
        }
    }
}
