//! The root crate's integration tests, one binary (CI links it once, not once per file): each
//! former test file is a module; `common` holds the shared helpers and the daemon tests' setup,
//! and `grbl_peer` (the real GRBL 1.1h firmware on a pty) is the simulator tests' own module.
//!
//! Tests of different modules run side by side in the test threads. Each one keeps to its own
//! temporary directories, ports chosen by the kernel and its own child processes; the
//! real-firmware tests run one at a time through `grbl_peer::exclusive`.

mod bad_input;
mod calibration;
mod calibration_colour;
mod common;
mod control;
mod daemon_api;
mod daemon_bad_input;
mod daemon_devices;
mod daemon_frames;
mod daemon_remote;
mod daemon_runs;
mod depth;
mod determinism;
mod dipole_model;
mod emulated_rig;
mod ground_truth;
mod kill_resume;
mod laser_geometry;
mod process;
mod real_grbl_quickstart;
mod rectification;
mod reflectometer;
mod run_state;
mod sequences;
mod sim_tradeoff;
mod verify_retake;
mod ward_model;

#[path = "../../simulator/tests/integration/grbl_peer/mod.rs"]
mod grbl_peer;
