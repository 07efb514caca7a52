//! The simulated light stage: a `World` holding the rig's state on the virtual clock,
//! simulated devices that change it, and a renderer that turns it into camera frames.

pub mod render;
pub mod world_state;
