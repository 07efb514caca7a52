//! The dcttech relay board's 8-byte feature reports as pure functions.
//!
//! Set reports: `[0xFF, ch, 0…]` relay `ch` (from 1) on, `[0xFD, ch, 0…]` off, `[0xFE, 0…]` all
//! on, `[0xFC, 0…]` all off. The get report carries the 5-character serial in bytes 0–4 and
//! the relay bitmask (relay 1 in bit 0) in byte 7. The report id (0) that hidapi puts in front
//! of the data is added and removed by [`with_report_id`] / [`data_of`], not here.

use thiserror::Error;

/// A get report too short to hold the board's state.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ReportError {
    /// hidapi filled fewer bytes than the report id and the data.
    #[error(
        "the board returned a {0} byte feature report, expected the report id and {REPORT_LEN} data bytes"
    )]
    ShortReport(usize),
    /// Fewer data bytes than a report has.
    #[error("feature report has {0} data bytes, expected {REPORT_LEN}")]
    ShortData(usize),
}

/// USB vendor id of the boards (shared V-USB id).
pub const VENDOR_ID: u16 = 0x16c0;
/// USB product id of the boards.
pub const PRODUCT_ID: u16 = 0x05df;
/// Data bytes of every feature report.
pub const REPORT_LEN: usize = 8;
/// The boards use unnumbered reports: hidapi wants report id 0 in front of the data.
pub const REPORT_ID: u8 = 0;
/// Most relays a board has (one bit each in the state byte).
pub const MAX_CHANNELS: u32 = 8;
/// Characters of the board's serial in the get report.
pub const SERIAL_LEN: usize = 5;

const ON: u8 = 0xFF;
const OFF: u8 = 0xFD;
const ALL_ON: u8 = 0xFE;
const ALL_OFF: u8 = 0xFC;

/// A set report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HidCommand {
    /// Relay `ch` (from 1) on.
    On(u8),
    /// Relay `ch` (from 1) off.
    Off(u8),
    /// Every relay on.
    AllOn,
    /// Every relay off.
    AllOff,
}

impl HidCommand {
    /// The 8 data bytes of the report.
    pub fn encode(self) -> [u8; REPORT_LEN] {
        let (op, ch) = match self {
            HidCommand::On(ch) => (ON, ch),
            HidCommand::Off(ch) => (OFF, ch),
            HidCommand::AllOn => (ALL_ON, 0),
            HidCommand::AllOff => (ALL_OFF, 0),
        };
        [op, ch, 0, 0, 0, 0, 0, 0]
    }

    /// The command in a report's data bytes as the board reads it (an emulator's view);
    /// `None` for an unknown opcode, relay 0 or fewer than 2 bytes.
    pub fn decode(data: &[u8]) -> Option<HidCommand> {
        match data {
            [ON, ch, ..] if *ch >= 1 => Some(HidCommand::On(*ch)),
            [OFF, ch, ..] if *ch >= 1 => Some(HidCommand::Off(*ch)),
            [ALL_ON, _, ..] => Some(HidCommand::AllOn),
            [ALL_OFF, _, ..] => Some(HidCommand::AllOff),
            _ => None,
        }
    }
}

/// The hidapi buffer for a report: report id 0, then the 8 data bytes.
pub fn with_report_id(data: [u8; REPORT_LEN]) -> [u8; REPORT_LEN + 1] {
    let mut buf = [REPORT_ID; REPORT_LEN + 1];
    buf[1..].copy_from_slice(&data);
    buf
}

/// The data bytes of a hidapi get-report buffer of which `n` bytes were filled (report id
/// first); an error if the board returned fewer than 8 data bytes.
pub fn data_of(buf: &[u8], n: usize) -> Result<&[u8], ReportError> {
    if n < REPORT_LEN + 1 || buf.len() < REPORT_LEN + 1 {
        return Err(ReportError::ShortReport(n.min(buf.len())));
    }
    Ok(&buf[1..=REPORT_LEN])
}

/// What the get report says: the board's serial and its relay bitmask.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HidState {
    /// The 5-character serial (trailing NULs and spaces dropped, unprintable bytes shown as `?`).
    pub serial: String,
    /// Relay states, relay 1 in bit 0.
    pub mask: u8,
}

impl HidState {
    /// Parses the 8 data bytes of a get report.
    pub fn parse(data: &[u8]) -> Result<HidState, ReportError> {
        if data.len() < REPORT_LEN {
            return Err(ReportError::ShortData(data.len()));
        }
        let raw = &data[..SERIAL_LEN];
        let end = raw
            .iter()
            .rposition(|&b| b != 0 && b != b' ')
            .map_or(0, |i| i + 1);
        let serial = raw[..end]
            .iter()
            .map(|&b| {
                if b.is_ascii_graphic() || b == b' ' {
                    char::from(b)
                } else {
                    '?'
                }
            })
            .collect();
        Ok(HidState {
            serial,
            mask: data[REPORT_LEN - 1],
        })
    }

    /// The 8 data bytes of the get report (the board's or an emulator's side). The serial
    /// is cut or NUL-padded to 5 bytes.
    pub fn encode(&self) -> [u8; REPORT_LEN] {
        let mut data = [0u8; REPORT_LEN];
        for (slot, b) in data.iter_mut().zip(self.serial.bytes().take(SERIAL_LEN)) {
            *slot = b;
        }
        data[REPORT_LEN - 1] = self.mask;
        data
    }

    /// States of relays 1..=`channels`, relay 1 first (false beyond the 8 bits).
    pub fn channels(&self, channels: u32) -> Vec<bool> {
        (0..channels)
            .map(|i| i < 8 && (self.mask >> i) & 1 == 1)
            .collect()
    }
}

/// Number of relays from the USB product string `USBRelayN` (N from 1 to 8).
pub fn channels_from_product(product: &str) -> Option<u32> {
    let n: u32 = product.trim().strip_prefix("USBRelay")?.parse().ok()?;
    (1..=MAX_CHANNELS).contains(&n).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn product_strings() {
        assert_eq!(channels_from_product("USBRelay8"), Some(8));
        assert_eq!(channels_from_product("USBRelay2"), Some(2));
        assert_eq!(channels_from_product("USBRelay9"), None);
        assert_eq!(channels_from_product("Keyboard"), None);
    }

    #[test]
    fn short_reports_are_errors() {
        assert!(HidState::parse(&[1, 2, 3]).is_err());
        assert!(data_of(&[0; 9], 5).is_err());
        assert_eq!(
            data_of(&[0, 1, 2, 3, 4, 5, 6, 7, 8], 9),
            Ok(&[1, 2, 3, 4, 5, 6, 7, 8][..])
        );
    }
}
