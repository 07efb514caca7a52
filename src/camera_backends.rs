//! Real camera backends, each compiled in by its Cargo feature (they need C libraries, so the
//! default build has none): `cam-v4l`, `cam-aravis`, `cam-gphoto2`.

use stagehand_devices::camera::CameraHandle;
use stagehand_devices::rig::{Backend, CameraSpec};

use crate::rig::OpenError;

/// Opens the real camera `c`, or says which feature the build lacks.
pub(crate) fn open(c: &CameraSpec) -> Result<CameraHandle, OpenError> {
    let no_driver = |feature| OpenError::NoDriver {
        device: c.id.clone(),
        backend: c.backend,
        feature,
    };
    match c.backend {
        Backend::V4l => Err(no_driver("cam-v4l")),
        Backend::Aravis => Err(no_driver("cam-aravis")),
        Backend::Gphoto2 => Err(no_driver("cam-gphoto2")),
        _ => Err(OpenError::Wiring {
            device: c.id.clone(),
            message: format!("backend `{:?}` is not a camera backend", c.backend),
        }),
    }
}
