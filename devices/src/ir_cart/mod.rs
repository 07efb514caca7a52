//! The reflectometer cart: a LEGO Power Functions motor driven over IR by a serial IR bridge.
//! `power_functions` is the PF word and IR timing codec, `bridge` the cart driver.
//!
//! See `devices/PROTOCOLS.md` ("LEGO Power Functions IR bridge").

pub mod bridge;
pub mod power_functions;
pub(crate) mod wiring;

pub use bridge::IrBridgeCart;
pub use power_functions::{Output, PfWord, Pwm};
