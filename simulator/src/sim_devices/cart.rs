//! The simulated reflectometer cart: a DC motor running at constant speed between end stops.

use std::sync::Arc;

use stagehand_devices::cart::{CartDriver, Drive};
use stagehand_devices::error::DeviceResult;

use crate::world::World;

/// Simulated cart driver.
pub struct SimCart {
    world: Arc<World>,
}

impl SimCart {
    pub fn new(world: Arc<World>) -> Self {
        Self { world }
    }
}

impl CartDriver for SimCart {
    async fn drive(&mut self, drive: Drive) -> DeviceResult<()> {
        let t = self.world.clock().now_s();
        let direction = match drive {
            Drive::Forward => 1.0,
            Drive::Reverse => -1.0,
            Drive::Stop => 0.0,
        };
        self.world.cart_drive(direction, t);
        Ok(())
    }
}
