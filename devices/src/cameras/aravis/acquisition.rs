//! The worker thread of one GenICam camera: configures exposure, gain and triggering (each
//! read back), arms and disarms the stream, fires software triggers and grabs frames,
//! matching them to triggers by block id, and marks the camera lost on a link failure (see
//! the module docs of [`super`]).

use std::net::Ipv4Addr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use aravis::glib::prelude::*;
use aravis::prelude::*;
use aravis::{
    AcquisitionMode, Buffer, BufferStatus, Camera, GvStream, GvStreamSocketBuffer, PixelFormat,
    Stream,
};

use super::{GV_BLOCK_IDS, StreamCounters, StreamStats, TRIGGER_LINE, connect, gvcp_probe};
use crate::cameras::config::{self, TriggerMode};
use crate::cameras::pixels::{self, PixelError};
use crate::cameras::worker::{Blocking, Image, RawFrame};
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::CameraSpec;

/// Frame buffers queued on the stream.
const BUFFERS: usize = 8;
/// Bootstrap register holding a GigE Vision device's current IPv4 address.
const GVBS_CURRENT_IP_ADDRESS: u64 = 0x0024;
/// How long a reopen waits for a lost GigE camera to answer a discovery before giving up
/// (a dead camera would otherwise hold each GVCP call for seconds of retries).
const PROBE_TIMEOUT: Duration = Duration::from_millis(300);
/// Socket buffer asked for per stream (the kernel caps it at `net.core.rmem_max`): a few
/// frames of slack so a busy host does not drop packets of a burst.
const SOCKET_BUFFER_BYTES: usize = 8 << 20;

/// How far the gain a camera reports may be from the one set (cameras step gain in ~0.03 dB).
const GAIN_TOLERANCE_DB: f64 = 0.1;

/// Whether an aravis error means the link to the camera failed (rather than a request the
/// camera refused): then the camera is treated as lost until it is reopened.
fn is_link_failure(e: &aravis::glib::Error) -> bool {
    use aravis::DeviceError as D;
    matches!(
        e.kind::<D>(),
        Some(D::Timeout | D::NotConnected | D::TransferError | D::NotController)
    )
}

/// The settings the camera reported back after the last configure and arm.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
struct ReadBack {
    exposure_feature: &'static str,
    exposure_us: f64,
    gain_feature: Option<&'static str>,
    gain: Option<f64>,
    trigger_selector: String,
    trigger_mode: String,
    trigger_source: String,
}

/// The blocking side, owned by the worker thread.
pub(super) struct Worker {
    spec: CameraSpec,
    port: String,
    mode: TriggerMode,
    /// `None` only in the middle of a reopen.
    camera: Option<Camera>,
    stream: Option<Stream>,
    /// Set by aravis's control-lost signal (heartbeat) or by a failed call.
    lost: Arc<AtomicBool>,
    /// The camera's IPv4 address (GigE only), for the probe before a reopen.
    address: Option<Ipv4Addr>,
    /// Block ids are 16-bit (GigE Vision without extended ids).
    short_ids: bool,
    /// Last configured exposure (s) and gain, applied again after a reopen.
    settings: Option<(f64, f64)>,
    read_back: ReadBack,
    stats: StreamStats,
    /// Counters of streams already closed, plus the driver's own counts.
    closed: StreamCounters,
}

impl Worker {
    pub(super) fn new(
        spec: CameraSpec,
        port: String,
        mode: TriggerMode,
        camera: Camera,
        stats: StreamStats,
    ) -> DeviceResult<Self> {
        let mut w = Self {
            spec,
            port,
            mode,
            camera: None,
            stream: None,
            lost: Arc::new(AtomicBool::new(false)),
            address: None,
            short_ids: false,
            settings: None,
            read_back: ReadBack::default(),
            stats,
            closed: StreamCounters::default(),
        };
        w.attach(camera)?;
        Ok(w)
    }

    fn is_lost(&self) -> bool {
        self.lost.load(Ordering::Acquire)
    }

    fn other(&self, message: String) -> DeviceError {
        DeviceError::new(self.spec.id.clone(), DeviceErrorKind::Other { message })
    }

    fn disconnected(&self, reason: String) -> DeviceError {
        DeviceError::new(
            self.spec.id.clone(),
            DeviceErrorKind::Disconnected {
                port: self.port.clone(),
                reason,
            },
        )
    }

    /// Maps an aravis error: a link failure marks the camera lost.
    fn fail(&self, what: &str, e: &aravis::glib::Error) -> DeviceError {
        if is_link_failure(e) {
            self.lost.store(true, Ordering::Release);
            tracing::warn!(device = %self.spec.id, port = %self.port, "{what}: {e}; camera lost");
            self.disconnected(format!("{what}: {e}"))
        } else {
            self.other(format!("{what} on {}: {e}", self.port))
        }
    }

    fn cam(&self) -> DeviceResult<&Camera> {
        self.camera
            .as_ref()
            .ok_or_else(|| self.disconnected("camera not open".into()))
    }

    fn available(&self, feature: &str) -> bool {
        self.camera
            .as_ref()
            .is_some_and(|c| c.is_feature_available(feature).unwrap_or(false))
    }

    fn set_string(&self, feature: &str, value: &str) -> DeviceResult<()> {
        self.cam()?
            .set_string(feature, value)
            .map_err(|e| self.fail(&format!("set {feature}={value}"), &e))
    }

    fn string(&self, feature: &str) -> DeviceResult<String> {
        self.cam()?
            .string(feature)
            .map(|s| s.to_string())
            .map_err(|e| self.fail(&format!("read {feature}"), &e))
    }

    /// Sets an enumeration and checks what the camera reports back.
    fn set_checked(&self, feature: &str, value: &str) -> DeviceResult<String> {
        self.set_string(feature, value)?;
        let back = self.string(feature)?;
        if back == value {
            Ok(back)
        } else {
            Err(self.other(format!(
                "set {feature}={value}, but the camera reports {feature}={back}"
            )))
        }
    }

    /// Takes `camera` as the open camera: watches for control loss and checks the image
    /// settings against the rig file.
    fn attach(&mut self, camera: Camera) -> DeviceResult<()> {
        self.lost.store(false, Ordering::Release);
        if let Some(device) = camera.device() {
            let lost = self.lost.clone();
            let id = self.spec.id.clone();
            device.connect_control_lost(move |_| {
                tracing::warn!(device = %id, "aravis reports the camera's control channel lost");
                lost.store(true, Ordering::Release);
            });
            if camera.is_gv_device() {
                self.address = match device.read_register(GVBS_CURRENT_IP_ADDRESS) {
                    Ok((_, ip)) if ip != 0 => Some(Ipv4Addr::from(ip)),
                    _ => self.port.parse().ok(),
                };
            }
        }
        let extended = camera
            .string("GevGVSPExtendedIDMode")
            .is_ok_and(|m| m == "On");
        self.short_ids = camera.is_gv_device() && !extended;
        self.camera = Some(camera);
        self.cam()?
            .set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(|e| self.fail("set continuous acquisition", &e))?;
        self.fit_image()
    }

    /// Sets Width/Height to the rig file's size when they differ, and checks that the pixel
    /// format is one this driver converts.
    fn fit_image(&self) -> DeviceResult<()> {
        let cam = self.cam()?;
        for (feature, want) in [("Width", self.spec.width), ("Height", self.spec.height)] {
            let have = cam
                .integer(feature)
                .map_err(|e| self.fail(&format!("read {feature}"), &e))?;
            if have == i64::from(want) {
                continue;
            }
            cam.set_integer(feature, i64::from(want)).map_err(|e| {
                self.other(format!(
                    "the rig file says {feature} {want} but the camera has {have} and refused {want}: {e}"
                ))
            })?;
            let back = cam
                .integer(feature)
                .map_err(|e| self.fail(&format!("read {feature}"), &e))?;
            if back != i64::from(want) {
                return Err(self.other(format!(
                    "set {feature}={want}, but the camera reports {back}"
                )));
            }
        }
        let format = cam
            .pixel_format()
            .map_err(|e| self.fail("read PixelFormat", &e))?;
        convert_pixels(format, 1, 1, 0, &[0; 8]).map_err(|e| self.other(e.to_string()))?;
        Ok(())
    }

    /// Drops the old camera and opens it again once it answers; re-applies the settings.
    fn reopen(&mut self) -> DeviceResult<()> {
        if let Some(address) = self.address
            && !gvcp_probe(address, PROBE_TIMEOUT)
        {
            return Err(DeviceError::new(
                self.spec.id.clone(),
                DeviceErrorKind::PortUnavailable {
                    port: self.port.clone(),
                    reason: format!("no answer to a GigE Vision discovery at {address}"),
                },
            ));
        }
        self.close_stream();
        // The old device leaves control (quick now that the camera answers) before the new
        // one takes it.
        self.camera = None;
        let camera = connect(&self.spec.id, &self.port)?;
        self.attach(camera)?;
        if let Some((exposure_s, gain)) = self.settings {
            self.apply(exposure_s, gain)?;
        }
        self.closed.reopens += 1;
        self.publish();
        tracing::info!(device = %self.spec.id, port = %self.port, "camera reopened");
        Ok(())
    }

    /// Sets exposure and gain and reads both back.
    fn apply(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        let id = self.spec.id.clone();
        let cam = self.cam()?.clone();
        let exposure_feature = if self.available("ExposureTimeAbs") {
            "ExposureTimeAbs"
        } else if self.available("ExposureTime") {
            "ExposureTime"
        } else {
            return Err(
                self.other("the camera has neither ExposureTimeAbs nor ExposureTime".into())
            );
        };
        if self.available("ExposureAuto") {
            self.set_string("ExposureAuto", "Off")?;
        }
        let (lo, hi) = cam
            .float_bounds(exposure_feature)
            .map_err(|e| self.fail(&format!("read {exposure_feature} bounds"), &e))?;
        let us = config::exposure_us(&id, exposure_s, lo, hi)?;
        cam.set_float(exposure_feature, us)
            .map_err(|e| self.fail(&format!("set {exposure_feature}"), &e))?;
        let exposure_us = cam
            .float(exposure_feature)
            .map_err(|e| self.fail(&format!("read {exposure_feature}"), &e))?;
        // Cameras quantise exposure (to a line time, often): within 5 % (or 1 µs) it took.
        if (exposure_us - us).abs() > (0.05 * us).max(1.0) {
            return Err(self.other(format!(
                "set {exposure_feature}={us} µs, but the camera reports {exposure_us} µs"
            )));
        }
        let (gain_feature, gain_value) = if self.available("Gain") {
            if self.available("GainAuto") {
                self.set_string("GainAuto", "Off")?;
            }
            let (lo, hi) = cam
                .float_bounds("Gain")
                .map_err(|e| self.fail("read Gain bounds", &e))?;
            let db = config::gain_db(&id, gain, lo, hi)?;
            cam.set_float("Gain", db)
                .map_err(|e| self.fail("set Gain", &e))?;
            let back = cam.float("Gain").map_err(|e| self.fail("read Gain", &e))?;
            if (back - db).abs() > GAIN_TOLERANCE_DB {
                return Err(self.other(format!(
                    "set Gain={db:.3} dB, but the camera reports {back:.3} dB"
                )));
            }
            (Some("Gain"), Some(back))
        } else if self.available("GainRaw") {
            if self.available("GainAuto") {
                self.set_string("GainAuto", "Off")?;
            }
            let (lo, hi) = cam
                .integer_bounds("GainRaw")
                .map_err(|e| self.fail("read GainRaw bounds", &e))?;
            let raw = config::linear_gain_value(&id, gain, self.spec.max_gain, lo, hi)?;
            cam.set_integer("GainRaw", raw)
                .map_err(|e| self.fail("set GainRaw", &e))?;
            let back = cam
                .integer("GainRaw")
                .map_err(|e| self.fail("read GainRaw", &e))?;
            if back != raw {
                return Err(self.other(format!("set GainRaw={raw}, but the camera reports {back}")));
            }
            (Some("GainRaw"), Some(back as f64))
        } else if gain != 1.0 {
            return Err(DeviceError::new(
                id,
                DeviceErrorKind::Gain { gain, max: 1.0 },
            ));
        } else {
            (None, None)
        };
        self.read_back.exposure_feature = exposure_feature;
        self.read_back.exposure_us = exposure_us;
        self.read_back.gain_feature = gain_feature;
        self.read_back.gain = gain_value;
        Ok(())
    }

    /// Only `FrameStart` waits for a trigger, from the line or the software command.
    fn set_trigger(&mut self) -> DeviceResult<()> {
        let source = match self.mode {
            TriggerMode::Hardware => TRIGGER_LINE,
            TriggerMode::Software => "Software",
        };
        let selectors = self
            .cam()?
            .dup_available_enumerations_as_strings("TriggerSelector")
            .map_err(|e| self.fail("list TriggerSelector", &e))?;
        for s in selectors.iter().filter(|s| s.as_str() != "FrameStart") {
            self.set_string("TriggerSelector", s)?;
            self.set_string("TriggerMode", "Off")?;
        }
        self.read_back.trigger_selector = self.set_checked("TriggerSelector", "FrameStart")?;
        self.read_back.trigger_mode = self.set_checked("TriggerMode", "On")?;
        self.read_back.trigger_source = self.set_checked("TriggerSource", source)?;
        Ok(())
    }

    /// Stops acquisition (unless the camera is lost) and folds the stream's counters in.
    fn close_stream(&mut self) {
        let Some(stream) = self.stream.take() else {
            return;
        };
        if !self.is_lost()
            && let Some(cam) = &self.camera
            && let Err(e) = cam.stop_acquisition()
        {
            let _ = self.fail("stop acquisition", &e);
        }
        self.closed = self.closed.plus(StreamCounters::of(&stream));
        self.publish();
    }

    /// Publishes closed + live counters.
    fn publish(&self) {
        let live = self
            .stream
            .as_ref()
            .map(StreamCounters::of)
            .unwrap_or_default();
        self.stats.set(self.closed.plus(live));
    }

    /// The camera's frame id as a sequence number that counts without gaps.
    fn sequence(&self, frame_id: u64) -> u64 {
        if self.short_ids {
            gv_sequence(frame_id)
        } else {
            frame_id
        }
    }

    fn convert(&self, buf: &Buffer) -> DeviceResult<Image> {
        let (w, h) = (buf.image_width(), buf.image_height());
        let (w, h) = match (u32::try_from(w), u32::try_from(h)) {
            (Ok(w), Ok(h)) => (w, h),
            _ => return Err(self.other(format!("frame has a negative size {w}×{h}"))),
        };
        let (ptr, len) = buf.data();
        if ptr.is_null() {
            return Err(self.other("frame has no data".into()));
        }
        // SAFETY: aravis returns the buffer's own memory and its size; `buf` is borrowed for
        // the whole use of the slice and is not pushed back to the stream until after it.
        let data = unsafe { std::slice::from_raw_parts(ptr.cast_const(), len) };
        let format = buf.image_pixel_format();
        // Single-part image payloads start at offset 0 without line padding (the GenICam
        // default); aravis < 0.8.23 offers no padding query.
        let (pixels, bit_depth) =
            convert_pixels(format, w, h, 0, data).map_err(|e| self.other(e.to_string()))?;
        Ok(Image {
            width: w,
            height: h,
            bit_depth,
            pixels,
        })
    }
}

/// A 16-bit GigE Vision block id as a sequence counting modulo [`GV_BLOCK_IDS`] without gaps:
/// block ids skip 0, so 1..=65535 becomes 0..=65534 and 65535 → 1 is a step of one.
fn gv_sequence(block_id: u64) -> u64 {
    (block_id % GV_BLOCK_IDS + GV_BLOCK_IDS - 1) % GV_BLOCK_IDS
}

/// Converts the formats that need no demosaicing or unpacking; bit depth from the format.
fn convert_pixels(
    format: PixelFormat,
    w: u32,
    h: u32,
    pad: usize,
    data: &[u8],
) -> Result<(Vec<u16>, u8), PixelError> {
    let width = w as usize;
    match format {
        PixelFormat::MONO_8 => pixels::mono8(w, h, width + pad, data).map(|p| (p, 8)),
        PixelFormat::MONO_10 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 10)),
        PixelFormat::MONO_12 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 12)),
        PixelFormat::MONO_16 => pixels::mono16le(w, h, 2 * width + pad, data).map(|p| (p, 16)),
        PixelFormat::RGB_8_PACKED => pixels::rgb24(w, h, 3 * width + pad, data).map(|p| (p, 8)),
        PixelFormat::BGR_8_PACKED => pixels::bgr24(w, h, 3 * width + pad, data).map(|p| (p, 8)),
        other => Err(PixelError::Unsupported {
            format: format!("0x{:08x}", other.raw()),
            advice: "(Bayer and packed formats are not converted); set PixelFormat to Mono8, Mono10, Mono12, Mono16, RGB8 or BGR8",
        }),
    }
}

impl Blocking for Worker {
    fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        if self.is_lost() {
            if self.stream.is_some() {
                return Err(self.disconnected(
                    "the camera was lost while armed; disarm and arm again to reopen it".into(),
                ));
            }
            self.reopen()?;
        }
        self.apply(exposure_s, gain)?;
        self.settings = Some((exposure_s, gain));
        Ok(())
    }

    fn arm(&mut self) -> DeviceResult<Option<u64>> {
        self.close_stream();
        if self.is_lost() {
            self.reopen()?;
        }
        self.set_trigger()?;
        let cam = self.cam()?.clone();
        let payload = cam
            .payload()
            .map_err(|e| self.fail("read PayloadSize", &e))?;
        let stream = cam
            .create_stream()
            .map_err(|e| self.fail("create stream", &e))?;
        if let Some(gv) = stream.downcast_ref::<GvStream>() {
            gv.set_socket_buffer(GvStreamSocketBuffer::Fixed);
            gv.set_socket_buffer_size(
                i32::try_from(SOCKET_BUFFER_BYTES.max(4 * payload as usize)).unwrap_or(i32::MAX),
            );
        }
        for _ in 0..BUFFERS {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        cam.start_acquisition()
            .map_err(|e| self.fail("start acquisition", &e))?;
        self.stream = Some(stream);
        self.publish();
        Ok(None)
    }

    fn disarm(&mut self) -> DeviceResult<()> {
        self.close_stream();
        Ok(())
    }

    fn software_trigger(&mut self) -> DeviceResult<()> {
        if self.is_lost() {
            return Err(self.disconnected("camera lost; the trigger was not sent".into()));
        }
        self.cam()?
            .execute_command("TriggerSoftware")
            .map_err(|e| self.fail("TriggerSoftware", &e))
    }

    fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>> {
        let Some(stream) = self.stream.as_ref() else {
            std::thread::sleep(timeout);
            return Ok(None);
        };
        let Some(buf) = stream.timeout_pop_buffer(timeout.as_micros() as u64) else {
            self.publish();
            return Ok(None);
        };
        let (frame_id, status) = (buf.frame_id(), buf.status());
        let image = match status {
            BufferStatus::Success => Some(self.convert(&buf)),
            // The frame's leader (which carries the id) was lost: it cannot be matched to a
            // trigger, so its trigger's deadline (or the next frame's gap) reports it missing.
            _ if frame_id == 0 => {
                self.closed.incomplete_frames += 1;
                tracing::warn!(device = %self.spec.id, status = ?status, "incomplete frame without an id dropped");
                None
            }
            BufferStatus::SizeMismatch => Some(Err(self.other(
                "frame larger than the buffer (the image size changed while armed)".into(),
            ))),
            other => {
                self.closed.incomplete_frames += 1;
                tracing::warn!(device = %self.spec.id, frame_id, status = ?other, "incomplete frame reported missing");
                Some(Err(DeviceError::new(
                    self.spec.id.clone(),
                    DeviceErrorKind::MissingFrame {
                        // Filled in by the worker with the trigger this frame answers.
                        trigger_id: 0,
                        timeout_s: 0.0,
                    },
                )))
            }
        };
        // aravis sets a buffer's frame id from the frame's leader only: clear it, so a
        // frame whose leader is lost does not come back with this frame's id.
        // SAFETY: `buf` is a live ArvBuffer owned here; the call only writes its frame id.
        unsafe { aravis_sys::arv_buffer_set_frame_id(buf.as_ptr(), 0) };
        stream.push_buffer(buf);
        self.publish();
        Ok(image.map(|image| RawFrame {
            sequence: self.sequence(frame_id),
            image,
        }))
    }

    fn readout_s(&self) -> f64 {
        self.spec.readout_s()
    }

    fn sequence_wrap(&self) -> u64 {
        if self.short_ids { GV_BLOCK_IDS } else { 0 }
    }

    fn frame_notes(&self) -> Option<serde_json::Value> {
        serde_json::to_value(&self.read_back).ok()
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.close_stream();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unsupported_formats_are_named() {
        let e = convert_pixels(PixelFormat::BAYER_RG_8, 2, 2, 0, &[0; 4])
            .unwrap_err()
            .to_string();
        assert!(e.contains("not supported") && e.contains("Mono8"), "{e}");
        assert_eq!(
            convert_pixels(PixelFormat::MONO_12, 1, 1, 0, &[0xff, 0x0f]),
            Ok((vec![0x0fff; 3], 12))
        );
    }

    /// aravis's fake camera starts its block ids at 65400 to reach the wrap soon: 65535 is
    /// followed by 1, which the accounting must see as the next frame, not a lost one.
    #[test]
    fn block_ids_wrap_without_a_gap() {
        use crate::cameras::accounting::TriggerAccounting;
        assert_eq!(gv_sequence(1), 0);
        assert_eq!(gv_sequence(65_535), 65_534);
        let mut acc = TriggerAccounting::with_wrap("gc0", GV_BLOCK_IDS);
        acc.reset(None);
        for (trigger, block_id) in [(1, 65_534), (2, 65_535), (3, 1), (4, 2)] {
            acc.expect(trigger, 0.0, 1.0);
            assert_eq!(acc.frame_result(gv_sequence(block_id)), Ok(trigger));
        }
        // 2 → 4 skips block id 3: that trigger's frame was lost.
        acc.expect(5, 0.0, 1.0);
        acc.expect(6, 0.0, 1.0);
        assert!(matches!(
            acc.frame_result(gv_sequence(4)),
            Err(DeviceError {
                kind: DeviceErrorKind::MissingFrame { trigger_id: 5, .. },
                ..
            })
        ));
    }
}
