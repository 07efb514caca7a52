//! Rotary axes: the capability a driver implements, and the actor handle the engine uses.
//!
//! The handle checks soft limits, takes up backlash by always making the final approach in the
//! positive direction, and bounds every request with a timeout derived from the motion physics.

use std::future::Future;
use std::sync::Arc;

use serde::Serialize;
use tokio::sync::{mpsc, oneshot, watch};

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::motion::{Trapezoid, move_duration_s};
use crate::request::call;
use crate::rig::AxisSpec;

/// What a backend (simulated stepper, GRBL controller, ...) must do for one axis.
pub trait AxisDriver: Send + 'static {
    /// Drives to the home switch; afterwards the position reads 0°.
    fn home(&mut self) -> impl Future<Output = DeviceResult<f64>> + Send;
    /// Moves to an absolute angle and returns the position reached. Must be cancel-safe:
    /// if the future is dropped, a following `stop` reports where the axis stopped.
    fn move_to(&mut self, target_deg: f64) -> impl Future<Output = DeviceResult<f64>> + Send;
    /// Stops any motion and returns the position.
    fn stop(&mut self) -> impl Future<Output = DeviceResult<f64>> + Send;
    /// Reads the current position.
    fn position(&mut self) -> impl Future<Output = DeviceResult<f64>> + Send;
}

/// Last known state of an axis, published by its actor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisStatus {
    pub position_deg: f64,
    pub homed: bool,
    pub moving: bool,
}

enum Cmd {
    Home(oneshot::Sender<DeviceResult<f64>>),
    MoveTo(f64, oneshot::Sender<DeviceResult<f64>>),
    Position(oneshot::Sender<DeviceResult<f64>>),
}

/// A stop: whether it forgets the home (an e-stop: a stepper stopped abruptly may have lost
/// steps), and where to send the position it stopped at.
type StopRequest = (bool, oneshot::Sender<DeviceResult<f64>>);

/// Cheap-to-clone handle to the task that owns one axis.
#[derive(Clone)]
pub struct AxisHandle {
    spec: Arc<AxisSpec>,
    /// Extra time a request may wait behind other axes sharing this axis's controller (a
    /// GRBL board runs its axes' moves one after another) and for a reconnect's handshake.
    shared_s: f64,
    tx: mpsc::Sender<Cmd>,
    stop_tx: mpsc::Sender<StopRequest>,
    status: watch::Receiver<AxisStatus>,
}

/// Extra time granted beyond the physics before a request is declared lost.
const MARGIN_S: f64 = 2.0;

impl AxisHandle {
    /// Spawns the actor task that owns `driver` and returns its handle.
    pub fn spawn<D: AxisDriver>(spec: AxisSpec, driver: D) -> Self {
        Self::spawn_shared(spec, driver, 0.0)
    }

    /// Like [`AxisHandle::spawn`] for an axis whose controller also serves other axes: every
    /// request may additionally wait `shared_s` seconds (their moves, a reconnect).
    pub fn spawn_shared<D: AxisDriver>(spec: AxisSpec, driver: D, shared_s: f64) -> Self {
        let (tx, rx) = mpsc::channel(8);
        let (stop_tx, stop_rx) = mpsc::channel(4);
        let (status_tx, status) = watch::channel(AxisStatus {
            position_deg: 0.0,
            homed: false,
            moving: false,
        });
        let spec = Arc::new(spec);
        tokio::spawn(run_actor(spec.clone(), driver, rx, stop_rx, status_tx));
        Self {
            spec,
            shared_s: if shared_s.is_finite() {
                shared_s.max(0.0)
            } else {
                0.0
            },
            tx,
            stop_tx,
            status,
        }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    pub fn spec(&self) -> &AxisSpec {
        &self.spec
    }

    /// Latest published status (no round trip).
    pub fn status(&self) -> AxisStatus {
        *self.status.borrow()
    }

    /// A receiver that sees every status change (for live dashboards).
    pub fn watch(&self) -> watch::Receiver<AxisStatus> {
        self.status.clone()
    }

    /// Homes the axis.
    pub async fn home(&self) -> DeviceResult<f64> {
        let s = &self.spec;
        let span = (s.max_deg - s.min_deg).abs();
        let timeout = span / s.homing_speed_deg_s * 1.5 + s.settle_s + MARGIN_S + self.shared_s;
        self.request("home", timeout, Cmd::Home).await
    }

    /// Moves to `target_deg`, approaching from below to take up backlash.
    pub async fn move_to(&self, target_deg: f64) -> DeviceResult<f64> {
        let s = &self.spec;
        if !target_deg.is_finite() || target_deg < s.min_deg || target_deg > s.max_deg {
            return Err(DeviceError::new(
                s.id.clone(),
                DeviceErrorKind::OutsideSoftLimits {
                    target_deg,
                    min_deg: s.min_deg,
                    max_deg: s.max_deg,
                },
            ));
        }
        let status = self.status();
        if !status.homed {
            return Err(DeviceError::new(s.id.clone(), DeviceErrorKind::NotHomed));
        }
        let timeout = move_duration_s(
            status.position_deg,
            target_deg,
            s.kinematics(),
            s.backlash_deg,
        ) * 1.5
            + s.settle_s
            + MARGIN_S
            + self.shared_s;
        self.request("move", timeout, |tx| Cmd::MoveTo(target_deg, tx))
            .await
    }

    /// Reads the position from the device.
    pub async fn position(&self) -> DeviceResult<f64> {
        self.request("position", MARGIN_S + self.shared_s, Cmd::Position)
            .await
    }

    /// Stops the axis now, interrupting a move in progress.
    pub async fn stop(&self) -> DeviceResult<f64> {
        let timeout = MARGIN_S + self.shared_s;
        call(&self.spec.id, &self.stop_tx, "stop", timeout, |tx| {
            (false, tx)
        })
        .await
    }

    /// Stops the axis now, as [`stop`](Self::stop), and marks it not homed: after an e-stop a
    /// stepper may have lost steps, so its position must be found again by homing.
    pub async fn emergency_stop(&self) -> DeviceResult<f64> {
        let timeout = MARGIN_S + self.shared_s;
        call(&self.spec.id, &self.stop_tx, "stop", timeout, |tx| {
            (true, tx)
        })
        .await
    }

    async fn request(
        &self,
        what: &str,
        timeout_s: f64,
        make: impl FnOnce(oneshot::Sender<DeviceResult<f64>>) -> Cmd,
    ) -> DeviceResult<f64> {
        call(&self.spec.id, &self.tx, what, timeout_s, make).await
    }
}

async fn run_actor<D: AxisDriver>(
    spec: Arc<AxisSpec>,
    mut driver: D,
    mut rx: mpsc::Receiver<Cmd>,
    mut stop_rx: mpsc::Receiver<StopRequest>,
    status: watch::Sender<AxisStatus>,
) {
    loop {
        tokio::select! {
            biased;
            Some((unhome, reply)) = stop_rx.recv() => {
                let r = driver.stop().await;
                publish(&status, &r, unhome.then_some(false), false);
                let _ = reply.send(r);
            }
            cmd = rx.recv() => {
                let Some(cmd) = cmd else { break };
                match cmd {
                    Cmd::Position(reply) => {
                        let r = driver.position().await;
                        publish(&status, &r, None, false);
                        let _ = reply.send(r);
                    }
                    Cmd::Home(reply) => {
                        status.send_modify(|s| s.moving = true);
                        let r = tokio::select! {
                            r = home_and_settle(&spec, &mut driver) => r,
                            Some((_, stop_reply)) = stop_rx.recv() => {
                                let r = driver.stop().await;
                                let _ = stop_reply.send(r.clone());
                                publish(&status, &r, Some(false), false);
                                r.and(Err(DeviceError::new(spec.id.clone(), DeviceErrorKind::Other { message: "homing interrupted by stop; home the axis again".into() })))
                            }
                        };
                        let homed = r.is_ok();
                        publish(&status, &r, Some(homed), false);
                        let _ = reply.send(r);
                    }
                    Cmd::MoveTo(target, reply) => {
                        status.send_modify(|s| s.moving = true);
                        let r = tokio::select! {
                            r = approach(&spec, &mut driver, target, status.borrow().position_deg) => r,
                            Some((unhome, stop_reply)) = stop_rx.recv() => {
                                let r = driver.stop().await;
                                let _ = stop_reply.send(r.clone());
                                // Where it stopped (the error below carries no position).
                                publish(&status, &r, unhome.then_some(false), false);
                                r.and(Err(DeviceError::new(spec.id.clone(), DeviceErrorKind::Other { message: "move interrupted by stop".into() })))
                            }
                        };
                        let homed = match &r {
                            Err(DeviceError { kind: DeviceErrorKind::HardLimit { .. }, .. } | DeviceError { kind: DeviceErrorKind::NotHomed, .. } | DeviceError { kind: DeviceErrorKind::Alarm { .. }, .. }) => Some(false),
                            _ => None,
                        };
                        publish(&status, &r, homed, false);
                        let _ = reply.send(r);
                    }
                }
            }
        }
    }
}

/// Homes, then waits the settling time.
async fn home_and_settle<D: AxisDriver>(spec: &AxisSpec, driver: &mut D) -> DeviceResult<f64> {
    let p = driver.home().await?;
    crate::clock::sleep(duration_s(spec.settle_s)).await;
    Ok(p)
}

/// Moves to `target`, making the final approach in the positive direction (a negative move
/// overshoots by the backlash and comes back), then waits the settling time.
async fn approach<D: AxisDriver>(
    spec: &AxisSpec,
    driver: &mut D,
    target: f64,
    from: f64,
) -> DeviceResult<f64> {
    if target == from {
        return Ok(from);
    }
    if target < from && spec.backlash_deg > 0.0 {
        driver.move_to(target - spec.backlash_deg).await?;
    }
    let p = driver.move_to(target).await?;
    crate::clock::sleep(duration_s(spec.settle_s)).await;
    Ok(p)
}

fn publish(
    status: &watch::Sender<AxisStatus>,
    r: &DeviceResult<f64>,
    homed: Option<bool>,
    moving: bool,
) {
    status.send_modify(|s| {
        if let Ok(p) = r {
            s.position_deg = *p;
        }
        if let Some(h) = homed {
            s.homed = h;
        }
        s.moving = moving;
    });
}

/// Time a move will take under this axis's physics, including backlash take-up and settling.
pub fn planned_move_s(spec: &AxisSpec, from_deg: f64, to_deg: f64) -> f64 {
    if from_deg == to_deg {
        return 0.0;
    }
    move_duration_s(from_deg, to_deg, spec.kinematics(), spec.backlash_deg) + spec.settle_s
}

/// The trapezoid of a single leg (no backlash) — used by simulated drivers.
pub fn leg(spec: &AxisSpec, from_deg: f64, to_deg: f64) -> Trapezoid {
    Trapezoid::plan(from_deg, to_deg, spec.kinematics())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{BUILTIN_LIGHTSTAGE, parse_rig};

    /// Moves take ten seconds; a stop reports 42°.
    struct Slow;

    impl AxisDriver for Slow {
        async fn home(&mut self) -> DeviceResult<f64> {
            Ok(0.0)
        }
        async fn move_to(&mut self, target_deg: f64) -> DeviceResult<f64> {
            tokio::time::sleep(std::time::Duration::from_secs(10)).await;
            Ok(target_deg)
        }
        async fn stop(&mut self) -> DeviceResult<f64> {
            Ok(42.0)
        }
        async fn position(&mut self) -> DeviceResult<f64> {
            Ok(0.0)
        }
    }

    /// The built-in turntable on the slow driver, homed, one second into a long move.
    async fn homed_turntable_moving() -> (AxisHandle, tokio::task::JoinHandle<DeviceResult<f64>>) {
        let spec = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml")
            .unwrap()
            .axes
            .into_iter()
            .find(|a| a.id == "turntable")
            .unwrap();
        let axis = AxisHandle::spawn(spec, Slow);
        axis.home().await.unwrap();
        let mover = axis.clone();
        let moving = tokio::spawn(async move { mover.move_to(300.0).await });
        tokio::time::sleep(std::time::Duration::from_secs(1)).await;
        (axis, moving)
    }

    #[tokio::test(start_paused = true)]
    async fn a_stop_interrupts_a_move_and_publishes_where_the_axis_stopped() {
        let (axis, moving) = homed_turntable_moving().await;
        assert!(axis.status().moving);
        assert_eq!(axis.stop().await.unwrap(), 42.0);
        assert!(
            moving.await.unwrap().is_err(),
            "the move reports the interruption"
        );
        let s = axis.status();
        assert!(!s.moving);
        assert_eq!(s.position_deg, 42.0, "the status says where it stopped");
        assert!(
            s.homed,
            "an ordinary stop (the end of a jog) keeps the home"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn an_emergency_stop_mid_move_forgets_the_home() {
        let (axis, moving) = homed_turntable_moving().await;
        assert_eq!(axis.emergency_stop().await.unwrap(), 42.0);
        assert!(moving.await.unwrap().is_err());
        let s = axis.status();
        assert!(!s.homed, "it may have lost steps: it must be homed again");
        assert!(matches!(
            axis.move_to(10.0).await,
            Err(DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            })
        ));
        // An e-stop of an axis standing still forgets the home too.
        axis.home().await.unwrap();
        axis.emergency_stop().await.unwrap();
        assert!(!axis.status().homed);
    }
}
