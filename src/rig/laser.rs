//! Opening the line laser: on a GRBL spindle output (optionally in series with a relay, and
//! mirrored into the world on a hybrid rig), on a switch-bank channel, or simulated. Every
//! variant watches the interlock.

use std::collections::BTreeMap;

use stagehand_devices::interlock::Interlock;
use stagehand_devices::laser::LaserHandle;
use stagehand_devices::rig::{Backend, LaserSpec};
use stagehand_devices::switch_bank::SwitchBankHandle;
use stagehand_devices::switch_wired::{SeriesLaser, SwitchLaser};
use stagehand_simulator::sim_devices::{MirroredLaser, SimLaser};

use super::OpenError;
use super::axes::GrblControllers;
use super::open::Opening;

/// The laser `l`; `banks` are the rig's opened switch banks (a relay may power it).
pub(super) fn open(
    ctx: &Opening,
    l: &LaserSpec,
    grbl: &GrblControllers,
    banks: &BTreeMap<String, SwitchBankHandle>,
    interlock: &Interlock,
) -> Result<LaserHandle, OpenError> {
    let bank = |bank_id: &str| {
        banks
            .get(bank_id)
            .cloned()
            .ok_or_else(|| OpenError::Wiring {
                device: l.id.clone(),
                message: format!("no switch bank `{bank_id}`"),
            })
    };
    let lock = interlock.watch();
    Ok(match l.backend {
        Backend::Grbl => {
            let output = stagehand_devices::grbl::GrblLaser::new(grbl.on(&l.id, &l.port)?, &l.id);
            // Optionally powered through a relay too (its board has the watchdog GRBL
            // lacks); in a hybrid rig the World follows the confirmed emission.
            let power = match &l.bank {
                Some(bank_id) => Some(SwitchLaser::new(
                    &l.id,
                    bank(bank_id)?,
                    l.channel.unwrap_or(0),
                )),
                None => None,
            };
            let l = l.clone();
            match (power, ctx.mirror()) {
                (Some(p), Some(w)) => LaserHandle::spawn_with_interlock(
                    l,
                    MirroredLaser::new(SeriesLaser::new(p, output), w.clone()),
                    lock,
                ),
                (Some(p), None) => {
                    LaserHandle::spawn_with_interlock(l, SeriesLaser::new(p, output), lock)
                }
                (None, Some(w)) => LaserHandle::spawn_with_interlock(
                    l,
                    MirroredLaser::new(output, w.clone()),
                    lock,
                ),
                (None, None) => LaserHandle::spawn_with_interlock(l, output, lock),
            }
        }
        Backend::Switch => {
            let bank = bank(l.bank.as_deref().unwrap_or_default())?;
            LaserHandle::spawn_with_interlock(
                l.clone(),
                SwitchLaser::new(&l.id, bank, l.channel.unwrap_or(0)),
                lock,
            )
        }
        _ => {
            LaserHandle::spawn_with_interlock(l.clone(), SimLaser::new(ctx.world()?.clone()), lock)
        }
    })
}
