//! Banks of individually switched outputs: halogen lamps, the backlight, laser power.

use std::future::Future;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot, watch};

use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::request::call;
use crate::rig::SwitchBankSpec;

/// What a backend (simulated relays, serial or HID relay board) must do.
pub trait SwitchBankDriver: Send + 'static {
    /// Switches channel `channel` (from 1) on or off.
    fn set(&mut self, channel: u32, on: bool) -> impl Future<Output = DeviceResult<()>> + Send;
    /// Reads every channel's state, channel 1 first.
    fn read_all(&mut self) -> impl Future<Output = DeviceResult<Vec<bool>>> + Send;
}

enum Cmd {
    Set(Vec<(u32, bool)>, oneshot::Sender<DeviceResult<()>>),
    Read(oneshot::Sender<DeviceResult<Vec<bool>>>),
}

/// Cheap-to-clone handle to the task that owns one switch bank.
#[derive(Clone)]
pub struct SwitchBankHandle {
    spec: Arc<SwitchBankSpec>,
    tx: mpsc::Sender<Cmd>,
    states: watch::Receiver<Vec<bool>>,
}

/// Relays switch in milliseconds; a second is generous.
const TIMEOUT_S: f64 = 1.0;

impl SwitchBankHandle {
    /// Spawns the actor task that owns `driver`.
    pub fn spawn<D: SwitchBankDriver>(spec: SwitchBankSpec, driver: D) -> Self {
        let (tx, rx) = mpsc::channel(8);
        let (state_tx, states) = watch::channel(vec![false; spec.channels as usize]);
        tokio::spawn(run_actor(driver, rx, state_tx));
        Self {
            spec: Arc::new(spec),
            tx,
            states,
        }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    /// Last known channel states (no round trip), channel 1 first.
    pub fn states(&self) -> Vec<bool> {
        self.states.borrow().clone()
    }

    /// Switches several channels in one request.
    pub async fn set_many(&self, changes: &[(u32, bool)]) -> DeviceResult<()> {
        for &(ch, _) in changes {
            if ch == 0 || ch > self.spec.channels {
                return Err(DeviceError::new(
                    self.spec.id.clone(),
                    DeviceErrorKind::NoSuchChannel {
                        channel: ch,
                        channels: self.spec.channels,
                    },
                ));
            }
        }
        let changes = changes.to_vec();
        call(&self.spec.id, &self.tx, "set", TIMEOUT_S, |tx| {
            Cmd::Set(changes, tx)
        })
        .await
    }

    /// Switches every channel off.
    pub async fn all_off(&self) -> DeviceResult<()> {
        let changes: Vec<(u32, bool)> = (1..=self.spec.channels).map(|c| (c, false)).collect();
        self.set_many(&changes).await
    }

    /// Reads the channel states from the device.
    pub async fn read(&self) -> DeviceResult<Vec<bool>> {
        call(&self.spec.id, &self.tx, "read", TIMEOUT_S, Cmd::Read).await
    }
}

async fn run_actor<D: SwitchBankDriver>(
    mut driver: D,
    mut rx: mpsc::Receiver<Cmd>,
    states: watch::Sender<Vec<bool>>,
) {
    while let Some(cmd) = rx.recv().await {
        match cmd {
            Cmd::Set(changes, reply) => {
                let mut result = Ok(());
                for (ch, on) in changes {
                    if let Err(e) = driver.set(ch, on).await {
                        result = Err(e);
                        break;
                    }
                    states.send_modify(|s| {
                        if let Some(slot) = s.get_mut(ch as usize - 1) {
                            *slot = on;
                        }
                    });
                }
                let _ = reply.send(result);
            }
            Cmd::Read(reply) => {
                let r = driver.read_all().await;
                if let Ok(v) = &r {
                    states.send_replace(v.clone());
                }
                let _ = reply.send(r);
            }
        }
    }
}
