//! Status reports: the state word, machine position, feed and spindle (`FS:`), and the
//! optional fields on their counters (`WCO:`, `Ov:`, `A:S`, `Pn:`).

use super::*;

impl Grbl {
    /// The spindle output: on after `M3`/`M4`, except in laser mode (`$32=1`), where GRBL
    /// lights it only during G1 motion (never emulated: G0 only).
    pub(super) fn output_on(&self) -> bool {
        self.spindle_on && !self.flag(32, 0)
    }

    pub(super) fn status_word(&self) -> &'static str {
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
    pub(super) fn status(&mut self, t: f64) -> String {
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
    pub(super) fn feed_at(&self, t: f64) -> f64 {
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
}
