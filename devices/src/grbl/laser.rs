//! The line laser on a GRBL controller's spindle output (laser mode `$32=1`): `M3 S1000` on,
//! `M5` off. Arming and colour checks are the [`LaserHandle`](crate::laser::LaserHandle)'s.
//!
//! A reset of the controller (reconnect, stop, power glitch) switches the output off, and the
//! driver does not switch it back on by itself; the controller's keepalive keeps the emulated
//! watchdog from switching it off while idle.

use std::sync::Arc;

use super::codec::{Command, LASER_FULL_POWER};
use super::controller::GrblController;
use crate::error::DeviceResult;
use crate::laser::LaserDriver;

/// Wait for the `ok` of `M3`/`M5`.
const TIMEOUT_S: f64 = 1.0;

/// The laser switched by a shared [`GrblController`].
pub struct GrblLaser {
    controller: Arc<GrblController>,
    device: String,
}

impl GrblLaser {
    /// The laser `device` (its id, used in errors) on `controller`.
    pub fn new(controller: Arc<GrblController>, device: &str) -> Self {
        Self {
            controller,
            device: device.to_string(),
        }
    }
}

impl LaserDriver for GrblLaser {
    async fn set_emission(&mut self, on: bool, _colour_nm: u32) -> DeviceResult<()> {
        let cmd = if on {
            Command::LaserOn {
                power: LASER_FULL_POWER,
            }
        } else {
            Command::LaserOff
        };
        self.controller.command(&self.device, cmd, TIMEOUT_S).await
    }

    async fn fitted(&mut self, _colour_nm: u32, _mount_elevation_deg: f64) -> DeviceResult<()> {
        // Swapping the module is manual; the controller has nothing to record.
        Ok(())
    }
}
