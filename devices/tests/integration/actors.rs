//! The actor handles enforce the device contracts whatever the backend does: exact trigger
//! accounting, timeouts derived from the physics, soft limits, laser arming.

use std::collections::VecDeque;
use std::time::Duration;

use stagehand_devices::axis::{AxisDriver, AxisHandle};
use stagehand_devices::camera::{CameraDriver, CameraHandle};
use stagehand_devices::error::DeviceResult;
use stagehand_devices::frame::Frame;
use stagehand_devices::laser::{LaserDriver, LaserHandle};
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, RigSpec, parse_rig};
use stagehand_devices::{DeviceError, DeviceErrorKind};

fn rig() -> RigSpec {
    parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").unwrap()
}

fn frame(id: u64) -> Frame {
    Frame {
        camera: "cam1".into(),
        trigger_id: id,
        width: 1,
        height: 1,
        bit_depth: 12,
        pixels: vec![0; 3],
        exposure_s: 0.01,
        gain: 1.0,
        rig_time_s: 0.0,
        notes: serde_json::Value::Null,
        ground_truth: None,
    }
}

/// A camera that delivers a scripted sequence of frames (or stalls when it runs out).
struct ScriptedCamera {
    frames: VecDeque<u64>,
}

impl CameraDriver for ScriptedCamera {
    async fn configure(&mut self, _e: f64, _g: f64) -> DeviceResult<()> {
        Ok(())
    }
    async fn arm(&mut self) -> DeviceResult<()> {
        Ok(())
    }
    async fn disarm(&mut self) -> DeviceResult<()> {
        Ok(())
    }
    async fn next_frame(&mut self) -> DeviceResult<Frame> {
        match self.frames.pop_front() {
            Some(id) => Ok(frame(id)),
            None => std::future::pending().await,
        }
    }
}

fn camera(frames: &[u64]) -> CameraHandle {
    let spec = rig().cameras[0].clone();
    CameraHandle::spawn(
        spec,
        ScriptedCamera {
            frames: frames.iter().copied().collect(),
        },
    )
}

#[tokio::test(start_paused = true)]
async fn frame_for_the_right_trigger_is_accepted() {
    let cam = camera(&[7]);
    assert_eq!(cam.frame_for(7, 0.01).await.unwrap().trigger_id, 7);
}

#[tokio::test(start_paused = true)]
async fn a_stalled_camera_is_a_missing_frame_within_exposure_plus_readout() {
    let cam = camera(&[]);
    let started = tokio::time::Instant::now();
    let err = cam.frame_for(3, 0.5).await.unwrap_err();
    assert!(
        matches!(
            err,
            DeviceError {
                kind: DeviceErrorKind::MissingFrame { trigger_id: 3, .. },
                ..
            }
        ),
        "{err}"
    );
    let waited = started.elapsed();
    // exposure + readout (1/15 s) + margin, never an unbounded wait
    assert!(
        waited >= Duration::from_secs_f64(0.5 + 1.0 / 15.0) && waited < Duration::from_secs(5),
        "{waited:?}"
    );
    assert!(err.to_string().contains("cam1"));
}

#[tokio::test(start_paused = true)]
async fn a_leftover_or_foreign_frame_is_an_error_not_accepted() {
    let cam = camera(&[4, 5]);
    let err = cam.frame_for(5, 0.01).await.unwrap_err();
    assert_eq!(
        err,
        DeviceError::new(
            "cam1",
            DeviceErrorKind::UnexpectedFrame {
                expected: 5,
                got: 4
            }
        )
    );
}

#[tokio::test(start_paused = true)]
async fn exposure_and_gain_outside_the_camera_ranges_are_refused() {
    let cam = camera(&[]);
    assert!(matches!(
        cam.configure(-0.01, 1.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::Exposure { .. },
            ..
        })
    ));
    assert!(matches!(
        cam.configure(f64::NAN, 1.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::Exposure { .. },
            ..
        })
    ));
    assert!(matches!(
        cam.configure(100.0, 1.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::Exposure { .. },
            ..
        })
    ));
    assert!(matches!(
        cam.configure(0.01, 0.5).await,
        Err(DeviceError {
            kind: DeviceErrorKind::Gain { .. },
            ..
        })
    ));
    cam.configure(0.01, 2.0).await.unwrap();
}

/// An axis whose controller never answers a move.
struct DeadAxis;

impl AxisDriver for DeadAxis {
    async fn home(&mut self) -> DeviceResult<f64> {
        Ok(0.0)
    }
    async fn move_to(&mut self, _t: f64) -> DeviceResult<f64> {
        std::future::pending().await
    }
    async fn stop(&mut self) -> DeviceResult<f64> {
        Ok(1.5)
    }
    async fn position(&mut self) -> DeviceResult<f64> {
        Ok(0.0)
    }
}

#[tokio::test(start_paused = true)]
async fn a_stalled_move_times_out_after_its_physical_duration_plus_margin() {
    let spec = rig().axes[0].clone();
    let axis = AxisHandle::spawn(spec.clone(), DeadAxis);
    axis.home().await.unwrap();
    let started = tokio::time::Instant::now();
    let err = axis.move_to(90.0).await.unwrap_err();
    assert!(
        matches!(
            err,
            DeviceError {
                kind: DeviceErrorKind::Timeout { .. },
                ..
            }
        ),
        "{err}"
    );
    let physical =
        stagehand_devices::motion::move_duration_s(0.0, 90.0, spec.kinematics(), spec.backlash_deg);
    let waited = started.elapsed().as_secs_f64();
    assert!(
        waited > physical && waited < physical * 2.0 + 5.0,
        "waited {waited} for a {physical} s move"
    );
    // Stop still reaches the actor and reports where the axis is.
    assert_eq!(axis.stop().await.unwrap(), 1.5);
}

#[tokio::test(start_paused = true)]
async fn soft_limits_and_homing_are_enforced_before_the_driver_is_asked() {
    let spec = rig().axes[0].clone();
    let axis = AxisHandle::spawn(spec, DeadAxis);
    assert!(matches!(
        axis.move_to(10.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::NotHomed,
            ..
        })
    ));
    axis.home().await.unwrap();
    assert!(matches!(
        axis.move_to(1000.0).await,
        Err(DeviceError {
            kind: DeviceErrorKind::OutsideSoftLimits { .. },
            ..
        })
    ));
    assert!(matches!(
        axis.move_to(f64::NAN).await,
        Err(DeviceError {
            kind: DeviceErrorKind::OutsideSoftLimits { .. },
            ..
        })
    ));
}

/// A laser that records what it was told.
#[derive(Default)]
struct RecordingLaser {
    emitting: std::sync::Arc<std::sync::Mutex<bool>>,
}

impl LaserDriver for RecordingLaser {
    async fn set_emission(&mut self, on: bool, _c: u32) -> DeviceResult<()> {
        *self.emitting.lock().unwrap() = on;
        Ok(())
    }
    async fn fitted(&mut self, _c: u32, _m: f64) -> DeviceResult<()> {
        Ok(())
    }
}

#[tokio::test(start_paused = true)]
async fn the_laser_emits_only_when_armed_and_disarming_switches_it_off() {
    let driver = RecordingLaser::default();
    let emitting = driver.emitting.clone();
    let laser = LaserHandle::spawn(rig().laser.unwrap(), driver);
    assert!(matches!(
        laser.on(650).await,
        Err(DeviceError {
            kind: DeviceErrorKind::LaserNotArmed,
            ..
        })
    ));
    assert!(!*emitting.lock().unwrap());
    laser.arm().await.unwrap();
    assert!(
        matches!(
            laser.on(532).await,
            Err(DeviceError {
                kind: DeviceErrorKind::LaserColour { .. },
                ..
            })
        ),
        "532 nm is not fitted"
    );
    laser.on(650).await.unwrap();
    assert!(*emitting.lock().unwrap());
    assert!(
        laser.fitted(532, 40.0).await.is_err(),
        "no swap while emitting"
    );
    laser.disarm().await.unwrap();
    assert!(!*emitting.lock().unwrap());
    let s = laser.status();
    assert!(!s.armed && !s.on);
}
