//! The rig description schema. Every table rejects unknown keys; units are in the key names.

use serde::{Deserialize, Serialize};

use crate::motion::Kinematics;

/// A whole rig as described in a TOML file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigSpec {
    pub rig: RigInfo,
    #[serde(default, rename = "axis")]
    pub axes: Vec<AxisSpec>,
    #[serde(default, rename = "switch_bank")]
    pub switch_banks: Vec<SwitchBankSpec>,
    #[serde(default, rename = "lamp")]
    pub lamps: Vec<LampSpec>,
    #[serde(default, rename = "camera")]
    pub cameras: Vec<CameraSpec>,
    #[serde(default)]
    pub trigger: Option<TriggerSpec>,
    #[serde(default)]
    pub laser: Option<LaserSpec>,
    #[serde(default)]
    pub cart: Option<CartSpec>,
    /// `[sim]`, read and checked by the simulator.
    #[serde(default)]
    pub sim: SimTable,
    /// `[calibration]`: the stored calibrations this rig's runs are processed with.
    #[serde(default)]
    pub calibration: CalibrationRefs,
}

/// The stored calibrations a rig uses, by id (`stagehand calibrations list`): recorded in the
/// manifest of every run, and what `stagehand process` uses when given none.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationRefs {
    /// A `response-…` calibration.
    pub response: Option<String>,
    /// A `colour-…` calibration.
    pub colour: Option<String>,
    /// A `geometry-…` calibration.
    pub geometry: Option<String>,
}

impl CalibrationRefs {
    /// (kind, id) of each calibration named, kinds in a fixed order.
    pub fn named(&self) -> Vec<(&'static str, &str)> {
        [
            ("response", &self.response),
            ("colour", &self.colour),
            ("geometry", &self.geometry),
        ]
        .into_iter()
        .filter_map(|(kind, id)| id.as_deref().map(|id| (kind, id)))
        .collect()
    }
}

/// Name and purpose of the rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigInfo {
    pub name: String,
    #[serde(default)]
    pub description: String,
}

/// Which driver talks to a device. `sim` is the built-in simulated backend. Rig files, JSON
/// and messages spell it as [`Backend::as_str`] does (serde goes through it too).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Sim,
    Grbl,
    RelaySerial,
    HidRelay,
    IrBridge,
    V4l,
    Aravis,
    Gphoto2,
    /// A laser or trigger wired to a channel of one of this rig's switch banks.
    Switch,
    /// Each camera triggers itself in software (no trigger line).
    Software,
}

impl Backend {
    /// Every backend.
    pub const ALL: [Backend; 10] = [
        Backend::Sim,
        Backend::Grbl,
        Backend::RelaySerial,
        Backend::HidRelay,
        Backend::IrBridge,
        Backend::V4l,
        Backend::Aravis,
        Backend::Gphoto2,
        Backend::Switch,
        Backend::Software,
    ];

    /// Every backend's name, in the order of [`Backend::ALL`] (for "expected one of" errors).
    pub const NAMES: [&'static str; 10] = {
        let mut names = [""; 10];
        let mut i = 0;
        while i < names.len() {
            names[i] = Backend::ALL[i].as_str();
            i += 1;
        }
        names
    };

    /// The name a rig file uses (`relay-serial`, `grbl`, …): the one spelling of backend
    /// names.
    pub const fn as_str(self) -> &'static str {
        match self {
            Backend::Sim => "sim",
            Backend::Grbl => "grbl",
            Backend::RelaySerial => "relay-serial",
            Backend::HidRelay => "hid-relay",
            Backend::IrBridge => "ir-bridge",
            Backend::V4l => "v4l",
            Backend::Aravis => "aravis",
            Backend::Gphoto2 => "gphoto2",
            Backend::Switch => "switch",
            Backend::Software => "software",
        }
    }
}

impl Serialize for Backend {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for Backend {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let name = String::deserialize(deserializer)?;
        Backend::ALL
            .into_iter()
            .find(|b| b.as_str() == name)
            .ok_or_else(|| serde::de::Error::unknown_variant(&name, &Backend::NAMES))
    }
}

/// Default baud rates of the serial protocols (USB CDC ports ignore the rate).
pub const GRBL_BAUD: u32 = 115_200;
pub const RELAY_SERIAL_BAUD: u32 = 19_200;
pub const IR_BRIDGE_BAUD: u32 = 9_600;

/// What an axis moves, so the simulator knows how it changes the optical geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AxisRole {
    /// Rotates the sample about the vertical axis; 0° is the sample's X axis.
    Turntable,
    /// Rotates the light arc (lamps, laser mount) about the vertical axis.
    LightArc,
    /// Tilts the laser fan within the light arc's plane.
    LaserTilt,
    /// Any other axis; it moves but does not change what the cameras see.
    Other,
}

/// A rotary stepper axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    pub role: AxisRole,
    pub speed_deg_s: f64,
    pub accel_deg_s2: f64,
    pub min_deg: f64,
    pub max_deg: f64,
    /// Mechanical backlash taken up by always making the final approach in + direction.
    #[serde(default)]
    pub backlash_deg: f64,
    /// Settling time after a move before a camera may expose.
    #[serde(default)]
    pub settle_s: f64,
    /// Speed of the homing move toward the home switch at 0°.
    #[serde(default = "default_homing_speed")]
    pub homing_speed_deg_s: f64,
    /// Microsteps per degree; positions are quantised to it. A GRBL controller must be set
    /// up with `$10x` equal to this (its "mm" are our degrees).
    #[serde(default = "default_steps_per_deg")]
    pub steps_per_deg: f64,
    /// The controller's letter for this axis (`X`, `Y` or `Z`; GRBL axes only).
    #[serde(default)]
    pub controller_axis: Option<String>,
    /// Serial baud rate (default 115200 for GRBL).
    #[serde(default)]
    pub baud: Option<u32>,
    /// The angle the axis rests at after homing (for GRBL: the pulled-off position next to
    /// the homing switch). Default 0°.
    #[serde(default)]
    pub home_deg: f64,
    /// How rig degrees map onto a GRBL controller's machine coordinate: +1 when they grow
    /// together, -1 when the machine coordinate falls as the angle rises. GRBL machine space
    /// is negative after homing (−`$13x`…0), so this and `home_deg` place the rig's range in
    /// it. Default +1.
    #[serde(default = "default_machine_sign")]
    pub machine_sign: f64,
}

fn default_machine_sign() -> f64 {
    1.0
}

fn default_homing_speed() -> f64 {
    20.0
}
fn default_steps_per_deg() -> f64 {
    3200.0 / 360.0 * 16.0
}

impl AxisSpec {
    /// Cruise speed and acceleration.
    pub fn kinematics(&self) -> Kinematics {
        Kinematics {
            speed_deg_s: self.speed_deg_s,
            accel_deg_s2: self.accel_deg_s2,
        }
    }
}

/// A bank of individually switched outputs (relay board, programmable PSU).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SwitchBankSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    /// Number of channels, numbered from 1.
    pub channels: u32,
    /// Serial baud rate (default 19200 for relay-serial).
    #[serde(default)]
    pub baud: Option<u32>,
    /// Watchdog lease: the driver renews it at a third of this period, and outputs switch off
    /// when it lapses (the emulator does it; real boards where they support it).
    #[serde(default = "default_watchdog")]
    pub watchdog_s: f64,
}

fn default_watchdog() -> f64 {
    3.0
}

/// What kind of light a switched channel powers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LampKind {
    /// A halogen lamp on the light arc: a small, warm-white area source.
    Halogen,
    /// The reflectometer's linear fluorescent tube, carried by the cart.
    Tube,
    /// A diffuse backlight panel under the sample.
    Backlight,
}

/// A light source wired to a switch-bank channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LampSpec {
    pub id: String,
    pub kind: LampKind,
    /// Switch bank id and channel (from 1).
    pub bank: String,
    pub channel: u32,
    /// Elevation on the light arc above the sample plane (halogen lamps).
    #[serde(default)]
    pub elevation_deg: f64,
    /// Distance from the sample centre (halogen) or height above the sample (tube).
    #[serde(default = "default_lamp_distance")]
    pub distance_mm: f64,
    /// Radiant power scale; 1.0 is the reference lamp.
    #[serde(default = "one")]
    pub power: f64,
    /// Time after switch-on until the output is within 1% of steady state.
    #[serde(default)]
    pub warmup_s: f64,
    /// A tube's length, mm (the seed's 15 W fluorescent tube: 300).
    #[serde(default = "default_tube_length")]
    pub length_mm: f64,
    /// A tube's glass radius, mm (a T8 tube: 13); its glass hides the sample from the camera.
    #[serde(default = "default_tube_radius")]
    pub radius_mm: f64,
}

fn default_lamp_distance() -> f64 {
    800.0
}
fn default_tube_length() -> f64 {
    300.0
}
fn default_tube_radius() -> f64 {
    13.0
}
fn one() -> f64 {
    1.0
}

/// A camera on the fixed camera arc (or fixed above the reflectometer).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    pub width: u32,
    pub height: u32,
    /// Maximum frame rate; readout takes 1/fps.
    pub fps: f64,
    #[serde(default = "default_bit_depth")]
    pub bit_depth: u8,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    pub distance_mm: f64,
    /// Horizontal field of view.
    pub fov_deg: f64,
    #[serde(default = "default_min_exposure")]
    pub min_exposure_s: f64,
    #[serde(default = "default_max_exposure")]
    pub max_exposure_s: f64,
    #[serde(default = "default_max_gain")]
    pub max_gain: f64,
    /// Brown–Conrady radial distortion coefficients on normalised image coordinates
    /// (see [`crate::lens`]); 0 is an ideal pinhole. Negative k1 is barrel distortion.
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub k3: f64,
    /// Brown–Conrady tangential (decentring) distortion coefficients.
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
    /// Principal point offset from the image centre, in pixels (+x right).
    #[serde(default)]
    pub cx: f64,
    /// Principal point offset from the image centre, in pixels (+y down).
    #[serde(default)]
    pub cy: f64,
}

fn default_bit_depth() -> u8 {
    12
}
fn default_min_exposure() -> f64 {
    1.0e-5
}
fn default_max_exposure() -> f64 {
    10.0
}
fn default_max_gain() -> f64 {
    16.0
}

impl CameraSpec {
    /// Time to read the sensor out after an exposure.
    pub fn readout_s(&self) -> f64 {
        1.0 / self.fps
    }
}

/// The trigger source that fires every armed camera at once.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriggerSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    /// Switch bank (a relay-serial board) whose GPIO line fires the cameras (backend `switch`).
    #[serde(default)]
    pub bank: Option<String>,
    /// GPIO line number on that board (from 0, as the board numbers them).
    #[serde(default)]
    pub line: Option<u32>,
    /// Length of the trigger pulse.
    #[serde(default = "default_pulse")]
    pub pulse_s: f64,
}

fn default_pulse() -> f64 {
    0.001
}

/// The line laser on the light arc; its tilt is an axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    /// Wavelengths the lab owns (one fits at a time).
    pub colours_nm: Vec<u32>,
    /// Wavelength fitted when the run starts.
    pub fitted_nm: u32,
    /// Id of the axis that tilts the laser fan.
    pub tilt_axis: String,
    /// Elevation on the light arc where the unit is mounted when the run starts.
    pub mount_elevation_deg: f64,
    pub distance_mm: f64,
    pub power_mw: f64,
    /// 1/e² half-thickness of the laser sheet at the sample.
    #[serde(default = "default_sheet")]
    pub sheet_half_width_mm: f64,
    /// Switch bank and channel that power the laser (backend `switch`; with backend `grbl`, a
    /// relay in series with the spindle output, so both must be on and the board's watchdog
    /// can switch the laser off).
    #[serde(default)]
    pub bank: Option<String>,
    #[serde(default)]
    pub channel: Option<u32>,
}

fn default_sheet() -> f64 {
    0.4
}

/// The reflectometer's DC-motor carriage carrying the linear light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CartSpec {
    pub id: String,
    pub backend: Backend,
    #[serde(default)]
    pub port: Option<String>,
    pub speed_mm_s: f64,
    /// Travel between the end stops; the carriage starts at 0.
    pub travel_mm: f64,
    /// Serial baud rate of the IR bridge (default 9600).
    #[serde(default)]
    pub baud: Option<u32>,
    /// Power Functions channel (1–4) the cart's IR receiver is set to.
    #[serde(default = "default_pf_channel")]
    pub ir_channel: u8,
    /// Power Functions output (`A` or `B`) the motor is plugged into.
    #[serde(default = "default_pf_output")]
    pub ir_output: String,
    /// PWM step (1–7) the motor runs at; `speed_mm_s` is the cart's speed at this step.
    #[serde(default = "default_pf_speed")]
    pub ir_speed_step: u8,
}

fn default_pf_channel() -> u8 {
    1
}
fn default_pf_output() -> String {
    "A".into()
}
fn default_pf_speed() -> u8 {
    7
}

/// The rig file's `[sim]` table (the simulated rig's settings: the sample on the stage, the
/// renderer's quality and knobs, ground truth), kept as raw TOML. The simulator owns its schema
/// and checks it (`stagehand_simulator::render::config`), at file:line:col through
/// [`super::span::locate`]; the device layer only carries it, so it knows no renderer setting.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct SimTable(pub toml::Table);

impl RigSpec {
    pub fn axis(&self, id: &str) -> Option<&AxisSpec> {
        self.axes.iter().find(|a| a.id == id)
    }
    pub fn camera(&self, id: &str) -> Option<&CameraSpec> {
        self.cameras.iter().find(|c| c.id == id)
    }
    pub fn bank(&self, id: &str) -> Option<&SwitchBankSpec> {
        self.switch_banks.iter().find(|b| b.id == id)
    }
    pub fn lamp(&self, id: &str) -> Option<&LampSpec> {
        self.lamps.iter().find(|l| l.id == id)
    }
    /// The first axis with the given role.
    pub fn axis_with_role(&self, role: AxisRole) -> Option<&AxisSpec> {
        self.axes.iter().find(|a| a.role == role)
    }

    /// What switches the laser off if stagehand dies mid-run (`None` without a laser).
    pub fn laser_watchdog(&self) -> Option<LaserWatchdog> {
        let l = self.laser.as_ref()?;
        let bank = l.bank.as_deref().and_then(|b| self.bank(b));
        Some(match (l.backend, bank) {
            (Backend::Sim, _) => LaserWatchdog::Simulated,
            (Backend::Switch | Backend::Grbl, Some(b)) => match b.backend {
                Backend::RelaySerial => LaserWatchdog::Relay {
                    bank: b.id.clone(),
                    watchdog_s: b.watchdog_s,
                },
                Backend::Sim => LaserWatchdog::Simulated,
                _ => LaserWatchdog::None(format!(
                    "the relay board of bank `{}` ({}) has no watchdog, so the laser stays on if stagehand dies",
                    b.id,
                    b.backend.as_str()
                )),
            },
            (Backend::Grbl, None) => LaserWatchdog::None(
                "GRBL has no watchdog: its spindle output stays on if stagehand dies; power the laser through a relay-serial channel too (`bank`, `channel` on the [laser] table) to get the relay board's watchdog".into(),
            ),
            (backend, _) => LaserWatchdog::None(format!(
                "backend `{}` has no watchdog",
                backend.as_str()
            )),
        })
    }
}

/// What switches a laser off when its host stops renewing a lease.
#[derive(Debug, Clone, PartialEq)]
pub enum LaserWatchdog {
    /// A relay-serial board's watchdog switches the relay off `watchdog_s` after the last
    /// command.
    Relay { bank: String, watchdog_s: f64 },
    /// A simulated laser: nothing real to protect.
    Simulated,
    /// Nothing does; the sentence says why and what to do.
    None(String),
}

impl LaserWatchdog {
    /// One line for people: the status page, the dry run.
    pub fn describe(&self) -> String {
        match self {
            LaserWatchdog::Relay { bank, watchdog_s } => format!(
                "the relay board of bank `{bank}` switches the laser off {watchdog_s} s after stagehand stops"
            ),
            LaserWatchdog::Simulated => "simulated laser".into(),
            LaserWatchdog::None(why) => format!("no watchdog: {why}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backends_read_and_write_as_their_names() {
        for b in Backend::ALL {
            let json = serde_json::to_string(&b).expect("serialises");
            assert_eq!(json, format!("\"{}\"", b.as_str()));
            assert_eq!(serde_json::from_str::<Backend>(&json).expect("reads"), b);
        }
        let e = serde_json::from_str::<Backend>("\"relay_serial\"").expect_err("unknown");
        assert!(e.to_string().contains("relay-serial"), "{e}");
    }
}
