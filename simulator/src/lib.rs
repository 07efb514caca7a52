//! The simulated light stage: a `World` holding the rig's state on the virtual clock,
//! simulated devices that change it, and a renderer that turns it into camera frames.

#![deny(unsafe_code)]

pub mod as_built;
pub mod emulators;
pub mod materials;
pub mod render;
mod render_ahead;
pub mod scene_file;
pub mod sim_devices;
pub mod world;
pub mod world_snapshot;

pub use world::World;
