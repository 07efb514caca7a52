//! A simulated camera: on each trigger pulse it exposes, renders the World as it was when the
//! exposure started, reads out, and delivers the frame tagged with the pulse's trigger id.

use std::sync::Arc;

use stagehand_devices::camera::CameraDriver;
use stagehand_devices::compute_time::ComputeTime;
use stagehand_devices::error::DeviceResult;
use stagehand_devices::frame::Frame;
use stagehand_devices::ground_truth::GroundTruthData;
use stagehand_devices::rig::CameraSpec;
use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::sync::broadcast;

use crate::render::config::FrameSource;
use crate::sim_devices::TestPattern;
use crate::world::{Pulse, World};
use crate::world_snapshot::WorldSnapshot;

/// Simulated camera driver.
pub struct SimCamera {
    spec: CameraSpec,
    world: Arc<World>,
    exposure_s: f64,
    gain: f64,
    armed: Option<broadcast::Receiver<Pulse>>,
    /// The trigger id the host announced for the next frame (tags hardware pulses).
    expected: Option<u64>,
    /// The last ground truth rendered and the scene it shows (rig time zeroed): the exposures
    /// of a bracket see the same scene, so they share one.
    ground_truth: Option<(WorldSnapshot, Arc<GroundTruthData>)>,
    /// Rendering time, which the camera's frame timeouts do not count.
    compute: ComputeTime,
    /// The test pattern's plate (`sim.frames = "pattern"`), drawn when the camera is first
    /// armed, as a camera allocates its buffers when acquisition starts: drawn at the first
    /// trigger instead, it delayed the first captures of a run.
    pattern: Option<TestPattern>,
}

impl SimCamera {
    pub fn new(spec: CameraSpec, world: Arc<World>) -> Self {
        Self {
            spec,
            world,
            exposure_s: 0.01,
            gain: 1.0,
            armed: None,
            expected: None,
            ground_truth: None,
            compute: ComputeTime::default(),
            pattern: None,
        }
    }

    /// Ground truth of `snapshot` when the rig asks for it (`sim.ground_truth`), reusing the
    /// previous one if the scene has not changed since.
    fn ground_truth(
        &mut self,
        snapshot: &WorldSnapshot,
    ) -> DeviceResult<Option<Arc<GroundTruthData>>> {
        let wanted = &self.world.sim().ground_truth;
        if !wanted.any() {
            return Ok(None);
        }
        let mut key = WorldSnapshot {
            rig_time_s: 0.0,
            ..snapshot.clone()
        };
        if wanted.geometry_only() {
            // Depth, normals and material see neither the lamps nor the laser (its tilt only
            // turns the sheet): a sweep shares one ground truth.
            key.lamps.clear();
            key.laser = None;
            if let Some(laser) = &self.world.rig().laser {
                key.axes.remove(&laser.tilt_axis);
            }
        }
        if let Some((seen, data)) = &self.ground_truth
            && *seen == key
        {
            return Ok(Some(Arc::clone(data)));
        }
        let data = self
            .world
            .renderer()
            .ground_truth_of(snapshot, &self.spec.id, wanted)
            .map_err(|e| {
                DeviceError::new(
                    self.spec.id.clone(),
                    DeviceErrorKind::Other {
                        message: format!("ground truth: {e}"),
                    },
                )
            })?;
        let data = Arc::new(data.into_data_of(wanted));
        self.ground_truth = Some((key, Arc::clone(&data)));
        Ok(Some(data))
    }

    /// The test pattern's plate, drawn (off the async workers) the first time it is asked for.
    fn pattern_plate(&mut self) -> &TestPattern {
        let (spec, seed) = (&self.spec, self.noise_seed(0));
        self.pattern.get_or_insert_with(|| {
            off_the_async_workers(|| {
                TestPattern::new(spec.width, spec.height, spec.bit_depth, seed)
            })
        })
    }

    fn noise_seed(&self, trigger_id: u64) -> u64 {
        // FNV-1a over (seed, camera id, trigger id): stable across runs and platforms.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for b in bytes {
                h ^= u64::from(*b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        eat(&self.world.seed().to_le_bytes());
        eat(self.spec.id.as_bytes());
        eat(&trigger_id.to_le_bytes());
        h
    }
}

impl CameraDriver for SimCamera {
    async fn configure(&mut self, exposure_s: f64, gain: f64) -> DeviceResult<()> {
        self.exposure_s = exposure_s;
        self.gain = gain;
        Ok(())
    }

    async fn arm(&mut self) -> DeviceResult<()> {
        if self.armed.is_none() {
            self.armed = Some(self.world.subscribe());
        }
        if self.world.sim().frames == FrameSource::Pattern {
            self.pattern_plate();
        }
        Ok(())
    }

    async fn disarm(&mut self) -> DeviceResult<()> {
        self.armed = None;
        Ok(())
    }

    fn compute_time(&self) -> Option<ComputeTime> {
        Some(self.compute.clone())
    }

    async fn expect(&mut self, trigger_id: u64, _exposure_s: f64) -> DeviceResult<()> {
        self.expected = Some(trigger_id);
        Ok(())
    }

    async fn next_frame(&mut self) -> DeviceResult<Frame> {
        let id = self.spec.id.clone();
        let rx = self
            .armed
            .as_mut()
            .ok_or_else(|| DeviceError::new(id.clone(), DeviceErrorKind::NotArmed))?;
        let pulse = loop {
            let pulse = match rx.recv().await {
                Ok(p) => p,
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    return Err(DeviceError::new(
                        id,
                        DeviceErrorKind::Other {
                            message: format!("missed {n} trigger pulses; the camera was too slow"),
                        },
                    ));
                }
                Err(broadcast::error::RecvError::Closed) => {
                    return Err(DeviceError::new(id, DeviceErrorKind::Gone));
                }
            };
            // A stalled camera (fault injection) swallows the pulse and delivers nothing.
            if !self.world.take_stalled_frame(&id) {
                break pulse;
            }
        };
        // A hardware pulse carries no id: the frame answers the trigger the host announced.
        let trigger_id = match (pulse.hardware, self.expected.take()) {
            (true, Some(expected)) => expected,
            _ => pulse.trigger_id,
        };
        let clock = self.world.clock();
        let start = pulse.rig_time_s;
        let end = start + self.exposure_s;
        self.world.begin_exposure(start, end);
        clock.sleep_until_s(end).await;
        let compute = self.compute.clone();
        let (pixels, notes, ground_truth) = if self.world.sim().frames == FrameSource::Pattern {
            let plate = self.pattern_plate();
            let pixels = off_the_async_workers(|| plate.frame(trigger_id));
            (
                pixels,
                serde_json::json!({ "source": "test pattern" }),
                None,
            )
        } else {
            let snapshot = self.world.snapshot_at(start);
            let (rendered, ground_truth) = off_the_async_workers(|| {
                compute.measure(|| {
                    let rendered = self
                        .world
                        .renderer()
                        .render(
                            &snapshot,
                            &id,
                            self.exposure_s,
                            self.gain,
                            self.noise_seed(trigger_id),
                        )
                        .map_err(|e| {
                            DeviceError::new(
                                id.clone(),
                                DeviceErrorKind::Other {
                                    message: e.to_string(),
                                },
                            )
                        })?;
                    Ok::<_, DeviceError>((rendered, self.ground_truth(&snapshot)?))
                })
            })?;
            (rendered.pixels, rendered.notes, ground_truth)
        };
        clock.sleep_until_s(end + self.spec.readout_s()).await;
        Ok(Frame {
            camera: id,
            trigger_id,
            width: self.spec.width,
            height: self.spec.height,
            bit_depth: self.spec.bit_depth,
            pixels,
            exposure_s: self.exposure_s,
            gain: self.gain,
            rig_time_s: start,
            notes,
            ground_truth,
        })
    }
}

/// Runs a render (CPU-bound for up to a second) without starving other tasks: on a
/// multi-threaded runtime (the daemon, real-time rigs) the worker hands its other tasks to a
/// fresh worker first, so the HTTP API and the e-stop stay responsive, and the render runs at
/// normal priority when the runtime's threads are real-time (`--realtime-priority`), so it
/// never keeps the frame writer off a core; on the single-threaded virtual-clock runtime it
/// simply runs.
fn off_the_async_workers<T>(f: impl FnOnce() -> T) -> T {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current().map(|h| h.runtime_flavor()) {
        Ok(RuntimeFlavor::MultiThread) => {
            tokio::task::block_in_place(|| stagehand_devices::realtime::at_normal_priority(f))
        }
        _ => f(),
    }
}
