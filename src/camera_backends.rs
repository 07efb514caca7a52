//! Real camera backends, each compiled in by its Cargo feature (they need C libraries, so the
//! default build has none): `cam-v4l`, `cam-aravis`, `cam-gphoto2`.

use stagehand_devices::camera::CameraHandle;
use stagehand_devices::rig::{Backend, CameraSpec, TriggerSpec};

use crate::rig::OpenError;

/// Opens the real camera `c`, hardware- or software-triggered as the rig's `trigger` says,
/// or says which feature the build lacks.
pub(crate) fn open(
    c: &CameraSpec,
    trigger: Option<&TriggerSpec>,
) -> Result<CameraHandle, OpenError> {
    #[cfg(any(feature = "cam-v4l", feature = "cam-aravis", feature = "cam-gphoto2"))]
    let mode = stagehand_devices::cameras::config::TriggerMode::from_rig(trigger);
    #[cfg(not(any(feature = "cam-v4l", feature = "cam-aravis", feature = "cam-gphoto2")))]
    let _ = trigger;
    match c.backend {
        #[cfg(feature = "cam-v4l")]
        Backend::V4l => Ok(CameraHandle::spawn(
            c.clone(),
            stagehand_devices::cameras::v4l::V4lCamera::open(c, mode)?,
        )),
        #[cfg(feature = "cam-aravis")]
        Backend::Aravis => Ok(CameraHandle::spawn(
            c.clone(),
            stagehand_devices::cameras::aravis::AravisCamera::open(c, mode)?,
        )),
        #[cfg(feature = "cam-gphoto2")]
        Backend::Gphoto2 => Ok(CameraHandle::spawn(
            c.clone(),
            stagehand_devices::cameras::gphoto2::Gphoto2Camera::open(c, mode)?,
        )),
        #[cfg(not(feature = "cam-v4l"))]
        Backend::V4l => Err(no_driver(c, "cam-v4l")),
        #[cfg(not(feature = "cam-aravis"))]
        Backend::Aravis => Err(no_driver(c, "cam-aravis")),
        #[cfg(not(feature = "cam-gphoto2"))]
        Backend::Gphoto2 => Err(no_driver(c, "cam-gphoto2")),
        _ => Err(OpenError::Wiring {
            device: c.id.clone(),
            message: format!("backend `{:?}` is not a camera backend", c.backend),
        }),
    }
}

/// True if this build has the driver for camera backend `b` (its Cargo feature is on).
pub(crate) fn compiled(b: Backend) -> bool {
    (b == Backend::V4l && cfg!(feature = "cam-v4l"))
        || (b == Backend::Aravis && cfg!(feature = "cam-aravis"))
        || (b == Backend::Gphoto2 && cfg!(feature = "cam-gphoto2"))
}

/// The build lacks `feature` for camera `c` (unused when every camera feature is on).
#[allow(dead_code)]
fn no_driver(c: &CameraSpec, feature: &'static str) -> OpenError {
    OpenError::NoDriver {
        device: c.id.clone(),
        backend: c.backend,
        feature,
    }
}
