//! Fault injection for the firmware emulators: a schedule of faults shared between a test (or
//! the integrator) and one emulator. Each fault fires at most once; the schedule records which
//! fired and when, so a test can check that the fault it meant to provoke really happened.

use std::sync::{Arc, Mutex, MutexGuard};

use crate::world::World;

/// One fault. Commands are counted per emulator from 1 by the protocol's command lines
/// (GRBL lines, relay-board `\r` lines, IR-bridge lines, HID set reports); moves are GRBL
/// lines that move an axis.
#[derive(Debug, Clone, PartialEq)]
pub enum Fault {
    /// After the reply to command `after_commands`, the device vanishes for `for_s` seconds
    /// (its pty closes; the link comes back pointing at a new pty, as USB re-enumeration).
    Disconnect { after_commands: u64, for_s: f64 },
    /// After the reply to command `after_commands`, the device sends `bytes` (line noise).
    Garbage { after_commands: u64, bytes: Vec<u8> },
    /// Command `nth_command` is carried out but its reply is never sent.
    DropReply { nth_command: u64 },
    /// The reply to command `nth_command` comes `delay_s` seconds late.
    SlowReply { nth_command: u64, delay_s: f64 },
    /// GRBL: halfway through move `nth_move` the controller stops and reports `ALARM:code`.
    AlarmDuringMove { nth_move: u64, code: u8 },
    /// After command `after_commands` the board power-cycles silently: every output switches
    /// off (GRBL: position lost, banner, `Alarm`).
    BoardReset { after_commands: u64 },
    /// Camera `camera` drops its next `frames` frames (applied through the World).
    StallCamera { camera: String, frames: u32 },
}

#[derive(Debug)]
struct Entry {
    fault: Fault,
    fired_at_s: Option<f64>,
}

/// A thread-safe fault schedule; share it as `Arc<Faults>` between a test and an emulator.
#[derive(Debug, Default)]
pub struct Faults {
    entries: Mutex<Vec<Entry>>,
}

impl Faults {
    /// An empty schedule (no faults).
    pub fn none() -> Arc<Faults> {
        Arc::new(Faults::default())
    }

    /// A schedule holding `faults`.
    pub fn new(faults: impl IntoIterator<Item = Fault>) -> Arc<Faults> {
        let f = Faults::default();
        for fault in faults {
            f.add(fault);
        }
        Arc::new(f)
    }

    fn lock(&self) -> MutexGuard<'_, Vec<Entry>> {
        self.entries.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Schedules one more fault.
    pub fn add(&self, fault: Fault) {
        self.lock().push(Entry {
            fault,
            fired_at_s: None,
        });
    }

    /// Faults that fired, in schedule order, with the rig time they fired at.
    pub fn fired(&self) -> Vec<(Fault, f64)> {
        self.lock()
            .iter()
            .filter_map(|e| e.fired_at_s.map(|t| (e.fault.clone(), t)))
            .collect()
    }

    /// Faults that have not fired yet.
    pub fn pending(&self) -> Vec<Fault> {
        self.lock()
            .iter()
            .filter(|e| e.fired_at_s.is_none())
            .map(|e| e.fault.clone())
            .collect()
    }

    /// True once every scheduled fault has fired.
    pub fn all_fired(&self) -> bool {
        self.lock().iter().all(|e| e.fired_at_s.is_some())
    }

    /// Fires every pending fault matching `select` at rig time `t` and returns them.
    pub(crate) fn take(&self, t: f64, select: impl Fn(&Fault) -> bool) -> Vec<Fault> {
        let mut entries = self.lock();
        let mut out = Vec::new();
        for e in entries.iter_mut() {
            if e.fired_at_s.is_none() && select(&e.fault) {
                e.fired_at_s = Some(t);
                out.push(e.fault.clone());
            }
        }
        out
    }

    /// Applies the faults that live in the World (`StallCamera`) now.
    pub fn apply_to_world(&self, world: &World) {
        let t = world.clock().now_s();
        for f in self.take(t, |f| matches!(f, Fault::StallCamera { .. })) {
            if let Fault::StallCamera { camera, frames } = f {
                world.stall_camera(&camera, frames);
            }
        }
    }

    /// The reply-shaping faults for command `n`: `Some(delay_s)` to send the reply (0 = at
    /// once), `None` to drop it.
    pub(crate) fn reply_plan(&self, n: u64, t: f64) -> Option<f64> {
        let mut delay = 0.0;
        let mut drop = false;
        for f in self.take(t, |f| {
            matches!(f, Fault::DropReply { nth_command } | Fault::SlowReply { nth_command, .. } if *nth_command == n)
        }) {
            match f {
                Fault::DropReply { .. } => drop = true,
                Fault::SlowReply { delay_s, .. } => delay += delay_s,
                _ => {}
            }
        }
        (!drop).then_some(delay)
    }

    /// The faults due after command `n` (`Garbage`, `BoardReset`, `Disconnect`), in that order
    /// of effect: garbage first, then the reset, the disconnect last.
    pub(crate) fn after_command(&self, n: u64, t: f64) -> Vec<Fault> {
        let mut due = self.take(t, |f| match f {
            Fault::Garbage { after_commands, .. }
            | Fault::BoardReset { after_commands }
            | Fault::Disconnect { after_commands, .. } => *after_commands == n,
            _ => false,
        });
        due.sort_by_key(|f| match f {
            Fault::Garbage { .. } => 0,
            Fault::BoardReset { .. } => 1,
            _ => 2,
        });
        due
    }
}
