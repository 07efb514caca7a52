//! Exact trigger accounting: one frame per camera per trigger id.
//!
//! Hardware frames carry the camera's own sequence number (V4L2 buffer sequence, GenICam frame
//! id, a DSLR capture counter) but not our trigger id. [`TriggerAccounting`] is told about every
//! trigger *before* it fires ([`TriggerAccounting::expect`]) and about every frame as it arrives
//! ([`TriggerAccounting::on_frame`]), in real-time order, and decides which trigger each frame
//! answers. Frames answer triggers in order; a jump in the sequence means frames were lost; a
//! frame with no trigger waiting is an extra; a trigger whose frame does not come within
//! [`frame_timeout_s`] is missing. Time is passed in as seconds so the logic is testable.

use std::collections::VecDeque;

use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};

/// Slack beyond exposure + readout before a frame counts as missing (USB latency, driver
/// queues, a DSLR writing its file).
pub const FRAME_MARGIN_S: f64 = 1.5;

/// How long a trigger may wait for its frame: exposure + readout + [`FRAME_MARGIN_S`].
/// Non-finite or negative inputs count as zero so a bad value never means "wait forever".
pub fn frame_timeout_s(exposure_s: f64, readout_s: f64) -> f64 {
    let clean = |v: f64| if v.is_finite() && v > 0.0 { v } else { 0.0 };
    clean(exposure_s) + clean(readout_s) + FRAME_MARGIN_S
}

/// A trigger that was announced and has not been answered.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pending {
    trigger_id: u64,
    deadline_s: f64,
    timeout_s: f64,
    /// Already reported missing (deadline passed); kept so that its late frame, should it
    /// still come, is recognised as late instead of answering the next trigger.
    expired: bool,
}

/// What a delivered frame turned out to be.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameVerdict {
    /// The frame answers this trigger.
    Answers(u64),
    /// The frame belongs to a trigger already reported missing (it came too late).
    Late(u64),
    /// No trigger was waiting: the camera fired on its own, twice, or repeated a frame.
    Extra,
}

/// Outcome of one delivered frame: frames lost before it (by sequence gap) and its verdict.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameDecision {
    /// Triggers whose frames were lost before this one (sequence gap), oldest first. Only
    /// triggers not already reported missing are listed.
    pub lost: Vec<u64>,
    pub verdict: FrameVerdict,
}

/// Matches delivered frames to announced triggers for one camera.
#[derive(Debug, Clone)]
pub struct TriggerAccounting {
    device: String,
    pending: VecDeque<Pending>,
    last_sequence: Option<u64>,
    last_answered: Option<u64>,
    /// The sequence counter counts modulo this (0 = the full u64 range).
    modulus: u128,
}

impl TriggerAccounting {
    /// Accounting for camera `device` whose sequence counter spans the full u64 range.
    pub fn new(device: impl Into<String>) -> Self {
        Self {
            device: device.into(),
            pending: VecDeque::new(),
            last_sequence: None,
            last_answered: None,
            modulus: 0,
        }
    }

    /// Accounting for a camera whose sequence counter wraps at `modulus` (V4L2: 2^32).
    /// A modulus of 0 or 1 means no wrap.
    pub fn with_wrap(device: impl Into<String>, modulus: u64) -> Self {
        let mut a = Self::new(device);
        a.modulus = if modulus > 1 { u128::from(modulus) } else { 0 };
        a
    }

    /// Camera id this accounting reports errors for.
    pub fn device(&self) -> &str {
        &self.device
    }

    /// Forgets every pending trigger and the last sequence number: call on arm / stream
    /// restart. `first_sequence` is the number the next frame will carry if the backend
    /// knows it (V4L2 restarts at 0), so even a lost first frame is noticed.
    pub fn reset(&mut self, first_sequence: Option<u64>) {
        self.pending.clear();
        self.last_sequence = first_sequence.map(|s| self.wrap_sub(s, 1));
        self.last_answered = None;
    }

    /// Announces that trigger `trigger_id` fires now (`now_s`); its frame is due within
    /// `timeout_s` (see [`frame_timeout_s`]). Call before the pulse goes out.
    pub fn expect(&mut self, trigger_id: u64, now_s: f64, timeout_s: f64) {
        let timeout_s = if timeout_s.is_finite() && timeout_s > 0.0 {
            timeout_s
        } else {
            0.0
        };
        self.pending.push_back(Pending {
            trigger_id,
            deadline_s: now_s + timeout_s,
            timeout_s,
            expired: false,
        });
    }

    /// Number of triggers still waiting for a frame (not yet reported missing).
    pub fn waiting(&self) -> usize {
        self.pending.iter().filter(|p| !p.expired).count()
    }

    /// True when no trigger is pending at all (not even one already reported missing).
    pub fn is_idle(&self) -> bool {
        self.pending.is_empty()
    }

    /// Earliest deadline of a trigger still waiting, for the caller's poll timeout.
    pub fn next_deadline_s(&self) -> Option<f64> {
        self.pending
            .iter()
            .filter(|p| !p.expired)
            .map(|p| p.deadline_s)
            .reduce(f64::min)
    }

    /// Reports triggers whose deadline has passed at `now_s` as [`DeviceErrorKind::MissingFrame`]
    /// (each exactly once), oldest first.
    pub fn expire(&mut self, now_s: f64) -> Vec<DeviceError> {
        let mut out = Vec::new();
        for p in self.pending.iter_mut() {
            if !p.expired && now_s >= p.deadline_s {
                p.expired = true;
                out.push(DeviceError::new(
                    self.device.clone(),
                    DeviceErrorKind::MissingFrame {
                        trigger_id: p.trigger_id,
                        timeout_s: p.timeout_s,
                    },
                ));
            }
        }
        out
    }

    /// Id of the last trigger a frame answered.
    pub fn last_answered(&self) -> Option<u64> {
        self.last_answered
    }

    /// The error for a frame that answers no waiting trigger: `expected` is the oldest trigger
    /// still waiting (or the last answered), `got` the late frame's own trigger, or for an
    /// extra frame the last trigger answered (most often the one that fired it twice).
    pub fn unexpected(&self, verdict: &FrameVerdict) -> DeviceError {
        let expected = self
            .pending
            .iter()
            .find(|p| !p.expired)
            .map(|p| p.trigger_id)
            .or(self.last_answered)
            .unwrap_or(0);
        let got = match verdict {
            FrameVerdict::Late(t) => *t,
            _ => self.last_answered.unwrap_or(0),
        };
        DeviceError::new(
            self.device.clone(),
            DeviceErrorKind::UnexpectedFrame { expected, got },
        )
    }

    /// Accounts for one delivered frame carrying camera sequence number `sequence`.
    pub fn on_frame(&mut self, sequence: u64) -> FrameDecision {
        let gap = match self.last_sequence {
            None => 1,
            Some(last) => self.wrap_sub(sequence, last),
        };
        // A repeated or backward sequence number: a duplicate or stale frame. The counter is
        // not moved back.
        if gap == 0 || self.is_backwards(gap) {
            return FrameDecision {
                lost: Vec::new(),
                verdict: FrameVerdict::Extra,
            };
        }
        self.last_sequence = Some(sequence);
        let mut lost = Vec::new();
        // The gap-1 frames in between were lost; they answered the oldest triggers.
        for _ in 1..gap {
            match self.pending.pop_front() {
                Some(p) if !p.expired => lost.push(p.trigger_id),
                Some(_) => {}
                None => break,
            }
        }
        let verdict = match self.pending.pop_front() {
            None => FrameVerdict::Extra,
            Some(p) if p.expired => FrameVerdict::Late(p.trigger_id),
            Some(p) => {
                self.last_answered = Some(p.trigger_id);
                FrameVerdict::Answers(p.trigger_id)
            }
        };
        FrameDecision { lost, verdict }
    }

    /// Like [`Self::on_frame`] but as a result: the trigger id the frame answers, or the
    /// error to report. Lost frames are reported first ([`DeviceErrorKind::MissingFrame`] naming
    /// the oldest lost trigger); a late or extra frame is [`DeviceErrorKind::UnexpectedFrame`]
    /// (see [`Self::unexpected`]).
    pub fn frame_result(&mut self, sequence: u64) -> DeviceResult<u64> {
        let decision = self.on_frame(sequence);
        if let Some(&first) = decision.lost.first() {
            return Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::MissingFrame {
                    trigger_id: first,
                    timeout_s: 0.0,
                },
            ));
        }
        match decision.verdict {
            FrameVerdict::Answers(id) => Ok(id),
            other => Err(self.unexpected(&other)),
        }
    }

    /// `a - b` in the counter's arithmetic.
    fn wrap_sub(&self, a: u64, b: u64) -> u64 {
        if self.modulus == 0 {
            a.wrapping_sub(b)
        } else {
            let m = self.modulus;
            ((u128::from(a) % m + m - u128::from(b) % m) % m) as u64
        }
    }

    /// A forward distance this large is really a step backwards (more than half the range).
    fn is_backwards(&self, gap: u64) -> bool {
        let half = if self.modulus == 0 {
            u128::from(u64::MAX) / 2
        } else {
            self.modulus / 2
        };
        u128::from(gap) > half
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timeout_is_exposure_plus_readout_plus_margin() {
        assert_eq!(frame_timeout_s(0.5, 0.1), 0.5 + 0.1 + FRAME_MARGIN_S);
        assert_eq!(frame_timeout_s(f64::NAN, -1.0), FRAME_MARGIN_S);
    }

    #[test]
    fn reset_with_first_sequence_detects_a_lost_first_frame() {
        let mut a = TriggerAccounting::with_wrap("cam", 1 << 32);
        a.reset(Some(0));
        a.expect(1, 0.0, 1.0);
        a.expect(2, 0.0, 1.0);
        let d = a.on_frame(1);
        assert_eq!(d.lost, vec![1]);
        assert_eq!(d.verdict, FrameVerdict::Answers(2));
    }

    #[test]
    fn wraps_at_the_modulus() {
        let mut a = TriggerAccounting::with_wrap("cam", 1 << 32);
        a.reset(Some(u64::from(u32::MAX)));
        a.expect(1, 0.0, 1.0);
        a.expect(2, 0.0, 1.0);
        assert_eq!(a.frame_result(u64::from(u32::MAX)), Ok(1));
        assert_eq!(a.frame_result(0), Ok(2));
    }
}
