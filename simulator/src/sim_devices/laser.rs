//! A simulated line laser: emission and the fitted module live in the World.

use std::sync::Arc;

use stagehand_devices::error::DeviceResult;
use stagehand_devices::laser::LaserDriver;

use crate::world::World;

/// Simulated laser driver.
pub struct SimLaser {
    world: Arc<World>,
}

impl SimLaser {
    pub fn new(world: Arc<World>) -> Self {
        Self { world }
    }
}

impl LaserDriver for SimLaser {
    async fn set_emission(&mut self, on: bool, colour_nm: u32) -> DeviceResult<()> {
        self.world.set_laser(on, colour_nm);
        Ok(())
    }

    async fn fitted(&mut self, colour_nm: u32, mount_elevation_deg: f64) -> DeviceResult<()> {
        self.world.fit_laser(colour_nm, mount_elevation_deg);
        Ok(())
    }
}
