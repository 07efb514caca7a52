//! GRBL 1.1 driver for the stepper axes and the laser (see `PROTOCOLS.md`, section GRBL).
//!
//! One [`GrblController`] per port is shared by the [`GrblAxis`] drivers of the axes on it and
//! by a [`GrblLaser`] on its spindle output. [`codec`] and [`flow`] hold the pure protocol
//! parts, [`codes`] the meanings of `error:N` and `ALARM:N`, [`settings`] what the board's
//! settings and build options mean for the rig.

pub mod axis;
pub mod codec;
pub mod codes;
mod conn;
pub mod controller;
pub mod flow;
pub mod laser;
pub mod settings;
pub(crate) mod wiring;

pub use axis::GrblAxis;
pub use controller::GrblController;
pub use laser::GrblLaser;
