//! Devices that are nothing but a switched output of another device: a laser powered through
//! a switch-bank channel (alone, or in series with a GRBL spindle output), and a camera trigger
//! on a relay board's GPIO line (backend `switch`).

pub(crate) mod wiring;

use std::sync::Arc;

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::laser::LaserDriver;
use crate::relay_serial::NumatoBoard;
use crate::relay_serial::codec::MAX_INDEX;
use crate::switch_bank::SwitchBankHandle;
use crate::trigger::TriggerDriver;

/// A laser whose emission is the power of one switch-bank channel: on = channel on.
pub struct SwitchLaser {
    device: String,
    bank: SwitchBankHandle,
    channel: u32,
}

impl SwitchLaser {
    /// Laser `device` powered by `channel` (from 1) of `bank`.
    pub fn new(device: &str, bank: SwitchBankHandle, channel: u32) -> Self {
        Self {
            device: device.to_string(),
            bank,
            channel,
        }
    }
}

impl LaserDriver for SwitchLaser {
    /// Switches the channel; the colour is whatever module is fitted (the relay cannot tell).
    async fn set_emission(&mut self, on: bool, colour_nm: u32) -> DeviceResult<()> {
        tracing::debug!(device = %self.device, bank = %self.bank.id(), channel = self.channel, on, colour_nm, "laser power");
        self.bank.set_many(&[(self.channel, on)]).await
    }

    /// Nothing to switch: the operator swapped the module by hand; only logged.
    async fn fitted(&mut self, colour_nm: u32, mount_elevation_deg: f64) -> DeviceResult<()> {
        tracing::info!(device = %self.device, colour_nm, mount_elevation_deg, "laser module fitted");
        Ok(())
    }
}

/// A laser behind two switches in series, e.g. a GRBL spindle output and a relay channel whose
/// board has a watchdog: it emits only while both are on. On switches the relay (`power`)
/// first and the controller (`output`) second; off switches both, in the reverse order, even if
/// the first fails, so a fault never leaves the laser powered.
pub struct SeriesLaser<P, O> {
    power: P,
    output: O,
}

impl<P: LaserDriver, O: LaserDriver> SeriesLaser<P, O> {
    /// The laser emitting when `power` and `output` are both on.
    pub fn new(power: P, output: O) -> Self {
        Self { power, output }
    }
}

impl<P: LaserDriver, O: LaserDriver> LaserDriver for SeriesLaser<P, O> {
    async fn set_emission(&mut self, on: bool, colour_nm: u32) -> DeviceResult<()> {
        if on {
            self.power.set_emission(true, colour_nm).await?;
            if let Err(e) = self.output.set_emission(true, colour_nm).await {
                let _ = self.power.set_emission(false, colour_nm).await;
                return Err(e);
            }
            Ok(())
        } else {
            let a = self.output.set_emission(false, colour_nm).await;
            let b = self.power.set_emission(false, colour_nm).await;
            a.and(b)
        }
    }

    async fn fitted(&mut self, colour_nm: u32, mount_elevation_deg: f64) -> DeviceResult<()> {
        self.output.fitted(colour_nm, mount_elevation_deg).await
    }
}

/// A camera trigger on a GPIO line of a Numato-style board: `gpio set`, the pulse, `gpio clear`.
pub struct GpioTrigger {
    device: String,
    board: Arc<NumatoBoard>,
    line: u32,
    pulse_s: f64,
    /// The line may still be high (a `gpio clear` failed): lower it before the next pulse.
    maybe_high: bool,
}

impl GpioTrigger {
    /// Trigger `device` on GPIO `line` (from 0, as the board numbers them) of `board`, high for
    /// `pulse_s` seconds per shot.
    pub fn new(
        device: &str,
        board: Arc<NumatoBoard>,
        line: u32,
        pulse_s: f64,
    ) -> DeviceResult<Self> {
        if line > MAX_INDEX {
            return Err(DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Other {
                    message: format!(
                        "GPIO line {line} does not exist; the board has lines 0 to {MAX_INDEX}"
                    ),
                },
            ));
        }
        if !pulse_s.is_finite() || !(0.0..=1.0).contains(&pulse_s) {
            return Err(DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Other {
                    message: format!("pulse_s = {pulse_s} is outside [0, 1] s"),
                },
            ));
        }
        Ok(Self {
            device: device.to_string(),
            board,
            line,
            pulse_s,
            maybe_high: false,
        })
    }
}

impl TriggerDriver for GpioTrigger {
    /// Checks the board's relays are as set, raises the line, holds it for the pulse length
    /// and lowers it again.
    async fn fire(&mut self, trigger_id: u64) -> DeviceResult<()> {
        tracing::trace!(device = %self.device, trigger_id, line = self.line, "trigger pulse");
        // Frames taken with a lamp that a board reset switched off would be wrong.
        self.board.verify_relays().await?;
        if self.maybe_high {
            self.board.gpio_clear(self.line).await?;
            self.maybe_high = false;
        }
        self.maybe_high = true;
        self.board.gpio_set(self.line).await?;
        tokio::time::sleep(duration_s(self.pulse_s)).await;
        self.board.gpio_clear(self.line).await?;
        self.maybe_high = false;
        Ok(())
    }
}
