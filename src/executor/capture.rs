//! One capture step: check the rig's state, arm every listed camera and set up the first
//! exposure, wait for lamp warm-up and pacing, then for each exposure of the bracket fire one
//! trigger and collect exactly one frame per camera for that trigger id.

use stagehand_devices::{DeviceError, DeviceErrorKind, Frame};

use super::{Execution, Live, StepFailure, missing, try_all, wall_now};
use crate::plan::{Action, Step};
use crate::storage::{FrameKind, FrameMeta};

/// Largest bracket a capture may have (trigger ids reserve 1000 per step).
pub const MAX_BRACKET: usize = 999;

/// Frames of one step, waiting to be written.
#[derive(Default)]
pub struct StepFrames {
    /// Raw frames with their metadata.
    pub frames: Vec<(FrameMeta, Frame)>,
    /// HDR merges to make: metadata of the merged frame, indices into `frames`, black level.
    pub hdr: Vec<(FrameMeta, Vec<usize>, f64)>,
}

/// The trigger id of exposure `exposure` of step `step`: unique in a run and the same in a
/// resumed run as in an uninterrupted one.
pub fn trigger_id(step: usize, exposure: usize) -> u64 {
    (step as u64 + 1) * 1000 + exposure as u64
}

pub(super) async fn capture(
    ex: &Execution,
    step: &Step,
    live: &mut Live,
) -> Result<StepFrames, StepFailure> {
    let Action::Capture {
        exposures_s,
        cameras,
        gain,
        hdr,
        label,
        min_interval_s,
    } = &step.action
    else {
        return Ok(StepFrames::default());
    };
    let rig = &ex.rig;
    if exposures_s.is_empty() || exposures_s.len() > MAX_BRACKET {
        return Err(missing(
            "trigger",
            &format!(
                "a capture needs 1..={MAX_BRACKET} exposures, got {}",
                exposures_s.len()
            ),
        )
        .into());
    }
    let handles = cameras
        .iter()
        .map(|id| {
            rig.cameras
                .get(id)
                .ok_or_else(|| missing(id, "no such camera in this rig"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let trigger = rig
        .trigger
        .as_ref()
        .ok_or_else(|| missing("trigger", "this rig has no trigger source"))?;

    // Lamp warm-up and sweep pacing: the earliest time the trigger may fire.
    let mut ready = rig.clock.now_s();
    for (id, since) in &live.lamp_on_since {
        let warm = rig.spec.lamp(id).map(|l| l.warmup_s).unwrap_or(0.0);
        ready = ready.max(since + warm);
    }
    if let Some(last) = live.last_capture_s {
        ready = ready.max(last + min_interval_s);
    }

    let mut out = StepFrames::default();
    // A frame is only worth keeping if the rig was as planned throughout its exposure: checked
    // before, after, and for the laser (which the interlock can switch off at any moment)
    // throughout. Everything a trigger needs (the check, arming, the first exposure's settings)
    // is done before the pacing deadline, so that at the deadline only the trigger fires: a
    // relay board read back over serial or a camera's settings over the network would
    // otherwise delay every paced trigger, and each device round trip is a chance for the
    // task to wait for a core.
    verify_state(ex, live).await?;
    let mut laser_watch = rig.laser.as_ref().map(|l| {
        let mut w = l.watch();
        w.mark_unchanged();
        w
    });
    try_all(handles.iter().map(|c| c.set_armed(true))).await?;
    let result = async {
        for (e, &exposure) in exposures_s.iter().enumerate() {
            try_all(handles.iter().map(|c| c.configure(exposure, *gain))).await?;
            let id = trigger_id(step.index, e);
            try_all(handles.iter().map(|c| c.expect(id, exposure))).await?;
            if e == 0 {
                rig.clock.sleep_until_s(ready).await;
                live.last_capture_s = Some(rig.clock.now_s());
            }
            trigger.fire(id).await?;
            let frames = try_all(handles.iter().map(|c| c.frame_for(id, exposure))).await?;
            for frame in frames {
                let meta = metadata(ex, step, live, label, &frame, Some(e), vec![exposure]);
                out.frames.push((meta, frame));
            }
        }
        Ok::<(), DeviceError>(())
    }
    .await;
    // Disarm whatever happened, so no stray trigger can produce an unaccounted frame.
    let disarmed = try_all(handles.iter().map(|c| c.set_armed(false))).await;
    result?;
    disarmed?;
    if let Some(w) = laser_watch.as_mut()
        && w.has_changed().unwrap_or(false)
        && live.state.laser_on
    {
        let closed = w.borrow_and_update().interlock_closed;
        return Err(laser_changed(ex, closed).into());
    }
    verify_state(ex, live).await?;

    if *hdr && exposures_s.len() > 1 {
        for cam in cameras {
            let idx: Vec<usize> = out
                .frames
                .iter()
                .enumerate()
                .filter(|(_, (m, _))| &m.camera == cam)
                .map(|(i, _)| i)
                .collect();
            let Some(&first) = idx.first() else { continue };
            let (template, frame) = &out.frames[first];
            let mut meta = template.clone();
            meta.kind = FrameKind::Hdr;
            meta.exposure_index = None;
            meta.exposures_s = exposures_s.clone();
            meta.exposure_s = exposures_s.iter().copied().fold(0.0, f64::max);
            meta.bit_depth = 32;
            meta.trigger_id = None;
            let black = black_level(ex, &frame.camera);
            out.hdr.push((meta, idx, black));
        }
    }
    Ok(out)
}

/// The laser's state changed while the cameras exposed with it planned on: an interlock that
/// opened (the run pauses) or a controller that switched it off (the step is retaken).
fn laser_changed(ex: &Execution, interlock_closed: bool) -> DeviceError {
    let device = ex
        .rig
        .laser
        .as_ref()
        .map(|l| l.id().to_string())
        .unwrap_or_else(|| "laser".into());
    if interlock_closed {
        DeviceError::new(
            device,
            DeviceErrorKind::StateLost {
                message: "the laser's state changed while the cameras exposed".into(),
            },
        )
    } else {
        DeviceError::new(device, DeviceErrorKind::InterlockOpen)
    }
}

/// Checks that the rig is in the state the plan has at this point: the laser armed, emitting
/// and fitted as planned (an open interlock is reported as such, so the run pauses), every
/// axis homed, still and at its target, the planned fixture on the stage, and every lamp as
/// planned. A frame taken in any other state would record something the plan did not ask for.
async fn verify_state(ex: &Execution, live: &Live) -> Result<(), DeviceError> {
    let rig = &ex.rig;
    let want = &live.state;
    if let Some(l) = &rig.laser {
        let s = l.status();
        let lost = |message: String| {
            DeviceError::new(l.id().to_string(), DeviceErrorKind::StateLost { message })
        };
        if want.laser_on && !s.on && !rig.interlock.is_closed() {
            return Err(DeviceError::new(
                l.id().to_string(),
                DeviceErrorKind::InterlockOpen,
            ));
        }
        if s.on != want.laser_on || s.armed != want.laser_armed {
            return Err(lost(format!(
                "the laser is {} and {} but should be {} and {}",
                if s.armed { "armed" } else { "disarmed" },
                if s.on { "on" } else { "off" },
                if want.laser_armed {
                    "armed"
                } else {
                    "disarmed"
                },
                if want.laser_on { "on" } else { "off" },
            )));
        }
        if s.fitted_nm != want.laser_fitted_nm {
            return Err(lost(format!(
                "the fitted laser is {} nm but the plan has {} nm",
                s.fitted_nm, want.laser_fitted_nm
            )));
        }
    }
    for (id, target) in &want.axes_deg {
        let Some(axis) = rig.axes.get(id) else {
            continue;
        };
        let s = axis.status();
        let tolerance = 2.0 / axis.spec().steps_per_deg.max(1.0);
        let problem = if !s.homed {
            Some("is not homed (its position is unknown)".to_string())
        } else if s.moving {
            Some("is moving".to_string())
        } else if (s.position_deg - target).abs() > tolerance {
            Some(format!(
                "is at {:.4}° but should be at {target:.4}°",
                s.position_deg
            ))
        } else {
            None
        };
        if let Some(problem) = problem {
            return Err(DeviceError::new(
                id.clone(),
                DeviceErrorKind::StateLost {
                    message: format!("the axis {problem}"),
                },
            ));
        }
    }
    if let Some(w) = &rig.world {
        let (on_stage, pose) = w.fixture();
        if on_stage != want.fixture || pose != want.fixture_pose {
            return Err(DeviceError::new(
                "stage",
                DeviceErrorKind::StateLost {
                    message: format!(
                        "`{on_stage}` ({}) is on the stage but the plan has `{}` ({})",
                        pose.describe(),
                        want.fixture,
                        want.fixture_pose.describe()
                    ),
                },
            ));
        }
    }
    verify_lamps(ex, live).await
}

/// Reads every switch bank back and checks that each lamp is on exactly when the plan has it
/// on. A relay board that reset (power glitch, watchdog) would otherwise darken frames
/// silently.
async fn verify_lamps(ex: &Execution, live: &Live) -> Result<(), DeviceError> {
    for (bank_id, bank) in &ex.rig.banks {
        let lamps: Vec<_> = ex
            .rig
            .spec
            .lamps
            .iter()
            .filter(|l| &l.bank == bank_id)
            .collect();
        if lamps.is_empty() {
            continue;
        }
        let states = bank.read().await?;
        for lamp in lamps {
            let want = live.state.lamps_on.contains(&lamp.id);
            let is = states
                .get(lamp.channel as usize - 1)
                .copied()
                .unwrap_or(false);
            if is != want {
                return Err(DeviceError::new(
                    bank_id.clone(),
                    DeviceErrorKind::StateLost {
                        message: format!(
                            "lamp `{}` (channel {}) is {} but should be {}",
                            lamp.id,
                            lamp.channel,
                            if is { "on" } else { "off" },
                            if want { "on" } else { "off" }
                        ),
                    },
                ));
            }
        }
    }
    Ok(())
}

fn black_level(ex: &Execution, camera: &str) -> f64 {
    ex.rig
        .world
        .as_ref()
        .map(|w| w.renderer().black_level_dn(camera))
        .unwrap_or(0.0)
}

fn metadata(
    ex: &Execution,
    step: &Step,
    live: &Live,
    label: &str,
    frame: &Frame,
    e: Option<usize>,
    exposures: Vec<f64>,
) -> FrameMeta {
    let rig = &ex.rig;
    let axes_deg = rig
        .axes
        .iter()
        .map(|(id, h)| (id.clone(), h.status().position_deg))
        .collect();
    let laser = rig.laser.as_ref().map(|l| l.status());
    let tilt = rig
        .spec
        .laser
        .as_ref()
        .and_then(|l| rig.axes.get(&l.tilt_axis))
        .map(|h| h.status().position_deg);
    FrameMeta {
        step: step.index,
        block: step.block.clone(),
        label: label.to_string(),
        camera: frame.camera.clone(),
        kind: FrameKind::Raw,
        exposure_index: e,
        exposure_s: frame.exposure_s,
        exposures_s: exposures,
        gain: frame.gain,
        trigger_id: Some(frame.trigger_id),
        axes_deg,
        lamps_on: live.state.lamps_on.iter().cloned().collect(),
        laser_armed: laser.map(|l| l.armed).unwrap_or(false),
        laser_on: laser.map(|l| l.on).unwrap_or(false),
        laser_colour_nm: laser.map(|l| l.fitted_nm).unwrap_or(0),
        laser_tilt_deg: tilt,
        laser_mount_deg: laser.map(|l| l.mount_elevation_deg),
        fixture: live.state.fixture.clone(),
        fixture_pose: live.state.fixture_pose,
        cart_mm: rig.cart.as_ref().map(|c| c.position_mm()),
        rig_time_s: frame.rig_time_s,
        wall_time_unix_s: wall_now(),
        width: frame.width,
        height: frame.height,
        bit_depth: frame.bit_depth,
        // The storage writer MSB-aligns raw samples and records the shift it applied.
        sample_shift: 0,
        saturated_samples: frame.saturated_samples() as u64,
        notes: frame.notes.clone(),
    }
}
