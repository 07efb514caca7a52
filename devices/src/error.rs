//! Typed device errors: each names the device and says what to check.

use thiserror::Error;

/// An error raised by a device or its actor. Every variant names the device.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DeviceError {
    #[error(
        "{device}: target {target_deg:.3}° is outside the soft limits [{min_deg:.3}°, {max_deg:.3}°]; choose a target inside the limits in the rig file"
    )]
    OutsideSoftLimits {
        device: String,
        target_deg: f64,
        min_deg: f64,
        max_deg: f64,
    },
    #[error("{device}: hit a hard limit at {position_deg:.3}°; the axis stopped and must be homed")]
    HardLimit { device: String, position_deg: f64 },
    #[error("{device}: not homed; home the axis before moving it")]
    NotHomed { device: String },
    #[error(
        "{device}: no reply to `{request}` within {timeout_s:.3} s; check the cable, power and port"
    )]
    Timeout {
        device: String,
        request: String,
        timeout_s: f64,
    },
    #[error("{device}: the device task has stopped; restart the daemon or check the port")]
    Gone { device: String },
    #[error(
        "{device}: channel {channel} does not exist (the bank has {channels} channels, numbered from 1)"
    )]
    NoSuchChannel {
        device: String,
        channel: u32,
        channels: u32,
    },
    #[error("{device}: laser is not armed; arm it before switching it on")]
    LaserNotArmed { device: String },
    #[error(
        "{device}: the laser interlock is open (the enclosure door switch); close the door before switching the laser on"
    )]
    InterlockOpen { device: String },
    #[error("{device}: colour {colour_nm} nm is not fitted; fitted colours: {fitted:?}")]
    LaserColour {
        device: String,
        colour_nm: u32,
        fitted: Vec<u32>,
    },
    #[error("{device}: exposure {exposure_s} s is outside [{min_s}, {max_s}] s")]
    Exposure {
        device: String,
        exposure_s: f64,
        min_s: f64,
        max_s: f64,
    },
    #[error("{device}: gain {gain} is outside [1, {max}]")]
    Gain { device: String, gain: f64, max: f64 },
    #[error(
        "{device}: no frame for trigger {trigger_id} within {timeout_s:.3} s (exposure + readout + margin); check the trigger cable and the camera link"
    )]
    MissingFrame {
        device: String,
        trigger_id: u64,
        timeout_s: f64,
    },
    #[error(
        "{device}: got a frame for trigger {got} while waiting for trigger {expected}; the camera fired without a trigger of ours or a frame was left over"
    )]
    UnexpectedFrame {
        device: String,
        expected: u64,
        got: u64,
    },
    #[error("{device}: camera is not armed")]
    NotArmed { device: String },
    #[error("{device}: motion while a camera exposes is forbidden; wait for the exposure to end")]
    MovingWhileExposing { device: String },
    #[error("{device}: carriage is at its end stop ({end})")]
    EndStop { device: String, end: &'static str },
    #[error(
        "{device}: port {port} is gone ({reason}); check the cable, the power and that no other program holds the port — stagehand reconnects when it comes back"
    )]
    Disconnected {
        device: String,
        port: String,
        reason: String,
    },
    #[error(
        "{device}: cannot open port {port} ({reason}); check that the path exists (see `stagehand devices`), the udev rules and that you are in the dialout group"
    )]
    PortUnavailable {
        device: String,
        port: String,
        reason: String,
    },
    #[error(
        "{device}: unexpected reply on {port}: {message}; check the baud rate, the firmware and the cable"
    )]
    Protocol {
        device: String,
        port: String,
        message: String,
    },
    #[error("{device}: controller rejected `{command}` with error:{code} ({meaning})")]
    Rejected {
        device: String,
        command: String,
        code: u32,
        meaning: String,
    },
    #[error(
        "{device}: controller alarm ALARM:{code} ({meaning}); the position is lost until the axis is homed again"
    )]
    Alarm {
        device: String,
        code: u32,
        meaning: String,
    },
    #[error(
        "{device}: {message}; the device lost the state it was set to (a reset or power glitch), so the step is retaken"
    )]
    StateLost { device: String, message: String },
    #[error(
        "{device}: the controller on {port} cannot work for this rig as set up: {problems}; then reconnect (check with `stagehand devices`)"
    )]
    Misconfigured {
        device: String,
        port: String,
        problems: String,
    },
    #[error("{device}: homing failed with ALARM:{code} ({meaning}); {check}")]
    HomingFailed {
        device: String,
        code: u32,
        meaning: String,
        check: String,
    },
    #[error(
        "{device}: the laser output did not switch {wanted}: {reason}; check the controller's spindle wiring and settings"
    )]
    LaserNotSwitched {
        device: String,
        wanted: &'static str,
        reason: String,
    },
    /// A fault of a simulated device (one injected into the simulation, or a stall of the
    /// simulator): there is no cable or port to check.
    #[error(
        "{device}: `{request}`: {message}; this is a simulated device, so nothing on the rig needs checking (a fault injected into the simulation, or a simulator bug if none was)"
    )]
    SimulatedFault {
        device: String,
        request: String,
        message: String,
    },
    #[error("{device}: {message}")]
    Other { device: String, message: String },
}

impl DeviceError {
    /// Name of the device the error is about.
    pub fn device(&self) -> &str {
        match self {
            DeviceError::OutsideSoftLimits { device, .. }
            | DeviceError::HardLimit { device, .. }
            | DeviceError::NotHomed { device }
            | DeviceError::Timeout { device, .. }
            | DeviceError::Gone { device }
            | DeviceError::NoSuchChannel { device, .. }
            | DeviceError::LaserNotArmed { device }
            | DeviceError::InterlockOpen { device }
            | DeviceError::LaserColour { device, .. }
            | DeviceError::Exposure { device, .. }
            | DeviceError::Gain { device, .. }
            | DeviceError::MissingFrame { device, .. }
            | DeviceError::UnexpectedFrame { device, .. }
            | DeviceError::NotArmed { device }
            | DeviceError::MovingWhileExposing { device }
            | DeviceError::EndStop { device, .. }
            | DeviceError::Disconnected { device, .. }
            | DeviceError::PortUnavailable { device, .. }
            | DeviceError::Protocol { device, .. }
            | DeviceError::Rejected { device, .. }
            | DeviceError::Alarm { device, .. }
            | DeviceError::StateLost { device, .. }
            | DeviceError::Misconfigured { device, .. }
            | DeviceError::HomingFailed { device, .. }
            | DeviceError::LaserNotSwitched { device, .. }
            | DeviceError::SimulatedFault { device, .. }
            | DeviceError::Other { device, .. } => device,
        }
    }

    /// The device name inside the error, for renaming.
    fn device_mut(&mut self) -> &mut String {
        match self {
            DeviceError::OutsideSoftLimits { device, .. }
            | DeviceError::HardLimit { device, .. }
            | DeviceError::NotHomed { device }
            | DeviceError::Timeout { device, .. }
            | DeviceError::Gone { device }
            | DeviceError::NoSuchChannel { device, .. }
            | DeviceError::LaserNotArmed { device }
            | DeviceError::InterlockOpen { device }
            | DeviceError::LaserColour { device, .. }
            | DeviceError::Exposure { device, .. }
            | DeviceError::Gain { device, .. }
            | DeviceError::MissingFrame { device, .. }
            | DeviceError::UnexpectedFrame { device, .. }
            | DeviceError::NotArmed { device }
            | DeviceError::MovingWhileExposing { device }
            | DeviceError::EndStop { device, .. }
            | DeviceError::Disconnected { device, .. }
            | DeviceError::PortUnavailable { device, .. }
            | DeviceError::Protocol { device, .. }
            | DeviceError::Rejected { device, .. }
            | DeviceError::Alarm { device, .. }
            | DeviceError::StateLost { device, .. }
            | DeviceError::Misconfigured { device, .. }
            | DeviceError::HomingFailed { device, .. }
            | DeviceError::LaserNotSwitched { device, .. }
            | DeviceError::SimulatedFault { device, .. }
            | DeviceError::Other { device, .. } => device,
        }
    }

    /// The same error naming `name` as its device (e.g. an axis instead of its controller).
    pub fn with_device(mut self, name: &str) -> Self {
        *self.device_mut() = name.to_string();
        self
    }

    /// True for faults of the link or the controller that a reconnect, a re-home and a retry
    /// of the step can cure (a lost port, garbage, a lost reply, an alarm, a stalled frame);
    /// false for requests that are wrong in themselves and would fail again.
    pub fn is_recoverable(&self) -> bool {
        matches!(
            self,
            DeviceError::Timeout { .. }
                | DeviceError::Disconnected { .. }
                | DeviceError::PortUnavailable { .. }
                | DeviceError::Protocol { .. }
                | DeviceError::Alarm { .. }
                | DeviceError::StateLost { .. }
                | DeviceError::HardLimit { .. }
                | DeviceError::NotHomed { .. }
                | DeviceError::MissingFrame { .. }
                | DeviceError::UnexpectedFrame { .. }
                | DeviceError::SimulatedFault { .. }
        )
    }
}

/// Result type of device requests.
pub type DeviceResult<T> = Result<T, DeviceError>;
