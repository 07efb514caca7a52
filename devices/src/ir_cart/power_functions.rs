//! LEGO Power Functions RC protocol (v1.20) words: encoding with the check nibble, decoding
//! with its verification, the single-output PWM commands the cart uses, and the IR mark/space
//! train of a word. Pure functions; the bridge firmware does the actual IR.
//!
//! A word is, most significant nibble first, `[T E C C] [a M M M] [D D D D] [L L L L]`:
//! toggle, escape, channel − 1, address, mode, data and `L = 0xF ^ n1 ^ n2 ^ n3`.

use std::fmt;

/// IR mark of every bit: 6 cycles of 38 kHz.
pub const MARK_US: u32 = 158;
/// Pause after the mark of a 0 bit.
pub const LOW_PAUSE_US: u32 = 263;
/// Pause after the mark of a 1 bit.
pub const HIGH_PAUSE_US: u32 = 553;
/// Pause after the mark of the start and the stop bit.
pub const START_STOP_PAUSE_US: u32 = 1026;

/// Single output mode, PWM, output A (`a M M M` = `0 100`).
const MODE_SINGLE_A: u8 = 0b100;
/// Single output mode, PWM, output B (`0 101`).
const MODE_SINGLE_B: u8 = 0b101;

/// A motor output of the PF receiver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    A,
    B,
}

impl Output {
    /// `A` or `B` (either case), as in the rig file's `ir_output`.
    pub fn parse(s: &str) -> Option<Output> {
        match s.trim() {
            "A" | "a" => Some(Output::A),
            "B" | "b" => Some(Output::B),
            _ => None,
        }
    }
}

/// A single-output PWM command. Steps run from 1 (slowest) to 7 (full speed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pwm {
    /// Motor unpowered, coasting.
    Float,
    /// Forward at step 1–7 (data `0001`–`0111`).
    Forward(u8),
    /// Motor shorted, stopping hard (data `1000`).
    Brake,
    /// Backward at step 1–7 (data `1111` is step 1 … `1001` step 7).
    Backward(u8),
}

impl Pwm {
    /// The data nibble; `None` for a step outside 1–7.
    pub fn nibble(self) -> Option<u8> {
        match self {
            Pwm::Float => Some(0),
            Pwm::Forward(s @ 1..=7) => Some(s),
            Pwm::Brake => Some(0b1000),
            Pwm::Backward(s @ 1..=7) => Some(16 - s),
            Pwm::Forward(_) | Pwm::Backward(_) => None,
        }
    }

    /// The command of a data nibble (its low four bits).
    pub fn from_nibble(n: u8) -> Pwm {
        match n & 0xF {
            0 => Pwm::Float,
            s @ 1..=7 => Pwm::Forward(s),
            8 => Pwm::Brake,
            n => Pwm::Backward(16 - n),
        }
    }
}

/// The check nibble of the first three nibbles.
pub fn check_nibble(n1: u8, n2: u8, n3: u8) -> u8 {
    0xF ^ (n1 & 0xF) ^ (n2 & 0xF) ^ (n3 & 0xF)
}

/// A word whose check nibble does not match its first three nibbles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChecksumError {
    /// The word as received.
    pub word: u16,
    /// The check nibble its first three nibbles call for.
    pub expected: u8,
}

impl fmt::Display for ChecksumError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "Power Functions word {:04X} has check nibble {:X}, expected {:X}",
            self.word,
            self.word & 0xF,
            self.expected
        )
    }
}

impl std::error::Error for ChecksumError {}

/// A Power Functions word, fields validated (channel 1–4, mode 0–7, data 0–15).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PfWord {
    toggle: bool,
    escape: bool,
    channel: u8,
    address: bool,
    mode: u8,
    data: u8,
}

impl PfWord {
    /// A word from its fields; `None` if channel is not 1–4, mode not 0–7 or data not 0–15.
    pub fn new(
        toggle: bool,
        escape: bool,
        channel: u8,
        address: bool,
        mode: u8,
        data: u8,
    ) -> Option<PfWord> {
        ((1..=4).contains(&channel) && mode <= 7 && data <= 15).then_some(PfWord {
            toggle,
            escape,
            channel,
            address,
            mode,
            data,
        })
    }

    /// A single-output PWM command for `output` on `channel` (1–4); `None` for a bad channel
    /// or step.
    pub fn single_output(channel: u8, output: Output, pwm: Pwm, toggle: bool) -> Option<PfWord> {
        let mode = match output {
            Output::A => MODE_SINGLE_A,
            Output::B => MODE_SINGLE_B,
        };
        PfWord::new(toggle, false, channel, false, mode, pwm.nibble()?)
    }

    /// The output and PWM command, if this is a single-output PWM word.
    pub fn as_single_output(&self) -> Option<(Output, Pwm)> {
        if self.escape || self.address {
            return None;
        }
        let output = match self.mode {
            MODE_SINGLE_A => Output::A,
            MODE_SINGLE_B => Output::B,
            _ => return None,
        };
        Some((output, Pwm::from_nibble(self.data)))
    }

    /// The same word with the toggle bit set to `toggle`.
    pub fn with_toggle(self, toggle: bool) -> PfWord {
        PfWord { toggle, ..self }
    }

    pub fn toggle(&self) -> bool {
        self.toggle
    }

    pub fn escape(&self) -> bool {
        self.escape
    }

    /// Channel 1–4.
    pub fn channel(&self) -> u8 {
        self.channel
    }

    pub fn address(&self) -> bool {
        self.address
    }

    /// Mode bits `MMM` (0–7).
    pub fn mode(&self) -> u8 {
        self.mode
    }

    /// Data nibble (0–15).
    pub fn data(&self) -> u8 {
        self.data
    }

    /// The first three nibbles.
    pub fn nibbles(&self) -> [u8; 3] {
        let n1 = u8::from(self.toggle) << 3 | u8::from(self.escape) << 2 | (self.channel - 1);
        let n2 = u8::from(self.address) << 3 | self.mode;
        [n1, n2, self.data]
    }

    /// The 16-bit word including the check nibble.
    pub fn encode(&self) -> u16 {
        let [n1, n2, n3] = self.nibbles();
        let l = check_nibble(n1, n2, n3);
        u16::from(n1) << 12 | u16::from(n2) << 8 | u16::from(n3) << 4 | u16::from(l)
    }

    /// The fields of `word`, after checking its check nibble.
    pub fn decode(word: u16) -> Result<PfWord, ChecksumError> {
        let n1 = (word >> 12) as u8 & 0xF;
        let n2 = (word >> 8) as u8 & 0xF;
        let n3 = (word >> 4) as u8 & 0xF;
        let expected = check_nibble(n1, n2, n3);
        if (word & 0xF) as u8 != expected {
            return Err(ChecksumError { word, expected });
        }
        Ok(PfWord {
            toggle: n1 & 0b1000 != 0,
            escape: n1 & 0b0100 != 0,
            channel: (n1 & 0b11) + 1,
            address: n2 & 0b1000 != 0,
            mode: n2 & 0b111,
            data: n3,
        })
    }
}

/// The word as the bridge's `PF hhhh` wants it: 4 upper-case hex digits.
pub fn to_hex(word: u16) -> String {
    format!("{word:04X}")
}

/// Parses exactly 4 hex digits (either case); `None` for anything else.
pub fn parse_hex(s: &str) -> Option<u16> {
    let s = s.trim();
    if s.len() == 4 && s.bytes().all(|b| b.is_ascii_hexdigit()) {
        u16::from_str_radix(s, 16).ok()
    } else {
        None
    }
}

/// The IR train of one transmission of `word`: (mark µs, pause µs) for the start bit, the 16
/// bits most significant first, and the stop bit.
pub fn ir_timing(word: u16) -> Vec<(u32, u32)> {
    let mut train = Vec::with_capacity(18);
    train.push((MARK_US, START_STOP_PAUSE_US));
    for bit in (0..16).rev() {
        let pause = if word >> bit & 1 == 1 {
            HIGH_PAUSE_US
        } else {
            LOW_PAUSE_US
        };
        train.push((MARK_US, pause));
    }
    train.push((MARK_US, START_STOP_PAUSE_US));
    train
}

/// The word carried by an IR train, or `None` if it is not a start bit, 16 bits and a stop
/// bit with pauses within ±25 % of the nominal ones (the check nibble is not verified here).
pub fn decode_ir_timing(train: &[(u32, u32)]) -> Option<u16> {
    let near = |got: u32, want: u32| got.abs_diff(want) <= want / 4;
    let [start, bits @ .., stop] = train else {
        return None;
    };
    if bits.len() != 16 || !near(start.1, START_STOP_PAUSE_US) || !near(stop.1, START_STOP_PAUSE_US)
    {
        return None;
    }
    bits.iter().try_fold(0u16, |word, &(_, pause)| {
        let bit = if near(pause, HIGH_PAUSE_US) {
            1
        } else if near(pause, LOW_PAUSE_US) {
            0
        } else {
            return None;
        };
        Some(word << 1 | bit)
    })
}
