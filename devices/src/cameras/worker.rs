//! The std thread that owns a blocking camera library, and the async link to it: every real
//! camera backend implements [`Blocking`] for its library and gets a [`Link`], the
//! `CameraDriver` the rig holds. No C library is needed here, so it is built and tested in the
//! default build, whichever camera features are on.

use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot};

use crate::cameras::accounting::{FrameVerdict, TriggerAccounting, frame_timeout_s};
use crate::cameras::config::TriggerMode;
use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::frame::Frame;

/// Longest a library call on the worker may take before the async side gives up.
pub const CALL_TIMEOUT_S: f64 = 10.0;
/// How long one grab waits before the worker looks at its commands again.
pub const POLL: Duration = Duration::from_millis(50);
/// How long a frame that arrives with no trigger announced is held for an `expect` that
/// may still be on its way (the camera actor announces a trigger after firing it).
pub const EARLY_FRAME_GRACE_S: f64 = 1.0;

/// One image as the library delivered it, with the camera's own sequence number.
pub struct RawFrame {
    /// The camera's own frame counter (block id, sequence number), as the library reports it.
    pub sequence: u64,
    /// Converted image, or why it could not be converted (the frame still counts). A
    /// frame that arrived incomplete is [`DeviceErrorKind::MissingFrame`]; the worker fills in
    /// the trigger it answers, so it is reported like a frame that never came.
    pub image: DeviceResult<Image>,
}

/// A converted image: interleaved RGB u16 samples.
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Significant bits per sample, as the sensor delivers them.
    pub bit_depth: u8,
    /// Interleaved RGB samples, row by row (`width · height · 3`).
    pub pixels: Vec<u16>,
}

/// What a blocking backend does on its own thread. Every call must return within a
/// bounded time (the library's own timeouts).
pub trait Blocking {
    /// Sets exposure and gain.
    fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()>;
    /// Starts acquisition; returns the sequence number the first frame will carry, if known.
    fn arm(&mut self) -> DeviceResult<Option<u64>>;
    /// Stops acquisition.
    fn disarm(&mut self) -> DeviceResult<()>;
    /// Starts one exposure now (software trigger mode only).
    fn software_trigger(&mut self) -> DeviceResult<()>;
    /// Waits up to `timeout` for the next frame; `None` if none came.
    fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>>;
    /// Readout time after an exposure, for the frame deadline.
    fn readout_s(&self) -> f64;
    /// Modulus of the sequence counter (0 = u64).
    fn sequence_wrap(&self) -> u64 {
        0
    }
    /// What the camera reports about the frame just grabbed (settings read back), kept
    /// in the frame's notes under `camera`.
    fn frame_notes(&self) -> Option<serde_json::Value> {
        None
    }
}

enum Cmd {
    Configure(f64, f64, oneshot::Sender<DeviceResult<()>>),
    Arm(bool, oneshot::Sender<DeviceResult<()>>),
    Expect(u64, f64),
}

impl crate::camera::CameraDriver for Link {
    async fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        Link::configure(self, exposure_s, gain).await
    }
    async fn arm(&mut self) -> DeviceResult<()> {
        self.set_armed(true).await
    }
    async fn disarm(&mut self) -> DeviceResult<()> {
        self.set_armed(false).await
    }
    async fn next_frame(&mut self) -> DeviceResult<Frame> {
        Link::next_frame(self).await
    }
    async fn expect(&mut self, trigger_id: u64, exposure_s: f64) -> DeviceResult<()> {
        Link::expect(self, trigger_id, exposure_s)
    }
}

/// The async side: sends commands, receives accounted frames.
pub struct Link {
    device: String,
    cmd: std_mpsc::Sender<Cmd>,
    frames: mpsc::Receiver<DeviceResult<Frame>>,
    last_expected: Option<u64>,
}

impl Link {
    /// Starts the worker thread; `open` runs on it and opens the camera.
    pub fn spawn<B, F>(device: &str, mode: TriggerMode, open: F) -> DeviceResult<Self>
    where
        B: Blocking,
        F: FnOnce() -> DeviceResult<B> + Send + 'static,
    {
        let (cmd_tx, cmd_rx) = std_mpsc::channel();
        let (frame_tx, frames) = mpsc::channel(32);
        let (ready_tx, ready_rx) = std_mpsc::channel();
        let name = device.to_string();
        std::thread::Builder::new()
            .name(format!("cam-{device}"))
            .spawn(move || match open() {
                Ok(cam) => {
                    let _ = ready_tx.send(Ok(()));
                    run(name, mode, cam, cmd_rx, frame_tx);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| {
                DeviceError::new(
                    device.to_string(),
                    DeviceErrorKind::Other {
                        message: format!("cannot start the camera thread: {e}"),
                    },
                )
            })?;
        match ready_rx.recv_timeout(duration_s(CALL_TIMEOUT_S)) {
            Ok(Ok(())) => Ok(Self {
                device: device.to_string(),
                cmd: cmd_tx,
                frames,
                last_expected: None,
            }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Timeout {
                    request: "open".into(),
                    timeout_s: CALL_TIMEOUT_S,
                },
            )),
        }
    }

    fn gone(&self) -> DeviceError {
        DeviceError::new(self.device.clone(), DeviceErrorKind::Gone)
    }

    async fn call(
        &mut self,
        what: &str,
        make: impl FnOnce(oneshot::Sender<DeviceResult<()>>) -> Cmd,
    ) -> DeviceResult<()> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(make(tx)).map_err(|_| self.gone())?;
        match tokio::time::timeout(duration_s(CALL_TIMEOUT_S), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(self.gone()),
            Err(_) => Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Timeout {
                    request: what.into(),
                    timeout_s: CALL_TIMEOUT_S,
                },
            )),
        }
    }

    /// Sets exposure and gain through the library.
    pub async fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        self.call("configure", |tx| Cmd::Configure(exposure_s, gain, tx))
            .await
    }

    /// Arms or disarms; frames and errors not yet collected are dropped.
    pub async fn set_armed(&mut self, armed: bool) -> DeviceResult<()> {
        let what = if armed { "arm" } else { "disarm" };
        let r = self.call(what, |tx| Cmd::Arm(armed, tx)).await;
        while self.frames.try_recv().is_ok() {}
        self.last_expected = None;
        r
    }

    /// Announces trigger `trigger_id` (in software mode this fires the exposure).
    pub fn expect(&mut self, trigger_id: u64, exposure_s: f64) -> DeviceResult<()> {
        self.last_expected = Some(trigger_id);
        self.cmd
            .send(Cmd::Expect(trigger_id, exposure_s))
            .map_err(|_| self.gone())
    }

    /// The next accounted frame or error. A missing-frame report or a late frame about
    /// another trigger than the one last announced is skipped: that trigger was already
    /// answered (the camera actor gave up on it with its own timeout), so its late frame
    /// would otherwise be taken for the next trigger's.
    pub async fn next_frame(&mut self) -> DeviceResult<Frame> {
        loop {
            let item = self.frames.recv().await.ok_or_else(|| self.gone())?;
            let stale = match &item {
                Err(DeviceError {
                    kind: DeviceErrorKind::MissingFrame { trigger_id, .. },
                    ..
                }) => Some(*trigger_id),
                Ok(f) => Some(f.trigger_id),
                Err(_) => None,
            }
            .filter(|t| self.last_expected.is_some_and(|last| last != *t));
            if let Some(trigger_id) = stale {
                let what = if item.is_ok() {
                    "late frame"
                } else {
                    "missing-frame report"
                };
                tracing::warn!(device = %self.device, trigger_id, "stale {what} dropped");
                continue;
            }
            return item;
        }
    }
}

/// The worker loop: commands first, then one bounded grab, then the deadlines.
fn run<B: Blocking>(
    device: String,
    mode: TriggerMode,
    mut cam: B,
    cmds: std_mpsc::Receiver<Cmd>,
    out: mpsc::Sender<DeviceResult<Frame>>,
) {
    let start = Instant::now();
    let now = || start.elapsed().as_secs_f64();
    let mut acc = TriggerAccounting::with_wrap(device.clone(), cam.sequence_wrap());
    let mut armed = false;
    let settings = std::cell::Cell::new((0.0f64, 1.0f64));
    let send = |r: DeviceResult<Frame>| {
        if out.try_send(r).is_err() {
            tracing::warn!(device = %device, "frame queue full or closed; frame dropped");
        }
    };
    let mut held: Option<(RawFrame, f64, Option<serde_json::Value>)> = None;
    // Accounts for one frame and sends the outcome: errors for frames lost before it,
    // then the frame tagged with its trigger (a late frame keeps its own old id, and the
    // link drops it as stale), or an error for an extra frame. A frame is matched before
    // the deadlines are looked at (the loop does that after every grab): one that was
    // already there when a busy worker got to it still answers its trigger.
    let judge = |acc: &mut TriggerAccounting,
                 raw: RawFrame,
                 at: f64,
                 camera_notes: Option<serde_json::Value>| {
        let d = acc.on_frame(raw.sequence);
        for t in d.lost {
            send(Err(DeviceError::new(
                device.clone(),
                DeviceErrorKind::MissingFrame {
                    trigger_id: t,
                    timeout_s: 0.0,
                },
            )));
        }
        let trigger_id = match d.verdict {
            FrameVerdict::Answers(t) | FrameVerdict::Late(t) => t,
            FrameVerdict::Extra => {
                tracing::warn!(device = %device, sequence = raw.sequence, "extra frame with no trigger waiting");
                send(Err(acc.unexpected(&FrameVerdict::Extra)));
                return;
            }
        };
        let mut notes = serde_json::json!({ "sequence": raw.sequence });
        if let Some(c) = camera_notes {
            notes["camera"] = c;
        }
        let image = match raw.image {
            // An incomplete frame: lost, like one that never came, for this trigger.
            Err(DeviceError {
                device,
                kind: DeviceErrorKind::MissingFrame { timeout_s, .. },
            }) => Err(DeviceError::new(
                device,
                DeviceErrorKind::MissingFrame {
                    trigger_id,
                    timeout_s,
                },
            )),
            other => other,
        };
        send(image.map(|img| Frame {
            camera: device.clone(),
            trigger_id,
            width: img.width,
            height: img.height,
            bit_depth: img.bit_depth,
            pixels: img.pixels,
            exposure_s: settings.get().0,
            gain: settings.get().1,
            rig_time_s: at,
            notes,
            ground_truth: None,
        }));
    };
    loop {
        // Commands: block briefly when idle, poll when armed.
        let first = if armed {
            match cmds.try_recv() {
                Ok(c) => Some(c),
                Err(std_mpsc::TryRecvError::Empty) => None,
                Err(std_mpsc::TryRecvError::Disconnected) => break,
            }
        } else {
            match cmds.recv_timeout(POLL) {
                Ok(c) => Some(c),
                Err(std_mpsc::RecvTimeoutError::Timeout) => None,
                Err(std_mpsc::RecvTimeoutError::Disconnected) => break,
            }
        };
        for cmd in first
            .into_iter()
            .chain(std::iter::from_fn(|| cmds.try_recv().ok()))
        {
            match cmd {
                Cmd::Configure(e, g, reply) => {
                    let r = cam.configure(e, g);
                    if r.is_ok() {
                        settings.set((e, g));
                    }
                    let _ = reply.send(r);
                }
                Cmd::Arm(true, reply) => {
                    held = None;
                    let r = cam.arm().map(|first| acc.reset(first));
                    armed = r.is_ok();
                    let _ = reply.send(r);
                }
                Cmd::Arm(false, reply) => {
                    armed = false;
                    held = None;
                    acc.reset(None);
                    let _ = reply.send(cam.disarm());
                }
                Cmd::Expect(id, e) => {
                    if !armed {
                        send(Err(DeviceError::new(
                            device.clone(),
                            DeviceErrorKind::NotArmed,
                        )));
                        continue;
                    }
                    acc.expect(id, now(), frame_timeout_s(e, cam.readout_s()));
                    if let Some((raw, at, notes)) = held.take() {
                        judge(&mut acc, raw, at, notes);
                    } else if mode == TriggerMode::Software
                        && let Err(err) = cam.software_trigger()
                    {
                        if err.is_recoverable() {
                            // The link failed: the trigger stays pending, so its deadline
                            // reports the frame missing (or a frame that does come is
                            // still matched to it).
                            tracing::warn!(device = %device, trigger_id = id, "software trigger failed: {err}");
                        } else {
                            send(Err(err));
                        }
                    }
                }
            }
        }
        if !armed {
            continue;
        }
        match cam.grab(POLL) {
            Ok(None) => {}
            Err(e) => send(Err(e)),
            Ok(Some(raw)) => {
                let at = now();
                let notes = cam.frame_notes();
                // A frame before any announced trigger may be early rather than extra:
                // hold it briefly. A second one means the first was extra.
                if acc.is_idle() {
                    if let Some((old, _, old_notes)) = held.take() {
                        judge(&mut acc, old, at, old_notes);
                    }
                    held = Some((raw, at, notes));
                } else {
                    judge(&mut acc, raw, at, notes);
                }
            }
        }
        if let Some((_, since, _)) = &held
            && now() - since > EARLY_FRAME_GRACE_S
            && let Some((raw, since, notes)) = held.take()
        {
            judge(&mut acc, raw, since, notes);
        }
        for e in acc.expire(now()) {
            send(Err(e));
        }
    }
    let _ = cam.disarm();
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    use super::{Blocking, Image, Link, RawFrame};
    use crate::cameras::config::TriggerMode;
    use crate::error::{DeviceErrorKind, DeviceResult};

    /// A hardware-triggered camera whose frames the test pushes (sequence numbers).
    struct Mock(Arc<Mutex<Vec<u64>>>);

    impl Blocking for Mock {
        fn configure(&mut self, _: f64, _: f64) -> DeviceResult<()> {
            Ok(())
        }
        fn arm(&mut self) -> DeviceResult<Option<u64>> {
            Ok(None)
        }
        fn disarm(&mut self) -> DeviceResult<()> {
            Ok(())
        }
        fn software_trigger(&mut self) -> DeviceResult<()> {
            Ok(())
        }
        fn grab(&mut self, timeout: Duration) -> DeviceResult<Option<RawFrame>> {
            let next = self.0.lock().ok().and_then(|mut q| q.pop());
            match next {
                Some(sequence) => Ok(Some(RawFrame {
                    sequence,
                    image: Ok(Image {
                        width: 1,
                        height: 1,
                        bit_depth: 8,
                        pixels: vec![1, 2, 3],
                    }),
                })),
                None => {
                    std::thread::sleep(timeout);
                    Ok(None)
                }
            }
        }
        fn readout_s(&self) -> f64 {
            0.01
        }
    }

    /// The camera actor announces a trigger after firing it, so a fast frame can arrive
    /// first: it is held and answers the trigger; a second frame without trigger is extra.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn early_frame_answers_the_trigger_announced_after_it() {
        let q = Arc::new(Mutex::new(Vec::new()));
        let q2 = q.clone();
        let mut link =
            Link::spawn("m", TriggerMode::Hardware, move || Ok(Mock(q2))).expect("spawn");
        link.set_armed(true).await.expect("arm");
        q.lock().expect("lock").push(10);
        tokio::time::sleep(Duration::from_millis(150)).await;
        link.expect(7, 0.01).expect("expect");
        let f = tokio::time::timeout(Duration::from_secs(2), link.next_frame())
            .await
            .expect("in time")
            .expect("frame");
        assert_eq!(f.trigger_id, 7);
        assert_eq!(f.notes["sequence"], 10);
        // Two frames for one trigger: the second is held, then judged extra after the grace.
        q.lock().expect("lock").extend([12, 11]);
        link.expect(8, 0.01).expect("expect");
        let f = tokio::time::timeout(Duration::from_secs(2), link.next_frame())
            .await
            .expect("in time")
            .expect("frame");
        assert_eq!(f.trigger_id, 8);
        let e = tokio::time::timeout(Duration::from_secs(3), link.next_frame())
            .await
            .expect("in time")
            .unwrap_err();
        assert!(
            matches!(e.kind, DeviceErrorKind::UnexpectedFrame { .. }),
            "{e}"
        );
    }

    /// A frame that comes after its trigger was reported missing keeps its own trigger id and
    /// is dropped as stale: the next trigger gets its own frame, not the late one.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn late_frame_is_not_taken_for_the_next_trigger() {
        let q = Arc::new(Mutex::new(Vec::new()));
        let q2 = q.clone();
        let mut link =
            Link::spawn("m", TriggerMode::Hardware, move || Ok(Mock(q2))).expect("spawn");
        link.set_armed(true).await.expect("arm");
        link.expect(1, 0.0).expect("expect");
        let e = tokio::time::timeout(Duration::from_secs(10), link.next_frame())
            .await
            .expect("the deadline passes")
            .unwrap_err();
        assert!(
            matches!(e.kind, DeviceErrorKind::MissingFrame { trigger_id: 1, .. }),
            "{e}"
        );
        // Trigger 1's frame (sequence 5) turns up late, then trigger 2's (6).
        q.lock().expect("lock").push(5);
        link.expect(2, 0.0).expect("expect");
        q.lock().expect("lock").insert(0, 6);
        let f = tokio::time::timeout(Duration::from_secs(10), link.next_frame())
            .await
            .expect("in time")
            .expect("frame");
        assert_eq!((f.trigger_id, f.notes["sequence"].as_u64()), (2, Some(6)));
    }
}
