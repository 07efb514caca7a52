//! A simulated relay bank: channels switch instantly; the lamps they power warm up in the World.

use std::sync::Arc;

use stagehand_devices::error::DeviceResult;
use stagehand_devices::rig::SwitchBankSpec;
use stagehand_devices::switch_bank::SwitchBankDriver;

use crate::world::World;

/// Simulated switch bank driver.
pub struct SimSwitchBank {
    spec: SwitchBankSpec,
    world: Arc<World>,
    states: Vec<bool>,
}

impl SimSwitchBank {
    pub fn new(spec: SwitchBankSpec, world: Arc<World>) -> Self {
        let states = vec![false; spec.channels as usize];
        Self {
            spec,
            world,
            states,
        }
    }
}

impl SwitchBankDriver for SimSwitchBank {
    async fn set(&mut self, channel: u32, on: bool) -> DeviceResult<()> {
        let t = self.world.clock().now_s();
        self.world.set_channel(&self.spec.id, channel, on, t);
        if let Some(slot) = self.states.get_mut(channel as usize - 1) {
            *slot = on;
        }
        Ok(())
    }

    async fn read_all(&mut self) -> DeviceResult<Vec<bool>> {
        let states = (1..=self.spec.channels)
            .map(|c| {
                self.world
                    .channel_on(&self.spec.id, c)
                    .unwrap_or(self.states[c as usize - 1])
            })
            .collect();
        Ok(states)
    }
}
