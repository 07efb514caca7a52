//! Opening the axes: one GRBL controller per port (shared by every axis, and the laser, that
//! names it), GRBL axes on it (mirrored into the world on a hybrid rig), simulated axes
//! otherwise.

use std::collections::BTreeMap;
use std::sync::Arc;

use stagehand_devices::axis::AxisHandle;
use stagehand_devices::grbl::{GrblAxis, GrblController};
use stagehand_devices::motion::move_duration_s;
use stagehand_devices::rig::{AxisSpec, Backend, GRBL_BAUD};
use stagehand_simulator::emulators::GrblEmulator;
use stagehand_simulator::sim_devices::{MirroredAxis, SimAxis};

use super::OpenError;
use super::emulation::io;
use super::open::{Opening, port_of, world_of};

/// Time for a reconnect's handshake (banner, settings).
const HANDSHAKE_S: f64 = 5.0;

/// The rig's GRBL controllers, one per port, with the axes each one serves.
pub(super) struct GrblControllers {
    controllers: BTreeMap<String, Arc<GrblController>>,
    axes_by_port: BTreeMap<String, Vec<AxisSpec>>,
}

impl GrblControllers {
    /// One controller per port that a GRBL axis or the GRBL laser names (its emulator started
    /// under emulation).
    pub fn open(ctx: &mut Opening) -> Result<Self, OpenError> {
        let spec = ctx.spec;
        let mut axes_by_port: BTreeMap<String, Vec<AxisSpec>> = BTreeMap::new();
        for a in spec.axes.iter().filter(|a| a.backend == Backend::Grbl) {
            axes_by_port
                .entry(port_of(&a.id, &a.port)?)
                .or_default()
                .push(a.clone());
        }
        if let Some(l) = spec.laser.as_ref().filter(|l| l.backend == Backend::Grbl) {
            axes_by_port.entry(port_of(&l.id, &l.port)?).or_default();
        }
        let world = ctx.world;
        let mut controllers = BTreeMap::new();
        for (port, axes) in &axes_by_port {
            let path = ctx.ports.reach(port, &|dir, name, faults| {
                GrblEmulator::spawn(
                    world_of(world).map_err(io)?.clone(),
                    axes,
                    dir,
                    name,
                    faults,
                )
            })?;
            let label = axes
                .first()
                .map(|a| a.id.clone())
                .or_else(|| spec.laser.as_ref().map(|l| l.id.clone()))
                .unwrap_or_else(|| Backend::Grbl.as_str().into());
            let baud = axes.iter().find_map(|a| a.baud).unwrap_or(GRBL_BAUD);
            controllers.insert(
                port.clone(),
                GrblController::new(&label, &path, baud, axes.clone()),
            );
        }
        Ok(Self {
            controllers,
            axes_by_port,
        })
    }

    /// The controller on `port`, for device `id`.
    pub fn on(&self, id: &str, port: &Option<String>) -> Result<Arc<GrblController>, OpenError> {
        self.controllers
            .get(&port_of(id, port)?)
            .cloned()
            .ok_or_else(|| OpenError::Wiring {
                device: id.to_string(),
                message: "no GRBL controller for its port".into(),
            })
    }

    /// How long a request to `axis` may wait behind the other axes of its GRBL controller:
    /// each of them homing or crossing its whole travel, plus a reconnect's handshake.
    fn shared_allowance_s(&self, axis: &AxisSpec) -> f64 {
        let others = self
            .axes_by_port
            .values()
            .find(|axes| axes.iter().any(|a| a.id == axis.id))
            .map(|axes| {
                axes.iter()
                    .filter(|a| a.id != axis.id)
                    .map(|a| {
                        let span = (a.max_deg - a.min_deg).abs();
                        let travel =
                            move_duration_s(a.min_deg, a.max_deg, a.kinematics(), a.backlash_deg);
                        (span / a.homing_speed_deg_s).max(travel) * 1.5 + a.settle_s
                    })
                    .sum::<f64>()
            })
            .unwrap_or(0.0);
        others + HANDSHAKE_S
    }
}

/// Every axis of the rig, by id.
pub(super) fn open(
    ctx: &Opening,
    grbl: &GrblControllers,
) -> Result<BTreeMap<String, AxisHandle>, OpenError> {
    let mut axes = BTreeMap::new();
    for a in &ctx.spec.axes {
        let handle = match a.backend {
            Backend::Grbl => {
                let driver = GrblAxis::new(grbl.on(&a.id, &a.port)?, a).map_err(OpenError::from)?;
                let shared_s = grbl.shared_allowance_s(a);
                match ctx.mirror() {
                    // A hybrid rig (real controller, simulated cameras): the World follows
                    // the positions the real axis reports, so frames show what it did.
                    Some(w) => AxisHandle::spawn_shared(
                        a.clone(),
                        MirroredAxis::new(&a.id, driver, w.clone()),
                        shared_s,
                    ),
                    None => AxisHandle::spawn_shared(a.clone(), driver, shared_s),
                }
            }
            _ => AxisHandle::spawn(a.clone(), SimAxis::new(a.clone(), ctx.world()?.clone())),
        };
        axes.insert(a.id.clone(), handle);
    }
    Ok(axes)
}
