//! Opening the reflectometer cart: the IR bridge on its serial port (or its emulator), or the
//! simulated cart.

use stagehand_devices::cart::CartHandle;
use stagehand_devices::ir_cart::IrBridgeCart;
use stagehand_devices::rig::{Backend, CartSpec};
use stagehand_simulator::emulators::IrBridgeEmulator;
use stagehand_simulator::sim_devices::SimCart;

use super::OpenError;
use super::emulation::io;
use super::open::{Opening, port_of, world_of};

/// The cart `c`.
pub(super) fn open(ctx: &mut Opening, c: &CartSpec) -> Result<CartHandle, OpenError> {
    Ok(match c.backend {
        Backend::IrBridge => {
            let port = port_of(&c.id, &c.port)?;
            let world = ctx.world;
            let path = ctx.ports.reach(&port, &|dir, name, faults| {
                IrBridgeEmulator::spawn(world_of(world).map_err(io)?.clone(), c, dir, name, faults)
            })?;
            let mut spec = c.clone();
            spec.port = Some(path);
            CartHandle::spawn(
                c.clone(),
                IrBridgeCart::from_spec(&spec).map_err(OpenError::from)?,
            )
        }
        _ => CartHandle::spawn(c.clone(), SimCart::new(ctx.world()?.clone())),
    })
}
