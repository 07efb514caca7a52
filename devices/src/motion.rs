//! Trapezoidal motion profiles: the physics shared by the simulator, the timeouts of real
//! drivers and the planner's time estimate.

use serde::{Deserialize, Serialize};

/// Kinematic limits of an axis, in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Kinematics {
    /// Cruise speed in degrees per second (> 0).
    pub speed_deg_s: f64,
    /// Acceleration and deceleration in degrees per second squared (> 0).
    pub accel_deg_s2: f64,
}

/// A planned point-to-point move with a trapezoidal (or triangular) velocity profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trapezoid {
    pub from_deg: f64,
    pub to_deg: f64,
    /// Peak speed reached (the cruise speed, or less for a short triangular move).
    pub peak_deg_s: f64,
    pub accel_deg_s2: f64,
    /// Time spent accelerating (and again decelerating).
    pub ramp_s: f64,
    /// Time at cruise speed.
    pub cruise_s: f64,
}

impl Trapezoid {
    /// Plans a move from `from_deg` to `to_deg` under `k`.
    pub fn plan(from_deg: f64, to_deg: f64, k: Kinematics) -> Self {
        let distance = (to_deg - from_deg).abs();
        let v = k.speed_deg_s.max(1e-9);
        let a = k.accel_deg_s2.max(1e-9);
        // Distance needed to reach cruise speed and stop again.
        let ramp_distance = v * v / a;
        let (peak, ramp_s, cruise_s) = if distance >= ramp_distance {
            (v, v / a, (distance - ramp_distance) / v)
        } else {
            let peak = (distance * a).sqrt();
            (peak, peak / a, 0.0)
        };
        Self {
            from_deg,
            to_deg,
            peak_deg_s: peak,
            accel_deg_s2: a,
            ramp_s,
            cruise_s,
        }
    }

    /// Total duration of the move in seconds.
    pub fn duration_s(&self) -> f64 {
        2.0 * self.ramp_s + self.cruise_s
    }

    /// Position `t` seconds after the move began (clamped to the move).
    pub fn position_at(&self, t: f64) -> f64 {
        let dir = if self.to_deg >= self.from_deg {
            1.0
        } else {
            -1.0
        };
        let t = t.clamp(0.0, self.duration_s());
        let a = self.accel_deg_s2;
        let travelled = if t < self.ramp_s {
            0.5 * a * t * t
        } else if t < self.ramp_s + self.cruise_s {
            0.5 * a * self.ramp_s * self.ramp_s + self.peak_deg_s * (t - self.ramp_s)
        } else {
            let td = t - self.ramp_s - self.cruise_s;
            0.5 * a * self.ramp_s * self.ramp_s
                + self.peak_deg_s * self.cruise_s
                + self.peak_deg_s * td
                - 0.5 * a * td * td
        };
        let distance = (self.to_deg - self.from_deg).abs();
        self.from_deg + dir * travelled.min(distance)
    }
}

/// Duration of a move including the backlash take-up approach used by stagehand axes: the
/// final approach is always made in the positive direction, so a move in the negative
/// direction overshoots by `backlash_deg` and comes back.
pub fn move_duration_s(from_deg: f64, to_deg: f64, k: Kinematics, backlash_deg: f64) -> f64 {
    if to_deg < from_deg && backlash_deg > 0.0 {
        let past = to_deg - backlash_deg;
        Trapezoid::plan(from_deg, past, k).duration_s()
            + Trapezoid::plan(past, to_deg, k).duration_s()
    } else {
        Trapezoid::plan(from_deg, to_deg, k).duration_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const K: Kinematics = Kinematics {
        speed_deg_s: 30.0,
        accel_deg_s2: 60.0,
    };

    #[test]
    fn long_move_cruises() {
        let t = Trapezoid::plan(0.0, 90.0, K);
        assert!((t.ramp_s - 0.5).abs() < 1e-12);
        assert!((t.duration_s() - (1.0 + 75.0 / 30.0)).abs() < 1e-9);
    }

    #[test]
    fn zero_move_takes_no_time() {
        assert_eq!(Trapezoid::plan(10.0, 10.0, K).duration_s(), 0.0);
    }

    #[test]
    fn backlash_adds_time_only_when_moving_negative() {
        let up = move_duration_s(0.0, 30.0, K, 0.5);
        let down = move_duration_s(30.0, 0.0, K, 0.5);
        assert!(down > up);
        assert_eq!(move_duration_s(0.0, 30.0, K, 0.0), up);
    }

    proptest! {
        #[test]
        fn position_is_monotone_and_ends_at_target(from in -360.0f64..360.0, to in -360.0f64..360.0) {
            let t = Trapezoid::plan(from, to, K);
            let d = t.duration_s();
            prop_assert!(d.is_finite() && d >= 0.0);
            prop_assert!((t.position_at(d) - to).abs() < 1e-6);
            prop_assert!((t.position_at(0.0) - from).abs() < 1e-9);
            let mut last = from;
            for i in 0..=50 {
                let p = t.position_at(d * i as f64 / 50.0);
                prop_assert!((p - last) * (to - from) >= -1e-9);
                last = p;
            }
        }
    }
}
