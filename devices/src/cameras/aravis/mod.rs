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

mod acquisition;
mod discover;
mod stats;

use std::net::Ipv4Addr;

use aravis::Camera;

use crate::cameras::HardwareCamera;
use crate::cameras::config::{self, TriggerMode};
use crate::cameras::worker::Link;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::CameraSpec;
use acquisition::Worker;

pub use discover::{GVCP_PORT, ListedDevice, gvcp_probe, list_devices};
pub use stats::{StreamCounters, StreamStats};

/// The input line a hardware trigger is wired to.
pub const TRIGGER_LINE: &str = "Line1";
/// GigE Vision 1.x block ids count 1..=65535 (0 is invalid), so the sequence wraps here.
pub const GV_BLOCK_IDS: u64 = 65_535;

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

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

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
}
