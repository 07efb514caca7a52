//! Opening the camera trigger: a relay board's GPIO line, software triggering (real cameras
//! that expose when told the trigger id), or the simulated world's trigger line.

use std::collections::BTreeMap;
use std::sync::Arc;

use stagehand_devices::error::DeviceResult;
use stagehand_devices::relay_serial::NumatoBoard;
use stagehand_devices::rig::{Backend, TriggerSpec};
use stagehand_devices::switch_wired::GpioTrigger;
use stagehand_devices::trigger::{TriggerDriver, TriggerHandle};
use stagehand_simulator::sim_devices::SimTrigger;

use super::OpenError;
use super::cameras::simulated_camera;
use super::open::Opening;

/// The trigger `t`; `boards` are the rig's serial relay boards, by bank id.
pub(super) fn open(
    ctx: &Opening,
    t: &TriggerSpec,
    boards: &BTreeMap<String, Arc<NumatoBoard>>,
) -> Result<TriggerHandle, OpenError> {
    let emulate = ctx.emulation.is_some();
    Ok(match (t.backend, ctx.world) {
        (Backend::Switch, _) => {
            let bank_id = t.bank.clone().unwrap_or_default();
            let board = boards
                .get(&bank_id)
                .cloned()
                .ok_or_else(|| OpenError::Wiring {
                    device: t.id.clone(),
                    message: format!("no relay-serial bank `{bank_id}` for the GPIO trigger"),
                })?;
            let gpio = GpioTrigger::new(&t.id, board, t.line.unwrap_or(0), t.pulse_s)
                .map_err(OpenError::from)?;
            TriggerHandle::spawn(t.clone(), gpio)
        }
        // Software-triggered real cameras expose when told the trigger id; simulated
        // cameras still need the world's trigger line.
        (Backend::Software, w)
            if w.is_none()
                || !ctx
                    .spec
                    .cameras
                    .iter()
                    .any(|c| simulated_camera(c, emulate)) =>
        {
            TriggerHandle::spawn(t.clone(), SoftwareTrigger)
        }
        (_, Some(w)) => TriggerHandle::spawn(t.clone(), SimTrigger::new(w.clone())),
        (_, None) => {
            return Err(OpenError::Simulator(
                "the simulated world is missing".into(),
            ));
        }
    })
}

/// The trigger of software-triggered cameras: each camera exposes when its driver is told
/// the trigger id, so there is no line to pulse.
struct SoftwareTrigger;

impl TriggerDriver for SoftwareTrigger {
    async fn fire(&mut self, _trigger_id: u64) -> DeviceResult<()> {
        Ok(())
    }
}
