//! One stepper axis of a GRBL controller as an [`AxisDriver`]. Backlash and soft limits are the
//! [`AxisHandle`](crate::axis::AxisHandle)'s business; this only talks to the controller.

use std::sync::Arc;

use super::controller::{GrblController, letter_of};
use crate::axis::AxisDriver;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::AxisSpec;

/// The axis `spec.controller_axis` of a shared [`GrblController`].
pub struct GrblAxis {
    controller: Arc<GrblController>,
    spec: AxisSpec,
    letter: char,
}

impl GrblAxis {
    /// The axis described by `spec` on `controller`. Fails if `controller_axis` is not X, Y or
    /// Z, or if the controller was not built with this axis (so `$10x` was not checked).
    pub fn new(controller: Arc<GrblController>, spec: &AxisSpec) -> DeviceResult<Self> {
        let letter = letter_of(spec).ok_or_else(|| DeviceError::new(spec.id.clone(), DeviceErrorKind::Other { message: format!(
                "controller_axis is {:?}; a GRBL axis needs controller_axis = \"X\", \"Y\" or \"Z\"",
                spec.controller_axis
            ) }))?;
        if !controller.serves(spec, letter) {
            return Err(DeviceError::new(
                spec.id.clone(),
                DeviceErrorKind::Other {
                    message: format!(
                        "the GRBL controller on {} was not set up with axis {letter} of `{}`",
                        controller.port(),
                        spec.id
                    ),
                },
            ));
        }
        Ok(Self {
            controller,
            spec: spec.clone(),
            letter,
        })
    }

    /// The controller's letter for this axis.
    pub fn letter(&self) -> char {
        self.letter
    }

    /// Time a feed hold may take to bring the axis to rest from full speed.
    fn decel_timeout_s(&self) -> f64 {
        let s = &self.spec;
        s.speed_deg_s / s.accel_deg_s2.max(1e-9) * 1.5 + 1.0
    }
}

impl AxisDriver for GrblAxis {
    async fn home(&mut self) -> DeviceResult<f64> {
        self.controller.home(&self.spec.id, self.letter).await
    }

    async fn move_to(&mut self, target_deg: f64) -> DeviceResult<f64> {
        self.controller
            .move_axis(&self.spec.id, &self.spec, self.letter, target_deg)
            .await
    }

    async fn stop(&mut self) -> DeviceResult<f64> {
        let timeout = self.decel_timeout_s();
        self.controller
            .stop(&self.spec.id, self.letter, timeout)
            .await
    }

    async fn position(&mut self) -> DeviceResult<f64> {
        self.controller
            .position_deg(&self.spec.id, self.letter)
            .await
    }
}
