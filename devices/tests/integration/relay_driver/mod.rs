//! The switched-output drivers against small scripted fakes: a Numato-style relay board and an
//! IR bridge, and an in-memory dcttech HID board. The fakes parse the wire text on their own
//! (not with the crate's codecs), so a misreading on either side fails a test.
//!
//! The serial fakes are tokio tasks on the other end of `tokio::io::duplex` streams (see
//! `fake_port.rs`) and their tests run on tokio's paused clock: keepalives, pulse widths and
//! timeouts happen at exact virtual instants, never racing the wall clock. One smoke test per
//! driver runs its fake over a real pty. The HID tests stay on the real clock: the HID driver
//! does blocking I/O on a std thread, which virtual time cannot see (they assert no timing).

mod hid;
mod ir_bridge;
mod numato;
