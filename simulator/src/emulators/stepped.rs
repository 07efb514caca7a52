//! An emulator driven with explicit rig time instead of a pty and a task: the test (or any
//! caller) hands it bytes and moves its clock with [`SteppedEmulator::advance_to`], so what the
//! firmware did to the World can be checked at exact simulated instants, never after a
//! wall-clock wait. The firmware is the same [`Firmware`] the port loop in `mod.rs` runs; only
//! the wire is replaced: what the firmware says is timestamped (a slow reply later, bytes said
//! while unplugged lost) and read with [`SteppedEmulator::read`].

use std::collections::VecDeque;
use std::sync::Arc;

use super::{EmulatorStats, Faults, Firmware, Output, Step};
use crate::world::World;

/// One emulator's firmware on the caller's clock. Made by each emulator's `stepped`
/// constructor (e.g. [`super::GrblEmulator::stepped`]).
pub struct SteppedEmulator {
    fw: Box<dyn Firmware>,
    now: f64,
    /// What the firmware said, with the rig time it reaches the wire, oldest first.
    said: VecDeque<(f64, Vec<u8>)>,
    /// The port is unplugged until this rig time (a `Disconnect` fault).
    unplugged_until: f64,
    stats: Arc<EmulatorStats>,
    faults: Arc<Faults>,
}

impl SteppedEmulator {
    /// Powers `fw` on at the World's current rig time, after applying the World-side faults.
    pub(crate) fn new(
        fw: impl Firmware,
        world: &World,
        stats: Arc<EmulatorStats>,
        faults: Arc<Faults>,
    ) -> Self {
        faults.apply_to_world(world);
        let now = world.clock().now_s();
        let mut em = SteppedEmulator {
            fw: Box::new(fw),
            now,
            said: VecDeque::new(),
            unplugged_until: f64::NEG_INFINITY,
            stats,
            faults,
        };
        let mut out = Output::default();
        em.fw.start(now, &mut out);
        em.carry_out(out);
        em
    }

    /// The emulator's rig time, s.
    pub fn now(&self) -> f64 {
        self.now
    }

    /// Bytes from the host, received at [`Self::now`].
    pub fn send(&mut self, bytes: &[u8]) {
        let mut out = Output::default();
        self.fw.receive(bytes, self.now, &mut out);
        self.carry_out(out);
    }

    /// Moves the clock to rig time `t` (never back), letting the firmware do everything due
    /// on the way at the instant it is due.
    pub fn advance_to(&mut self, t: f64) {
        loop {
            let mut out = Output::default();
            self.fw.tick(self.now, &mut out);
            self.carry_out(out);
            match self.fw.next_event() {
                Some(e) if e > self.now && e <= t => self.now = e,
                _ => break,
            }
        }
        if t > self.now {
            self.now = t;
            let mut out = Output::default();
            self.fw.tick(t, &mut out);
            self.carry_out(out);
        }
    }

    /// Moves the clock on by `dt` seconds ([`Self::advance_to`]).
    pub fn advance(&mut self, dt: f64) {
        self.advance_to(self.now + dt);
    }

    /// Rig time of the next thing the firmware will do by itself, if any.
    pub fn next_event(&self) -> Option<f64> {
        self.fw.next_event()
    }

    /// Rig time at which the oldest unread output reaches the wire, if any.
    pub fn next_output(&self) -> Option<f64> {
        self.said.front().map(|(t, _)| *t)
    }

    /// Everything said up to [`Self::now`] and not yet read, as text (lossy UTF-8).
    pub fn read(&mut self) -> String {
        let mut bytes = Vec::new();
        while let Some((t, _)) = self.said.front() {
            if *t > self.now {
                break;
            }
            if let Some((_, b)) = self.said.pop_front() {
                bytes.extend_from_slice(&b);
            }
        }
        String::from_utf8_lossy(&bytes).into_owned()
    }

    /// True while an injected disconnect has the port unplugged.
    pub fn unplugged(&self) -> bool {
        self.now < self.unplugged_until
    }

    /// The emulator's counters.
    pub fn stats(&self) -> &EmulatorStats {
        &self.stats
    }

    /// The fault schedule (which faults fired).
    pub fn faults(&self) -> &Arc<Faults> {
        &self.faults
    }

    /// Timestamps the firmware's output as the port loop would carry it out: a delay holds
    /// back what follows, a disconnect loses what is said while unplugged.
    fn carry_out(&mut self, out: Output) {
        let mut at = self.now;
        for step in out.steps {
            match step {
                Step::Send(bytes) => {
                    if at >= self.unplugged_until {
                        self.said.push_back((at, bytes));
                    }
                }
                Step::Delay(s) => at += s,
                Step::Disconnect(s) => {
                    self.unplugged_until = at + s;
                    self.stats.count_disconnect();
                }
            }
        }
    }
}
