//! The simulator's integration tests, one binary (CI links it once): each former test file is
//! a module, and `grbl_peer` (the real GRBL 1.1h firmware on a pty) is shared by the modules
//! that need it, whose tests run one at a time through `grbl_peer::exclusive`.

mod emulators;
mod grbl_conformance;
mod grbl_peer;
mod grbl_real_driver;
mod numerics;
mod scenes;
mod world;
