//! The rig-file wiring of real cameras: a V4L2 camera names its device node (aravis and
//! gphoto2 cameras may leave `port` out: the first camera found).

use crate::rig::span::{Problem, at, needs_port};
use crate::rig::{Backend, RigSpec};

/// The port of every V4L2 camera.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    for (i, c) in spec.cameras.iter().enumerate() {
        if c.backend == Backend::V4l {
            needs_port(
                at("camera", i, "backend"),
                &format!("camera `{}`", c.id),
                c.backend,
                &c.port,
            )?;
        }
    }
    Ok(())
}
