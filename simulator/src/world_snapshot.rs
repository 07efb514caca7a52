//! What the simulated rig looks like at one instant: the input of the renderer.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use stagehand_devices::fixture_pose::FixturePose;

/// The laser while it emits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LaserBeam {
    pub colour_nm: u32,
    /// Tilt of the fan within the light arc's plane (the laser tilt axis), degrees.
    pub tilt_deg: f64,
    /// Elevation on the light arc where the unit is mounted, degrees.
    pub mount_elevation_deg: f64,
}

/// The state of the simulated rig at one instant of rig time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldSnapshot {
    pub rig_time_s: f64,
    /// Load-side angle of every axis in degrees, by axis id (backlash included).
    pub axes: BTreeMap<String, f64>,
    /// Output of every lamp as a fraction of its steady state (0 = off; warm-up ramps to 1).
    pub lamps: BTreeMap<String, f64>,
    /// The laser, if it is emitting.
    pub laser: Option<LaserBeam>,
    /// Reflectometer cart position in millimetres from the - end stop.
    pub cart_mm: f64,
    /// What lies on the stage: the rig's `sim.sample` or a fixture an operator placed
    /// (checkerboard, colorchecker, planes, or a procedural sample name).
    pub fixture: String,
    /// How the fixture was placed on the turntable (flat and centred unless a prompt said).
    #[serde(default)]
    pub fixture_pose: FixturePose,
}
