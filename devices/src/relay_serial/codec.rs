//! The Numato text protocol as pure functions: command lines to bytes, and the board's echoed,
//! prompt-terminated answers back to reply text. No I/O here, so the codec is tested on its own.
//!
//! A command is its text followed by `\r`. The board echoes what it receives, then answers
//! `\n\r`, the reply text (if the command has one) and `\n\r`, then the prompt `>`.

use thiserror::Error;

/// What is wrong with a command to send or an answer of the board.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum NumatoError {
    /// A relay or GPIO index no channel character names.
    #[error("relay/GPIO index {0} is beyond the board's range 0..={MAX_INDEX}")]
    IndexOutOfRange(u32),
    /// A `relay writeall` mask that does not fit its digits.
    #[error("mask {mask:#x} does not fit in {digits} hex digits (1 to 8)")]
    MaskTooWide {
        /// The relay bitmask.
        mask: u32,
        /// Hex digits asked for.
        digits: u8,
    },
    /// The answer did not start with the echo of the command.
    #[error("expected the echo of `{command}`, got `{got}`")]
    WrongEcho {
        /// The command sent.
        command: String,
        /// The first line of the answer (escaped).
        got: String,
    },
    /// Nothing came before the prompt.
    #[error("no echo of `{0}` before the prompt")]
    NoEcho(String),
    /// A command with a reply got none.
    #[error("no reply text to `{0}` (the board does not know the command?)")]
    NoReplyText(String),
    /// More reply lines than the command has.
    #[error("unexpected reply text to `{command}`: `{text}`")]
    UnexpectedReply {
        /// The command sent.
        command: String,
        /// The extra lines joined with ` | ` (escaped).
        text: String,
    },
    /// The reply to `ver` is not a firmware version.
    #[error(
        "`ver` answered `{0}`, not an 8-character firmware version; is this a Numato-style relay board?"
    )]
    BadVersion(String),
    /// The reply to `relay readall` is not a hex bitmask.
    #[error("`relay readall` answered `{0}`, not a hex bitmask of up to 8 digits")]
    BadMask(String),
    /// The reply to `relay read N` is not `on` or `off`.
    #[error("expected `on` or `off`, got `{0}`")]
    NotOnOff(String),
    /// The reply to `gpio read N` is not `1` or `0`.
    #[error("expected `1` or `0`, got `{0}`")]
    NotLevel(String),
}

/// End of every command line.
pub const COMMAND_END: u8 = b'\r';
/// The prompt that ends every answer of the board.
pub const PROMPT: u8 = b'>';
/// Highest relay or GPIO index a channel character can name (`0`–`9`, then `A`–`V`).
pub const MAX_INDEX: u32 = 31;

/// The board's character for relay or GPIO `index` (from 0): `0`–`9`, then `A`–`V` for 10–31.
pub fn index_char(index: u32) -> Option<char> {
    match index {
        0..=9 => char::from_digit(index, 10),
        10..=MAX_INDEX => char::from_u32(u32::from(b'A') + index - 10),
        _ => None,
    }
}

/// The index named by a channel character (upper or lower case); `None` for anything else.
pub fn parse_index_char(c: char) -> Option<u32> {
    match c {
        '0'..='9' => c.to_digit(10),
        'A'..='V' => Some(u32::from(c) - u32::from('A') + 10),
        'a'..='v' => Some(u32::from(c) - u32::from('a') + 10),
        _ => None,
    }
}

/// Hex digits of the `relay readall` / `relay writeall` mask on a board with `relays` relays
/// (two for eight relays, at least one).
pub fn mask_digits(relays: u32) -> u8 {
    relays.div_ceil(4).clamp(1, 8) as u8
}

/// One command to the board. Relay and GPIO numbers are the board's, from 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `ver`: firmware version (the handshake and the watchdog keepalive).
    Ver,
    /// `id get`: the board's 8-character id.
    IdGet,
    /// `relay on N`.
    RelayOn(u32),
    /// `relay off N`.
    RelayOff(u32),
    /// `relay read N`: `on` or `off`.
    RelayRead(u32),
    /// `relay readall`: hex bitmask of every relay, relay 0 in bit 0.
    RelayReadAll,
    /// `relay writeall HH`: sets every relay from a bitmask written with `digits` hex digits.
    RelayWriteAll { mask: u32, digits: u8 },
    /// `reset`: every relay off.
    Reset,
    /// `gpio set N`: drives GPIO line N high.
    GpioSet(u32),
    /// `gpio clear N`: drives GPIO line N low.
    GpioClear(u32),
    /// `gpio read N`: `1` or `0`.
    GpioRead(u32),
}

impl Command {
    /// The command's text without the line end; an error says why it cannot be sent
    /// (an index beyond `V`, a mask that does not fit its digits).
    pub fn text(&self) -> Result<String, NumatoError> {
        let idx = |n: u32| index_char(n).ok_or(NumatoError::IndexOutOfRange(n));
        Ok(match *self {
            Command::Ver => "ver".into(),
            Command::IdGet => "id get".into(),
            Command::RelayOn(n) => format!("relay on {}", idx(n)?),
            Command::RelayOff(n) => format!("relay off {}", idx(n)?),
            Command::RelayRead(n) => format!("relay read {}", idx(n)?),
            Command::RelayReadAll => "relay readall".into(),
            Command::RelayWriteAll { mask, digits } => {
                if !(1..=8).contains(&digits) || (digits < 8 && mask >> (4 * digits) != 0) {
                    return Err(NumatoError::MaskTooWide { mask, digits });
                }
                format!(
                    "relay writeall {mask:0width$x}",
                    width = usize::from(digits)
                )
            }
            Command::Reset => "reset".into(),
            Command::GpioSet(n) => format!("gpio set {}", idx(n)?),
            Command::GpioClear(n) => format!("gpio clear {}", idx(n)?),
            Command::GpioRead(n) => format!("gpio read {}", idx(n)?),
        })
    }

    /// The bytes to send: the text and `\r`.
    pub fn encode(&self) -> Result<Vec<u8>, NumatoError> {
        let mut bytes = self.text()?.into_bytes();
        bytes.push(COMMAND_END);
        Ok(bytes)
    }

    /// True if the board answers with reply text (between the echo and the prompt).
    pub fn expects_reply(&self) -> bool {
        matches!(
            self,
            Command::Ver
                | Command::IdGet
                | Command::RelayRead(_)
                | Command::RelayReadAll
                | Command::GpioRead(_)
        )
    }

    /// Parses a command line (without `\r`) as the board would; `None` for an unknown command.
    /// The inverse of [`Command::text`], used by tests and emulators.
    pub fn parse(line: &str) -> Option<Command> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let one = |w: &str| {
            let mut chars = w.chars();
            match (chars.next(), chars.next()) {
                (Some(c), None) => parse_index_char(c),
                _ => None,
            }
        };
        match words.as_slice() {
            ["ver"] => Some(Command::Ver),
            ["id", "get"] => Some(Command::IdGet),
            ["reset"] => Some(Command::Reset),
            ["relay", "readall"] => Some(Command::RelayReadAll),
            ["relay", "writeall", hex] => {
                let digits = u8::try_from(hex.len())
                    .ok()
                    .filter(|d| (1..=8).contains(d))?;
                let mask = u32::from_str_radix(hex, 16).ok()?;
                Some(Command::RelayWriteAll { mask, digits })
            }
            ["relay", "on", n] => one(n).map(Command::RelayOn),
            ["relay", "off", n] => one(n).map(Command::RelayOff),
            ["relay", "read", n] => one(n).map(Command::RelayRead),
            ["gpio", "set", n] => one(n).map(Command::GpioSet),
            ["gpio", "clear", n] => one(n).map(Command::GpioClear),
            ["gpio", "read", n] => one(n).map(Command::GpioRead),
            _ => None,
        }
    }
}

/// Splits the board's answer to `command` (everything before the prompt, `raw`) into the
/// reply text: checks the echo, drops the `\n\r` framing, and returns the one reply line when
/// `expects_reply`, `None` otherwise. An error describes what was wrong with the answer.
pub fn parse_reply(
    raw: &str,
    command: &str,
    expects_reply: bool,
) -> Result<Option<String>, NumatoError> {
    let mut lines = raw
        .split(['\r', '\n'])
        .map(str::trim)
        .filter(|l| !l.is_empty());
    match lines.next() {
        Some(echo) if echo == command.trim() => {}
        Some(other) => {
            return Err(NumatoError::WrongEcho {
                command: command.to_string(),
                got: other.escape_debug().to_string(),
            });
        }
        None => return Err(NumatoError::NoEcho(command.to_string())),
    }
    let rest: Vec<&str> = lines.collect();
    match (expects_reply, rest.as_slice()) {
        (true, [reply]) => Ok(Some((*reply).to_string())),
        (true, []) => Err(NumatoError::NoReplyText(command.to_string())),
        (false, []) => Ok(None),
        (_, more) => Err(NumatoError::UnexpectedReply {
            command: command.to_string(),
            text: more.join(" | ").escape_debug().to_string(),
        }),
    }
}

/// Checks the reply to `ver`: 8 letters or digits (`00000008`).
pub fn parse_version(text: &str) -> Result<String, NumatoError> {
    let t = text.trim();
    if t.len() == 8 && t.bytes().all(|b| b.is_ascii_alphanumeric()) {
        Ok(t.to_string())
    } else {
        Err(NumatoError::BadVersion(t.escape_debug().to_string()))
    }
}

/// Parses the hex bitmask of `relay readall` into the states of relays `0..relays`, relay 0
/// first. Bits beyond `relays` (a bigger board) are ignored.
pub fn parse_mask(text: &str, relays: u32) -> Result<Vec<bool>, NumatoError> {
    let t = text.trim();
    let bad = || NumatoError::BadMask(t.escape_debug().to_string());
    if t.is_empty() || t.len() > 8 || !t.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(bad());
    }
    let mask = u32::from_str_radix(t, 16).map_err(|_| bad())?;
    Ok((0..relays)
        .map(|i| i < 32 && (mask >> i) & 1 == 1)
        .collect())
}

/// Parses the reply to `relay read N` (`on` / `off`).
pub fn parse_on_off(text: &str) -> Result<bool, NumatoError> {
    match text.trim() {
        t if t.eq_ignore_ascii_case("on") => Ok(true),
        t if t.eq_ignore_ascii_case("off") => Ok(false),
        t => Err(NumatoError::NotOnOff(t.escape_debug().to_string())),
    }
}

/// Parses the reply to `gpio read N` (`1` / `0`).
pub fn parse_level(text: &str) -> Result<bool, NumatoError> {
    match text.trim() {
        "1" => Ok(true),
        "0" => Ok(false),
        t => Err(NumatoError::NotLevel(t.escape_debug().to_string())),
    }
}

/// The bitmask of `states` (relay 0 first) as written by `relay writeall` / read by `readall`.
pub fn mask_of(states: &[bool]) -> u32 {
    states
        .iter()
        .take(32)
        .enumerate()
        .filter(|(_, on)| **on)
        .fold(0, |m, (i, _)| m | (1 << i))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_characters_run_0_to_9_then_a_to_v() {
        assert_eq!(index_char(0), Some('0'));
        assert_eq!(index_char(9), Some('9'));
        assert_eq!(index_char(10), Some('A'));
        assert_eq!(index_char(31), Some('V'));
        assert_eq!(index_char(32), None);
        assert_eq!(parse_index_char('v'), Some(31));
        assert_eq!(parse_index_char('W'), None);
    }

    #[test]
    fn reply_framing() {
        let raw = "ver\r\n\r00000008\n\r";
        assert_eq!(parse_reply(raw, "ver", true), Ok(Some("00000008".into())));
        assert_eq!(parse_reply("relay on 3\n\r", "relay on 3", false), Ok(None));
        assert!(parse_reply("ver\n\r", "ver", true).is_err());
        assert!(parse_reply("vex\n\r0\n\r", "ver", true).is_err());
    }
}
