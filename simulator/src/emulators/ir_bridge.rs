//! The LEGO Power Functions IR bridge driving the reflectometer cart: `ver`, `PF hhhh` with
//! check-nibble verification, single-output PWM decoded for the cart's channel and output, and
//! `END -`/`END +` when the cart runs onto an end-stop switch (the bridge cuts the motor).

use std::path::Path;
use std::sync::Arc;

use stagehand_devices::rig::CartSpec;

use super::{
    EmulatorHandle, EmulatorStats, Fault, Faults, Firmware, Output, SteppedEmulator, spawn_firmware,
};
use crate::world::World;

/// Reply to `ver`.
pub const VERSION: &str = "IRBRIDGE 1.0";
/// Longest line kept; longer input is garbage.
const MAX_LINE: usize = 64;

/// What a Power Functions word tells one receiver output to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PfCommand {
    /// Single-output PWM: `channel` 0–3, `output` 0 (A) or 1 (B), `step` −7..=7 (0 float).
    Pwm { channel: u8, output: u8, step: i8 },
    /// Single-output brake.
    Brake { channel: u8, output: u8 },
    /// A valid word of another mode (ignored by the cart).
    Other,
}

/// Decodes a 16-bit PF word; `None` if its check nibble is wrong.
pub fn decode_pf(word: u16) -> Option<PfCommand> {
    let n = [
        (word >> 12) as u8 & 0xF,
        (word >> 8) as u8 & 0xF,
        (word >> 4) as u8 & 0xF,
        word as u8 & 0xF,
    ];
    if n[3] != 0xF ^ n[0] ^ n[1] ^ n[2] {
        return None;
    }
    let escape = n[0] >> 2 & 1;
    let channel = n[0] & 3;
    let address = n[1] >> 3;
    let mode = n[1] & 7;
    if escape != 0 || address != 0 || (mode != 0b100 && mode != 0b101) {
        return Some(PfCommand::Other);
    }
    let output = mode & 1;
    let step = match n[2] {
        0 => 0,
        8 => return Some(PfCommand::Brake { channel, output }),
        d @ 1..=7 => d as i8,
        d => d as i8 - 16,
    };
    Some(PfCommand::Pwm {
        channel,
        output,
        step,
    })
}

/// Spawns emulated IR bridges.
pub struct IrBridgeEmulator;

impl IrBridgeEmulator {
    /// Starts a bridge for `cart` (its channel, output and speed step) at `<link_dir>/<name>`.
    /// Needs a tokio runtime.
    pub fn spawn(
        world: Arc<World>,
        cart: &CartSpec,
        link_dir: &Path,
        name: &str,
        faults: Arc<Faults>,
    ) -> std::io::Result<EmulatorHandle> {
        let (fw, stats) = Self::firmware(&world, cart, &faults);
        spawn_firmware(fw, &world, link_dir, name, stats, faults)
    }

    /// A bridge for `cart` on the caller's clock, without a pty (see [`SteppedEmulator`]).
    pub fn stepped(world: Arc<World>, cart: &CartSpec, faults: Arc<Faults>) -> SteppedEmulator {
        let (fw, stats) = Self::firmware(&world, cart, &faults);
        SteppedEmulator::new(fw, &world, stats, faults)
    }

    /// The firmware, with its fresh counters.
    fn firmware(
        world: &Arc<World>,
        cart: &CartSpec,
        faults: &Arc<Faults>,
    ) -> (Bridge, Arc<EmulatorStats>) {
        let stats = Arc::new(EmulatorStats::default());
        let fw = Bridge {
            world: Arc::clone(world),
            channel: cart.ir_channel.saturating_sub(1),
            output: u8::from(cart.ir_output.eq_ignore_ascii_case("B")),
            speed_step: f64::from(cart.ir_speed_step.clamp(1, 7)),
            speed_mm_s: cart.speed_mm_s,
            travel_mm: cart.travel_mm,
            stats: Arc::clone(&stats),
            faults: Arc::clone(faults),
            line: Vec::new(),
            run: None,
        };
        (fw, stats)
    }
}

struct Bridge {
    world: Arc<World>,
    channel: u8,
    output: u8,
    speed_step: f64,
    speed_mm_s: f64,
    travel_mm: f64,
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
    line: Vec<u8>,
    /// Drive in progress: speed factor (signed) and the rig time it reaches its end stop.
    run: Option<(f64, f64)>,
}

impl Bridge {
    fn cart_mm(&self, t: f64) -> f64 {
        self.world.snapshot_at(t).cart_mm
    }

    fn drive(&mut self, factor: f64, t: f64, out: &mut Output) {
        self.world.cart_drive(factor, t);
        self.run = None;
        if factor == 0.0 {
            return;
        }
        let p = self.cart_mm(t);
        let (end, at_end) = if factor > 0.0 {
            (self.travel_mm, p >= self.travel_mm)
        } else {
            (0.0, p <= 0.0)
        };
        if at_end {
            self.end_stop(factor, t, out);
        } else {
            let hit = t + (end - p).abs() / (factor.abs() * self.speed_mm_s).max(1e-9);
            self.run = Some((factor, hit));
        }
    }

    fn end_stop(&mut self, factor: f64, t: f64, out: &mut Output) {
        self.world.cart_drive(0.0, t);
        self.run = None;
        out.send(if factor > 0.0 { "END +\n" } else { "END -\n" });
    }

    fn execute(&mut self, line: &str, t: f64, out: &mut Output) -> String {
        if line == "ver" {
            return VERSION.into();
        }
        let Some(hex) = line.strip_prefix("PF ") else {
            return "ERR syntax".into();
        };
        let word = match u16::from_str_radix(hex, 16) {
            Ok(w) if hex.len() == 4 && hex.bytes().all(|b| b.is_ascii_hexdigit()) => w,
            _ => return "ERR syntax".into(),
        };
        match decode_pf(word) {
            None => format!("ERR checksum {word:04X}"),
            Some(cmd) => {
                match cmd {
                    PfCommand::Pwm {
                        channel,
                        output,
                        step,
                    } if channel == self.channel && output == self.output => {
                        self.drive(f64::from(step) / self.speed_step, t, out);
                    }
                    PfCommand::Brake { channel, output }
                        if channel == self.channel && output == self.output =>
                    {
                        self.drive(0.0, t, out);
                    }
                    _ => {}
                }
                format!("OK {word:04X}")
            }
        }
    }

    fn command(&mut self, t: f64, out: &mut Output) {
        let raw = std::mem::take(&mut self.line);
        let line = String::from_utf8_lossy(&raw).trim().to_string();
        if line.is_empty() {
            return;
        }
        let n = self.stats.count_command();
        // The drive happens before the reply is sent (the bridge transmits, then answers); an
        // end-stop message caused by the command goes after the reply.
        let mut effects = Output::default();
        let reply = self.execute(&line, t, &mut effects);
        if let Some(delay) = self.faults.reply_plan(n, t) {
            out.delay(delay);
            out.send(format!("{reply}\n"));
        }
        for step in effects.steps {
            if let super::Step::Send(b) = step {
                out.send(b);
            }
        }
        for f in self.faults.after_command(n, t) {
            match f {
                Fault::Garbage { bytes, .. } => out.send(bytes),
                Fault::BoardReset { .. } => {
                    self.world.cart_drive(0.0, t);
                    self.run = None;
                }
                Fault::Disconnect { for_s, .. } => out.disconnect(for_s),
                _ => {}
            }
        }
    }
}

impl Firmware for Bridge {
    fn start(&mut self, _t: f64, _out: &mut Output) {}

    fn receive(&mut self, bytes: &[u8], t: f64, out: &mut Output) {
        self.tick(t, out);
        for &b in bytes {
            if out.disconnecting() {
                return;
            }
            if b == b'\n' {
                self.command(t, out);
            } else if self.line.len() < MAX_LINE {
                self.line.push(b);
            }
        }
    }

    fn tick(&mut self, t: f64, out: &mut Output) {
        if let Some((factor, hit)) = self.run
            && hit <= t
        {
            // Stop a hair past the computed instant, so the World clamps the cart exactly onto
            // the switch instead of a rounding error short of it.
            self.end_stop(factor, hit + 1e-6, out);
        }
    }

    fn next_event(&self) -> Option<f64> {
        self.run.map(|(_, hit)| hit)
    }
}
