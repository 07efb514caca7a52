//! The one way a handle talks to its actor: send a command carrying a reply channel, and wait
//! for the reply at most `timeout_s`, so no request to a device can hang.

use tokio::sync::{mpsc, oneshot};

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};

/// Sends `make(reply)` to the actor of `device` and awaits the reply within `timeout_s`.
/// A stopped actor is `Gone`; no reply in time is `Timeout` naming the request.
pub(crate) async fn call<C, T>(
    device: &str,
    tx: &mpsc::Sender<C>,
    what: &str,
    timeout_s: f64,
    make: impl FnOnce(oneshot::Sender<DeviceResult<T>>) -> C,
) -> DeviceResult<T> {
    let gone = || DeviceError::new(device.to_string(), DeviceErrorKind::Gone);
    let (reply, rx) = oneshot::channel();
    tx.send(make(reply)).await.map_err(|_| gone())?;
    match tokio::time::timeout(duration_s(timeout_s), rx).await {
        Ok(Ok(r)) => r,
        Ok(Err(_)) => Err(gone()),
        Err(_) => Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Timeout {
                request: what.to_string(),
                timeout_s,
            },
        )),
    }
}
