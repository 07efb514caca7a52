//! A GRBL 1.1h controller, following the real firmware (checked by the conformance suite in
//! `simulator/tests/integration/grbl_conformance.rs` against GRBL 1.1h itself): banner and homing lock,
//! `$I` build info for a stock build (`$H` only; `$HX` answers `error:3` and leaves it stuck
//! in Home) or one with single-axis homing, `$$` settings, status reports with the real
//! optional fields (`WCO:`, `Ov:`, `A:S`, `FS:`, `Pn:` on their counters), silence during
//! homing, negative machine space after homing (−`$27`), soft limits (`ALARM:2`, then nothing
//! but a reset), work offsets (`G10 L2`, `G54`) and `G53`, feed hold/resume, soft reset, the
//! spindle output (off in laser mode `$32=1` without G1 motion) and no watchdog, as GRBL has
//! none. Moves are planned with the axes' kinematics and written into the World exactly as
//! `SimAxis` does, through the rig file's `home_deg`/`machine_sign` map from machine
//! coordinates to degrees, so cameras see the motion and the motion interlock sees moves
//! during exposures.
//!
//! This file holds the board (`Grbl`: its state, axes and the map to World degrees) and its
//! `Firmware` face; `settings` the `$$` table, `parser` the RX buffer, lines and commands,
//! `motion` the planner, moves, homing and feed hold, and `report` the status reports. The
//! pty it speaks on is the emulators' shared port loop (`emulators::spawn_firmware`).

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::sync::Arc;

use stagehand_devices::motion::Trapezoid;
use stagehand_devices::rig::AxisSpec;

use super::{
    EmulatorHandle, EmulatorStats, Fault, Faults, Firmware, Output, SteppedEmulator, spawn_firmware,
};
use crate::world::World;

mod motion;
mod parser;
mod report;
mod settings;

/// The banner printed at power-on and after a soft reset.
pub const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";
/// Printed after the banner while homing is required.
pub const HOMING_LOCK_MSG: &str = "[MSG:'$H'|'$X' to unlock]\r\n";
/// Usable bytes of GRBL's serial receive buffer.
pub const RX_BUFFER: usize = 127;
/// `$I` version line of GRBL 1.1h.
pub const VERSION: &str = "[VER:1.1h.20190830:]";
/// Status report refresh counts of `config.h` (reports between `Ov:` and `WCO:` fields).
const OVR_BUSY: u32 = 20;
const OVR_IDLE: u32 = 10;
const WCO_BUSY: u32 = 30;
const WCO_IDLE: u32 = 10;
/// Settings printed as integers (the rest with 3 decimals).
const INTEGER_SETTINGS: [u32; 17] = [0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32];
/// Blocks the planner holds; a full planner stops the line parser.
const PLANNER_BLOCKS: usize = 15;
/// Longest line GRBL accepts (LINE_BUFFER_SIZE 80 minus the terminator).
const MAX_LINE: usize = 79;
const LETTERS: [char; 3] = ['X', 'Y', 'Z'];

/// Pseudo status code: the line hit the soft limits (`ALARM:2`, its `ok` held until reset).
const SOFT_LIMIT: u8 = 255;

/// The integer of a G or M word (`G90`), or `None` for a fractional one (`G38.2`).
fn command_number(value: f64) -> Option<u32> {
    (value.fract() == 0.0 && (0.0..1000.0).contains(&value)).then_some(value as u32)
}

/// A running GRBL emulator; see [`EmulatorHandle`] for the path and counters.
pub struct GrblEmulator;

/// How the emulated board was built and set up.
#[derive(Debug, Clone, Default)]
pub struct GrblBuild {
    /// Built with `HOMING_SINGLE_AXIS_COMMANDS` (`$HX`); otherwise a stock build (`$H` only).
    pub single_axis_homing: bool,
    /// Settings written after the rig-derived defaults (`$N`, value), as a lab would send.
    pub settings: Vec<(u32, f64)>,
}

impl GrblEmulator {
    /// Starts a stock controller for `axes` (each with `controller_axis` `X`, `Y` or `Z`; an
    /// axis without a letter takes the next free one) at `<link_dir>/<name>`, set up for the
    /// rig (`$10x`, rates, travel, `$22=1`, `$32=0`). Needs a tokio runtime.
    pub fn spawn(
        world: Arc<World>,
        axes: &[AxisSpec],
        link_dir: &Path,
        name: &str,
        faults: Arc<Faults>,
    ) -> std::io::Result<EmulatorHandle> {
        Self::spawn_with(world, axes, link_dir, name, faults, GrblBuild::default())
    }

    /// Like [`GrblEmulator::spawn`] for the board `build`.
    pub fn spawn_with(
        world: Arc<World>,
        axes: &[AxisSpec],
        link_dir: &Path,
        name: &str,
        faults: Arc<Faults>,
        build: GrblBuild,
    ) -> std::io::Result<EmulatorHandle> {
        let (fw, stats) = Self::board(&world, axes, &faults, build)?;
        spawn_firmware(fw, &world, link_dir, name, stats, faults)
    }

    /// The board `build` for `axes` on the caller's clock, without a pty (see
    /// [`SteppedEmulator`]).
    pub fn stepped(
        world: Arc<World>,
        axes: &[AxisSpec],
        faults: Arc<Faults>,
        build: GrblBuild,
    ) -> std::io::Result<SteppedEmulator> {
        let (fw, stats) = Self::board(&world, axes, &faults, build)?;
        Ok(SteppedEmulator::new(fw, &world, stats, faults))
    }

    /// The firmware of the board `build`, set up and powered on at the World's rig time.
    fn board(
        world: &Arc<World>,
        axes: &[AxisSpec],
        faults: &Arc<Faults>,
        build: GrblBuild,
    ) -> std::io::Result<(Grbl, Arc<EmulatorStats>)> {
        let stats = Arc::new(EmulatorStats::default());
        let mut fw = Grbl::new(
            Arc::clone(world),
            axes,
            Arc::clone(&stats),
            Arc::clone(faults),
        )?;
        fw.single_axis = build.single_axis_homing;
        for (k, v) in build.settings {
            fw.set_setting(k, v).map_err(|code| {
                std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    format!("setting ${k}={v} refused with error:{code}"),
                )
            })?;
        }
        fw.power_on_refs(world.clock().now_s());
        Ok((fw, stats))
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Idle,
    Alarm,
}

/// A queued move: absolute machine targets per controller axis (None = that axis stays).
#[derive(Debug, Clone, Copy)]
struct Block {
    targets: [Option<f64>; 3],
    /// The World angles the targets stand for, before GRBL's step quantisation.
    world: [Option<f64>; 3],
    move_no: u64,
}

#[derive(Debug, Clone, Copy)]
enum Active {
    Move {
        block: Block,
        end_s: f64,
        /// Rig time of a scheduled alarm (fault injection) and its code.
        alarm: Option<(f64, u8)>,
    },
    Home {
        axes: [bool; 3],
        end_s: f64,
        /// Command number of the `$H` line, answered when homing ends.
        cmd_no: u64,
        /// The switch of some axis is out of reach: the cycle ends in `ALARM:9`.
        fails: bool,
    },
}

struct Grbl {
    world: Arc<World>,
    axes: [Option<AxisSpec>; 3],
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
    mode: Mode,
    held: bool,
    /// Built with single-axis homing (`$HX`).
    single_axis: bool,
    /// A stock build given `$HX`: error:3 and the state machine left in Home until a reset.
    stuck_home: bool,
    /// A critical alarm (1, 2) locks everything out, status reports too, until a soft reset.
    locked_until_reset: bool,
    /// The `ok` of the line that raised a critical alarm, printed when the reset comes.
    ok_on_reset: Option<u64>,
    /// `?` received during a homing cycle: one report is printed when the cycle ends.
    status_pending: bool,
    /// Per axis, a World angle and the machine coordinate it had then (power-on: 0; after
    /// homing: the home position), so machine = m + sign × (angle − w).
    refs: [(f64, f64); 3],
    /// `G54` work offset (`G10 L2 P1`).
    g54: [f64; 3],
    /// Machine position of each axis at rest after a move or homing, in GRBL's own steps
    /// (the World may sit on the rig's microstep grid a fraction of a step away).
    rest: [Option<f64>; 3],
    /// The parser's programmed position in machine coordinates (unquantised, as GRBL keeps
    /// `gc_state.position`): the base of relative moves.
    programmed: [f64; 3],
    /// A `G4` dwell waiting for the planner to empty: its command number and, once the
    /// planner is empty, when it answers.
    sync: Option<(u64, Option<f64>)>,
    sync_dwell: f64,
    wco_counter: u32,
    ovr_counter: u32,
    active: Option<Active>,
    queue: VecDeque<Block>,
    /// Received line bytes not yet taken by the parser (the serial RX buffer).
    rx: VecDeque<u8>,
    /// The line being assembled by the parser, and whether it grew too long.
    line: Vec<u8>,
    line_overflow: bool,
    relative: bool,
    spindle_on: bool,
    spindle_s: f64,
    laser_on: bool,
    moves: u64,
    settings: BTreeMap<u32, String>,
}

impl Grbl {
    fn new(
        world: Arc<World>,
        axes: &[AxisSpec],
        stats: Arc<EmulatorStats>,
        faults: Arc<Faults>,
    ) -> std::io::Result<Self> {
        let mut slots: [Option<AxisSpec>; 3] = [None, None, None];
        let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
        for a in axes.iter().filter(|a| a.controller_axis.is_some()) {
            let letter = a.controller_axis.as_deref().unwrap_or_default();
            let i = LETTERS
                .iter()
                .position(|l| letter.eq_ignore_ascii_case(&l.to_string()))
                .ok_or_else(|| {
                    invalid(format!(
                        "axis `{}`: controller_axis `{letter}` is not X, Y or Z",
                        a.id
                    ))
                })?;
            if slots[i].is_some() {
                return Err(invalid(format!("two axes on controller axis {letter}")));
            }
            slots[i] = Some(a.clone());
        }
        for a in axes.iter().filter(|a| a.controller_axis.is_none()) {
            let i = slots
                .iter()
                .position(Option::is_none)
                .ok_or_else(|| invalid(format!("axis `{}`: no free controller axis", a.id)))?;
            slots[i] = Some(a.clone());
        }
        let mut settings = BTreeMap::new();
        for (k, v) in [
            (0, "10"),
            (1, "25"),
            (2, "0"),
            (3, "0"),
            (4, "0"),
            (5, "0"),
            (6, "0"),
        ] {
            settings.insert(k, v.to_string());
        }
        for (k, v) in [(10, "1"), (11, "0.010"), (12, "0.002"), (13, "0")] {
            settings.insert(k, v.to_string());
        }
        // Homing on, as a rig needs (stock GRBL ships with `$22=0`), seeking at the fastest
        // axis's homing speed and locating at a quarter of it; laser mode off.
        let seek = axes
            .iter()
            .map(|a| a.homing_speed_deg_s * 60.0)
            .fold(500.0, f64::max);
        for (k, v) in [
            (20, "0".to_string()),
            (21, "0".into()),
            (22, "1".into()),
            (23, "0".into()),
            (24, format!("{:.3}", seek / 4.0)),
            (25, format!("{seek:.3}")),
            (26, "250".into()),
            (27, "1.000".into()),
            (30, "1000".into()),
            (31, "0".into()),
            (32, "0".into()),
        ] {
            settings.insert(k, v);
        }
        for (i, slot) in slots.iter().enumerate() {
            let i = i as u32;
            let (steps, rate, accel, travel) = match slot {
                Some(a) => (
                    a.steps_per_deg,
                    a.speed_deg_s * 60.0,
                    a.accel_deg_s2,
                    a.max_deg - a.min_deg,
                ),
                None => (250.0, 500.0, 10.0, 200.0),
            };
            // Room for the rig range and for a seek round the rotary flag (1.5 × travel).
            let travel = match slot {
                Some(_) => travel.max(360.0),
                None => travel,
            };
            settings.insert(100 + i, format!("{steps:.3}"));
            settings.insert(110 + i, format!("{rate:.3}"));
            settings.insert(120 + i, format!("{accel:.3}"));
            settings.insert(130 + i, format!("{travel:.3}"));
        }
        Ok(Self {
            world,
            axes: slots,
            stats,
            faults,
            mode: Mode::Alarm,
            held: false,
            single_axis: false,
            stuck_home: false,
            locked_until_reset: false,
            ok_on_reset: None,
            status_pending: false,
            refs: [(0.0, 0.0); 3],
            g54: [0.0; 3],
            rest: [None; 3],
            programmed: [0.0; 3],
            sync: None,
            sync_dwell: 0.0,
            wco_counter: 0,
            ovr_counter: 0,
            active: None,
            queue: VecDeque::new(),
            rx: VecDeque::new(),
            line: Vec::new(),
            line_overflow: false,
            relative: false,
            spindle_on: false,
            spindle_s: 0.0,
            laser_on: false,
            moves: 0,
            settings,
        })
    }

    fn axis_id(&self, i: usize) -> Option<&str> {
        self.axes[i].as_ref().map(|a| a.id.as_str())
    }

    /// Motor angle in the World of controller axis `i` at `t` (0 for an axis not configured).
    fn world_at(&self, i: usize, t: f64) -> f64 {
        self.axis_id(i)
            .and_then(|id| self.world.with_axis(id, |a| a.motor_at(t)))
            .unwrap_or(0.0)
    }

    fn sign(&self, i: usize) -> f64 {
        match &self.axes[i] {
            Some(a) if a.machine_sign < 0.0 => -1.0,
            _ => 1.0,
        }
    }

    fn steps(&self, i: usize) -> f64 {
        self.setting(100 + i as u32).max(1e-9)
    }

    /// Machine position of axis `i` at `t`, quantised to its steps as GRBL counts them.
    fn position(&self, i: usize, t: f64) -> f64 {
        if let Some(m) = self.rest[i] {
            return m;
        }
        let (w, m) = self.refs[i];
        let raw = m + self.sign(i) * (self.world_at(i, t) - w);
        (raw * self.steps(i)).round() / self.steps(i)
    }

    /// The World angle of machine coordinate `m` on axis `i`.
    fn world_of(&self, i: usize, m: f64) -> f64 {
        let (w, m0) = self.refs[i];
        w + self.sign(i) * (m - m0)
    }

    /// Power-on: every axis reads machine 0 where it stands.
    fn power_on_refs(&mut self, t: f64) {
        self.rest = [None; 3];
        for i in 0..3 {
            self.refs[i] = (self.world_at(i, t), 0.0);
        }
    }
}

impl Firmware for Grbl {
    fn start(&mut self, t: f64, out: &mut Output) {
        out.send(BANNER);
        out.send(HOMING_LOCK_MSG);
        self.after_command(0, t, out);
    }

    fn receive(&mut self, bytes: &[u8], t: f64, out: &mut Output) {
        self.advance(t, out);
        for &b in bytes {
            if out.disconnecting() {
                return;
            }
            match b {
                // Nothing is answered during a homing cycle or a critical alarm.
                b'?' if matches!(self.active, Some(Active::Home { .. })) => {
                    self.status_pending = true
                }
                b'?' if self.locked_until_reset => {}
                b'?' => {
                    let report = self.status(t);
                    out.send(report);
                }
                b'!' => self.feed_hold(t),
                b'~' => {
                    if self.held {
                        self.held = false;
                        self.advance(t, out);
                    }
                }
                0x18 => self.reset(t, false, out),
                0x80..=0xff => {} // extended real-time commands: not emulated
                _ => {
                    if self.rx.len() >= RX_BUFFER {
                        self.stats.count_overflow();
                    } else {
                        self.rx.push_back(b);
                    }
                    self.process_lines(t, out);
                }
            }
        }
    }

    fn tick(&mut self, t: f64, out: &mut Output) {
        self.advance(t, out);
        self.process_lines(t, out);
    }

    fn next_event(&self) -> Option<f64> {
        match self.active {
            Some(Active::Move { end_s, alarm, .. }) => {
                Some(alarm.map_or(end_s, |(at, _)| at.min(end_s)))
            }
            Some(Active::Home { end_s, .. }) => Some(end_s),
            None => self.sync.and_then(|(_, due)| due),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use stagehand_devices::clock::RigClock;
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};

    fn grbl() -> Grbl {
        let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
        let axes = rig.axes.clone();
        let world = World::new(Arc::new(rig), RigClock::starting_at(0.0), 1).expect("world");
        Grbl::new(world, &axes, Arc::default(), Faults::none()).expect("grbl")
    }

    fn sent(out: Output) -> String {
        out.steps
            .into_iter()
            .filter_map(|s| match s {
                super::super::Step::Send(b) => Some(String::from_utf8_lossy(&b).into_owned()),
                _ => None,
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any bytes: no panic, never more replies than lines, and the status report still works.
        #[test]
        fn arbitrary_bytes_never_break_the_parser(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let mut g = grbl();
            let mut out = Output::default();
            g.receive(&bytes, 0.0, &mut out);
            g.tick(10.0, &mut out);
            let text = sent(out);
            let lines = bytes.iter().filter(|b| **b == b'\n' || **b == b'\r').count();
            let replies = text.matches("ok\r\n").count() + text.matches("error:").count();
            prop_assert!(replies <= lines);
            let mut out = Output::default();
            g.receive(b"?", 10.0, &mut out);
            prop_assert!(sent(out).contains("|MPos:"));
        }
    }
}
