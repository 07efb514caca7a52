//! Motion: the planner queue, trapezoidal moves written into the World, homing cycles with
//! their limit switches, feed hold, and the spindle output driving the laser.

use super::*;

impl Grbl {
    /// Stops every axis where it is at `t` (steps stop at once).
    pub(super) fn freeze(&mut self, t: f64) {
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
        self.world.settling();
    }

    pub(super) fn lose_position(&self) {
        for i in 0..3 {
            if let Some(id) = self.axis_id(i) {
                self.world.with_axis(id, |a| a.homed = false);
            }
        }
    }

    pub(super) fn set_laser(&mut self, on: bool) {
        if on != self.laser_on {
            self.laser_on = on;
            self.world.set_laser(on, self.world.laser_colour_nm());
        }
    }

    /// The World angle where axis `i`'s homing switch trips (next to the home position).
    pub(super) fn switch_world(&self, i: usize) -> f64 {
        let home_deg = self.axes[i].as_ref().map_or(0.0, |a| a.home_deg);
        let trip = if self.flag(23, i) {
            -self.setting(130 + i as u32)
        } else {
            0.0
        };
        home_deg + self.sign(i) * (trip - self.home_machine(i))
    }

    /// The switch is pressed over 2 units past its trip point, every 360 (a rotary flag).
    pub(super) fn switch_pressed(&self, i: usize, t: f64) -> bool {
        if self.axes[i].is_none() {
            return false;
        }
        let dir = self.seek_dir(i);
        let past = (dir * (self.world_at(i, t) - self.switch_world(i))).rem_euclid(360.0);
        past < 2.0 && self.mode != Mode::Alarm && self.active.is_none()
    }

    /// World direction of the homing seek (toward the switch).
    pub(super) fn seek_dir(&self, i: usize) -> f64 {
        let machine_dir = if self.flag(23, i) { -1.0 } else { 1.0 };
        machine_dir * self.sign(i)
    }

    /// Starts a homing cycle of the axes in `which`: each seeks its switch (a rotary flag,
    /// so it is found within one turn) at `$25`, then locates it at `$24` and pulls off `$27`.
    /// A switch farther than 1.5 × `$13x` fails the cycle with `ALARM:9`.
    pub(super) fn start_homing(&mut self, which: [bool; 3], cmd_no: u64, t: f64) {
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
        self.world.settling();
    }

    /// Starts `block` at rig time `start`.
    pub(super) fn start_block(&mut self, block: Block, start: f64) {
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
        // A render-ahead guesses this move's end; the next block starts a new guess.
        self.world.settling();
    }

    /// Finishes what is due at `t` and starts queued moves, chaining them back to back.
    pub(super) fn advance(&mut self, t: f64, out: &mut Output) {
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

    pub(super) fn next_block(&mut self) -> Option<Block> {
        if self.held || self.mode == Mode::Alarm || self.stuck_home {
            return None;
        }
        self.queue.pop_front()
    }

    /// Ends a move in the World as SimAxis does, with backlash on the load side after a move in
    /// the negative direction.
    pub(super) fn finish_block(&mut self, block: Block) {
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

    pub(super) fn feed_hold(&mut self, t: f64) {
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
