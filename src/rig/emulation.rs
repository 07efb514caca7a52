//! Emulation: the real serial and HID drivers talk to firmware emulators on pseudo-terminals
//! instead of the ports the rig file names, so the whole acquisition loop runs through real
//! bytes without hardware. Also where each rig port is reached ([`PortPaths`]): the port itself,
//! or its emulator's link.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use stagehand_devices::hid_relay::HidTransport;
use stagehand_simulator::emulators::{EmulatorHandle, Faults, HidRelayBoard};

use super::OpenError;
use super::port_lock::PortLock;

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

    /// The faults to inject on `key` (a rig port, or a HID bank's id); none when unset.
    pub(super) fn faults_for(&self, key: &str) -> Arc<Faults> {
        self.faults.get(key).cloned().unwrap_or_else(Faults::none)
    }
}

/// The running emulators of an emulated rig, by the port they stand in for.
#[derive(Default)]
pub struct Emulators {
    pub by_port: BTreeMap<String, EmulatorHandle>,
    /// The locks on the rig's real ports (none when simulated or emulated): held as long as
    /// the rig lives, so no other process opens its devices (see [`super::port_lock`]).
    pub port_locks: Vec<PortLock>,
}

/// Starts one emulator: link directory, link name, faults.
pub(super) type StartEmulator<'a> =
    dyn Fn(&Path, &str, Arc<Faults>) -> std::io::Result<EmulatorHandle> + 'a;

/// The path each rig port is reached at while the devices are opened: the port itself, or,
/// under emulation, the link of the emulator started for it (one per port, however many
/// devices share it).
pub(super) struct PortPaths<'a> {
    emulation: Option<&'a Emulation>,
    paths: BTreeMap<String, String>,
    /// The emulators started so far (and the port locks), handed to the rig at the end.
    pub emulators: Emulators,
}

impl<'a> PortPaths<'a> {
    /// No port reached yet.
    pub fn new(emulation: Option<&'a Emulation>) -> Self {
        Self {
            emulation,
            paths: BTreeMap::new(),
            emulators: Emulators::default(),
        }
    }

    /// The path to open for rig port `port`; under emulation, `start` starts its emulator the
    /// first time the port is asked for.
    pub fn reach(&mut self, port: &str, start: &StartEmulator) -> Result<String, OpenError> {
        if let Some(p) = self.paths.get(port) {
            return Ok(p.clone());
        }
        let path = match self.emulation {
            None => port.to_string(),
            Some(em) => {
                let name = format!("port{}", self.emulators.by_port.len());
                let handle = start(&em.link_dir, &name, em.faults_for(port)).map_err(|e| {
                    OpenError::Simulator(format!("cannot start the emulator for {port}: {e}"))
                })?;
                let path = handle.path().display().to_string();
                self.emulators.by_port.insert(port.to_string(), handle);
                path
            }
        };
        self.paths.insert(port.to_string(), path.clone());
        Ok(path)
    }
}

/// An [`OpenError`] inside an emulator's start function, which returns `io::Error`.
pub(super) fn io(e: OpenError) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

/// The emulated HID relay board as the driver's transport.
pub(super) struct EmulatedHid(pub HidRelayBoard);

impl HidTransport for EmulatedHid {
    fn send_feature_report(&mut self, data: &[u8]) -> std::io::Result<()> {
        self.0.send_feature_report(data)
    }

    fn get_feature_report(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.0.get_feature_report(buf)
    }
}
