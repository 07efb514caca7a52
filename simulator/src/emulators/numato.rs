//! A Numato-style USB serial relay board: echo, `\n\r`-framed replies and the `>` prompt,
//! relays that switch the World's lamps (and laser), GPIO lines of which one may be the camera
//! trigger, and a watchdog that switches every relay off when the host goes quiet.

use std::path::Path;
use std::sync::Arc;

use stagehand_devices::rig::{Backend, RigSpec};

use super::{
    EmulatorHandle, EmulatorStats, Fault, Faults, Firmware, Output, SteppedEmulator, drive_channel,
    spawn_firmware,
};
use crate::world::World;

/// Firmware version `ver` reports.
pub const VERSION: &str = "00000008";
/// GPIO lines the emulated board has (`0`–`9`, `A`–`V`).
const GPIO_LINES: usize = 32;
/// Longest command line kept; longer input is garbage and is cut.
const MAX_LINE: usize = 64;

/// How an emulated relay board is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct NumatoConfig {
    /// Switch bank id in the rig (whose channels the relays drive).
    pub bank: String,
    /// Relays on the board (relay r drives channel r + 1).
    pub channels: u32,
    /// Every relay switches off when no command arrives for this long (0 = no watchdog).
    pub watchdog_s: f64,
    /// GPIO line wired to the cameras' trigger input: a rising edge fires the World's trigger.
    pub trigger_line: Option<u32>,
    /// 8-character board id for `id get`.
    pub board_id: String,
}

impl NumatoConfig {
    /// The board for switch bank `bank` of `rig`: its channels and watchdog, and the trigger
    /// line if the rig's trigger (backend `switch`) is wired to this bank. `None` if the rig has
    /// no such bank.
    pub fn from_rig(rig: &RigSpec, bank: &str) -> Option<Self> {
        let spec = rig.switch_banks.iter().find(|b| b.id == bank)?;
        let trigger_line = rig
            .trigger
            .as_ref()
            .filter(|t| t.backend == Backend::Switch && t.bank.as_deref() == Some(bank))
            .and_then(|t| t.line);
        Some(Self {
            bank: bank.to_string(),
            channels: spec.channels,
            watchdog_s: spec.watchdog_s,
            trigger_line,
            board_id: format!(
                "{:0>8}",
                bank.chars()
                    .filter(char::is_ascii_alphanumeric)
                    .take(8)
                    .collect::<String>()
            ),
        })
    }
}

/// Spawns emulated relay boards.
pub struct NumatoEmulator;

impl NumatoEmulator {
    /// Starts a board set up by `config` at `<link_dir>/<name>`. Needs a tokio runtime.
    pub fn spawn(
        world: Arc<World>,
        config: NumatoConfig,
        link_dir: &Path,
        name: &str,
        faults: Arc<Faults>,
    ) -> std::io::Result<EmulatorHandle> {
        let (fw, stats) = Self::firmware(&world, config, &faults);
        spawn_firmware(fw, &world, link_dir, name, stats, faults)
    }

    /// A board set up by `config` on the caller's clock, without a pty (see
    /// [`SteppedEmulator`]).
    pub fn stepped(
        world: Arc<World>,
        config: NumatoConfig,
        faults: Arc<Faults>,
    ) -> SteppedEmulator {
        let (fw, stats) = Self::firmware(&world, config, &faults);
        SteppedEmulator::new(fw, &world, stats, faults)
    }

    /// The firmware, with its fresh counters.
    fn firmware(
        world: &Arc<World>,
        config: NumatoConfig,
        faults: &Arc<Faults>,
    ) -> (Numato, Arc<EmulatorStats>) {
        let stats = Arc::new(EmulatorStats::default());
        let fw = Numato {
            world: Arc::clone(world),
            relays: vec![false; config.channels as usize],
            gpio: [false; GPIO_LINES],
            board_id: config.board_id.clone(),
            config,
            stats: Arc::clone(&stats),
            faults: Arc::clone(faults),
            line: Vec::new(),
            lease_from_s: 0.0,
        };
        (fw, stats)
    }
}

struct Numato {
    world: Arc<World>,
    config: NumatoConfig,
    relays: Vec<bool>,
    gpio: [bool; GPIO_LINES],
    board_id: String,
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
    line: Vec<u8>,
    /// Rig time of the last command (the watchdog lease runs from it).
    lease_from_s: f64,
}

/// Index of a relay/GPIO digit: `0`–`9`, then `A`–`V` (either case).
fn index(s: &str) -> Option<usize> {
    let mut chars = s.chars();
    let c = chars.next()?;
    if chars.next().is_some() {
        return None;
    }
    c.to_digit(32).map(|d| d as usize)
}

impl Numato {
    fn set_relay(&mut self, r: usize, on: bool, t: f64) {
        if let Some(slot) = self.relays.get_mut(r) {
            *slot = on;
            drive_channel(&self.world, &self.config.bank, r as u32 + 1, on, t);
        }
    }

    fn all_off(&mut self, t: f64) {
        for r in 0..self.relays.len() {
            self.set_relay(r, false, t);
        }
    }

    fn hex_digits(&self) -> usize {
        (self.relays.len().div_ceil(8) * 2).max(2)
    }

    fn relay(&self, arg: &str) -> Option<usize> {
        index(arg).filter(|r| *r < self.relays.len())
    }

    /// Executes one command; `Some(text)` is the reply text, `None` no reply text.
    fn execute(&mut self, line: &str, t: f64) -> Option<String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["ver"] => Some(VERSION.into()),
            ["id", "get"] => Some(self.board_id.clone()),
            ["id", "set", id] if id.len() == 8 => {
                self.board_id = (*id).to_string();
                None
            }
            ["relay", "on", n] => {
                let r = self.relay(n)?;
                self.set_relay(r, true, t);
                None
            }
            ["relay", "off", n] => {
                let r = self.relay(n)?;
                self.set_relay(r, false, t);
                None
            }
            ["relay", "read", n] => {
                let r = self.relay(n)?;
                Some(if self.relays[r] { "on" } else { "off" }.into())
            }
            ["relay", "readall"] => {
                let mask = self
                    .relays
                    .iter()
                    .enumerate()
                    .fold(0u64, |m, (i, on)| m | (u64::from(*on) << i));
                Some(format!("{mask:0width$x}", width = self.hex_digits()))
            }
            ["relay", "writeall", hex] if hex.len() <= self.hex_digits() => {
                let mask = u64::from_str_radix(hex, 16).ok()?;
                for r in 0..self.relays.len() {
                    self.set_relay(r, mask >> r & 1 == 1, t);
                }
                None
            }
            ["reset"] => {
                self.all_off(t);
                None
            }
            ["gpio", "set", n] => {
                let g = index(n)?;
                let was = std::mem::replace(&mut self.gpio[g], true);
                if !was && self.config.trigger_line == Some(g as u32) {
                    self.world.pulse_hardware(t);
                }
                None
            }
            ["gpio", "clear", n] => {
                self.gpio[index(n)?] = false;
                None
            }
            ["gpio", "read", n] => Some(if self.gpio[index(n)?] { "1" } else { "0" }.into()),
            _ => None,
        }
    }

    fn command(&mut self, t: f64, out: &mut Output) {
        let line = String::from_utf8_lossy(&std::mem::take(&mut self.line))
            .trim()
            .to_string();
        if line.is_empty() {
            out.send("\n\r>");
            return;
        }
        self.lease_from_s = t;
        let n = self.stats.count_command();
        let reply = self.execute(&line, t);
        if let Some(delay) = self.faults.reply_plan(n, t) {
            out.delay(delay);
            match reply {
                Some(text) => out.send(format!("\n\r{text}\n\r>")),
                None => out.send("\n\r>"),
            }
        }
        for f in self.faults.after_command(n, t) {
            match f {
                Fault::Garbage { bytes, .. } => out.send(bytes),
                Fault::BoardReset { .. } => {
                    self.all_off(t);
                    self.gpio = [false; GPIO_LINES];
                }
                Fault::Disconnect { for_s, .. } => out.disconnect(for_s),
                _ => {}
            }
        }
    }
}

impl Firmware for Numato {
    fn start(&mut self, t: f64, _out: &mut Output) {
        self.lease_from_s = t;
        self.all_off(t);
    }

    fn receive(&mut self, bytes: &[u8], t: f64, out: &mut Output) {
        for &b in bytes {
            if out.disconnecting() {
                return;
            }
            out.send([b]);
            if b == b'\r' {
                self.command(t, out);
            } else if self.line.len() < MAX_LINE {
                self.line.push(b);
            }
        }
    }

    fn tick(&mut self, t: f64, _out: &mut Output) {
        if self.config.watchdog_s > 0.0
            && t - self.lease_from_s >= self.config.watchdog_s
            && self.relays.iter().any(|on| *on)
        {
            self.all_off(t);
        }
    }

    fn next_event(&self) -> Option<f64> {
        (self.config.watchdog_s > 0.0 && self.relays.iter().any(|on| *on))
            .then_some(self.lease_from_s + self.config.watchdog_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use stagehand_devices::clock::RigClock;
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any bytes: no panic, every byte echoed, one prompt per `\r`.
        #[test]
        fn arbitrary_bytes_are_echoed_and_prompted(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
            let config = NumatoConfig::from_rig(&rig, "lamps").expect("bank");
            let world = World::new(Arc::new(rig), RigClock::starting_at(0.0), 1).expect("world");
            let mut board = Numato {
                world,
                relays: vec![false; config.channels as usize],
                gpio: [false; GPIO_LINES],
                board_id: config.board_id.clone(),
                config,
                stats: Arc::default(),
                faults: Faults::none(),
                line: Vec::new(),
                lease_from_s: 0.0,
            };
            let mut out = Output::default();
            board.receive(&bytes, 0.0, &mut out);
            let sent: Vec<u8> = out
                .steps
                .into_iter()
                .flat_map(|s| match s {
                    super::super::Step::Send(b) => b,
                    _ => Vec::new(),
                })
                .collect();
            let prompts = bytes.iter().filter(|b| **b == b'\r').count();
            let extra_prompts = bytes.iter().filter(|b| **b == b'>').count();
            prop_assert_eq!(sent.iter().filter(|b| **b == b'>').count(), prompts + extra_prompts);
            prop_assert!(sent.len() >= bytes.len());
        }
    }
}
