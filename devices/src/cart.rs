//! The reflectometer's DC-motor carriage: forward, reverse, stop, and a time-based position
//! estimate (the LEGO cart has no encoder), bounded by its end stops.

use std::future::Future;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot, watch};

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::request::call;
use crate::rig::CartSpec;

/// Direction of the cart's motor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    Forward,
    Reverse,
    Stop,
}

/// What a backend (simulated cart, IR bridge) must do.
pub trait CartDriver: Send + 'static {
    fn drive(&mut self, drive: Drive) -> impl Future<Output = DeviceResult<()>> + Send;
}

type Reply = oneshot::Sender<DeviceResult<f64>>;

/// Cheap-to-clone handle to the task that owns the cart.
#[derive(Clone)]
pub struct CartHandle {
    spec: Arc<CartSpec>,
    tx: mpsc::Sender<(f64, Reply)>,
    position: watch::Receiver<f64>,
}

impl CartHandle {
    /// Spawns the actor. The cart is assumed parked at the - end stop (0 mm).
    pub fn spawn<D: CartDriver>(spec: CartSpec, mut driver: D) -> Self {
        let (tx, mut rx) = mpsc::channel::<(f64, Reply)>(4);
        let (pos_tx, position) = watch::channel(0.0);
        let speed = spec.speed_mm_s;
        tokio::spawn(async move {
            while let Some((target, reply)) = rx.recv().await {
                let from = *pos_tx.borrow();
                let dir = if target > from {
                    Drive::Forward
                } else {
                    Drive::Reverse
                };
                let r = async {
                    if target != from {
                        driver.drive(dir).await?;
                        tokio::time::sleep(duration_s((target - from).abs() / speed)).await;
                        driver.drive(Drive::Stop).await?;
                    }
                    Ok(target)
                }
                .await;
                if r.is_ok() {
                    pos_tx.send_replace(target);
                } else {
                    let _ = driver.drive(Drive::Stop).await;
                }
                let _ = reply.send(r);
            }
        });
        Self {
            spec: Arc::new(spec),
            tx,
            position,
        }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    /// Estimated position in millimetres from the - end stop.
    pub fn position_mm(&self) -> f64 {
        *self.position.borrow()
    }

    /// Drives to `target_mm` by running the motor for the time the distance takes.
    pub async fn move_to(&self, target_mm: f64) -> DeviceResult<f64> {
        let s = &self.spec;
        if !target_mm.is_finite() || target_mm < 0.0 {
            return Err(DeviceError::new(
                s.id.clone(),
                DeviceErrorKind::EndStop { end: "- end" },
            ));
        }
        if target_mm > s.travel_mm {
            return Err(DeviceError::new(
                s.id.clone(),
                DeviceErrorKind::EndStop { end: "+ end" },
            ));
        }
        let timeout_s = (target_mm - self.position_mm()).abs() / s.speed_mm_s * 1.5 + 2.0;
        call(&s.id, &self.tx, "move", timeout_s, |tx| (target_mm, tx)).await
    }
}
