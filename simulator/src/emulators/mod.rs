//! Firmware emulators: the device side of every wire protocol in `devices/PROTOCOLS.md`, spoken
//! over pseudo-terminals (serial devices) or in memory (HID), driven by and updating the
//! simulated [`World`] on its clock, with fault injection. [`SteppedEmulator`] runs the same
//! firmware on the caller's clock, without a pty, for tests that check physics at exact times. Real drivers talk to them exactly as
//! to the hardware, so a driver/emulator pair tests both readings of the protocol document.

pub mod faults;
pub mod grbl;
pub mod hid_board;
pub mod ir_bridge;
pub mod numato;
// The only unsafe in the crate: registering the pty master with tokio, and FIONREAD.
#[allow(unsafe_code)]
pub mod pty;
pub mod stepped;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use stagehand_devices::clock::RigClock;
use tokio::task::JoinHandle;

pub use faults::{Fault, Faults};
pub use grbl::GrblEmulator;
pub use hid_board::HidRelayBoard;
pub use ir_bridge::IrBridgeEmulator;
pub use numato::{NumatoConfig, NumatoEmulator};
pub use pty::EmulatedPort;
pub use stepped::SteppedEmulator;

use crate::world::World;

/// Longest the emulator loop sleeps without looking at the clock.
const IDLE_WAKE_S: f64 = 0.25;
/// Longest wait for the driver to read the last reply before an unplug.
const UNPLUG_GRACE_S: f64 = 0.5;
/// How long a write to the pty may block before the unread output is thrown away.
const WRITE_TIMEOUT: Duration = Duration::from_millis(500);

/// Counters an emulator publishes for tests and the integrator.
#[derive(Debug, Default)]
pub struct EmulatorStats {
    commands: AtomicU64,
    overflows: AtomicU64,
    disconnects: AtomicU64,
}

impl EmulatorStats {
    /// Command lines received so far (the count the faults use).
    pub fn commands(&self) -> u64 {
        self.commands.load(Ordering::Relaxed)
    }

    /// Bytes dropped because the host overflowed the receive buffer (GRBL's 127 bytes).
    pub fn overflows(&self) -> u64 {
        self.overflows.load(Ordering::Relaxed)
    }

    /// Completed unplug/re-plug cycles.
    pub fn disconnects(&self) -> u64 {
        self.disconnects.load(Ordering::Relaxed)
    }

    pub(crate) fn count_command(&self) -> u64 {
        self.commands.fetch_add(1, Ordering::Relaxed) + 1
    }

    pub(crate) fn count_disconnect(&self) {
        self.disconnects.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_overflow(&self) {
        self.overflows.fetch_add(1, Ordering::Relaxed);
    }
}

/// What firmware logic asks the port loop to do, in order.
#[derive(Debug)]
pub(crate) enum Step {
    Send(Vec<u8>),
    /// Wait before the next step (a slow reply).
    Delay(f64),
    /// Unplug for this many seconds, then plug back in.
    Disconnect(f64),
}

/// Output collected while the firmware handles bytes or time.
#[derive(Debug, Default)]
pub(crate) struct Output {
    steps: Vec<Step>,
}

impl Output {
    pub(crate) fn send(&mut self, bytes: impl AsRef<[u8]>) {
        let bytes = bytes.as_ref();
        if let Some(Step::Send(last)) = self.steps.last_mut() {
            last.extend_from_slice(bytes);
        } else {
            self.steps.push(Step::Send(bytes.to_vec()));
        }
    }

    pub(crate) fn delay(&mut self, seconds: f64) {
        if seconds > 0.0 {
            self.steps.push(Step::Delay(seconds));
        }
    }

    pub(crate) fn disconnect(&mut self, seconds: f64) {
        self.steps.push(Step::Disconnect(seconds));
    }

    /// True once a disconnect is queued: bytes after it were never received.
    pub(crate) fn disconnecting(&self) -> bool {
        self.steps.iter().any(|s| matches!(s, Step::Disconnect(_)))
    }

    fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }
}

/// The protocol logic of one serial device, fed bytes and time by [`run`].
pub(crate) trait Firmware: Send + 'static {
    /// Power-on at rig time `t`.
    fn start(&mut self, t: f64, out: &mut Output);
    /// Bytes from the driver, received at rig time `t`.
    fn receive(&mut self, bytes: &[u8], t: f64, out: &mut Output);
    /// Time passed: finish whatever is due at rig time `t`.
    fn tick(&mut self, t: f64, out: &mut Output);
    /// Rig time of the next thing `tick` must do, if any.
    fn next_event(&self) -> Option<f64>;
}

/// A running serial emulator: its stable path, counters and fault schedule. Dropping it stops
/// the emulator and removes its link.
pub struct EmulatorHandle {
    path: PathBuf,
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
    task: JoinHandle<()>,
}

impl EmulatorHandle {
    /// The symlink drivers open (`<link_dir>/<name>`); stable across disconnects.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The emulator's counters.
    pub fn stats(&self) -> &EmulatorStats {
        &self.stats
    }

    /// The fault schedule (which faults fired).
    pub fn faults(&self) -> &Arc<Faults> {
        &self.faults
    }

    /// Stops the emulator (its pty closes and its link goes away).
    pub fn shutdown(&self) {
        self.task.abort();
    }
}

impl Drop for EmulatorHandle {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Creates the port `<link_dir>/<name>` and runs `firmware` on it in a tokio task.
pub(crate) fn spawn_firmware(
    firmware: impl Firmware,
    world: &World,
    link_dir: &Path,
    name: &str,
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
) -> std::io::Result<EmulatorHandle> {
    let port = EmulatedPort::create(link_dir, name)?;
    let path = port.path().to_path_buf();
    faults.apply_to_world(world);
    // Power on now, so the banner is in the pty before anyone can open it.
    let mut firmware = firmware;
    let mut out = Output::default();
    firmware.start(world.clock().now_s(), &mut out);
    if let Some(Step::Send(bytes)) = out.steps.first_mut() {
        let n = port.write_now(bytes).unwrap_or(0);
        bytes.drain(..n);
    }
    let task = tokio::spawn(run(firmware, port, out, world.clock(), Arc::clone(&stats)));
    Ok(EmulatorHandle {
        path,
        stats,
        faults,
        task,
    })
}

/// The byte loop: reads from the pty, feeds the firmware, wakes it for its timed events and
/// carries out its output (including slow replies and disconnects).
async fn run(
    mut fw: impl Firmware,
    mut port: EmulatedPort,
    mut out: Output,
    clock: RigClock,
    stats: Arc<EmulatorStats>,
) {
    let mut buf = [0u8; 512];
    loop {
        carry_out(&mut out, &mut fw, &mut port, clock, &stats).await;
        let now = clock.now_s();
        fw.tick(now, &mut out);
        if !out.is_empty() {
            continue;
        }
        let wait = fw
            .next_event()
            .map(|e| (e - now).max(0.0))
            .unwrap_or(IDLE_WAKE_S)
            .min(IDLE_WAKE_S);
        tokio::select! {
            r = port.read(&mut buf) => match r {
                Ok(n) if n > 0 => fw.receive(&buf[..n], clock.now_s(), &mut out),
                _ => clock.sleep_s(0.01).await,
            },
            _ = clock.sleep_s(wait) => {}
        }
    }
}

async fn carry_out(
    out: &mut Output,
    fw: &mut impl Firmware,
    port: &mut EmulatedPort,
    clock: RigClock,
    stats: &EmulatorStats,
) {
    let steps = std::mem::take(&mut out.steps);
    for step in steps {
        match step {
            Step::Send(bytes) => {
                if !port.is_connected() {
                    continue;
                }
                match tokio::time::timeout(WRITE_TIMEOUT, port.write_all(&bytes)).await {
                    Ok(Ok(())) => {}
                    // Nobody reads (or the pty is gone): what we said is lost, as on a wire.
                    _ => port.drop_unread(),
                }
            }
            Step::Delay(s) => clock.sleep_s(s).await,
            Step::Disconnect(s) => {
                // Let the driver read what was said before the device vanished (bounded).
                // The pty hands written bytes to the reader asynchronously: give it a moment
                // before trusting the count of unread bytes.
                let give_up = clock.now_s() + UNPLUG_GRACE_S;
                clock.sleep_s(0.02).await;
                while port.unread() > 0 && clock.now_s() < give_up {
                    clock.sleep_s(0.005).await;
                }
                port.unplug();
                let until = clock.now_s() + s;
                // The device keeps running while unplugged (moves finish, watchdogs lapse);
                // what it says meanwhile is lost.
                let mut lost = Output::default();
                loop {
                    let now = clock.now_s();
                    fw.tick(now, &mut lost);
                    lost.steps.clear();
                    if now >= until {
                        break;
                    }
                    let next = fw.next_event().unwrap_or(until).clamp(now, until);
                    clock.sleep_s((next - now).min(IDLE_WAKE_S)).await;
                }
                while let Err(e) = port.plug() {
                    tracing::warn!("emulator could not re-create its pty: {e}");
                    clock.sleep_s(0.05).await;
                }
                stats.count_disconnect();
            }
        }
    }
}

/// Switches channel `channel` (from 1) of bank `bank` as a relay would: the lamps wired to it,
/// and the laser if the rig powers it from that channel (laser backend `switch`).
pub(crate) fn drive_channel(world: &World, bank: &str, channel: u32, on: bool, t: f64) {
    world.set_channel(bank, channel, on, t);
    if let Some(laser) = &world.rig().laser
        && laser.bank.as_deref() == Some(bank)
        && laser.channel == Some(channel)
    {
        world.set_laser(on, world.laser_colour_nm());
    }
}
