//! Opening a rig's devices: a driver for every device (simulated or real), each behind its
//! actor handle. With [`Emulation`], the real serial drivers talk to firmware emulators on
//! pseudo-terminals instead of the ports the rig file names, and cameras are rendered from the
//! simulated world: the whole acquisition loop then runs through real bytes without hardware.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use stagehand_devices::axis::AxisHandle;
use stagehand_devices::camera::CameraHandle;
use stagehand_devices::cart::CartHandle;
use stagehand_devices::error::DeviceResult;
use stagehand_devices::grbl::{GrblAxis, GrblController, GrblLaser};
use stagehand_devices::hid_relay::{HidRelayBank, HidTransport};
use stagehand_devices::interlock::Interlock;
use stagehand_devices::ir_cart::IrBridgeCart;
use stagehand_devices::laser::LaserHandle;
use stagehand_devices::relay_serial::{NumatoBoard, RelaySerialBank};
use stagehand_devices::rig::{
    AxisSpec, Backend, GRBL_BAUD, RELAY_SERIAL_BAUD, RigSpec, SwitchBankSpec,
};
use stagehand_devices::switch_bank::SwitchBankHandle;
use stagehand_devices::switch_wired::{GpioTrigger, SeriesLaser, SwitchLaser};
use stagehand_devices::trigger::{TriggerDriver, TriggerHandle};
use stagehand_devices::{DeviceError, rig::CameraSpec};
use stagehand_simulator::World;
use stagehand_simulator::emulators::{
    EmulatorHandle, Faults, GrblEmulator, HidRelayBoard, IrBridgeEmulator, NumatoConfig,
    NumatoEmulator,
};
use stagehand_simulator::sim_devices::{
    MirroredAxis, MirroredLaser, SimAxis, SimCamera, SimCart, SimLaser, SimSwitchBank, SimTrigger,
};

use crate::rig::OpenError;

/// Run the real drivers against firmware emulators instead of the rig's ports.
#[derive(Debug, Clone, Default)]
pub struct Emulation {
    /// Where the emulators' port links go (`<dir>/<name>` → `/dev/pts/N`).
    pub link_dir: PathBuf,
    /// Faults to inject, by the port the rig file names (or the device id of a HID bank
    /// without a port). Ports without an entry get none.
    pub faults: BTreeMap<String, Arc<Faults>>,
}

impl Emulation {
    /// Emulation with the port links in `link_dir` and no faults.
    pub fn new(link_dir: &Path) -> Self {
        Self {
            link_dir: link_dir.to_path_buf(),
            faults: BTreeMap::new(),
        }
    }

    fn faults_for(&self, key: &str) -> Arc<Faults> {
        self.faults.get(key).cloned().unwrap_or_else(Faults::none)
    }
}

/// The running emulators of an emulated rig, by the port they stand in for.
#[derive(Default)]
pub struct Emulators {
    pub by_port: BTreeMap<String, EmulatorHandle>,
    /// The locks on the rig's real ports (none when simulated or emulated): held as long as
    /// the rig lives, so no other process opens its devices (see [`crate::port_lock`]).
    pub port_locks: Vec<crate::port_lock::PortLock>,
}

/// Every device handle of a rig.
pub(crate) struct Devices {
    pub axes: BTreeMap<String, AxisHandle>,
    pub banks: BTreeMap<String, SwitchBankHandle>,
    pub cameras: BTreeMap<String, CameraHandle>,
    pub trigger: Option<TriggerHandle>,
    pub laser: Option<LaserHandle>,
    pub cart: Option<CartHandle>,
    pub emulators: Emulators,
}

/// Starts one emulator: link directory, link name, faults.
type StartEmulator<'a> = dyn Fn(&Path, &str, Arc<Faults>) -> std::io::Result<EmulatorHandle> + 'a;

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
pub(crate) fn needs_world(spec: &RigSpec, emulate: bool) -> bool {
    emulate || backends(spec).any(|b| b == Backend::Sim)
}

/// True if any device has a real driver (it talks over a port in real time).
pub fn needs_real_time(spec: &RigSpec) -> bool {
    backends(spec).any(|b| b != Backend::Sim)
}

fn port_of(id: &str, port: &Option<String>) -> Result<String, OpenError> {
    port.clone().ok_or_else(|| OpenError::Wiring {
        device: id.to_string(),
        message: "needs `port` in the rig file".into(),
    })
}

fn emulator_error(port: &str, e: std::io::Error) -> OpenError {
    OpenError::Simulator(format!("cannot start the emulator for {port}: {e}"))
}

fn world_of(world: &Option<Arc<World>>) -> Result<&Arc<World>, OpenError> {
    world
        .as_ref()
        .ok_or_else(|| OpenError::Simulator("the simulated world is missing".into()))
}

/// Opens every device of `spec`; the laser watches `interlock`. Must run inside a tokio
/// runtime.
pub(crate) fn open_devices(
    spec: &Arc<RigSpec>,
    world: &Option<Arc<World>>,
    emulation: Option<&Emulation>,
    interlock: &Interlock,
) -> Result<Devices, OpenError> {
    let mut emulators = Emulators::default();
    if emulation.is_none() {
        emulators.port_locks = lock_real_ports(spec)?;
    }
    // The path each rig port is reached at: itself, or its emulator's link.
    let mut paths: BTreeMap<String, String> = BTreeMap::new();
    let mut emulate_port = |port: &str, start: &StartEmulator| -> Result<String, OpenError> {
        if let Some(p) = paths.get(port) {
            return Ok(p.clone());
        }
        let path = match emulation {
            None => port.to_string(),
            Some(em) => {
                let name = format!("port{}", emulators.by_port.len());
                let handle = start(&em.link_dir, &name, em.faults_for(port))
                    .map_err(|e| emulator_error(port, e))?;
                let path = handle.path().display().to_string();
                emulators.by_port.insert(port.to_string(), handle);
                path
            }
        };
        paths.insert(port.to_string(), path.clone());
        Ok(path)
    };

    // GRBL controllers: one per port, serving every axis (and the laser) that names it.
    let mut grbl_axes: BTreeMap<String, Vec<AxisSpec>> = BTreeMap::new();
    for a in spec.axes.iter().filter(|a| a.backend == Backend::Grbl) {
        grbl_axes
            .entry(port_of(&a.id, &a.port)?)
            .or_default()
            .push(a.clone());
    }
    if let Some(l) = spec.laser.as_ref().filter(|l| l.backend == Backend::Grbl) {
        grbl_axes.entry(port_of(&l.id, &l.port)?).or_default();
    }
    let mut controllers: BTreeMap<String, Arc<GrblController>> = BTreeMap::new();
    for (port, axes) in &grbl_axes {
        let path = emulate_port(port, &|dir, name, faults| {
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
            .unwrap_or_else(|| "grbl".into());
        let baud = axes.iter().find_map(|a| a.baud).unwrap_or(GRBL_BAUD);
        controllers.insert(
            port.clone(),
            GrblController::new(&label, &path, baud, axes.clone()),
        );
    }

    let mut axes = BTreeMap::new();
    for a in &spec.axes {
        let handle = match a.backend {
            Backend::Grbl => {
                let ctrl = controllers
                    .get(&port_of(&a.id, &a.port)?)
                    .cloned()
                    .ok_or_else(|| missing_controller(&a.id))?;
                let shared_s = shared_allowance_s(&grbl_axes, a);
                let driver = GrblAxis::new(ctrl, a).map_err(OpenError::from)?;
                match (emulation, world) {
                    // A hybrid rig (real controller, simulated cameras): the World follows
                    // the positions the real axis reports, so frames show what it did.
                    (None, Some(w)) => AxisHandle::spawn_shared(
                        a.clone(),
                        MirroredAxis::new(&a.id, driver, w.clone()),
                        shared_s,
                    ),
                    _ => AxisHandle::spawn_shared(a.clone(), driver, shared_s),
                }
            }
            _ => AxisHandle::spawn(a.clone(), SimAxis::new(a.clone(), world_of(world)?.clone())),
        };
        axes.insert(a.id.clone(), handle);
    }

    // Switch banks; relay boards are kept for the GPIO trigger.
    let mut boards: BTreeMap<String, Arc<NumatoBoard>> = BTreeMap::new();
    let mut banks = BTreeMap::new();
    for b in &spec.switch_banks {
        let handle = match b.backend {
            Backend::RelaySerial => {
                let port = port_of(&b.id, &b.port)?;
                let config = NumatoConfig::from_rig(spec, &b.id);
                let path = emulate_port(&port, &|dir, name, faults| {
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
            Backend::HidRelay => SwitchBankHandle::spawn(b.clone(), hid_bank(b, world, emulation)?),
            _ => SwitchBankHandle::spawn(
                b.clone(),
                SimSwitchBank::new(b.clone(), world_of(world)?.clone()),
            ),
        };
        banks.insert(b.id.clone(), handle);
    }

    let laser = match &spec.laser {
        None => None,
        Some(l) => Some(match l.backend {
            Backend::Grbl => {
                let ctrl = controllers
                    .get(&port_of(&l.id, &l.port)?)
                    .cloned()
                    .ok_or_else(|| missing_controller(&l.id))?;
                let output = GrblLaser::new(ctrl, &l.id);
                // Optionally powered through a relay too (its board has the watchdog GRBL
                // lacks); in a hybrid rig the World follows the confirmed emission.
                let power = match &l.bank {
                    Some(bank_id) => Some(SwitchLaser::new(
                        &l.id,
                        banks
                            .get(bank_id)
                            .cloned()
                            .ok_or_else(|| OpenError::Wiring {
                                device: l.id.clone(),
                                message: format!("no switch bank `{bank_id}`"),
                            })?,
                        l.channel.unwrap_or(0),
                    )),
                    None => None,
                };
                let mirror = match (emulation, world) {
                    (None, Some(w)) => Some(w.clone()),
                    _ => None,
                };
                let (l, lock) = (l.clone(), interlock.watch());
                match (power, mirror) {
                    (Some(p), Some(w)) => LaserHandle::spawn_with_interlock(
                        l,
                        MirroredLaser::new(SeriesLaser::new(p, output), w),
                        lock,
                    ),
                    (Some(p), None) => {
                        LaserHandle::spawn_with_interlock(l, SeriesLaser::new(p, output), lock)
                    }
                    (None, Some(w)) => {
                        LaserHandle::spawn_with_interlock(l, MirroredLaser::new(output, w), lock)
                    }
                    (None, None) => LaserHandle::spawn_with_interlock(l, output, lock),
                }
            }
            Backend::Switch => {
                let bank_id = l.bank.clone().unwrap_or_default();
                let bank = banks
                    .get(&bank_id)
                    .cloned()
                    .ok_or_else(|| OpenError::Wiring {
                        device: l.id.clone(),
                        message: format!("no switch bank `{bank_id}`"),
                    })?;
                LaserHandle::spawn_with_interlock(
                    l.clone(),
                    SwitchLaser::new(&l.id, bank, l.channel.unwrap_or(0)),
                    interlock.watch(),
                )
            }
            _ => LaserHandle::spawn_with_interlock(
                l.clone(),
                SimLaser::new(world_of(world)?.clone()),
                interlock.watch(),
            ),
        }),
    };

    let trigger = match &spec.trigger {
        None => None,
        Some(t) => Some(match (t.backend, world) {
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
                    || !spec
                        .cameras
                        .iter()
                        .any(|c| simulated_camera(c, emulation.is_some())) =>
            {
                TriggerHandle::spawn(t.clone(), SoftwareTrigger)
            }
            (_, Some(w)) => TriggerHandle::spawn(t.clone(), SimTrigger::new(w.clone())),
            (_, None) => {
                return Err(OpenError::Simulator(
                    "the simulated world is missing".into(),
                ));
            }
        }),
    };

    let cart = match &spec.cart {
        None => None,
        Some(c) => Some(match c.backend {
            Backend::IrBridge => {
                let port = port_of(&c.id, &c.port)?;
                let path = emulate_port(&port, &|dir, name, faults| {
                    IrBridgeEmulator::spawn(
                        world_of(world).map_err(io)?.clone(),
                        c,
                        dir,
                        name,
                        faults,
                    )
                })?;
                let mut spec = c.clone();
                spec.port = Some(path);
                CartHandle::spawn(
                    c.clone(),
                    IrBridgeCart::from_spec(&spec).map_err(OpenError::from)?,
                )
            }
            _ => CartHandle::spawn(c.clone(), SimCart::new(world_of(world)?.clone())),
        }),
    };

    let mut cameras = BTreeMap::new();
    for c in &spec.cameras {
        cameras.insert(
            c.id.clone(),
            open_camera(c, spec.trigger.as_ref(), world, emulation.is_some())?,
        );
    }

    Ok(Devices {
        axes,
        banks,
        cameras,
        trigger,
        laser,
        cart,
        emulators,
    })
}

/// Locks every real port of the rig before any is opened (see [`crate::port_lock`]): serial
/// ports, HID relay boards (by path or serial number; the first board when unnamed) and real
/// cameras (by port or backend). The CLI also calls it (and drops the locks) before creating a
/// run directory, so a rig the daemon holds is refused before anything is written.
pub(crate) fn lock_real_ports(
    spec: &RigSpec,
) -> Result<Vec<crate::port_lock::PortLock>, OpenError> {
    let named = |backend: Backend, port: &Option<String>, what: &str| {
        port.clone()
            .unwrap_or_else(|| format!("{what}:{backend:?}:first").to_lowercase())
    };
    let mut ports = std::collections::BTreeSet::new();
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
        .map(|p| crate::port_lock::lock(p).map_err(OpenError::from))
        .collect()
}

/// A camera: simulated (also every camera of an emulated rig: the world renders its frames),
/// or a real backend compiled into this build.
/// True if camera `c` renders from the simulated World: a `sim` camera, or under `--emulate` a
/// camera whose backend this build lacks (real cameras that can be opened stay real: they have
/// no serial port to emulate).
fn simulated_camera(c: &CameraSpec, emulate: bool) -> bool {
    c.backend == Backend::Sim || (emulate && !crate::camera_backends::compiled(c.backend))
}

fn open_camera(
    c: &CameraSpec,
    trigger: Option<&stagehand_devices::rig::TriggerSpec>,
    world: &Option<Arc<World>>,
    emulate: bool,
) -> Result<CameraHandle, OpenError> {
    if simulated_camera(c, emulate) {
        return Ok(CameraHandle::spawn(
            c.clone(),
            SimCamera::new(c.clone(), world_of(world)?.clone()),
        ));
    }
    crate::camera_backends::open(c, trigger)
}

fn hid_bank(
    b: &SwitchBankSpec,
    world: &Option<Arc<World>>,
    emulation: Option<&Emulation>,
) -> Result<HidRelayBank, OpenError> {
    match emulation {
        Some(em) => {
            let key = b.port.clone().unwrap_or_else(|| b.id.clone());
            let board = HidRelayBoard::new(
                world_of(world)?.clone(),
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

/// Time for a reconnect's handshake (banner, settings).
const HANDSHAKE_S: f64 = 5.0;

/// How long a request to `axis` may wait behind the other axes of its GRBL controller: each
/// of them homing or crossing its whole travel, plus a reconnect's handshake.
fn shared_allowance_s(grbl_axes: &BTreeMap<String, Vec<AxisSpec>>, axis: &AxisSpec) -> f64 {
    let others = grbl_axes
        .values()
        .find(|axes| axes.iter().any(|a| a.id == axis.id))
        .map(|axes| {
            axes.iter()
                .filter(|a| a.id != axis.id)
                .map(|a| {
                    let span = (a.max_deg - a.min_deg).abs();
                    let travel = stagehand_devices::motion::move_duration_s(
                        a.min_deg,
                        a.max_deg,
                        a.kinematics(),
                        a.backlash_deg,
                    );
                    (span / a.homing_speed_deg_s).max(travel) * 1.5 + a.settle_s
                })
                .sum::<f64>()
        })
        .unwrap_or(0.0);
    others + HANDSHAKE_S
}

fn missing_controller(id: &str) -> OpenError {
    OpenError::Wiring {
        device: id.to_string(),
        message: "no GRBL controller for its port".into(),
    }
}

fn io(e: OpenError) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

/// The emulated HID relay board as the driver's transport.
struct EmulatedHid(HidRelayBoard);

impl HidTransport for EmulatedHid {
    fn send_feature_report(&mut self, data: &[u8]) -> std::io::Result<()> {
        self.0.send_feature_report(data)
    }

    fn get_feature_report(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.0.get_feature_report(buf)
    }
}

/// The trigger of software-triggered cameras: each camera exposes when its driver is told
/// the trigger id, so there is no line to pulse.
struct SoftwareTrigger;

impl TriggerDriver for SoftwareTrigger {
    async fn fire(&mut self, _trigger_id: u64) -> DeviceResult<()> {
        Ok(())
    }
}

impl From<DeviceError> for OpenError {
    fn from(e: DeviceError) -> Self {
        OpenError::Device(Box::new(e))
    }
}
