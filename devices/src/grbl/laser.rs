//! The line laser on a GRBL controller's spindle output: `M3 S1000` on, `M5` off, each
//! confirmed from the status report (`A:S`, the `FS:` spindle speed), since a board in laser
//! mode (`$32=1`) or with a broken output acknowledges `M3` and stays dark. Arming and colour
//! checks are the [`LaserHandle`](crate::laser::LaserHandle)'s.
//!
//! GRBL has no watchdog: the output stays on if stagehand dies. A rig that needs one powers
//! the laser through a relay as well (rig file `bank`/`channel` on a `grbl` laser; see
//! [`crate::switched`]). A reset of the controller (reconnect, stop, power glitch) switches the
//! output off, and the driver does not switch it back on by itself.

use std::sync::Arc;

use super::codec::LASER_FULL_POWER;
use super::controller::GrblController;
use crate::error::DeviceResult;
use crate::laser::LaserDriver;

/// Wait for the `ok` of `M3`/`M5` (GRBL waits for the planner to empty before switching).
const TIMEOUT_S: f64 = 2.0;

/// The laser switched by a shared [`GrblController`].
pub struct GrblLaser {
    controller: Arc<GrblController>,
    device: String,
}

impl GrblLaser {
    /// The laser `device` (its id, used in errors) on `controller`.
    pub fn new(controller: Arc<GrblController>, device: &str) -> Self {
        controller.attach_laser();
        Self {
            controller,
            device: device.to_string(),
        }
    }
}

impl LaserDriver for GrblLaser {
    async fn set_emission(&mut self, on: bool, _colour_nm: u32) -> DeviceResult<()> {
        self.controller
            .switch_spindle(&self.device, on, LASER_FULL_POWER, TIMEOUT_S)
            .await
    }

    async fn fitted(&mut self, _colour_nm: u32, _mount_elevation_deg: f64) -> DeviceResult<()> {
        // Swapping the module is manual; the controller has nothing to record.
        Ok(())
    }
}
