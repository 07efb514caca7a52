//! Opening the cameras: simulated cameras render the world; real camera backends are each
//! compiled in by their Cargo feature (they need C libraries, so the default build has none):
//! `cam-v4l`, `cam-aravis`, `cam-gphoto2`.

use std::collections::BTreeMap;

use stagehand_devices::camera::CameraHandle;
use stagehand_devices::rig::{Backend, CameraSpec, TriggerSpec};
use stagehand_simulator::sim_devices::SimCamera;

use super::OpenError;
use super::open::Opening;

/// Every camera of the rig, by id.
pub(super) fn open_all(ctx: &Opening) -> Result<BTreeMap<String, CameraHandle>, OpenError> {
    let emulate = ctx.emulation.is_some();
    let mut cameras = BTreeMap::new();
    for c in &ctx.spec.cameras {
        let handle = if simulated_camera(c, emulate) {
            CameraHandle::spawn(c.clone(), SimCamera::new(c.clone(), ctx.world()?.clone()))
        } else {
            open_real(c, ctx.spec.trigger.as_ref())?
        };
        cameras.insert(c.id.clone(), handle);
    }
    Ok(cameras)
}

/// True if camera `c` renders from the simulated World: a `sim` camera, or under `--emulate` a
/// camera whose backend this build lacks (real cameras that can be opened stay real: they have
/// no serial port to emulate).
pub(super) fn simulated_camera(c: &CameraSpec, emulate: bool) -> bool {
    c.backend == Backend::Sim || (emulate && !compiled(c.backend))
}

/// Opens the real camera `c`, hardware- or software-triggered as the rig's `trigger` says,
/// or says which feature the build lacks.
fn open_real(c: &CameraSpec, trigger: Option<&TriggerSpec>) -> Result<CameraHandle, OpenError> {
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
            message: format!("backend `{}` is not a camera backend", c.backend.as_str()),
        }),
    }
}

/// True if this build has the driver for camera backend `b` (its Cargo feature is on).
fn compiled(b: Backend) -> bool {
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
