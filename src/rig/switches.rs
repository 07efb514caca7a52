//! Opening the switch banks (serial relay boards, USB HID relay boards or simulated relays)
//! and wiring the lamps to their channels. Serial relay boards are kept for the GPIO trigger.

use std::collections::BTreeMap;
use std::sync::Arc;

use stagehand_devices::hid_relay::HidRelayBank;
use stagehand_devices::relay_serial::{NumatoBoard, RelaySerialBank};
use stagehand_devices::rig::{Backend, RELAY_SERIAL_BAUD, RigSpec, SwitchBankSpec};
use stagehand_devices::switch_bank::SwitchBankHandle;
use stagehand_simulator::emulators::{HidRelayBoard, NumatoConfig, NumatoEmulator};
use stagehand_simulator::sim_devices::SimSwitchBank;

use super::emulation::{EmulatedHid, io};
use super::open::{Opening, port_of, world_of};
use super::{LampWiring, OpenError};

/// The opened switch banks, and the serial relay boards behind them (by bank id).
pub(super) struct Opened {
    pub banks: BTreeMap<String, SwitchBankHandle>,
    pub boards: BTreeMap<String, Arc<NumatoBoard>>,
}

/// Every switch bank of the rig.
pub(super) fn open(ctx: &mut Opening) -> Result<Opened, OpenError> {
    let (spec, world) = (ctx.spec, ctx.world);
    let mut boards = BTreeMap::new();
    let mut banks = BTreeMap::new();
    for b in &spec.switch_banks {
        let handle = match b.backend {
            Backend::RelaySerial => {
                let port = port_of(&b.id, &b.port)?;
                let config = NumatoConfig::from_rig(spec, &b.id);
                let path = ctx.ports.reach(&port, &|dir, name, faults| {
                    let config = config
                        .clone()
                        .ok_or_else(|| io(OpenError::Simulator(format!("no bank `{}`", b.id))))?;
                    NumatoEmulator::spawn(
                        world_of(world).map_err(io)?.clone(),
                        config,
                        dir,
                        name,
                        faults,
                    )
                })?;
                let board = NumatoBoard::new(
                    &b.id,
                    &path,
                    b.baud.unwrap_or(RELAY_SERIAL_BAUD),
                    b.watchdog_s,
                );
                boards.insert(b.id.clone(), board.clone());
                SwitchBankHandle::spawn(
                    b.clone(),
                    RelaySerialBank::new(board, b.channels).map_err(OpenError::from)?,
                )
            }
            Backend::HidRelay => SwitchBankHandle::spawn(b.clone(), hid_bank(ctx, b)?),
            _ => SwitchBankHandle::spawn(
                b.clone(),
                SimSwitchBank::new(b.clone(), ctx.world()?.clone()),
            ),
        };
        banks.insert(b.id.clone(), handle);
    }
    Ok(Opened { banks, boards })
}

/// A USB HID relay board: the real one, or an emulated board under emulation.
fn hid_bank(ctx: &Opening, b: &SwitchBankSpec) -> Result<HidRelayBank, OpenError> {
    match ctx.emulation {
        Some(em) => {
            let key = b.port.clone().unwrap_or_else(|| b.id.clone());
            let board = HidRelayBoard::new(
                ctx.world()?.clone(),
                &b.id,
                b.channels,
                "EMU01",
                em.faults_for(&key),
            );
            HidRelayBank::new(
                &b.id,
                &format!("emulated-hid:{}", b.id),
                b.channels,
                Box::new(EmulatedHid(board)),
            )
            .map_err(OpenError::from)
        }
        None => HidRelayBank::open(&b.id, b.port.as_deref(), b.channels).map_err(OpenError::from),
    }
}

/// Which bank channel powers each lamp, by lamp id.
pub(super) fn lamps(spec: &RigSpec) -> BTreeMap<String, LampWiring> {
    spec.lamps
        .iter()
        .map(|l| {
            (
                l.id.clone(),
                LampWiring {
                    bank: l.bank.clone(),
                    channel: l.channel,
                },
            )
        })
        .collect()
}
