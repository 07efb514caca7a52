//! The simulated trigger line: a pulse reaches every armed simulated camera at once.

use std::sync::Arc;

use stagehand_devices::error::DeviceResult;
use stagehand_devices::trigger::TriggerDriver;

use crate::world::World;

/// Simulated trigger driver.
pub struct SimTrigger {
    world: Arc<World>,
}

impl SimTrigger {
    pub fn new(world: Arc<World>) -> Self {
        Self { world }
    }
}

impl TriggerDriver for SimTrigger {
    async fn fire(&mut self, trigger_id: u64) -> DeviceResult<()> {
        let t = self.world.clock().now_s();
        self.world.pulse(trigger_id, t);
        Ok(())
    }
}
