//! Cameras: exposure, gain, arming, and exact trigger accounting — one frame per trigger id.

use std::future::Future;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot};

use crate::clock::duration_s;
use crate::compute_time::ComputeTime;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::frame::Frame;
use crate::request::call;
use crate::rig::CameraSpec;

/// What a backend (simulated camera, V4L2, GenICam, gphoto2) must do.
pub trait CameraDriver: Send + 'static {
    /// Sets exposure time and analogue gain for the following triggers.
    fn configure(
        &mut self,
        exposure_s: f64,
        gain: f64,
    ) -> impl Future<Output = DeviceResult<()>> + Send;
    /// Starts listening to the trigger.
    fn arm(&mut self) -> impl Future<Output = DeviceResult<()>> + Send;
    /// Stops listening to the trigger and drops frames not yet collected.
    fn disarm(&mut self) -> impl Future<Output = DeviceResult<()>> + Send;
    /// Waits for the next frame the camera delivers.
    fn next_frame(&mut self) -> impl Future<Output = DeviceResult<Frame>> + Send;
    /// Announces that the next frame answers `trigger_id`, before it is awaited. Hardware
    /// frames carry the camera's own sequence number, not our id: drivers tag frames in
    /// order and use the sequence to notice lost or extra frames; software-triggered cameras
    /// expose now. Drivers whose frames carry the id (the simulator's) need do nothing.
    fn expect(
        &mut self,
        trigger_id: u64,
        exposure_s: f64,
    ) -> impl Future<Output = DeviceResult<()>> + Send {
        let _ = (trigger_id, exposure_s);
        async { Ok(()) }
    }
    /// For a simulated camera, the account of its rendering time, which frame timeouts do not
    /// count (the physical camera it stands in for would not spend it); `None` for hardware.
    fn compute_time(&self) -> Option<ComputeTime> {
        None
    }
}

enum Cmd {
    Configure(f64, f64, oneshot::Sender<DeviceResult<()>>),
    Arm(bool, oneshot::Sender<DeviceResult<()>>),
    Expect(u64, f64, oneshot::Sender<DeviceResult<()>>),
    FrameFor(u64, f64, oneshot::Sender<DeviceResult<Frame>>),
}

/// Cheap-to-clone handle to the task that owns one camera.
#[derive(Clone)]
pub struct CameraHandle {
    spec: Arc<CameraSpec>,
    tx: mpsc::Sender<Cmd>,
    /// Rendering time of a simulated camera (never counted against a frame's timeout).
    compute: ComputeTime,
    simulated: bool,
}

/// Slack beyond exposure + readout before a frame is declared missing.
const MARGIN_S: f64 = 2.0;

impl CameraHandle {
    /// Spawns the actor task that owns `driver`.
    pub fn spawn<D: CameraDriver>(spec: CameraSpec, driver: D) -> Self {
        let (tx, rx) = mpsc::channel(8);
        let spec = Arc::new(spec);
        let simulated = driver.compute_time();
        let compute = simulated.clone().unwrap_or_default();
        tokio::spawn(run_actor(spec.clone(), driver, rx, compute.clone()));
        Self {
            spec,
            tx,
            compute,
            simulated: simulated.is_some(),
        }
    }

    pub fn id(&self) -> &str {
        &self.spec.id
    }

    pub fn spec(&self) -> &CameraSpec {
        &self.spec
    }

    /// Sets exposure and gain, checking them against the camera's ranges.
    pub async fn configure(&self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        let s = &self.spec;
        if !(exposure_s.is_finite()
            && exposure_s >= s.min_exposure_s
            && exposure_s <= s.max_exposure_s)
        {
            return Err(DeviceError::new(
                s.id.clone(),
                DeviceErrorKind::Exposure {
                    exposure_s,
                    min_s: s.min_exposure_s,
                    max_s: s.max_exposure_s,
                },
            ));
        }
        if !(gain.is_finite() && (1.0..=s.max_gain).contains(&gain)) {
            return Err(DeviceError::new(
                s.id.clone(),
                DeviceErrorKind::Gain {
                    gain,
                    max: s.max_gain,
                },
            ));
        }
        call(&s.id, &self.tx, "configure", MARGIN_S, |tx| {
            Cmd::Configure(exposure_s, gain, tx)
        })
        .await
    }

    /// Arms (true) or disarms (false) the camera.
    pub async fn set_armed(&self, armed: bool) -> DeviceResult<()> {
        let what = if armed { "arm" } else { "disarm" };
        call(&self.spec.id, &self.tx, what, MARGIN_S, |tx| {
            Cmd::Arm(armed, tx)
        })
        .await
    }

    /// Announces that the next trigger is `trigger_id`, before it fires (hardware cameras tag
    /// their next frame with it; software-triggered ones expose now).
    pub async fn expect(&self, trigger_id: u64, exposure_s: f64) -> DeviceResult<()> {
        call(&self.spec.id, &self.tx, "expect", MARGIN_S, |tx| {
            Cmd::Expect(trigger_id, exposure_s, tx)
        })
        .await
    }

    /// Collects the frame for `trigger_id`. Waits at most exposure + readout + margin; a
    /// frame of another trigger is an error, never silently accepted.
    /// A simulated camera's rendering time is not counted, and its failures say they are
    /// simulated faults rather than sending anyone to check a cable.
    pub async fn frame_for(&self, trigger_id: u64, exposure_s: f64) -> DeviceResult<Frame> {
        let wait_s = exposure_s + self.spec.readout_s() + MARGIN_S;
        let timeout_s = wait_s + MARGIN_S;
        let id = &self.spec.id;
        let gone = || DeviceError::new(id.clone(), DeviceErrorKind::Gone);
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Cmd::FrameFor(trigger_id, wait_s, reply))
            .await
            .map_err(|_| gone())?;
        let r = match self.compute.timeout(duration_s(timeout_s), rx).await {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(gone()),
            None => Err(DeviceError::new(
                id.clone(),
                DeviceErrorKind::Timeout {
                    request: "frame".into(),
                    timeout_s,
                },
            )),
        };
        match r {
            Err(
                DeviceError {
                    kind: DeviceErrorKind::Timeout { timeout_s, .. },
                    ..
                }
                | DeviceError {
                    kind: DeviceErrorKind::MissingFrame { timeout_s, .. },
                    ..
                },
            ) if self.simulated => Err(DeviceError::new(
                id.clone(),
                DeviceErrorKind::SimulatedFault {
                    request: "frame".into(),
                    message: format!(
                        "no frame for trigger {trigger_id} within {timeout_s:.3} s of rig time (rendering not counted)"
                    ),
                },
            )),
            other => other,
        }
    }
}

async fn run_actor<D: CameraDriver>(
    spec: Arc<CameraSpec>,
    mut driver: D,
    mut rx: mpsc::Receiver<Cmd>,
    compute: ComputeTime,
) {
    while let Some(cmd) = rx.recv().await {
        match cmd {
            Cmd::Configure(e, g, reply) => {
                let _ = reply.send(driver.configure(e, g).await);
            }
            Cmd::Arm(true, reply) => {
                let _ = reply.send(driver.arm().await);
            }
            Cmd::Arm(false, reply) => {
                let _ = reply.send(driver.disarm().await);
            }
            Cmd::Expect(id, exposure_s, reply) => {
                let _ = reply.send(driver.expect(id, exposure_s).await);
            }
            Cmd::FrameFor(id, wait_s, reply) => {
                let r = match compute
                    .timeout(duration_s(wait_s), driver.next_frame())
                    .await
                {
                    None => Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::MissingFrame {
                            trigger_id: id,
                            timeout_s: wait_s,
                        },
                    )),
                    Some(Err(e)) => Err(e),
                    Some(Ok(frame)) if frame.trigger_id != id => Err(DeviceError::new(
                        spec.id.clone(),
                        DeviceErrorKind::UnexpectedFrame {
                            expected: id,
                            got: frame.trigger_id,
                        },
                    )),
                    Some(Ok(frame)) => Ok(frame),
                };
                let _ = reply.send(r);
            }
        }
    }
}
