//! Opening a rig's devices: a driver for every device (simulated, real, or real against an
//! emulator with [`Emulation`]), each behind its actor handle. This file decides the order
//! (GRBL controllers and axes, switch banks, laser, trigger, cart, cameras) and locks the real
//! ports first; each kind of device is opened in its own file of this module.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use stagehand_devices::axis::AxisHandle;
use stagehand_devices::camera::CameraHandle;
use stagehand_devices::cart::CartHandle;
use stagehand_devices::interlock::Interlock;
use stagehand_devices::laser::LaserHandle;
use stagehand_devices::rig::{Backend, RigSpec};
use stagehand_devices::switch_bank::SwitchBankHandle;
use stagehand_devices::trigger::TriggerHandle;
use stagehand_simulator::World;

use super::OpenError;
use super::emulation::{Emulation, Emulators, PortPaths};
use super::port_lock::{self, PortLock};
use super::{axes, cameras, cart, laser, switches, trigger};

/// Every device handle of a rig.
pub(super) struct Devices {
    pub axes: BTreeMap<String, AxisHandle>,
    pub banks: BTreeMap<String, SwitchBankHandle>,
    pub cameras: BTreeMap<String, CameraHandle>,
    pub trigger: Option<TriggerHandle>,
    pub laser: Option<LaserHandle>,
    pub cart: Option<CartHandle>,
    pub emulators: Emulators,
}

/// What opening any device needs: the rig, its simulated world (if any), the emulation (if
/// any) and the path each port is reached at.
pub(super) struct Opening<'a> {
    pub spec: &'a RigSpec,
    pub world: &'a Option<Arc<World>>,
    pub emulation: Option<&'a Emulation>,
    pub ports: PortPaths<'a>,
}

impl Opening<'_> {
    /// The simulated world, which a simulated or emulated device cannot do without.
    pub fn world(&self) -> Result<&Arc<World>, OpenError> {
        world_of(self.world)
    }

    /// The world a hybrid rig's real devices are mirrored into (real drivers on real ports,
    /// simulated cameras), so frames show what the real axes and laser did.
    pub fn mirror(&self) -> Option<&Arc<World>> {
        match (self.emulation, self.world) {
            (None, Some(w)) => Some(w),
            _ => None,
        }
    }
}

/// The simulated world, or an error naming it missing.
pub(super) fn world_of(world: &Option<Arc<World>>) -> Result<&Arc<World>, OpenError> {
    world
        .as_ref()
        .ok_or_else(|| OpenError::Simulator("the simulated world is missing".into()))
}

/// The backend of every device of the rig.
fn backends(spec: &RigSpec) -> impl Iterator<Item = Backend> + '_ {
    spec.axes
        .iter()
        .map(|a| a.backend)
        .chain(spec.switch_banks.iter().map(|b| b.backend))
        .chain(spec.cameras.iter().map(|c| c.backend))
        .chain(spec.trigger.iter().map(|t| t.backend))
        .chain(spec.laser.iter().map(|l| l.backend))
        .chain(spec.cart.iter().map(|c| c.backend))
}

/// True if the rig needs the simulated world: a simulated device, or emulation (the emulators
/// move the world and the cameras render it).
pub(super) fn needs_world(spec: &RigSpec, emulate: bool) -> bool {
    emulate || backends(spec).any(|b| b == Backend::Sim)
}

/// True if any device has a real driver (it talks over a port in real time).
pub fn needs_real_time(spec: &RigSpec) -> bool {
    backends(spec).any(|b| b != Backend::Sim)
}

/// The port device `id` names in the rig file, which its backend needs.
pub(super) fn port_of(id: &str, port: &Option<String>) -> Result<String, OpenError> {
    port.clone().ok_or_else(|| OpenError::Wiring {
        device: id.to_string(),
        message: "needs `port` in the rig file".into(),
    })
}

/// Opens every device of `spec`; the laser watches `interlock`. Must run inside a tokio
/// runtime.
pub(super) fn open_devices(
    spec: &Arc<RigSpec>,
    world: &Option<Arc<World>>,
    emulation: Option<&Emulation>,
    interlock: &Interlock,
) -> Result<Devices, OpenError> {
    let mut ctx = Opening {
        spec,
        world,
        emulation,
        ports: PortPaths::new(emulation),
    };
    if emulation.is_none() {
        ctx.ports.emulators.port_locks = lock_real_ports(spec)?;
    }
    let grbl = axes::GrblControllers::open(&mut ctx)?;
    let axes = axes::open(&ctx, &grbl)?;
    let switches::Opened { banks, boards } = switches::open(&mut ctx)?;
    let laser = match &spec.laser {
        Some(l) => Some(laser::open(&ctx, l, &grbl, &banks, interlock)?),
        None => None,
    };
    let trigger = match &spec.trigger {
        Some(t) => Some(trigger::open(&ctx, t, &boards)?),
        None => None,
    };
    let cart = match &spec.cart {
        Some(c) => Some(cart::open(&mut ctx, c)?),
        None => None,
    };
    let cameras = cameras::open_all(&ctx)?;
    Ok(Devices {
        axes,
        banks,
        cameras,
        trigger,
        laser,
        cart,
        emulators: ctx.ports.emulators,
    })
}

/// Locks every real port of the rig before any is opened (see [`port_lock`]): serial
/// ports, HID relay boards (by path or serial number; the first board when unnamed) and real
/// cameras (by port or backend). The CLI also calls it (and drops the locks) before creating a
/// run directory, so a rig the daemon holds is refused before anything is written.
pub fn lock_real_ports(spec: &RigSpec) -> Result<Vec<PortLock>, OpenError> {
    let named = |backend: Backend, port: &Option<String>, what: &str| {
        port.clone()
            .unwrap_or_else(|| format!("{what}:{}:first", backend.as_str()))
    };
    let mut ports = BTreeSet::new();
    let serial = |b: Backend| matches!(b, Backend::Grbl | Backend::RelaySerial | Backend::IrBridge);
    for a in spec.axes.iter().filter(|a| serial(a.backend)) {
        ports.insert(port_of(&a.id, &a.port)?);
    }
    for b in &spec.switch_banks {
        match b.backend {
            Backend::HidRelay => ports.insert(named(b.backend, &b.port, "hid")),
            bk if serial(bk) => ports.insert(port_of(&b.id, &b.port)?),
            _ => false,
        };
    }
    for l in spec.laser.iter().filter(|l| serial(l.backend)) {
        ports.insert(port_of(&l.id, &l.port)?);
    }
    for c in spec.cart.iter().filter(|c| serial(c.backend)) {
        ports.insert(port_of(&c.id, &c.port)?);
    }
    for c in spec.cameras.iter().filter(|c| c.backend != Backend::Sim) {
        ports.insert(named(c.backend, &c.port, "camera"));
    }
    ports
        .iter()
        .map(|p| port_lock::lock(p).map_err(OpenError::from))
        .collect()
}
