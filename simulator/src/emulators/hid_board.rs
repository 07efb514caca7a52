//! An in-memory dcttech-compatible USB HID relay board (`USBRelayN`): feature reports of 8 data
//! bytes behind report id 0, as hidapi passes them, switching the World's channels.

use std::io;
use std::sync::Arc;

use stagehand_devices::hid_relay::HidTransport;

use super::{Fault, Faults, drive_channel};
use crate::world::World;

/// USB vendor id the board enumerates with.
pub const VID: u16 = 0x16c0;
/// USB product id the board enumerates with.
pub const PID: u16 = 0x05df;
/// Length of a feature report buffer: report id + 8 data bytes.
pub const REPORT_LEN: usize = 9;

/// An emulated HID relay board driving switch bank `bank` of the World. Of the faults it
/// honours `BoardReset` (counted in set reports); the serial faults do not apply to it.
pub struct HidRelayBoard {
    world: Arc<World>,
    bank: String,
    serial: [u8; 5],
    states: Vec<bool>,
    faults: Arc<Faults>,
    commands: u64,
}

impl HidRelayBoard {
    /// A board with `channels` relays (1–8), all off, reporting `serial` (5 ASCII characters,
    /// padded or cut) and driving channels of `bank`.
    pub fn new(
        world: Arc<World>,
        bank: &str,
        channels: u32,
        serial: &str,
        faults: Arc<Faults>,
    ) -> Self {
        let mut s = [b' '; 5];
        for (slot, b) in s.iter_mut().zip(serial.bytes()) {
            *slot = b;
        }
        Self {
            world,
            bank: bank.to_string(),
            serial: s,
            states: vec![false; channels.clamp(1, 8) as usize],
            faults,
            commands: 0,
        }
    }

    /// The USB product string (`USBRelayN`).
    pub fn product(&self) -> String {
        format!("USBRelay{}", self.states.len())
    }

    /// The board's relay states, relay 1 first.
    pub fn states(&self) -> &[bool] {
        &self.states
    }

    /// Set commands received (the count the faults use).
    pub fn commands(&self) -> u64 {
        self.commands
    }

    fn set(&mut self, relay: usize, on: bool, t: f64) {
        if let Some(slot) = self.states.get_mut(relay) {
            *slot = on;
            drive_channel(&self.world, &self.bank, relay as u32 + 1, on, t);
        }
    }

    /// hidapi's `send_feature_report`: `data[0]` is the report id (0), then the command bytes.
    pub fn send_feature_report(&mut self, data: &[u8]) -> io::Result<()> {
        if data.len() < 3 || data[0] != 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "a feature report is report id 0 followed by 8 data bytes",
            ));
        }
        let t = self.world.clock().now_s();
        self.commands += 1;
        let n = self.commands;
        let (cmd, ch) = (data[1], data[2] as usize);
        match cmd {
            0xFF | 0xFD if (1..=self.states.len()).contains(&ch) => {
                self.set(ch - 1, cmd == 0xFF, t)
            }
            0xFE | 0xFC => {
                for r in 0..self.states.len() {
                    self.set(r, cmd == 0xFE, t);
                }
            }
            // Anything else is ignored by the firmware.
            _ => {}
        }
        for f in self.faults.after_command(n, t) {
            if let Fault::BoardReset { .. } = f {
                for r in 0..self.states.len() {
                    self.set(r, false, t);
                }
            }
        }
        Ok(())
    }

    /// hidapi's `get_feature_report`: `buf[0]` holds the report id (0) on entry; on return
    /// bytes 1–5 are the serial and byte 8 the state bitmask. Returns the bytes written, report
    /// id included.
    pub fn get_feature_report(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if buf.len() < REPORT_LEN {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "the buffer must hold the report id and 8 data bytes",
            ));
        }
        let mask = self
            .states
            .iter()
            .enumerate()
            .fold(0u8, |m, (i, on)| m | (u8::from(*on) << i));
        buf[0] = 0;
        buf[1..6].copy_from_slice(&self.serial);
        buf[6] = 0;
        buf[7] = 0;
        buf[8] = mask;
        Ok(REPORT_LEN)
    }
}

/// The board as the HID relay driver's transport (what hidapi gives the real driver).
impl HidTransport for HidRelayBoard {
    fn send_feature_report(&mut self, data: &[u8]) -> io::Result<()> {
        HidRelayBoard::send_feature_report(self, data)
    }

    fn get_feature_report(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        HidRelayBoard::get_feature_report(self, buf)
    }
}
