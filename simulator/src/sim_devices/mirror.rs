//! Real devices in a hybrid rig (real controllers, simulated cameras): each wraps a real
//! driver and copies what the real device reports into the World, so the simulated cameras
//! render the positions the real axes reached and the laser the real output switched.

use std::sync::Arc;

use stagehand_devices::axis::AxisDriver;
use stagehand_devices::error::DeviceResult;
use stagehand_devices::laser::LaserDriver;

use crate::world::World;

/// A real axis whose reported positions are copied into the World's axis `id`.
pub struct MirroredAxis<D> {
    id: String,
    inner: D,
    world: Arc<World>,
}

impl<D: AxisDriver> MirroredAxis<D> {
    /// Mirrors `inner` (the driver of axis `id`) into `world`.
    pub fn new(id: &str, inner: D, world: Arc<World>) -> Self {
        Self {
            id: id.to_string(),
            inner,
            world,
        }
    }

    /// Records a position the real axis reported (the motor is the load: the real driver's
    /// handle already took up the backlash).
    fn record(&self, r: &DeviceResult<f64>, homed: Option<bool>) {
        if let Ok(p) = r {
            self.world.with_axis(&self.id, |a| {
                a.moving = None;
                a.motor_deg = *p;
                a.backlash_offset_deg = 0.0;
                if let Some(h) = homed {
                    a.homed = h;
                }
            });
        }
    }
}

impl<D: AxisDriver> AxisDriver for MirroredAxis<D> {
    async fn home(&mut self) -> DeviceResult<f64> {
        let r = self.inner.home().await;
        self.record(&r, Some(true));
        r
    }

    async fn move_to(&mut self, target_deg: f64) -> DeviceResult<f64> {
        let r = self.inner.move_to(target_deg).await;
        self.record(&r, None);
        r
    }

    async fn stop(&mut self) -> DeviceResult<f64> {
        let r = self.inner.stop().await;
        self.record(&r, None);
        r
    }

    async fn position(&mut self) -> DeviceResult<f64> {
        let r = self.inner.position().await;
        self.record(&r, None);
        r
    }
}

/// A real laser whose confirmed emission is copied into the World.
pub struct MirroredLaser<D> {
    inner: D,
    world: Arc<World>,
}

impl<D: LaserDriver> MirroredLaser<D> {
    /// Mirrors `inner` into `world`.
    pub fn new(inner: D, world: Arc<World>) -> Self {
        Self { inner, world }
    }
}

impl<D: LaserDriver> LaserDriver for MirroredLaser<D> {
    async fn set_emission(&mut self, on: bool, colour_nm: u32) -> DeviceResult<()> {
        let r = self.inner.set_emission(on, colour_nm).await;
        // On is shown only once confirmed; a failed switch shows it off (the step fails anyway).
        if r.is_ok() || !on {
            self.world.set_laser(on && r.is_ok(), colour_nm);
        }
        r
    }

    async fn fitted(&mut self, colour_nm: u32, mount_elevation_deg: f64) -> DeviceResult<()> {
        let r = self.inner.fitted(colour_nm, mount_elevation_deg).await;
        if r.is_ok() {
            self.world.fit_laser(colour_nm, mount_elevation_deg);
        }
        r
    }
}
