//! The trigger source: one pulse fires every armed camera at once and gets a fresh id.

use std::future::Future;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot};

use crate::error::DeviceResult;
use crate::request::call;
use crate::rig::TriggerSpec;

/// What a backend (simulated line, a GPIO or serial trigger box, software trigger) must do.
pub trait TriggerDriver: Send + 'static {
    /// Emits one pulse carrying `trigger_id`.
    fn fire(&mut self, trigger_id: u64) -> impl Future<Output = DeviceResult<()>> + Send;
}

/// Cheap-to-clone handle to the task that owns the trigger source.
///
/// Trigger ids are chosen by the caller (the executor derives them from step and exposure),
/// so a resumed run re-fires exactly the ids an uninterrupted run would have used.
#[derive(Clone)]
pub struct TriggerHandle {
    spec: Arc<TriggerSpec>,
    tx: mpsc::Sender<(u64, oneshot::Sender<DeviceResult<()>>)>,
}

const TIMEOUT_S: f64 = 1.0;

impl TriggerHandle {
    /// Spawns the actor that owns `driver`.
    pub fn spawn<D: TriggerDriver>(spec: TriggerSpec, mut driver: D) -> Self {
        let (tx, mut rx) = mpsc::channel::<(u64, oneshot::Sender<DeviceResult<()>>)>(8);
        tokio::spawn(async move {
            while let Some((id, reply)) = rx.recv().await {
                let _ = reply.send(driver.fire(id).await);
            }
        });
        Self {
            spec: Arc::new(spec),
            tx,
        }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    /// Fires once; every armed camera tags the frame of this pulse with `trigger_id`.
    pub async fn fire(&self, trigger_id: u64) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "fire", TIMEOUT_S, |tx| {
            (trigger_id, tx)
        })
        .await
    }
}
