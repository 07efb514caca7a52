//! A simulated stepper axis: trapezoidal moves quantised to microsteps, homing at constant
//! speed, hard limits 5° beyond the soft limits, and backlash that shows up on the load side
//! after a move in the negative direction.

use std::sync::Arc;

use stagehand_devices::axis::{AxisDriver, leg};
use stagehand_devices::error::DeviceResult;
use stagehand_devices::motion::Trapezoid;
use stagehand_devices::rig::AxisSpec;
use stagehand_devices::{DeviceError, DeviceErrorKind};

use super::COMMAND_LATENCY_S;
use crate::world::World;

/// How far beyond the soft limits the hard limit switches sit.
const HARD_LIMIT_MARGIN_DEG: f64 = 5.0;

/// Simulated stepper axis driver.
pub struct SimAxis {
    spec: AxisSpec,
    world: Arc<World>,
}

impl SimAxis {
    pub fn new(spec: AxisSpec, world: Arc<World>) -> Self {
        Self { spec, world }
    }

    fn now(&self) -> f64 {
        self.world.clock().now_s()
    }

    fn quantise(&self, deg: f64) -> f64 {
        (deg * self.spec.steps_per_deg).round() / self.spec.steps_per_deg
    }

    fn current(&self) -> f64 {
        let t = self.now();
        self.world
            .with_axis(&self.spec.id, |a| a.motor_at(t))
            .unwrap_or(0.0)
    }

    async fn run(&self, traj: Trapezoid) {
        let start = self.now();
        self.world
            .with_axis(&self.spec.id, |a| a.moving = Some((traj, start)));
        self.world.settling();
        self.world.clock().sleep_s(traj.duration_s()).await;
        let end = traj.to_deg;
        let backlash = self.spec.backlash_deg;
        self.world.with_axis(&self.spec.id, |a| {
            a.moving = None;
            a.motor_deg = end;
            if traj.to_deg < traj.from_deg {
                a.backlash_offset_deg = backlash;
            } else if traj.to_deg > traj.from_deg {
                a.backlash_offset_deg = 0.0;
            }
        });
    }
}

impl AxisDriver for SimAxis {
    async fn home(&mut self) -> DeviceResult<f64> {
        self.world.clock().sleep_s(COMMAND_LATENCY_S).await;
        let from = self.current();
        // Homing runs at constant speed (no ramp) toward the home position.
        let speed = self.spec.homing_speed_deg_s;
        let home = self.spec.home_deg;
        let traj = Trapezoid {
            from_deg: from,
            to_deg: home,
            peak_deg_s: speed,
            accel_deg_s2: f64::INFINITY,
            ramp_s: 0.0,
            cruise_s: (from - home).abs() / speed,
        };
        self.run(traj).await;
        self.world.with_axis(&self.spec.id, |a| {
            a.homed = true;
            a.backlash_offset_deg = 0.0;
        });
        Ok(home)
    }

    async fn move_to(&mut self, target_deg: f64) -> DeviceResult<f64> {
        let id = self.spec.id.clone();
        let homed = self.world.with_axis(&id, |a| a.homed).unwrap_or(false);
        if !homed {
            return Err(DeviceError::new(id, DeviceErrorKind::NotHomed));
        }
        self.world.clock().sleep_s(COMMAND_LATENCY_S).await;
        let now = self.now();
        if self.world.exposing_at(now) {
            self.world.violation(format!(
                "axis `{id}` was commanded to move during an exposure at rig time {now:.3} s"
            ));
            return Err(DeviceError::new(id, DeviceErrorKind::MovingWhileExposing));
        }
        let from = self.current();
        let target = self.quantise(target_deg);
        let (lo, hi) = (
            self.spec.min_deg - HARD_LIMIT_MARGIN_DEG,
            self.spec.max_deg + HARD_LIMIT_MARGIN_DEG,
        );
        if target < lo || target > hi {
            // Drive to the switch, stop there and lose the reference, as a real axis would.
            let at = target.clamp(lo, hi);
            self.run(leg(&self.spec, from, at)).await;
            self.world.with_axis(&id, |a| a.homed = false);
            return Err(DeviceError::new(
                id,
                DeviceErrorKind::HardLimit { position_deg: at },
            ));
        }
        self.run(leg(&self.spec, from, target)).await;
        Ok(target)
    }

    async fn stop(&mut self) -> DeviceResult<f64> {
        let t = self.now();
        let p = self
            .world
            .with_axis(&self.spec.id, |a| {
                let p = a.motor_at(t);
                a.moving = None;
                a.motor_deg = p;
                p
            })
            .unwrap_or(0.0);
        Ok(p)
    }

    async fn position(&mut self) -> DeviceResult<f64> {
        self.world.clock().sleep_s(COMMAND_LATENCY_S).await;
        Ok(self.current())
    }
}
