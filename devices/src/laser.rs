//! The line laser: arming, colour and on/off. Its tilt is an ordinary axis.
//!
//! The handle enforces the safety rule in one place: the laser emits only while armed, and
//! disarming switches it off first.

use std::future::Future;
use std::sync::Arc;

use serde::Serialize;
use tokio::sync::{mpsc, oneshot, watch};

use crate::error::{DeviceError, DeviceResult};
use crate::request::call;
use crate::rig::LaserSpec;

/// What a backend (simulated laser, relay channel, GRBL M-codes) must do.
pub trait LaserDriver: Send + 'static {
    /// Switches the emission on or off.
    fn set_emission(
        &mut self,
        on: bool,
        colour_nm: u32,
    ) -> impl Future<Output = DeviceResult<()>> + Send;
    /// The operator fitted another laser module (recorded; the simulator changes colour).
    fn fitted(
        &mut self,
        colour_nm: u32,
        mount_elevation_deg: f64,
    ) -> impl Future<Output = DeviceResult<()>> + Send;
}

/// Safety-relevant state of the laser.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LaserStatus {
    pub armed: bool,
    pub on: bool,
    pub fitted_nm: u32,
    pub mount_elevation_deg: f64,
}

enum Cmd {
    Arm(bool, oneshot::Sender<DeviceResult<()>>),
    Emit(bool, u32, oneshot::Sender<DeviceResult<()>>),
    Fit(u32, f64, oneshot::Sender<DeviceResult<()>>),
}

/// Cheap-to-clone handle to the task that owns the laser.
#[derive(Clone)]
pub struct LaserHandle {
    spec: Arc<LaserSpec>,
    tx: mpsc::Sender<Cmd>,
    status: watch::Receiver<LaserStatus>,
}

const TIMEOUT_S: f64 = 1.0;

impl LaserHandle {
    /// Spawns the actor task that owns `driver`. The laser starts disarmed and off.
    pub fn spawn<D: LaserDriver>(spec: LaserSpec, driver: D) -> Self {
        let (tx, rx) = mpsc::channel(8);
        let initial = LaserStatus {
            armed: false,
            on: false,
            fitted_nm: spec.fitted_nm,
            mount_elevation_deg: spec.mount_elevation_deg,
        };
        let (status_tx, status) = watch::channel(initial);
        let spec = Arc::new(spec);
        tokio::spawn(run_actor(spec.clone(), driver, rx, status_tx));
        Self { spec, tx, status }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    pub fn status(&self) -> LaserStatus {
        *self.status.borrow()
    }

    /// Allows emission from now on.
    pub async fn arm(&self) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "arm", TIMEOUT_S, |tx| {
            Cmd::Arm(true, tx)
        })
        .await
    }

    /// Switches emission off and disarms.
    pub async fn disarm(&self) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "disarm", TIMEOUT_S, |tx| {
            Cmd::Arm(false, tx)
        })
        .await
    }

    /// Switches emission on; fails unless armed and `colour_nm` is the fitted module.
    pub async fn on(&self, colour_nm: u32) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "on", TIMEOUT_S, |tx| {
            Cmd::Emit(true, colour_nm, tx)
        })
        .await
    }

    /// Switches emission off (stays armed).
    pub async fn off(&self) -> DeviceResult<()> {
        let fitted = self.status().fitted_nm;
        call(&self.spec.id, &self.tx, "off", TIMEOUT_S, |tx| {
            Cmd::Emit(false, fitted, tx)
        })
        .await
    }

    /// Records that the operator fitted `colour_nm` at `mount_elevation_deg` (emission must be off).
    pub async fn fitted(&self, colour_nm: u32, mount_elevation_deg: f64) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "fit", TIMEOUT_S, |tx| {
            Cmd::Fit(colour_nm, mount_elevation_deg, tx)
        })
        .await
    }
}

async fn run_actor<D: LaserDriver>(
    spec: Arc<LaserSpec>,
    mut driver: D,
    mut rx: mpsc::Receiver<Cmd>,
    status: watch::Sender<LaserStatus>,
) {
    while let Some(cmd) = rx.recv().await {
        let current = *status.borrow();
        match cmd {
            Cmd::Arm(arm, reply) => {
                let mut r = Ok(());
                if !arm && current.on {
                    r = driver.set_emission(false, current.fitted_nm).await;
                    if r.is_ok() {
                        status.send_modify(|s| s.on = false);
                    }
                }
                if r.is_ok() {
                    status.send_modify(|s| s.armed = arm);
                }
                let _ = reply.send(r);
            }
            Cmd::Emit(on, colour, reply) => {
                let r = if on && !current.armed {
                    Err(DeviceError::LaserNotArmed {
                        device: spec.id.clone(),
                    })
                } else if on && colour != current.fitted_nm {
                    Err(DeviceError::LaserColour {
                        device: spec.id.clone(),
                        colour_nm: colour,
                        fitted: vec![current.fitted_nm],
                    })
                } else {
                    driver.set_emission(on, current.fitted_nm).await
                };
                if r.is_ok() {
                    status.send_modify(|s| s.on = on);
                }
                let _ = reply.send(r);
            }
            Cmd::Fit(colour, mount, reply) => {
                let r = if !spec.colours_nm.contains(&colour) {
                    Err(DeviceError::LaserColour {
                        device: spec.id.clone(),
                        colour_nm: colour,
                        fitted: spec.colours_nm.clone(),
                    })
                } else if current.on {
                    Err(DeviceError::Other {
                        device: spec.id.clone(),
                        message: "switch the laser off before swapping or remounting it".into(),
                    })
                } else {
                    driver.fitted(colour, mount).await
                };
                if r.is_ok() {
                    status.send_modify(|s| {
                        s.fitted_nm = colour;
                        s.mount_elevation_deg = mount;
                    });
                }
                let _ = reply.send(r);
            }
        }
    }
}
