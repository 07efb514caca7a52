//! The device crate's integration tests, one binary (CI links it once): each former test file
//! is a module. `aravis_gige.rs` stays its own binary: it needs the `cam-aravis` feature and
//! the fake GigE cameras, and `.ci/gige.sh` runs it in a network namespace.

mod actors;
mod camera_accounting;
mod fake_port;
mod grbl_codec;
mod grbl_driver;
mod relay_codecs;
mod relay_driver;
