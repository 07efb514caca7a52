//! Device layer of stagehand: capability traits, the actor handles that own each device,
//! the motion physics shared by drivers and the planner, and rig descriptions (TOML).
//!
//! This crate knows nothing of the engine or the simulator (see ARCHITECTURE.md).

#![deny(unsafe_code)]

pub mod axis;
pub mod camera;
pub mod cameras;
pub mod cart;
pub mod clock;
pub mod compute_time;
pub mod discover;
pub mod error;
pub mod fixture_pose;
pub mod frame;
pub mod grbl;
pub mod ground_truth;
pub mod hid_relay;
pub mod interlock;
pub mod ir_cart;
pub mod laser;
pub mod lens;
pub mod motion;
pub mod realtime;
pub mod relay_serial;
mod request;
pub mod rig;
pub mod serial_link;
pub mod switch_bank;
pub mod switch_wired;
pub mod trigger;

pub use error::{DeviceError, DeviceErrorKind, DeviceResult};
pub use frame::Frame;
