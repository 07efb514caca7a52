//! Simulated drivers for every device trait, all coupled through one [`World`](crate::world::World).

mod axis;
mod camera;
mod cart;
mod laser;
mod mirror;
mod switches;
mod test_pattern;
mod trigger;

pub use axis::SimAxis;
pub use camera::SimCamera;
pub use cart::SimCart;
pub use laser::SimLaser;
pub use mirror::{MirroredAxis, MirroredLaser};
pub use switches::SimSwitchBank;
pub use test_pattern::{TestPattern, test_pattern};
pub use trigger::SimTrigger;

/// Latency of one command on the simulated serial link (not modelled by the planner's
/// estimate, like the real link's latency).
pub(crate) const COMMAND_LATENCY_S: f64 = 0.002;
