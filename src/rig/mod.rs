//! The running rig: one actor handle per device, built from a rig description, plus the
//! simulated World when devices are simulated or emulated. Opening the devices is split by
//! kind (`axes`, `switches`, `laser`, `trigger`, `cart`, `cameras`, ordered by `open`);
//! `emulation` puts firmware emulators behind the real drivers; `port_lock` makes one process
//! the owner of the rig's real ports.

mod axes;
mod cameras;
mod cart;
mod emulation;
mod laser;
mod open;
pub mod port_lock;
mod switches;
mod trigger;

use std::collections::BTreeMap;
use std::sync::Arc;

use stagehand_devices::axis::AxisHandle;
use stagehand_devices::camera::CameraHandle;
use stagehand_devices::cart::CartHandle;
use stagehand_devices::clock::RigClock;
use stagehand_devices::interlock::Interlock;
use stagehand_devices::laser::LaserHandle;
use stagehand_devices::rig::{
    BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, Backend, RigError, RigSpec, parse_rig,
};
use stagehand_devices::switch_bank::SwitchBankHandle;
use stagehand_devices::trigger::TriggerHandle;
use stagehand_devices::{DeviceError, DeviceResult};
use stagehand_simulator::World;

pub use emulation::{Emulation, Emulators};
pub use open::{lock_real_ports, needs_real_time};

use open::{needs_world, open_devices};

/// A rig description together with the text it was read from (stored in every run).
#[derive(Debug, Clone)]
pub struct RigSource {
    pub spec: RigSpec,
    pub text: String,
    /// Where it came from: a path or `builtin:<name>`.
    pub origin: String,
}

impl RigSource {
    /// `None` or `lightstage` → the built-in simulated light stage; `reflectometer` → the built-in
    /// reflectometer; anything else is a path to a rig TOML file.
    pub fn load(arg: Option<&str>) -> Result<RigSource, RigError> {
        let builtin = |name: &str, text: &str| Self::from_text(text, &format!("builtin:{name}"));
        match arg {
            None | Some("lightstage") => builtin("lightstage", BUILTIN_LIGHTSTAGE),
            Some("reflectometer") => builtin("reflectometer", BUILTIN_REFLECTOMETER),
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|e| RigError::Read {
                    path: path.to_string(),
                    reason: e.to_string(),
                })?;
                Self::from_text(&text, path)
            }
        }
    }

    /// Parses rig text given inline (e.g. the snapshot stored in a run's manifest): the device
    /// layer checks the devices, the simulator the `[sim]` table, both at file:line:col.
    pub fn from_text(text: &str, origin: &str) -> Result<RigSource, RigError> {
        let spec = parse_rig(text, origin)?;
        stagehand_simulator::render::config::check_rig(text, origin)?;
        Ok(RigSource {
            spec,
            text: text.to_string(),
            origin: origin.to_string(),
        })
    }
}

/// Which lamp a switch-bank channel powers.
#[derive(Debug, Clone)]
pub struct LampWiring {
    pub bank: String,
    pub channel: u32,
}

/// Every device of a rig, each owned by its actor task.
#[derive(Clone)]
pub struct Rig {
    pub spec: Arc<RigSpec>,
    pub clock: RigClock,
    pub axes: BTreeMap<String, AxisHandle>,
    pub banks: BTreeMap<String, SwitchBankHandle>,
    pub lamps: BTreeMap<String, LampWiring>,
    pub cameras: BTreeMap<String, CameraHandle>,
    pub trigger: Option<TriggerHandle>,
    pub laser: Option<LaserHandle>,
    pub cart: Option<CartHandle>,
    /// The laser interlock (door switch): simulated on simulated and emulated rigs, "not
    /// fitted" (always closed) on real rigs, which have no interlock wiring.
    pub interlock: Interlock,
    /// The simulated world, when the rig is simulated or emulated.
    pub world: Option<Arc<World>>,
    /// The firmware emulators standing in for the ports (emulated rigs only).
    pub emulators: Arc<Emulators>,
}

/// Why a rig could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(
        "{device}: backend `{}` has no driver in this build; rebuild with `--features {feature}` (see the README) or use backend = \"sim\"", backend.as_str()
    )]
    NoDriver {
        device: String,
        backend: Backend,
        feature: &'static str,
    },
    #[error("{device}: {message}")]
    Wiring { device: String, message: String },
    #[error("{0}")]
    Device(Box<DeviceError>),
    #[error("simulator: {0}")]
    Simulator(String),
    /// A real port is held by another process (the daemon, or another `run`).
    #[error("{0}")]
    PortLock(#[from] port_lock::PortLockError),
}

impl From<DeviceError> for OpenError {
    fn from(e: DeviceError) -> Self {
        OpenError::Device(Box::new(e))
    }
}

impl Rig {
    /// Spawns every device's actor. Must run inside a tokio runtime. `seed` drives the
    /// simulated sensor noise; `clock` continues a resumed run's rig time.
    pub fn open(spec: RigSpec, clock: RigClock, seed: u64) -> Result<Rig, OpenError> {
        Self::open_with(spec, clock, seed, None)
    }

    /// Like [`Rig::open`]; with `emulation`, the real drivers talk to firmware emulators on
    /// pseudo-terminals in place of the rig's ports (see [`Emulation`]).
    pub fn open_with(
        spec: RigSpec,
        clock: RigClock,
        seed: u64,
        emulation: Option<&Emulation>,
    ) -> Result<Rig, OpenError> {
        let spec = Arc::new(spec);
        let world = if needs_world(&spec, emulation.is_some()) {
            Some(
                World::new(spec.clone(), clock, seed)
                    .map_err(|e| OpenError::Simulator(e.to_string()))?,
            )
        } else {
            None
        };
        let interlock = if emulation.is_some() || !needs_real_time(&spec) {
            Interlock::simulated()
        } else {
            Interlock::not_fitted()
        };
        let devices = open_devices(&spec, &world, emulation, &interlock)?;
        let lamps = switches::lamps(&spec);
        Ok(Rig {
            spec,
            clock,
            axes: devices.axes,
            banks: devices.banks,
            lamps,
            cameras: devices.cameras,
            trigger: devices.trigger,
            laser: devices.laser,
            cart: devices.cart,
            interlock,
            world,
            emulators: Arc::new(devices.emulators),
        })
    }

    /// Safe state: laser off and disarmed, every switched output off, every axis stopped, every
    /// camera disarmed (a capture arms them before its pacing wait, where an abort can end it).
    /// Tries every device even if one fails and reports the first failure.
    pub async fn safe_state(&self) -> DeviceResult<()> {
        let mut first: Option<DeviceError> = None;
        let mut note = |r: DeviceResult<()>| {
            if let Err(e) = r {
                tracing::error!("safe state: {e}");
                first.get_or_insert(e);
            }
        };
        if let Some(l) = &self.laser {
            note(l.disarm().await);
        }
        for b in self.banks.values() {
            note(b.all_off().await);
        }
        for a in self.axes.values() {
            note(a.stop().await.map(|_| ()));
        }
        for c in self.cameras.values() {
            note(c.set_armed(false).await);
        }
        match first {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
