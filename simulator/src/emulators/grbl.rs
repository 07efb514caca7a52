//! A GRBL 1.1h controller: banner, homing lock, status reports, feed hold/resume, soft reset,
//! homing, `$$` settings, absolute/relative G0 moves through a planner queue, the laser on the
//! spindle output, a 127-byte receive buffer and a laser watchdog. Moves are planned with the
//! axes' kinematics and written into the World exactly as `SimAxis` does, so cameras see the
//! motion and the motion interlock sees moves during exposures.

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
/// No byte for this long switches the laser off (safety lease).
pub const WATCHDOG_S: f64 = 3.0;
/// Blocks the planner holds; a full planner stops the line parser.
const PLANNER_BLOCKS: usize = 15;
/// Longest line GRBL accepts (LINE_BUFFER_SIZE 80 minus the terminator).
const MAX_LINE: usize = 79;
const LETTERS: [char; 3] = ['X', 'Y', 'Z'];

/// The integer of a G or M word (`G90`), or `None` for a fractional one (`G38.2`).
fn command_number(value: f64) -> Option<u32> {
    (value.fract() == 0.0 && (0.0..1000.0).contains(&value)).then_some(value as u32)
}

/// A running GRBL emulator; see [`EmulatorHandle`] for the path and counters.
pub struct GrblEmulator;

impl GrblEmulator {
    /// Starts a controller for `axes` (each with `controller_axis` `X`, `Y` or `Z`; an axis
    /// without a letter takes the next free one) at `<link_dir>/<name>`. Needs a tokio runtime.
    pub fn spawn(
        world: Arc<World>,
        axes: &[AxisSpec],
        link_dir: &Path,
        name: &str,
        faults: Arc<Faults>,
    ) -> std::io::Result<EmulatorHandle> {
        let stats = Arc::new(EmulatorStats::default());
        let fw = Grbl::new(
            Arc::clone(&world),
            axes,
            Arc::clone(&stats),
            Arc::clone(&faults),
        )?;
        spawn_firmware(fw, &world, link_dir, name, stats, faults)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Idle,
    Alarm,
}

/// A queued move: absolute targets per controller axis (None = that axis stays).
#[derive(Debug, Clone, Copy)]
struct Block {
    targets: [Option<f64>; 3],
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
    },
}

struct Grbl {
    world: Arc<World>,
    axes: [Option<AxisSpec>; 3],
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
    mode: Mode,
    held: bool,
    /// A critical alarm (1, 2) locks everything out until a soft reset.
    locked_until_reset: bool,
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
    last_byte_s: f64,
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
        for (k, v) in [(20, "0"), (21, "0"), (22, "1"), (23, "0"), (24, "25.000")] {
            settings.insert(k, v.to_string());
        }
        for (k, v) in [
            (25, "500.000"),
            (26, "250"),
            (27, "1.000"),
            (30, "1000"),
            (31, "0"),
            (32, "1"),
        ] {
            settings.insert(k, v.to_string());
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
            locked_until_reset: false,
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
            last_byte_s: 0.0,
            settings,
        })
    }

    fn axis_id(&self, i: usize) -> Option<&str> {
        self.axes[i].as_ref().map(|a| a.id.as_str())
    }

    /// Motor position of controller axis `i` at `t` (0 for an axis not configured).
    fn position(&self, i: usize, t: f64) -> f64 {
        self.axis_id(i)
            .and_then(|id| self.world.with_axis(id, |a| a.motor_at(t)))
            .unwrap_or(0.0)
    }

    /// Stops every axis where it is at `t` (steps stop at once).
    fn freeze(&self, t: f64) {
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

    fn status(&self, t: f64) -> String {
        let state = if self.mode == Mode::Alarm {
            "Alarm"
        } else if matches!(self.active, Some(Active::Home { .. })) {
            "Home"
        } else if self.held {
            "Hold:0"
        } else if self.active.is_some() || !self.queue.is_empty() {
            "Run"
        } else {
            "Idle"
        };
        let p: Vec<String> = (0..3)
            .map(|i| format!("{:.3}", self.position(i, t)))
            .collect();
        format!("<{state}|MPos:{}|FS:0,0>\r\n", p.join(","))
    }

    /// Soft reset (0x18) or a power cycle (`power_cycle`: position always lost).
    fn reset(&mut self, t: f64, power_cycle: bool, out: &mut Output) {
        let alarm = match self.active {
            Some(Active::Home { .. }) if !power_cycle => Some(6),
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
        if self.mode == Mode::Alarm {
            return Err(9);
        }
        self.gcode(&line, t)
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
            "I" => {
                out.send("[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\n");
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
                if self.mode == Mode::Alarm {
                    out.send("[MSG:Caution: Unlocked]\r\n");
                    self.mode = Mode::Idle;
                }
                Ok(Some("ok".into()))
            }
            "H" | "HX" | "HY" | "HZ" => {
                if self.held || self.active.is_some() || !self.queue.is_empty() {
                    return Err(8);
                }
                let mut which = [false; 3];
                for (i, w) in which.iter_mut().enumerate() {
                    *w = self.axes[i].is_some()
                        && (cmd == "H" || cmd[1..] == *LETTERS[i].to_string());
                }
                self.start_homing(which, cmd_no, t);
                Ok(None)
            }
            _ => {
                if let Some((k, v)) = cmd.split_once('=')
                    && let Ok(k) = k.parse::<u32>()
                {
                    if !self.settings.contains_key(&k) {
                        return Err(3);
                    }
                    let v: f64 = v.parse().map_err(|_| 2u8)?;
                    if v < 0.0 {
                        return Err(4);
                    }
                    let text = if v.fract() == 0.0 && k < 100 {
                        format!("{}", v as i64)
                    } else {
                        format!("{v:.3}")
                    };
                    self.settings.insert(k, text);
                    return Ok(Some("ok".into()));
                }
                Err(3)
            }
        }
    }

    fn start_homing(&mut self, which: [bool; 3], cmd_no: u64, t: f64) {
        let mut end_s = t;
        for (i, &w) in which.iter().enumerate() {
            let (Some(spec), true) = (&self.axes[i], w) else {
                continue;
            };
            let from = self.position(i, t);
            // Homing runs at constant speed toward the switch at 0°, as SimAxis homes.
            let speed = spec.homing_speed_deg_s.max(1e-9);
            let traj = Trapezoid {
                from_deg: from,
                to_deg: 0.0,
                peak_deg_s: speed,
                accel_deg_s2: f64::INFINITY,
                ramp_s: 0.0,
                cruise_s: from.abs() / speed,
            };
            end_s = end_s.max(t + traj.duration_s());
            self.world
                .with_axis(&spec.id, |a| a.moving = Some((traj, t)));
        }
        self.active = Some(Active::Home {
            axes: which,
            end_s,
            cmd_no,
        });
    }

    fn gcode(&mut self, line: &str, t: f64) -> Result<Option<String>, u8> {
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
        for &(letter, value) in &words {
            match letter {
                'G' => match command_number(value) {
                    Some(0 | 1 | 17 | 21 | 54 | 94) => {}
                    Some(90) => relative = false,
                    Some(91) => relative = true,
                    _ => return Err(20),
                },
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
        self.relative = relative;
        self.spindle_on = spindle_on;
        self.spindle_s = spindle_s;
        let on = spindle_on && spindle_s > 0.0;
        self.set_laser(on);
        if targets.iter().any(Option::is_some) {
            // Targets are absolute, quantised to the steps; relative moves are taken from the
            // end of the last queued block.
            let mut abs = [None; 3];
            for k in 0..3 {
                let (Some(v), Some(spec)) = (targets[k], &self.axes[k]) else {
                    continue;
                };
                let base = if relative {
                    self.planned_end(k, t)
                } else {
                    0.0
                };
                abs[k] = Some(((base + v) * spec.steps_per_deg).round() / spec.steps_per_deg);
            }
            self.moves += 1;
            self.queue.push_back(Block {
                targets: abs,
                move_no: self.moves,
            });
        }
        Ok(Some("ok".into()))
    }

    /// Where axis `k` will be once every queued block has run.
    fn planned_end(&self, k: usize, t: f64) -> f64 {
        let active = match self.active {
            Some(Active::Move { block, .. }) => block.targets[k],
            _ => None,
        };
        self.queue
            .iter()
            .rev()
            .find_map(|b| b.targets[k])
            .or(active)
            .unwrap_or_else(|| self.position(k, t))
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
            let from = self.position(k, start);
            if from == target {
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
                }) if end_s <= t => {
                    for (k, &homed) in axes.iter().enumerate() {
                        if let (true, Some(id)) = (homed, self.axis_id(k)) {
                            self.world.with_axis(id, |a| {
                                a.moving = None;
                                a.motor_deg = 0.0;
                                a.homed = true;
                                a.backlash_offset_deg = 0.0;
                            });
                        }
                    }
                    self.active = None;
                    self.mode = Mode::Idle;
                    self.reply(cmd_no, "ok", end_s, out);
                }
                None => match self.next_block() {
                    Some(next) => self.start_block(next, t),
                    None => return,
                },
                _ => return,
            }
        }
    }

    fn next_block(&mut self) -> Option<Block> {
        if self.held || self.mode == Mode::Alarm {
            return None;
        }
        self.queue.pop_front()
    }

    /// Ends a move in the World as SimAxis does, with backlash on the load side after a move in
    /// the negative direction.
    fn finish_block(&self, block: Block) {
        for k in 0..3 {
            let (Some(_), Some(spec)) = (block.targets[k], &self.axes[k]) else {
                continue;
            };
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
        self.last_byte_s = t;
        out.send(BANNER);
        out.send(HOMING_LOCK_MSG);
        self.after_command(0, t, out);
    }

    fn receive(&mut self, bytes: &[u8], t: f64, out: &mut Output) {
        self.last_byte_s = t;
        self.advance(t, out);
        for &b in bytes {
            if out.disconnecting() {
                return;
            }
            match b {
                b'?' => out.send(self.status(t)),
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
        if self.laser_on && t - self.last_byte_s >= WATCHDOG_S {
            self.spindle_on = false;
            self.set_laser(false);
        }
    }

    fn next_event(&self) -> Option<f64> {
        let motion = match self.active {
            Some(Active::Move { end_s, alarm, .. }) => {
                Some(alarm.map_or(end_s, |(at, _)| at.min(end_s)))
            }
            Some(Active::Home { end_s, .. }) => Some(end_s),
            None => None,
        };
        let watchdog = self.laser_on.then_some(self.last_byte_s + WATCHDOG_S);
        match (motion, watchdog) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
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
