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
            | DeviceError::LaserColour { device, .. }
            | DeviceError::Exposure { device, .. }
            | DeviceError::Gain { device, .. }
            | DeviceError::MissingFrame { device, .. }
            | DeviceError::UnexpectedFrame { device, .. }
            | DeviceError::NotArmed { device }
            | DeviceError::MovingWhileExposing { device }
            | DeviceError::EndStop { device, .. }
            | DeviceError::Other { device, .. } => device,
        }
    }
}

/// Result type of device requests.
pub type DeviceResult<T> = Result<T, DeviceError>;
