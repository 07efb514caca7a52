//! The line parser and command execution: the RX buffer and its flow control, soft reset,
//! realtime and `$` system commands, G-code words, and the replies (`ok`, `error:N`, `ALARM:N`).

use super::*;

impl Grbl {
    /// Soft reset (0x18) or a power cycle (`power_cycle`: position always lost).
    pub(super) fn reset(&mut self, t: f64, power_cycle: bool, out: &mut Output) {
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

    pub(super) fn reply(&self, cmd_no: u64, text: &str, t: f64, out: &mut Output) {
        if let Some(delay) = self.faults.reply_plan(cmd_no, t) {
            out.delay(delay);
            out.send(format!("{text}\r\n"));
        }
    }

    pub(super) fn after_command(&mut self, cmd_no: u64, t: f64, out: &mut Output) {
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
    pub(super) fn parser_blocked(&self) -> bool {
        self.locked_until_reset
            || self.ok_on_reset.is_some()
            || self.sync.is_some()
            || matches!(self.active, Some(Active::Home { .. }))
            || self.queue.len() >= PLANNER_BLOCKS
    }

    /// Moves bytes from the RX buffer into the line buffer and executes complete lines while
    /// the parser may run (as GRBL's protocol loop does; a blocked loop lets the RX buffer fill).
    pub(super) fn process_lines(&mut self, t: f64, out: &mut Output) {
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
    pub(super) fn execute(
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

    pub(super) fn system_command(
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

    pub(super) fn gcode(&mut self, line: &str, cmd_no: u64) -> Result<Option<String>, u8> {
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
}
