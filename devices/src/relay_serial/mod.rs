//! Numato-style serial relay boards (USB CDC, 19200 8N1): the text codec, the board shared by
//! every user of one port (relay bank, GPIO trigger), and the switch-bank driver on top.
//!
//! See `devices/PROTOCOLS.md` ("Numato-style serial relay boards") for the wire protocol.

pub mod board;
pub mod codec;
pub(crate) mod wiring;

pub use board::{NumatoBoard, RelaySerialBank};
pub use codec::Command;
