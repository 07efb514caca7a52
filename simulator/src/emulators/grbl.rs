//! A GRBL 1.1h controller, following the real firmware (checked by the conformance suite in
//! `simulator/tests/grbl_conformance.rs` against GRBL 1.1h itself): banner and homing lock,
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

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::sync::Arc;

use stagehand_devices::motion::Trapezoid;
use stagehand_devices::rig::AxisSpec;

use super::{EmulatorHandle, EmulatorStats, Fault, Faults, Firmware, Output, spawn_firmware};
use crate::world::World;

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
        let stats = Arc::new(EmulatorStats::default());
        let mut fw = Grbl::new(
            Arc::clone(&world),
            axes,
            Arc::clone(&stats),
            Arc::clone(&faults),
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
        let now = world.clock().now_s();
        fw.power_on_refs(now);
        spawn_firmware(fw, &world, link_dir, name, stats, faults)
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

    fn setting(&self, k: u32) -> f64 {
        self.settings
            .get(&k)
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0)
    }

    fn flag(&self, k: u32, bit: usize) -> bool {
        (self.setting(k) as u32) & (1 << bit) != 0
    }

    /// `$N=v` as GRBL stores it: error:3 for an unknown setting, error:4 for a negative value.
    fn set_setting(&mut self, k: u32, v: f64) -> Result<(), u8> {
        if !self.settings.contains_key(&k) {
            return Err(3);
        }
        if !v.is_finite() || v < 0.0 {
            return Err(4);
        }
        let text = if INTEGER_SETTINGS.contains(&k) {
            format!("{}", v.trunc() as i64)
        } else {
            format!("{v:.3}")
        };
        self.settings.insert(k, text);
        Ok(())
    }

    /// The machine coordinate an axis rests at after homing (−`$27`, or −`$13x` + `$27`
    /// when `$23` makes it home toward −).
    fn home_machine(&self, i: usize) -> f64 {
        let raw = if self.flag(23, i) {
            -self.setting(130 + i as u32) + self.setting(27)
        } else {
            -self.setting(27)
        };
        (raw * self.steps(i)).round() / self.steps(i)
    }

    /// Stops every axis where it is at `t` (steps stop at once).
    fn freeze(&mut self, t: f64) {
        self.rest = [None; 3];
        for i in 0..3 {
            if let Some(id) = self.axis_id(i) {
                self.world.with_axis(id, |a| {
                    let p = a.motor_at(t);
                    a.moving = None;
                    a.motor_deg = p;
                });
            }
        }
    }

    fn lose_position(&self) {
        for i in 0..3 {
            if let Some(id) = self.axis_id(i) {
                self.world.with_axis(id, |a| a.homed = false);
            }
        }
    }

    fn set_laser(&mut self, on: bool) {
        if on != self.laser_on {
            self.laser_on = on;
            self.world.set_laser(on, self.world.laser_colour_nm());
        }
    }

    /// The spindle output: on after `M3`/`M4`, except in laser mode (`$32=1`), where GRBL
    /// lights it only during G1 motion (never emulated: G0 only).
    fn output_on(&self) -> bool {
        self.spindle_on && !self.flag(32, 0)
    }

    fn status_word(&self) -> &'static str {
        if self.stuck_home || matches!(self.active, Some(Active::Home { .. })) {
            "Home"
        } else if self.mode == Mode::Alarm {
            "Alarm"
        } else if self.held {
            "Hold:0"
        } else if self.active.is_some() || !self.queue.is_empty() {
            "Run"
        } else {
            "Idle"
        }
    }

    /// One status report as `report_realtime_status` prints it, advancing its counters.
    fn status(&mut self, t: f64) -> String {
        let state = self.status_word();
        let busy = !matches!(state, "Idle" | "Alarm");
        let mpos: Vec<f64> = (0..3).map(|i| self.position(i, t)).collect();
        let fmt = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{:.3}", if x.abs() < 0.0005 { 0.0 } else { *x }))
                .collect::<Vec<_>>()
                .join(",")
        };
        let mut line = format!("<{state}|");
        if self.flag(10, 0) {
            line.push_str(&format!("MPos:{}", fmt(&mpos)));
        } else {
            let w: Vec<f64> = (0..3).map(|i| mpos[i] - self.g54[i]).collect();
            line.push_str(&format!("WPos:{}", fmt(&w)));
        }
        let feed = match self.active {
            Some(Active::Move { .. }) => self.feed_at(t),
            _ => 0.0,
        };
        let speed = if self.output_on() {
            self.spindle_s
        } else {
            0.0
        };
        line.push_str(&format!("|FS:{feed:.0},{speed:.0}"));
        let pins: String = (0..3)
            .filter(|&i| self.switch_pressed(i, t))
            .map(|i| LETTERS[i])
            .collect();
        if !pins.is_empty() {
            line.push_str(&format!("|Pn:{pins}"));
        }
        if self.wco_counter > 0 {
            self.wco_counter -= 1;
        } else {
            self.wco_counter = if busy { WCO_BUSY } else { WCO_IDLE } - 1;
            if self.ovr_counter == 0 {
                self.ovr_counter = 1;
            }
            line.push_str(&format!("|WCO:{}", fmt(&self.g54)));
        }
        if self.ovr_counter > 0 {
            self.ovr_counter -= 1;
        } else {
            self.ovr_counter = if busy { OVR_BUSY } else { OVR_IDLE } - 1;
            line.push_str("|Ov:100,100,100");
            if self.output_on() {
                line.push_str("|A:S");
            }
        }
        line.push_str(">\r\n");
        line
    }

    /// Current feed rate of the active move in units per minute (the fastest axis).
    fn feed_at(&self, t: f64) -> f64 {
        (0..3)
            .filter_map(|i| {
                let id = self.axis_id(i)?;
                self.world.with_axis(id, |a| {
                    a.moving.map_or(0.0, |(traj, start)| {
                        let dt = 1e-3;
                        let ds =
                            traj.position_at(t - start + dt) - traj.position_at(t - start - dt);
                        (ds / (2.0 * dt)).abs() * 60.0
                    })
                })
            })
            .fold(0.0, f64::max)
    }

    /// The World angle where axis `i`'s homing switch trips (next to the home position).
    fn switch_world(&self, i: usize) -> f64 {
        let home_deg = self.axes[i].as_ref().map_or(0.0, |a| a.home_deg);
        let trip = if self.flag(23, i) {
            -self.setting(130 + i as u32)
        } else {
            0.0
        };
        home_deg + self.sign(i) * (trip - self.home_machine(i))
    }

    /// The switch is pressed over 2 units past its trip point, every 360 (a rotary flag).
    fn switch_pressed(&self, i: usize, t: f64) -> bool {
        if self.axes[i].is_none() {
            return false;
        }
        let dir = self.seek_dir(i);
        let past = (dir * (self.world_at(i, t) - self.switch_world(i))).rem_euclid(360.0);
        past < 2.0 && self.mode != Mode::Alarm && self.active.is_none()
    }

    /// World direction of the homing seek (toward the switch).
    fn seek_dir(&self, i: usize) -> f64 {
        let machine_dir = if self.flag(23, i) { -1.0 } else { 1.0 };
        machine_dir * self.sign(i)
    }

    /// Soft reset (0x18) or a power cycle (`power_cycle`: position always lost).
    fn reset(&mut self, t: f64, power_cycle: bool, out: &mut Output) {
        let homing = self.stuck_home || matches!(self.active, Some(Active::Home { .. }));
        let alarm = match self.active {
            _ if homing && !power_cycle => Some(6),
            Some(Active::Move { .. }) if !self.held && !power_cycle => Some(3),
            _ => None,
        };
        self.freeze(t);
        if alarm.is_some() || power_cycle {
            self.lose_position();
            self.mode = Mode::Alarm;
        }
        if let Some(code) = alarm {
            out.send(format!("ALARM:{code}\r\n"));
        }
        if let Some(cmd_no) = self.ok_on_reset.take() {
            self.reply(cmd_no, "ok", t, out);
        }
        if power_cycle {
            self.power_on_refs(t);
            self.g54 = [0.0; 3];
        }
        self.stuck_home = false;
        self.status_pending = false;
        self.sync = None;
        // gc_sync_position: the parser starts again from where the axes stand.
        for i in 0..3 {
            self.programmed[i] = self.position(i, t);
        }
        self.wco_counter = 0;
        self.ovr_counter = 0;
        self.active = None;
        self.queue.clear();
        self.rx.clear();
        self.line.clear();
        self.line_overflow = false;
        self.held = false;
        self.locked_until_reset = false;
        self.relative = false;
        self.spindle_on = false;
        self.spindle_s = 0.0;
        self.set_laser(false);
        out.send(BANNER);
        if self.mode == Mode::Alarm {
            out.send(HOMING_LOCK_MSG);
        }
    }

    fn reply(&self, cmd_no: u64, text: &str, t: f64, out: &mut Output) {
        if let Some(delay) = self.faults.reply_plan(cmd_no, t) {
            out.delay(delay);
            out.send(format!("{text}\r\n"));
        }
    }

    fn after_command(&mut self, cmd_no: u64, t: f64, out: &mut Output) {
        for f in self.faults.after_command(cmd_no, t) {
            match f {
                Fault::Garbage { bytes, .. } => out.send(bytes),
                Fault::BoardReset { .. } => self.reset(t, true, out),
                Fault::Disconnect { for_s, .. } => out.disconnect(for_s),
                _ => {}
            }
        }
    }

    /// True while the line parser cannot take another line.
    fn parser_blocked(&self) -> bool {
        self.locked_until_reset
            || self.ok_on_reset.is_some()
            || self.sync.is_some()
            || matches!(self.active, Some(Active::Home { .. }))
            || self.queue.len() >= PLANNER_BLOCKS
    }

    /// Moves bytes from the RX buffer into the line buffer and executes complete lines while
    /// the parser may run (as GRBL's protocol loop does; a blocked loop lets the RX buffer fill).
    fn process_lines(&mut self, t: f64, out: &mut Output) {
        while !self.parser_blocked() && !out.disconnecting() {
            let Some(b) = self.rx.pop_front() else { break };
            if b != b'\n' && b != b'\r' {
                if self.line.len() < MAX_LINE {
                    self.line.push(b);
                } else {
                    self.line_overflow = true;
                }
                continue;
            }
            let line = std::mem::take(&mut self.line);
            let overflowed = std::mem::replace(&mut self.line_overflow, false);
            if !overflowed && line.iter().all(u8::is_ascii_whitespace) {
                // Blank lines (and the \n of a \r\n pair) are not commands.
                continue;
            }
            let cmd_no = self.stats.count_command();
            let result = if overflowed {
                Err(11)
            } else {
                self.execute(&line, cmd_no, t, out)
            };
            match result {
                Ok(Some(reply)) => self.reply(cmd_no, &reply, t, out),
                Ok(None) => {}
                Err(SOFT_LIMIT) => {
                    // limits_soft_check: reset, ALARM:2, then nothing until the user resets;
                    // the line's `ok` comes out with the reset.
                    self.freeze(t);
                    self.mode = Mode::Alarm;
                    self.locked_until_reset = true;
                    self.ok_on_reset = Some(cmd_no);
                    self.spindle_on = false;
                    self.set_laser(false);
                    out.send("ALARM:2\r\n[MSG:Reset to continue]\r\n");
                }
                Err(code) => self.reply(cmd_no, &format!("error:{code}"), t, out),
            }
            self.after_command(cmd_no, t, out);
            self.advance(t, out);
        }
    }

    /// Executes one line; `Ok(None)` when the reply comes later (homing).
    fn execute(
        &mut self,
        raw: &[u8],
        cmd_no: u64,
        t: f64,
        out: &mut Output,
    ) -> Result<Option<String>, u8> {
        let mut line = String::new();
        let mut in_comment = false;
        for &b in raw {
            match b {
                b'(' => in_comment = true,
                b')' => in_comment = false,
                b';' if !in_comment => break,
                _ if in_comment || b.is_ascii_whitespace() => {}
                _ if !b.is_ascii() || b.is_ascii_control() => return Err(1),
                _ => line.push(b.to_ascii_uppercase() as char),
            }
        }
        if line.is_empty() {
            return Ok(Some("ok".into()));
        }
        if let Some(cmd) = line.strip_prefix('$') {
            return self.system_command(cmd, cmd_no, t, out);
        }
        if self.mode == Mode::Alarm && !self.stuck_home {
            return Err(9);
        }
        self.gcode(&line, cmd_no)
    }

    fn system_command(
        &mut self,
        cmd: &str,
        cmd_no: u64,
        t: f64,
        out: &mut Output,
    ) -> Result<Option<String>, u8> {
        match cmd {
            "" => {
                out.send(
                    "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n",
                );
                Ok(Some("ok".into()))
            }
            "$" => {
                for (k, v) in &self.settings {
                    out.send(format!("${k}={v}\r\n"));
                }
                Ok(Some("ok".into()))
            }
            "I" if self.stuck_home => Err(8),
            "I" => {
                let opt = if self.single_axis { "VH" } else { "V" };
                out.send(format!("{VERSION}\r\n[OPT:{opt},15,128]\r\n"));
                Ok(Some("ok".into()))
            }
            "G" => {
                let dist = if self.relative { "G91" } else { "G90" };
                let spindle = if self.spindle_on { "M3" } else { "M5" };
                out.send(format!(
                    "[GC:G0 G54 G17 G21 {dist} G94 {spindle} M9 T0 F0 S{}]\r\n",
                    self.spindle_s
                ));
                Ok(Some("ok".into()))
            }
            "X" => {
                if self.mode == Mode::Alarm && !self.stuck_home {
                    out.send("[MSG:Caution: Unlocked]\r\n");
                    self.mode = Mode::Idle;
                }
                Ok(Some("ok".into()))
            }
            _ if self.stuck_home && !cmd.starts_with('$') => Err(8),
            _ if cmd.starts_with('H') => {
                if self.held || self.active.is_some() || !self.queue.is_empty() {
                    return Err(8);
                }
                if self.setting(22) == 0.0 {
                    return Err(5);
                }
                if cmd != "H" && !self.single_axis {
                    // A stock build: the state machine is already in Home when the parser
                    // refuses the letter, and stays there until a reset.
                    self.stuck_home = true;
                    return Err(3);
                }
                let which = match cmd {
                    "H" => [true; 3],
                    "HX" => [true, false, false],
                    "HY" => [false, true, false],
                    "HZ" => [false, false, true],
                    _ => return Err(3),
                };
                self.start_homing(which, cmd_no, t);
                Ok(None)
            }
            _ => {
                if let Some((k, v)) = cmd.split_once('=')
                    && let Ok(k) = k.parse::<u32>()
                {
                    if self.stuck_home {
                        return Err(8);
                    }
                    let v: f64 = v.parse().map_err(|_| 2u8)?;
                    self.set_setting(k, v)?;
                    return Ok(Some("ok".into()));
                }
                if cmd.starts_with('N') {
                    // Startup blocks are not stored: none are printed after a reset.
                    return Ok(Some("ok".into()));
                }
                // Anything else is read as a setting number: a letter is a bad number.
                if cmd.starts_with(|c: char| c.is_ascii_digit()) {
                    Err(3)
                } else {
                    Err(2)
                }
            }
        }
    }

    /// Starts a homing cycle of the axes in `which`: each seeks its switch (a rotary flag,
    /// so it is found within one turn) at `$25`, then locates it at `$24` and pulls off `$27`.
    /// A switch farther than 1.5 × `$13x` fails the cycle with `ALARM:9`.
    fn start_homing(&mut self, which: [bool; 3], cmd_no: u64, t: f64) {
        let seek = self.setting(25).max(1e-3) / 60.0;
        let locate = self.setting(24).max(1e-3) / 60.0;
        let pull = self.setting(27);
        let mut end_s = t;
        let mut fails = false;
        for (i, &w) in which.iter().enumerate() {
            let (Some(spec), true) = (self.axes[i].clone(), w) else {
                continue;
            };
            self.rest[i] = None;
            let from = self.world_at(i, t);
            let dir = self.seek_dir(i);
            let reach = 1.5 * self.setting(130 + i as u32);
            let d = (dir * (self.switch_world(i) - from)).rem_euclid(360.0);
            let (to, travel) = if d <= reach {
                // Ends back at the home position (the flag found is the home flag).
                (spec.home_deg, d)
            } else {
                fails = true;
                (from + dir * reach, reach)
            };
            let dur = travel / seek + (2.0 + 5.0) * pull / locate;
            end_s = end_s.max(t + dur);
            // Constant speed over the whole cycle (the ramps are negligibly short).
            let peak = (to - from).abs() / dur.max(1e-9);
            let accel = 1e12;
            let ramp_s = peak / accel;
            let traj = Trapezoid {
                from_deg: from,
                to_deg: to,
                peak_deg_s: peak,
                accel_deg_s2: accel,
                ramp_s,
                cruise_s: (dur - 2.0 * ramp_s).max(0.0),
            };
            self.world
                .with_axis(&spec.id, |a| a.moving = Some((traj, t)));
        }
        self.active = Some(Active::Home {
            axes: which,
            end_s,
            cmd_no,
            fails,
        });
    }

    fn gcode(&mut self, line: &str, cmd_no: u64) -> Result<Option<String>, u8> {
        let bytes = line.as_bytes();
        let mut i = 0;
        let mut words: Vec<(char, f64)> = Vec::new();
        while i < bytes.len() {
            let letter = bytes[i] as char;
            if !letter.is_ascii_uppercase() {
                return Err(1);
            }
            i += 1;
            let start = i;
            while i < bytes.len()
                && (bytes[i].is_ascii_digit()
                    || bytes[i] == b'.'
                    || bytes[i] == b'-'
                    || bytes[i] == b'+')
            {
                i += 1;
            }
            let value: f64 = line[start..i].parse().map_err(|_| 2u8)?;
            if !value.is_finite() {
                return Err(2);
            }
            words.push((letter, value));
        }
        let mut relative = self.relative;
        let mut spindle_on = self.spindle_on;
        let mut spindle_s = self.spindle_s;
        let mut targets: [Option<f64>; 3] = [None; 3];
        let mut machine = false;
        let mut set_offset = false;
        let mut dwell = false;
        let mut l_word = None;
        let mut p_word = 0.0;
        for &(letter, value) in &words {
            match letter {
                'G' => match command_number(value) {
                    Some(0 | 1 | 17 | 21 | 54 | 94) => {}
                    Some(53) => machine = true,
                    Some(4) => dwell = true,
                    Some(10) => set_offset = true,
                    Some(90) => relative = false,
                    Some(91) => relative = true,
                    _ => return Err(20),
                },
                'L' => l_word = Some(value),
                'P' if set_offset || dwell => p_word = value,
                'M' => match command_number(value) {
                    Some(3 | 4) => spindle_on = true,
                    Some(5) => spindle_on = false,
                    _ => return Err(20),
                },
                'S' if value >= 0.0 => spindle_s = value,
                'S' => return Err(4),
                'F' | 'N' => {}
                'X' | 'Y' | 'Z' => {
                    let k = LETTERS.iter().position(|l| *l == letter).unwrap_or(0);
                    if targets[k].is_some() {
                        return Err(25);
                    }
                    targets[k] = Some(value);
                }
                _ => return Err(20),
            }
        }
        if dwell {
            self.sync = Some((cmd_no, None));
            self.sync_dwell = p_word.max(0.0);
            return Ok(None);
        }
        if set_offset {
            // `G10 L2 P1 X..`: the G54 offset (the only coordinate system emulated).
            if l_word != Some(2.0) {
                return Err(20);
            }
            for (k, v) in targets.iter().enumerate() {
                if let Some(v) = v {
                    self.g54[k] = *v;
                }
            }
            self.wco_counter = 0;
            return Ok(Some("ok".into()));
        }
        self.relative = relative;
        if spindle_on != self.spindle_on || spindle_s != self.spindle_s {
            // spindle_set_state: the next report carries `Ov:` (and `A:`).
            self.ovr_counter = 0;
        }
        self.spindle_on = spindle_on;
        self.spindle_s = spindle_s;
        let on = self.output_on() && spindle_s > 0.0;
        self.set_laser(on);
        if targets.iter().any(Option::is_some) {
            // Targets are machine coordinates (work + G54, or G53), quantised to the steps;
            // relative moves are taken from the programmed position.
            let mut abs = [None; 3];
            let mut unquantised = [None; 3];
            for k in 0..3 {
                let (Some(v), Some(_)) = (targets[k], &self.axes[k]) else {
                    continue;
                };
                let target = if relative && !machine {
                    self.programmed[k] + v
                } else if machine {
                    v
                } else {
                    self.g54[k] + v
                };
                let steps = self.steps(k);
                abs[k] = Some((target * steps).round() / steps);
                unquantised[k] = Some(target);
            }
            if self.setting(20) != 0.0 {
                let outside = (0..3)
                    .any(|k| abs[k].is_some_and(|m| m > 0.0 || m < -self.setting(130 + k as u32)));
                if outside {
                    return Err(SOFT_LIMIT);
                }
            }
            for (p, u) in self.programmed.iter_mut().zip(unquantised) {
                if let Some(u) = u {
                    *p = u;
                }
            }
            self.moves += 1;
            let mut world = [None; 3];
            for (k, w) in world.iter_mut().enumerate() {
                *w = unquantised[k].map(|m| self.world_of(k, m));
            }
            self.queue.push_back(Block {
                targets: abs,
                world,
                move_no: self.moves,
            });
        }
        Ok(Some("ok".into()))
    }

    /// Starts `block` at rig time `start`.
    fn start_block(&mut self, block: Block, start: f64) {
        let mut end_s = start;
        if self.world.exposing_at(start) {
            self.world.violation(format!(
                "a GRBL axis was commanded to move during an exposure at rig time {start:.3} s"
            ));
        }
        for k in 0..3 {
            let (Some(target), Some(spec)) = (block.targets[k], &self.axes[k]) else {
                continue;
            };
            let from = self.world_at(k, start);
            // The World lands on the rig's microstep grid, exactly as SimAxis does, so frames
            // match the simulated rig's; the board's reports quantise to its own `$10x`.
            let steps = spec.steps_per_deg.max(1e-9);
            self.rest[k] = None;
            let exact = block.world[k].unwrap_or_else(|| self.world_of(k, target));
            let target = (exact * steps).round() / steps;
            if (from - target).abs() < 1e-12 {
                continue;
            }
            let traj = Trapezoid::plan(from, target, spec.kinematics());
            end_s = end_s.max(start + traj.duration_s());
            self.world
                .with_axis(&spec.id, |a| a.moving = Some((traj, start)));
        }
        let alarm = self
            .faults
            .pending()
            .into_iter()
            .find_map(|f| match f {
                Fault::AlarmDuringMove { nth_move, code } if nth_move == block.move_no => {
                    Some(code)
                }
                _ => None,
            })
            .map(|code| (start + (end_s - start) / 2.0, code));
        self.active = Some(Active::Move {
            block,
            end_s,
            alarm,
        });
    }

    /// Finishes what is due at `t` and starts queued moves, chaining them back to back.
    fn advance(&mut self, t: f64, out: &mut Output) {
        loop {
            match self.active {
                Some(Active::Move {
                    alarm: Some((at, code)),
                    block,
                    ..
                }) if at <= t => {
                    let fired = self.faults.take(at, |f| {
                        matches!(f, Fault::AlarmDuringMove { nth_move, .. } if *nth_move == block.move_no)
                    });
                    if fired.is_empty() {
                        // Cancelled meanwhile (the schedule no longer holds it): run on.
                        if let Some(Active::Move { alarm, .. }) = &mut self.active {
                            *alarm = None;
                        }
                        continue;
                    }
                    self.freeze(at);
                    self.lose_position();
                    self.active = None;
                    self.queue.clear();
                    self.held = false;
                    self.mode = Mode::Alarm;
                    self.set_laser(false);
                    out.send(format!("ALARM:{code}\r\n"));
                    if matches!(code, 1 | 2 | 10) {
                        out.send("[MSG:Reset to continue]\r\n");
                        self.locked_until_reset = true;
                    }
                    return;
                }
                Some(Active::Move { block, end_s, .. }) if end_s <= t => {
                    self.finish_block(block);
                    self.active = None;
                    if let Some(next) = self.next_block() {
                        self.start_block(next, end_s);
                    }
                }
                Some(Active::Home {
                    axes,
                    end_s,
                    cmd_no,
                    fails,
                }) if end_s <= t => {
                    if fails {
                        // ALARM:9, then the `$H` line's `ok`, then GRBL resets itself.
                        self.freeze(end_s);
                        self.lose_position();
                        self.active = None;
                        self.status_pending = false;
                        out.send("ALARM:9\r\n");
                        self.reply(cmd_no, "ok", end_s, out);
                        self.mode = Mode::Alarm;
                        self.reset(end_s, false, out);
                        return;
                    }
                    for (k, &homed) in axes.iter().enumerate() {
                        if let (true, Some(spec)) = (homed, self.axes[k].clone()) {
                            self.world.with_axis(&spec.id, |a| {
                                a.moving = None;
                                a.motor_deg = spec.home_deg;
                                a.homed = true;
                                a.backlash_offset_deg = 0.0;
                            });
                            self.refs[k] = (spec.home_deg, self.home_machine(k));
                            self.rest[k] = Some(self.home_machine(k));
                            self.programmed[k] = self.home_machine(k);
                        }
                    }
                    self.active = None;
                    if std::mem::take(&mut self.status_pending) {
                        // The `?` sent during the cycle, answered at its end (still Home).
                        self.active = Some(Active::Home {
                            axes,
                            end_s,
                            cmd_no,
                            fails,
                        });
                        let report = self.status(end_s);
                        self.active = None;
                        out.send(report);
                    }
                    self.mode = Mode::Idle;
                    self.reply(cmd_no, "ok", end_s, out);
                }
                None => match self.next_block() {
                    Some(next) => self.start_block(next, t),
                    None => {
                        // `G4` waits for the planner to empty, then dwells, then answers.
                        if let Some((cmd_no, due)) = self.sync
                            && !self.held
                            && self.queue.is_empty()
                        {
                            let due = due.unwrap_or(t + self.sync_dwell);
                            if due <= t {
                                self.sync = None;
                                self.reply(cmd_no, "ok", due, out);
                                continue;
                            }
                            self.sync = Some((cmd_no, Some(due)));
                        }
                        return;
                    }
                },
                _ => return,
            }
        }
    }

    fn next_block(&mut self) -> Option<Block> {
        if self.held || self.mode == Mode::Alarm || self.stuck_home {
            return None;
        }
        self.queue.pop_front()
    }

    /// Ends a move in the World as SimAxis does, with backlash on the load side after a move in
    /// the negative direction.
    fn finish_block(&mut self, block: Block) {
        for k in 0..3 {
            let (Some(m), Some(spec)) = (block.targets[k], &self.axes[k]) else {
                continue;
            };
            self.rest[k] = Some(m);
            let backlash = spec.backlash_deg;
            self.world.with_axis(&spec.id, |a| {
                if let Some((traj, _)) = a.moving.take() {
                    a.motor_deg = traj.to_deg;
                    if traj.to_deg < traj.from_deg {
                        a.backlash_offset_deg = backlash;
                    } else if traj.to_deg > traj.from_deg {
                        a.backlash_offset_deg = 0.0;
                    }
                }
            });
        }
    }

    fn feed_hold(&mut self, t: f64) {
        if self.mode == Mode::Alarm || matches!(self.active, Some(Active::Home { .. })) {
            return;
        }
        if let Some(Active::Move { block, .. }) = self.active {
            // Stop where we are; the rest of the block runs again on resume.
            self.freeze(t);
            self.active = None;
            self.queue.push_front(block);
        }
        self.held = true;
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
