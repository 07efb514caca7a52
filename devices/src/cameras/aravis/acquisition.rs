//! GenICam cameras (GigE Vision, USB3 Vision) through aravis (feature `cam-aravis`).
//!
//! - **Opening.** The rig file's `port` names the camera: an IPv4 address (`192.168.10.21`), an
//!   aravis device id (`Basler-acA1300-200001`, `Aravis-Fake-GV02`), vendor-serial, user id or
//!   MAC, or the bare serial number (`GV02`), looked up in the device list.
//! - **Triggering.** Every trigger selector but `FrameStart` is switched off, then
//!   `TriggerSelector=FrameStart, TriggerMode=On, TriggerSource=Line1` (hardware) or `Software`
//!   (fired with `TriggerSoftware` on `expect`); each is read back.
//! - **Exposure and gain.** `ExposureTimeAbs` (GigE cameras of the pre-SFNC naming, and aravis's
//!   fake camera), else `ExposureTime`, in µs; `Gain` in dB, else `GainRaw` mapped linearly
//!   from gain 1 to the rig's `max_gain` across the raw range. Each is read back, and the values
//!   the camera reports go into every frame's notes (`camera`).
//! - **Accounting.** Frames are matched to triggers by the GigE Vision block id (16 bits, 0
//!   skipped, so it counts modulo 65535) or the 64-bit id of USB3 Vision and extended-id GigE.
//! - **Faults.** A frame that arrived incomplete (packets lost that resends did not bring back)
//!   is reported as [`DeviceErrorKind::MissingFrame`] for its trigger, never delivered. A link
//!   failure (GVCP timeout, control lost, heartbeat lost) marks the camera lost: no further
//!   command is sent to it, its triggers are reported missing at their deadline, and the next
//!   arm (or configure while disarmed) reopens it once it answers again.
//!
//! [`StreamStats`] exposes the transport counters (packets resent and missing, frames failed
//! or incomplete, reopens) summed over every stream the camera opened.

use std::ffi::{CStr, c_char};
use std::net::{Ipv4Addr, SocketAddrV4, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use aravis::glib::prelude::*;
use aravis::prelude::*;
use aravis::{
    AcquisitionMode, Buffer, BufferStatus, Camera, GvStream, GvStreamSocketBuffer, PixelFormat,
    Stream,
};

use crate::cameras::HardwareCamera;
use crate::cameras::config::{self, TriggerMode};
use crate::cameras::pixels;
use crate::cameras::worker::{Blocking, Image, Link, RawFrame};
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::CameraSpec;

/// The input line a hardware trigger is wired to.
pub const TRIGGER_LINE: &str = "Line1";
/// The GigE Vision control protocol's UDP port.
pub const GVCP_PORT: u16 = 3956;
/// Frame buffers queued on the stream.
const BUFFERS: usize = 8;
/// Bootstrap register holding a GigE Vision device's current IPv4 address.
const GVBS_CURRENT_IP_ADDRESS: u64 = 0x0024;
/// GigE Vision 1.x block ids count 1..=65535 (0 is invalid), so the sequence wraps here.
pub const GV_BLOCK_IDS: u64 = 65_535;
/// How long a reopen waits for a lost GigE camera to answer a discovery before giving up
/// (a dead camera would otherwise hold each GVCP call for seconds of retries).
const PROBE_TIMEOUT: Duration = Duration::from_millis(300);
/// Socket buffer asked for per stream (the kernel caps it at `net.core.rmem_max`): a few
/// frames of slack so a busy host does not drop packets of a burst.
const SOCKET_BUFFER_BYTES: usize = 8 << 20;

/// How far the gain a camera reports may be from the one set (cameras step gain in ~0.03 dB).
const GAIN_TOLERANCE_DB: f64 = 0.1;

/// Serialises use of aravis's global device list (its strings live until the next update).
static DEVICE_LIST: Mutex<()> = Mutex::new(());

/// One GenICam device as aravis's discovery sees it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ListedDevice {
    /// The id aravis opens it by (`vendor-model-serial` for GigE).
    pub id: String,
    /// Network address (GigE) or bus address (USB).
    pub address: String,
    /// Serial number as the device reports it (`port` may name the camera by it).
    pub serial: String,
    /// Manufacturer name, for the operator.
    pub vendor: String,
    /// Model name, for the operator.
    pub model: String,
    /// `GigEVision`, `USB3Vision`, `Fake`, …
    pub protocol: String,
    /// MAC address (GigE) or bus id (USB).
    pub physical_id: String,
}

/// Every GenICam device aravis can see now. GigE discovery waits about a second for answers.
pub fn list_devices() -> Vec<ListedDevice> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(PoisonError::into_inner);
    /// Copies a C string aravis owns (empty for NULL).
    ///
    /// # Safety
    /// `p` is NULL or a NUL-terminated string valid for the duration of the call.
    unsafe fn text(p: *const c_char) -> String {
        if p.is_null() {
            String::new()
        } else {
            // SAFETY: non-NULL and NUL-terminated per the caller's contract.
            unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
        }
    }
    // SAFETY: the list is global state in aravis; the guard makes this the only code in the
    // process that updates or reads it, and every string is copied before the guard drops.
    unsafe {
        aravis_sys::arv_update_device_list();
        let n = aravis_sys::arv_get_n_devices();
        (0..n)
            .map(|i| ListedDevice {
                id: text(aravis_sys::arv_get_device_id(i)),
                address: text(aravis_sys::arv_get_device_address(i)),
                serial: text(aravis_sys::arv_get_device_serial_nbr(i)),
                vendor: text(aravis_sys::arv_get_device_vendor(i)),
                model: text(aravis_sys::arv_get_device_model(i)),
                protocol: text(aravis_sys::arv_get_device_protocol(i)),
                physical_id: text(aravis_sys::arv_get_device_physical_id(i)),
            })
            .collect()
    }
}

/// Whether a GigE Vision device answers a unicast GVCP discovery at `address` within
/// `timeout`. Cheap, so a lost camera is probed before aravis spends seconds on retries.
pub fn gvcp_probe(address: Ipv4Addr, timeout: Duration) -> bool {
    const REQ_ID: u16 = 0x5348;
    let Ok(socket) = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0)) else {
        return false;
    };
    // GVCP command header: key 0x42, flags (ack required), DISCOVERY_CMD, no payload, req id.
    let [hi, lo] = REQ_ID.to_be_bytes();
    let discovery = [0x42, 0x01, 0x00, 0x02, 0x00, 0x00, hi, lo];
    if socket
        .send_to(&discovery, SocketAddrV4::new(address, GVCP_PORT))
        .is_err()
    {
        return false;
    }
    let deadline = Instant::now() + timeout;
    let mut reply = [0u8; 600];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() || socket.set_read_timeout(Some(left)).is_err() {
            return false;
        }
        match socket.recv_from(&mut reply) {
            // DISCOVERY_ACK (0x0003) carrying our request id.
            Ok((n, _)) if n >= 8 && reply[2..4] == [0x00, 0x03] && reply[6..8] == [hi, lo] => {
                return true;
            }
            Ok(_) => {}
            Err(_) => return false,
        }
    }
}

/// Transport counters of one camera, summed over every stream it opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamCounters {
    /// Frames the stream completed (aravis `n_completed_buffers`).
    pub completed_frames: u64,
    /// Frames the stream gave up on or delivered incomplete (aravis `n_failures`).
    pub failed_frames: u64,
    /// Frames dropped because no buffer was free (aravis `n_underruns`).
    pub underruns: u64,
    /// Packets the camera sent again when asked (aravis `n_resent_packets`).
    pub resent_packets: u64,
    /// Packets still missing when their frame was given up (aravis `n_missing_packets`).
    pub missing_packets: u64,
    /// Frames this driver reported as missing because they arrived incomplete.
    pub incomplete_frames: u64,
    /// Times the camera was reopened after it was lost.
    pub reopens: u64,
}

impl StreamCounters {
    fn plus(self, o: Self) -> Self {
        Self {
            completed_frames: self.completed_frames + o.completed_frames,
            failed_frames: self.failed_frames + o.failed_frames,
            underruns: self.underruns + o.underruns,
            resent_packets: self.resent_packets + o.resent_packets,
            missing_packets: self.missing_packets + o.missing_packets,
            incomplete_frames: self.incomplete_frames + o.incomplete_frames,
            reopens: self.reopens + o.reopens,
        }
    }

    /// The counters aravis keeps for `stream` (the driver's own counts are zero).
    fn of(stream: &Stream) -> Self {
        let (completed_frames, failed_frames, underruns) = stream.statistics();
        let (resent_packets, missing_packets) = stream
            .downcast_ref::<GvStream>()
            .map_or((0, 0), |gv| gv.statistics());
        Self {
            completed_frames,
            failed_frames,
            underruns,
            resent_packets,
            missing_packets,
            ..Self::default()
        }
    }
}

/// A live view of one camera's [`StreamCounters`], updated by its worker thread.
#[derive(Debug, Clone, Default)]
pub struct StreamStats(Arc<Mutex<StreamCounters>>);

impl StreamStats {
    /// The counters as of the worker's last grab.
    pub fn snapshot(&self) -> StreamCounters {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn set(&self, c: StreamCounters) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = c;
    }
}

/// A GenICam camera driven from its own thread.
pub struct AravisCamera;

impl AravisCamera {
    /// Opens the camera `spec.port` names (see the module docs for the forms it takes).
    pub fn open(spec: &CameraSpec, mode: TriggerMode) -> DeviceResult<HardwareCamera> {
        Self::open_with_stats(spec, mode).map(|(link, _)| link)
    }

    /// Like [`Self::open`], also returning the camera's live transport counters.
    pub fn open_with_stats(
        spec: &CameraSpec,
        mode: TriggerMode,
    ) -> DeviceResult<(HardwareCamera, StreamStats)> {
        let port = config::aravis_device_id(spec)?;
        let stats = StreamStats::default();
        let (spec, s) = (spec.clone(), stats.clone());
        let link = Link::spawn(&spec.id.clone(), mode, move || {
            let camera = connect(&spec.id, &port)?;
            Worker::new(spec, port, mode, camera, s)
        })?;
        Ok((link, stats))
    }
}

/// Opens the camera `port` names: address or aravis id first, then the bare serial number.
fn connect(device: &str, port: &str) -> DeviceResult<Camera> {
    let unavailable = |reason: String| {
        DeviceError::new(
            device.to_string(),
            DeviceErrorKind::PortUnavailable {
                port: port.to_string(),
                reason,
            },
        )
    };
    let first = match Camera::new(Some(port)) {
        Ok(c) => return Ok(c),
        Err(e) => e,
    };
    if port.parse::<Ipv4Addr>().is_ok()
        || first.kind::<aravis::DeviceError>() != Some(aravis::DeviceError::NotFound)
    {
        return Err(unavailable(first.to_string()));
    }
    let by_serial: Vec<ListedDevice> = list_devices()
        .into_iter()
        .filter(|d| d.serial == port)
        .collect();
    match by_serial.as_slice() {
        [d] => Camera::new(Some(&d.id)).map_err(|e| unavailable(format!("{} ({e})", d.id))),
        [] => Err(unavailable(format!(
            "{first}; no camera has this id, address or serial number (see `stagehand devices`)"
        ))),
        many => Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Other {
                message: format!(
                    "serial number `{port}` is shared by {}; name the camera by its id in `port`",
                    many.iter()
                        .map(|d| d.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            },
        )),
    }
}

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
struct Worker {
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
    fn new(
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
        convert_pixels(format, 1, 1, 0, &[0; 8]).map_err(|m| self.other(m))?;
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
            convert_pixels(format, w, h, 0, data).map_err(|m| self.other(m))?;
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
        let e = convert_pixels(PixelFormat::BAYER_RG_8, 2, 2, 0, &[0; 4]).unwrap_err();
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

    #[test]
    fn counters_add_up() {
        let a = StreamCounters {
            completed_frames: 3,
            resent_packets: 2,
            reopens: 1,
            ..StreamCounters::default()
        };
        let b = StreamCounters {
            completed_frames: 4,
            missing_packets: 5,
            incomplete_frames: 1,
            ..StreamCounters::default()
        };
        let s = a.plus(b);
        assert_eq!(
            (s.completed_frames, s.resent_packets, s.missing_packets),
            (7, 2, 5)
        );
        assert_eq!((s.incomplete_frames, s.reopens), (1, 1));
    }

    /// Aravis's in-process fake camera: configure, arm, one software trigger, one accounted
    /// frame carrying the settings read back.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn fake_camera_grabs_one_frame_per_trigger() {
        let spec: CameraSpec = toml::from_str(
            "id = \"gc0\"\nbackend = \"aravis\"\nport = \"Fake_1\"\nwidth = 512\nheight = 512\nfps = 20.0\nazimuth_deg = 0.0\nelevation_deg = 0.0\ndistance_mm = 1.0\nfov_deg = 30.0\nmax_gain = 11.0\n",
        )
        .expect("spec");
        let mut link = Link::spawn("gc0", TriggerMode::Software, move || {
            // SAFETY: a plain C call with a NUL-terminated static string; libaravis is linked.
            unsafe { aravis_sys::arv_enable_interface(c"Fake".as_ptr()) };
            let camera = connect("gc0", "Fake_1")?;
            Worker::new(
                spec,
                "Fake_1".into(),
                TriggerMode::Software,
                camera,
                StreamStats::default(),
            )
        })
        .expect("fake camera opens");
        link.configure(0.01, 3.0).await.expect("configure");
        link.set_armed(true).await.expect("arm");
        link.expect(41, 0.01).expect("expect");
        let f = tokio::time::timeout(Duration::from_secs(4), link.next_frame())
            .await
            .expect("a frame within 4 s")
            .expect("frame ok");
        assert_eq!(f.trigger_id, 41);
        assert_eq!(f.camera, "gc0");
        assert_eq!((f.width, f.height), (512, 512));
        assert_eq!(f.pixels.len(), (f.width * f.height * 3) as usize);
        let cam = &f.notes["camera"];
        assert_eq!(cam["exposure_feature"], "ExposureTimeAbs");
        assert_eq!(cam["exposure_us"], 10_000.0);
        assert_eq!(cam["gain_feature"], "GainRaw");
        assert_eq!(cam["gain"], 2.0);
        assert_eq!(cam["trigger_source"], "Software");
        link.set_armed(false).await.expect("disarm");
    }

    /// Nothing listens on this loopback address's GVCP port: the probe says so in time.
    #[test]
    fn probe_of_a_silent_address_is_false() {
        let t = Instant::now();
        assert!(!gvcp_probe(
            Ipv4Addr::new(127, 0, 0, 254),
            Duration::from_millis(100)
        ));
        assert!(t.elapsed() < Duration::from_secs(5));
    }
}
