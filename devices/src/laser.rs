//! The line laser: arming, colour and on/off. Its tilt is an ordinary axis.
//!
//! The handle enforces the safety rule in one place: the laser emits only while armed and the
//! interlock (the enclosure's door switch, see [`crate::interlock`]) is closed; disarming
//! switches it off first, and so does the interlock opening while it emits.

use std::future::Future;
use std::sync::Arc;

use serde::Serialize;
use tokio::sync::{mpsc, oneshot, watch};

use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
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
    /// The interlock (door switch) is closed: emission is allowed if armed.
    pub interlock_closed: bool,
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
    /// Spawns the actor task that owns `driver`, with no interlock (it reads as closed). The
    /// laser starts disarmed and off.
    pub fn spawn<D: LaserDriver>(spec: LaserSpec, driver: D) -> Self {
        // The sender is dropped at once: the actor keeps the last value, closed.
        let (_, interlock) = watch::channel(true);
        Self::spawn_with_interlock(spec, driver, interlock)
    }

    /// Spawns the actor task that owns `driver`, watching `interlock` (true = closed): the
    /// laser emits only while armed and the interlock is closed, and switches off at once when
    /// it opens. The laser starts disarmed and off.
    pub fn spawn_with_interlock<D: LaserDriver>(
        spec: LaserSpec,
        driver: D,
        interlock: watch::Receiver<bool>,
    ) -> Self {
        let (tx, rx) = mpsc::channel(8);
        let initial = LaserStatus {
            armed: false,
            on: false,
            fitted_nm: spec.fitted_nm,
            mount_elevation_deg: spec.mount_elevation_deg,
            interlock_closed: *interlock.borrow(),
        };
        let (status_tx, status) = watch::channel(initial);
        let spec = Arc::new(spec);
        tokio::spawn(run_actor(spec.clone(), driver, rx, interlock, status_tx));
        Self { spec, tx, status }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    pub fn status(&self) -> LaserStatus {
        *self.status.borrow()
    }

    /// A receiver that sees every status change (for live dashboards).
    pub fn watch(&self) -> watch::Receiver<LaserStatus> {
        self.status.clone()
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

    /// Switches emission on; fails unless armed, the interlock is closed and `colour_nm` is
    /// the fitted module.
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
    mut interlock: watch::Receiver<bool>,
    status: watch::Sender<LaserStatus>,
) {
    // False once the interlock's sender is gone: its last value then holds for good.
    let mut watching = true;
    loop {
        let cmd = tokio::select! {
            biased;
            changed = interlock.changed(), if watching => {
                if changed.is_err() {
                    watching = false;
                } else {
                    let closed = *interlock.borrow_and_update();
                    interlock_changed(&spec, &mut driver, &status, closed).await;
                }
                continue;
            }
            cmd = rx.recv() => cmd,
        };
        let Some(cmd) = cmd else { break };
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
                    Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::LaserNotArmed,
                    ))
                } else if on && !*interlock.borrow() {
                    Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::InterlockOpen,
                    ))
                } else if on && colour != current.fitted_nm {
                    Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::LaserColour {
                            colour_nm: colour,
                            fitted: vec![current.fitted_nm],
                        },
                    ))
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
                    Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::LaserColour {
                            colour_nm: colour,
                            fitted: spec.colours_nm.clone(),
                        },
                    ))
                } else if current.on {
                    Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::Other {
                            message: "switch the laser off before swapping or remounting it".into(),
                        },
                    ))
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

/// The interlock opened or closed: publish it, and switch the emission off at once if it
/// opened while emitting (if the driver fails, the status keeps saying `on` and the failure
/// is logged: the truth, for the operator to act on).
async fn interlock_changed<D: LaserDriver>(
    spec: &LaserSpec,
    driver: &mut D,
    status: &watch::Sender<LaserStatus>,
    closed: bool,
) {
    status.send_modify(|s| s.interlock_closed = closed);
    let current = *status.borrow();
    if closed || !current.on {
        return;
    }
    match driver.set_emission(false, current.fitted_nm).await {
        Ok(()) => {
            tracing::warn!("{}: the interlock opened; emission switched off", spec.id);
            status.send_modify(|s| s.on = false);
        }
        Err(e) => tracing::error!(
            "{}: the interlock opened but the emission could not be switched off: {e}",
            spec.id
        ),
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;
    use crate::interlock::Interlock;
    use crate::rig::{BUILTIN_LIGHTSTAGE, parse_rig};

    /// Records whether the driver was told to emit.
    #[derive(Clone, Default)]
    struct Recording(Arc<Mutex<bool>>);

    impl LaserDriver for Recording {
        async fn set_emission(&mut self, on: bool, _colour_nm: u32) -> DeviceResult<()> {
            *self.0.lock().unwrap() = on;
            Ok(())
        }
        async fn fitted(&mut self, _colour_nm: u32, _mount: f64) -> DeviceResult<()> {
            Ok(())
        }
    }

    fn spec() -> LaserSpec {
        parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml")
            .unwrap()
            .laser
            .unwrap()
    }

    /// Lets the actor handle what was just sent to it.
    async fn settle() {
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
    }

    #[tokio::test(start_paused = true)]
    async fn the_laser_emits_only_while_armed_with_the_interlock_closed() {
        let driver = Recording::default();
        let emitting = driver.0.clone();
        let door = Interlock::simulated();
        let laser = LaserHandle::spawn_with_interlock(spec(), driver, door.watch());
        laser.arm().await.unwrap();

        door.set_closed(false).unwrap();
        settle().await;
        let e = laser.on(650).await.unwrap_err();
        assert!(
            matches!(e, DeviceError { ref device, kind: DeviceErrorKind::InterlockOpen } if device == "laser")
        );
        assert!(e.to_string().contains("interlock"), "{e}");
        assert!(!*emitting.lock().unwrap());
        assert!(!laser.status().interlock_closed);

        door.set_closed(true).unwrap();
        settle().await;
        laser.on(650).await.unwrap();
        assert!(*emitting.lock().unwrap());
        assert!(laser.status().on && laser.status().interlock_closed);

        // Opening the door while emitting switches the emission off at once.
        door.set_closed(false).unwrap();
        settle().await;
        assert!(!*emitting.lock().unwrap());
        let s = laser.status();
        assert!(!s.on && s.armed && !s.interlock_closed);
    }

    #[tokio::test(start_paused = true)]
    async fn a_laser_without_interlock_reads_closed() {
        let laser = LaserHandle::spawn(spec(), Recording::default());
        assert!(laser.status().interlock_closed);
        laser.arm().await.unwrap();
        laser.on(650).await.unwrap();
        assert!(laser.status().on);
    }
}
