//! Rig descriptions: which devices exist, their backends, ports and physics, read from TOML.

mod load;
pub mod span;
mod spec;
mod wiring;

pub use load::{RigError, load_rig_file, parse_rig};
pub use spec::*;

/// The built-in simulated light stage (devices/rigs/lightstage.toml), used when no rig is given.
pub const BUILTIN_LIGHTSTAGE: &str = include_str!("../../rigs/lightstage.toml");
/// The built-in simulated linear-light reflectometer (devices/rigs/reflectometer.toml).
pub const BUILTIN_REFLECTOMETER: &str = include_str!("../../rigs/reflectometer.toml");
