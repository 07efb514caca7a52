//! dcttech-compatible USB HID relay boards (VID 0x16c0, PID 0x05df, product `USBRelayN`):
//! the feature-report codec, a transport trait with its hidapi implementation, and the
//! switch-bank driver that runs the blocking transport on its own thread.
//!
//! See `devices/PROTOCOLS.md` ("dcttech-compatible USB HID relays").

pub mod codec;
pub mod driver;
pub(crate) mod wiring;

pub use codec::{HidCommand, HidState};
pub use driver::{
    HidOpenError, HidRelayBank, HidRelayInfo, HidTransport, HidapiTransport, list_hid_relays,
};
