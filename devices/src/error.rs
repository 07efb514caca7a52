//! Typed device errors: each names the device and says what to check.

use thiserror::Error;

/// An error raised by a device or its actor: the device it names and what went wrong.
/// Displays as `"{device}: {kind}"`.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{device}: {kind}")]
pub struct DeviceError {
    /// Id of the device the error is about (as in the rig file).
    pub device: String,
    /// What went wrong, and what to check.
    pub kind: DeviceErrorKind,
}

/// What went wrong with a device; [`DeviceError`] adds which device.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DeviceErrorKind {
    #[error(
        "target {target_deg:.3}° is outside the soft limits [{min_deg:.3}°, {max_deg:.3}°]; choose a target inside the limits in the rig file"
    )]
    OutsideSoftLimits {
        target_deg: f64,
        min_deg: f64,
        max_deg: f64,
    },
    #[error("hit a hard limit at {position_deg:.3}°; the axis stopped and must be homed")]
    HardLimit { position_deg: f64 },
    #[error("not homed; home the axis before moving it")]
    NotHomed,
    #[error("no reply to `{request}` within {timeout_s:.3} s; check the cable, power and port")]
    Timeout { request: String, timeout_s: f64 },
    #[error("the device task has stopped; restart the daemon or check the port")]
    Gone,
    #[error("channel {channel} does not exist (the bank has {channels} channels, numbered from 1)")]
    NoSuchChannel { channel: u32, channels: u32 },
    #[error("laser is not armed; arm it before switching it on")]
    LaserNotArmed,
    #[error(
        "the laser interlock is open (the enclosure door switch); close the door before switching the laser on"
    )]
    InterlockOpen,
    #[error("colour {colour_nm} nm is not fitted; fitted colours: {fitted:?}")]
    LaserColour { colour_nm: u32, fitted: Vec<u32> },
    #[error("exposure {exposure_s} s is outside [{min_s}, {max_s}] s")]
    Exposure {
        exposure_s: f64,
        min_s: f64,
        max_s: f64,
    },
    #[error("gain {gain} is outside [1, {max}]")]
    Gain { gain: f64, max: f64 },
    #[error(
        "no frame for trigger {trigger_id} within {timeout_s:.3} s (exposure + readout + margin); check the trigger cable and the camera link"
    )]
    MissingFrame { trigger_id: u64, timeout_s: f64 },
    #[error(
        "got a frame for trigger {got} while waiting for trigger {expected}; the camera fired without a trigger of ours or a frame was left over"
    )]
    UnexpectedFrame { expected: u64, got: u64 },
    #[error("camera is not armed")]
    NotArmed,
    #[error("motion while a camera exposes is forbidden; wait for the exposure to end")]
    MovingWhileExposing,
    #[error("carriage is at its end stop ({end})")]
    EndStop { end: &'static str },
    #[error(
        "port {port} is gone ({reason}); check the cable, the power and that no other program holds the port — stagehand reconnects when it comes back"
    )]
    Disconnected { port: String, reason: String },
    #[error(
        "cannot open port {port} ({reason}); check that the path exists (see `stagehand devices`), the udev rules and that you are in the dialout group"
    )]
    PortUnavailable { port: String, reason: String },
    #[error(
        "unexpected reply on {port}: {message}; check the baud rate, the firmware and the cable"
    )]
    Protocol { port: String, message: String },
    #[error("controller rejected `{command}` with error:{code} ({meaning})")]
    Rejected {
        command: String,
        code: u32,
        meaning: String,
    },
    #[error(
        "controller alarm ALARM:{code} ({meaning}); the position is lost until the axis is homed again"
    )]
    Alarm { code: u32, meaning: String },
    #[error(
        "{message}; the device lost the state it was set to (a reset or power glitch), so the step is retaken"
    )]
    StateLost { message: String },
    #[error(
        "the controller on {port} cannot work for this rig as set up: {problems}; then reconnect (check with `stagehand devices`)"
    )]
    Misconfigured { port: String, problems: String },
    #[error("homing failed with ALARM:{code} ({meaning}); {check}")]
    HomingFailed {
        code: u32,
        meaning: String,
        check: String,
    },
    #[error(
        "the laser output did not switch {wanted}: {reason}; check the controller's spindle wiring and settings"
    )]
    LaserNotSwitched {
        wanted: &'static str,
        reason: String,
    },
    /// A fault of a simulated device (one injected into the simulation, or a stall of the
    /// simulator): there is no cable or port to check.
    #[error(
        "`{request}`: {message}; this is a simulated device, so nothing on the rig needs checking (a fault injected into the simulation, or a simulator bug if none was)"
    )]
    SimulatedFault { request: String, message: String },
    #[error("{message}")]
    Other { message: String },
}

impl DeviceError {
    /// An error of `kind` about `device`.
    pub fn new(device: impl Into<String>, kind: DeviceErrorKind) -> Self {
        DeviceError {
            device: device.into(),
            kind,
        }
    }

    /// Name of the device the error is about.
    pub fn device(&self) -> &str {
        &self.device
    }

    /// The same error naming `name` as its device (e.g. an axis instead of its controller).
    pub fn with_device(mut self, name: &str) -> Self {
        self.device = name.to_string();
        self
    }

    /// True for faults of the link or the controller that a reconnect, a re-home and a retry
    /// of the step can cure (a lost port, garbage, a lost reply, an alarm, a stalled frame);
    /// false for requests that are wrong in themselves and would fail again.
    pub fn is_recoverable(&self) -> bool {
        matches!(
            self.kind,
            DeviceErrorKind::Timeout { .. }
                | DeviceErrorKind::Disconnected { .. }
                | DeviceErrorKind::PortUnavailable { .. }
                | DeviceErrorKind::Protocol { .. }
                | DeviceErrorKind::Alarm { .. }
                | DeviceErrorKind::StateLost { .. }
                | DeviceErrorKind::HardLimit { .. }
                | DeviceErrorKind::NotHomed
                | DeviceErrorKind::MissingFrame { .. }
                | DeviceErrorKind::UnexpectedFrame { .. }
                | DeviceErrorKind::SimulatedFault { .. }
        )
    }
}

/// Result type of device requests.
pub type DeviceResult<T> = Result<T, DeviceError>;
