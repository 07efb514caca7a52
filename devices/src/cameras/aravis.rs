//! GenICam cameras (USB3 Vision, GigE Vision) through aravis (feature `cam-aravis`).
//!
//! Hardware mode arms `TriggerSource=Line1, TriggerMode=On`; software mode arms the software
//! trigger and fires it on `expect`. Frames are matched by the GenICam frame id.

use std::time::Duration;

use aravis::prelude::*;
use aravis::{AcquisitionMode, Auto, Buffer, BufferStatus, Camera, PixelFormat, Stream};

use super::HardwareCamera;
use super::config::{self, TriggerMode};
use super::pixels;
use super::worker::{Blocking, Image, Link, RawFrame};
use crate::error::{DeviceError, DeviceResult};
use crate::rig::CameraSpec;

/// The input line a hardware trigger is wired to.
pub const TRIGGER_LINE: &str = "Line1";
/// Frame buffers queued on the stream.
const BUFFERS: usize = 8;

/// A GenICam camera driven from its own thread.
pub struct AravisCamera;

impl AravisCamera {
    /// Opens the camera whose GenICam device id is `spec.port`.
    pub fn open(spec: &CameraSpec, mode: TriggerMode) -> DeviceResult<HardwareCamera> {
        let id = config::aravis_device_id(spec)?;
        let spec = spec.clone();
        let link = Link::spawn(&spec.id.clone(), mode, move || {
            let camera = Camera::new(Some(&id)).map_err(|e| DeviceError::PortUnavailable {
                device: spec.id.clone(),
                port: id.clone(),
                reason: e.to_string(),
            })?;
            Worker::new(spec, id, mode, camera)
        })?;
        Ok(link)
    }
}

/// The blocking side, owned by the worker thread.
struct Worker {
    spec: CameraSpec,
    port: String,
    mode: TriggerMode,
    camera: Camera,
    stream: Option<Stream>,
}

impl Worker {
    fn new(
        spec: CameraSpec,
        port: String,
        mode: TriggerMode,
        camera: Camera,
    ) -> DeviceResult<Self> {
        let w = Self {
            spec,
            port,
            mode,
            camera,
            stream: None,
        };
        w.camera
            .set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(|e| w.err("set continuous acquisition", &e))?;
        Ok(w)
    }

    fn err(&self, what: &str, e: &aravis::glib::Error) -> DeviceError {
        DeviceError::Other {
            device: self.spec.id.clone(),
            message: format!("{what} on {}: {e}", self.port),
        }
    }

    fn convert(&self, buf: &Buffer) -> DeviceResult<Image> {
        let other = |message: String| DeviceError::Other {
            device: self.spec.id.clone(),
            message,
        };
        if buf.status() != BufferStatus::Success {
            return Err(other(format!(
                "frame {} arrived incomplete ({:?}); check the link bandwidth and cable",
                buf.frame_id(),
                buf.status()
            )));
        }
        let (w, h) = (buf.image_width(), buf.image_height());
        let (w, h) = match (u32::try_from(w), u32::try_from(h)) {
            (Ok(w), Ok(h)) => (w, h),
            _ => return Err(other(format!("frame has a negative size {w}×{h}"))),
        };
        let (ptr, len) = buf.data();
        if ptr.is_null() {
            return Err(other("frame has no data".into()));
        }
        // SAFETY: aravis returns the buffer's own memory and its size; `buf` is borrowed for
        // the whole use of the slice and is not pushed back to the stream until after it.
        let data = unsafe { std::slice::from_raw_parts(ptr.cast_const(), len) };
        let format = buf.image_pixel_format();
        // Single-part image payloads start at offset 0 without line padding (the GenICam
        // default); aravis < 0.8.23 offers no padding query.
        let (pixels, bit_depth) = convert_pixels(format, w, h, 0, data).map_err(other)?;
        Ok(Image {
            width: w,
            height: h,
            bit_depth,
            pixels,
        })
    }

    fn stop(&mut self) {
        if self.stream.take().is_some() {
            let _ = self.camera.stop_acquisition();
        }
    }
}

/// Converts the formats that need no demosaicing or unpacking; bit depth from the format.
fn convert_pixels(
    format: PixelFormat,
    w: u32,
    h: u32,
    pad: usize,
    data: &[u8],
) -> Result<(Vec<u16>, u8), String> {
    let width = w as usize;
    match format {
        PixelFormat::MONO_8 => pixels::mono8(w, h, width + pad, data).map(|p| (p, 8)),
        PixelFormat::MONO_10 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 10)),
        PixelFormat::MONO_12 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 12)),
        PixelFormat::MONO_16 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 16)),
        PixelFormat::RGB_8_PACKED => pixels::rgb24(w, h, 3 * width + pad, data).map(|p| (p, 8)),
        PixelFormat::BGR_8_PACKED => pixels::bgr24(w, h, 3 * width + pad, data).map(|p| (p, 8)),
        other => Err(format!(
            "pixel format 0x{:08x} is not supported (Bayer and packed formats are not converted); set PixelFormat to Mono8, Mono10, Mono12, Mono16, RGB8 or BGR8",
            other.raw()
        )),
    }
}

impl Blocking for Worker {
    fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        let id = self.spec.id.clone();
        let cam = &self.camera;
        let _ = cam.set_exposure_time_auto(Auto::Off);
        let (lo, hi) = cam
            .exposure_time_bounds()
            .map_err(|e| self.err("read exposure bounds", &e))?;
        let us = config::exposure_us(&id, exposure_s, lo, hi)?;
        cam.set_exposure_time(us)
            .map_err(|e| self.err("set exposure", &e))?;
        if cam.is_gain_available().unwrap_or(false) {
            let _ = cam.set_gain_auto(Auto::Off);
            let (lo, hi) = cam
                .gain_bounds()
                .map_err(|e| self.err("read gain bounds", &e))?;
            let db = config::gain_db(&id, gain, lo, hi)?;
            cam.set_gain(db).map_err(|e| self.err("set gain", &e))?;
        } else if gain != 1.0 {
            return Err(DeviceError::Gain {
                device: id,
                gain,
                max: 1.0,
            });
        }
        Ok(())
    }

    fn arm(&mut self) -> DeviceResult<Option<u64>> {
        self.stop();
        let source = match self.mode {
            TriggerMode::Hardware => TRIGGER_LINE,
            TriggerMode::Software => "Software",
        };
        self.camera
            .set_trigger(source)
            .map_err(|e| self.err(&format!("set trigger source {source}"), &e))?;
        let payload = self
            .camera
            .payload()
            .map_err(|e| self.err("read payload size", &e))?;
        let stream = self
            .camera
            .create_stream()
            .map_err(|e| self.err("create stream", &e))?;
        for _ in 0..BUFFERS {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        self.camera
            .start_acquisition()
            .map_err(|e| self.err("start acquisition", &e))?;
        self.stream = Some(stream);
        Ok(None)
    }

    fn disarm(&mut self) -> DeviceResult<()> {
        self.stop();
        Ok(())
    }

    fn software_trigger(&mut self) -> DeviceResult<()> {
        self.camera
            .software_trigger()
            .map_err(|e| self.err("software trigger", &e))
    }

    fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>> {
        let Some(stream) = self.stream.as_ref() else {
            std::thread::sleep(timeout);
            return Ok(None);
        };
        let Some(buf) = stream.timeout_pop_buffer(timeout.as_micros() as u64) else {
            return Ok(None);
        };
        let raw = RawFrame {
            sequence: buf.frame_id(),
            image: self.convert(&buf),
        };
        stream.push_buffer(buf);
        Ok(Some(raw))
    }

    fn readout_s(&self) -> f64 {
        self.spec.readout_s()
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

    fn spec() -> CameraSpec {
        toml::from_str(
            "id = \"gc0\"\nbackend = \"aravis\"\nport = \"Fake_1\"\nwidth = 512\nheight = 512\nfps = 20.0\nazimuth_deg = 0.0\nelevation_deg = 0.0\ndistance_mm = 1.0\nfov_deg = 30.0\nmax_gain = 16.0\n",
        )
        .expect("spec")
    }

    #[test]
    fn unsupported_formats_are_named() {
        let e = convert_pixels(PixelFormat::BAYER_RG_8, 2, 2, 0, &[0; 4]).unwrap_err();
        assert!(e.contains("not supported") && e.contains("Mono8"), "{e}");
        assert_eq!(
            convert_pixels(PixelFormat::MONO_12, 1, 1, 0, &[0xff, 0x0f]),
            Ok((vec![0x0fff; 3], 12))
        );
    }

    /// Aravis's fake camera: configure, arm, one software trigger, one accounted frame.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn fake_camera_grabs_one_frame_per_trigger() {
        let spec = spec();
        let s = spec.clone();
        let mut link = Link::spawn("gc0", TriggerMode::Software, move || {
            unsafe extern "C" {
                fn arv_enable_interface(interface_id: *const std::ffi::c_char);
            }
            // SAFETY: a plain C call with a NUL-terminated static string; libaravis is linked.
            unsafe { arv_enable_interface(c"Fake".as_ptr()) };
            let camera = Camera::new(Some("Fake_1")).map_err(|e| DeviceError::Other {
                device: "gc0".into(),
                message: e.to_string(),
            })?;
            Worker::new(s, "Fake".into(), TriggerMode::Software, camera)
        })
        .expect("fake camera opens");
        link.configure(0.01, 2.0).await.expect("configure");
        link.set_armed(true).await.expect("arm");
        link.expect(41, 0.01).expect("expect");
        let f = tokio::time::timeout(Duration::from_secs(4), link.next_frame())
            .await
            .expect("a frame within 4 s")
            .expect("frame ok");
        assert_eq!(f.trigger_id, 41);
        assert_eq!(f.camera, "gc0");
        assert_eq!(f.pixels.len(), (f.width * f.height * 3) as usize);
        assert!(f.width > 0 && f.height > 0);
        link.set_armed(false).await.expect("disarm");
    }
}
