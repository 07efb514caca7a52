//! GRBL 1.1 text, both ways: one received line parsed into a [`Reply`], and the commands and
//! real-time bytes the driver sends. Pure functions with no I/O, so they can be tested (and
//! fuzzed) on their own; parsing never panics, whatever the bytes.

use std::fmt::Write as _;

/// Letters of the three axes the driver uses, in `$100..$102` / MPos order.
pub const AXIS_LETTERS: [char; 3] = ['X', 'Y', 'Z'];

/// Spindle value that switches the laser fully on (`$30` max spindle speed is 1000).
pub const LASER_FULL_POWER: u32 = 1000;

/// Index (0 for X, 1 for Y, 2 for Z) of an axis letter, case-insensitive.
pub fn axis_index(letter: char) -> Option<usize> {
    AXIS_LETTERS
        .iter()
        .position(|l| *l == letter.to_ascii_uppercase())
}

/// Machine state at the start of a status report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum State {
    #[default]
    Idle,
    Run,
    /// `Hold:0` (hold complete, safe to reset) or `Hold:1` (decelerating).
    Hold(u8),
    Jog,
    Alarm,
    /// `Door:0..3`.
    Door(u8),
    Check,
    Home,
    Sleep,
}

impl State {
    /// Parses the state word of a status report (`Hold` and `Door` without a number read as 0).
    pub fn parse(text: &str) -> Option<State> {
        let (word, sub) = match text.split_once(':') {
            Some((w, s)) => (w, Some(s.parse::<u8>().ok()?)),
            None => (text, None),
        };
        let state = match (word, sub) {
            ("Idle", None) => State::Idle,
            ("Run", None) => State::Run,
            ("Hold", s) => State::Hold(s.unwrap_or(0)),
            ("Jog", None) => State::Jog,
            ("Alarm", None) => State::Alarm,
            ("Door", s) => State::Door(s.unwrap_or(0)),
            ("Check", None) => State::Check,
            ("Home", None) => State::Home,
            ("Sleep", None) => State::Sleep,
            _ => return None,
        };
        Some(state)
    }

    /// The state word as GRBL prints it.
    pub fn text(&self) -> String {
        match self {
            State::Idle => "Idle".into(),
            State::Run => "Run".into(),
            State::Hold(n) => format!("Hold:{n}"),
            State::Jog => "Jog".into(),
            State::Alarm => "Alarm".into(),
            State::Door(n) => format!("Door:{n}"),
            State::Check => "Check".into(),
            State::Home => "Home".into(),
            State::Sleep => "Sleep".into(),
        }
    }
}

/// Which position a status report carries (`$10` bit 0): machine position, or work position
/// (machine position minus the work coordinate offset `WCO`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PosKind {
    #[default]
    Machine,
    Work,
}

/// A parsed status report (`<Idle|MPos:1.000,2.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>`).
/// GRBL sends its optional fields only now and then (`WCO:` every 10–30 reports and after an
/// offset changes, `Ov:` and `A:` every 10–20 reports and after the spindle changes), so each
/// is an `Option`; `Bf:` and `Ln:` are ignored.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Status {
    pub state: State,
    /// X, Y, Z in the controller's "mm" (our degrees); further axes are dropped.
    pub pos: [f64; 3],
    pub kind: PosKind,
    /// `WCO:` work coordinate offset, when the report carries it.
    pub wco: Option<[f64; 3]>,
    /// `FS:` current feed rate and spindle speed (`F:` without a spindle value).
    pub feed: Option<f64>,
    pub spindle_speed: Option<f64>,
    /// Whether the spindle output is on, known only from a report with `Ov:` (which carries
    /// `A:S`/`A:C` exactly when the output is on); `None` without `Ov:`.
    pub spindle_on: Option<bool>,
    /// `Pn:` limit switches pressed, X, Y, Z.
    pub limit_pins: [bool; 3],
}

impl Status {
    /// Position of the axis with `letter`, if it is X, Y or Z.
    pub fn axis(&self, letter: char) -> Option<f64> {
        axis_index(letter).map(|i| self.pos[i])
    }
}

/// One line received from the controller.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    Ok,
    Error(u32),
    Alarm(u32),
    Status(Status),
    /// Start-up banner `Grbl 1.1h ['$' for help]`; `version` is the word after `Grbl`.
    Banner {
        version: String,
    },
    /// A push message in brackets (`[MSG:...]`, `[GC:...]`), without the brackets, or a
    /// startup-block echo starting with `>`, kept whole.
    Message(String),
    /// A setting line `$N=value`.
    Setting {
        n: u32,
        value: f64,
    },
    /// Anything else: not GRBL 1.1 text (garbage where a reply is due).
    Other(String),
}

impl Reply {
    /// The line as the controller prints it (without the `\r\n`); the inverse of [`parse_line`]
    /// (used by tests and emulators).
    pub fn to_line(&self) -> String {
        match self {
            Reply::Ok => "ok".into(),
            Reply::Error(n) => format!("error:{n}"),
            Reply::Alarm(n) => format!("ALARM:{n}"),
            Reply::Status(s) => {
                let key = match s.kind {
                    PosKind::Machine => "MPos",
                    PosKind::Work => "WPos",
                };
                let axes = |p: [f64; 3]| format!("{:.3},{:.3},{:.3}", p[0], p[1], p[2]);
                let mut line = format!("<{}|{key}:{}", s.state.text(), axes(s.pos));
                let _ = write!(
                    line,
                    "|FS:{},{}",
                    s.feed.unwrap_or(0.0),
                    s.spindle_speed.unwrap_or(0.0)
                );
                if s.limit_pins.contains(&true) {
                    line.push_str("|Pn:");
                    for (on, l) in s.limit_pins.iter().zip(AXIS_LETTERS) {
                        if *on {
                            line.push(l);
                        }
                    }
                }
                if let Some(w) = s.wco {
                    let _ = write!(line, "|WCO:{}", axes(w));
                }
                if let Some(on) = s.spindle_on {
                    line.push_str("|Ov:100,100,100");
                    if on {
                        line.push_str("|A:S");
                    }
                }
                line.push('>');
                line
            }
            Reply::Banner { version } => format!("Grbl {version} ['$' for help]"),
            Reply::Message(m) if m.starts_with('>') => m.clone(),
            Reply::Message(m) => format!("[{m}]"),
            Reply::Setting { n, value } => format!("${n}={value}"),
            Reply::Other(t) => t.clone(),
        }
    }
}

/// Parses raw bytes of one line (lossy UTF-8); never panics.
pub fn parse_bytes(bytes: &[u8]) -> Reply {
    parse_line(&String::from_utf8_lossy(bytes))
}

/// Parses one line (surrounding whitespace and the line end are ignored); never panics.
pub fn parse_line(line: &str) -> Reply {
    let line = line.trim();
    let other = || Reply::Other(line.to_string());
    if line == "ok" {
        return Reply::Ok;
    }
    if let Some(n) = line.strip_prefix("error:") {
        return n.parse().map(Reply::Error).unwrap_or_else(|_| other());
    }
    if let Some(n) = line.strip_prefix("ALARM:") {
        return n.parse().map(Reply::Alarm).unwrap_or_else(|_| other());
    }
    if let Some(body) = line.strip_prefix('<').and_then(|l| l.strip_suffix('>')) {
        return parse_status(body).map(Reply::Status).unwrap_or_else(other);
    }
    if let Some(rest) = line.strip_prefix("Grbl ") {
        let version = rest.split_whitespace().next().unwrap_or("");
        return Reply::Banner {
            version: version.to_string(),
        };
    }
    if let Some(m) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
        return Reply::Message(m.to_string());
    }
    if line.starts_with('>') || line.starts_with("$N") {
        return Reply::Message(line.to_string());
    }
    if let Some((n, value)) = line.strip_prefix('$').and_then(|l| l.split_once('='))
        && let (Ok(n), Ok(value)) = (n.parse::<u32>(), value.trim().parse::<f64>())
        && value.is_finite()
    {
        return Reply::Setting { n, value };
    }
    other()
}

fn parse_status(body: &str) -> Option<Status> {
    let mut fields = body.split('|');
    let mut s = Status {
        state: State::parse(fields.next()?)?,
        ..Status::default()
    };
    let mut have_pos = false;
    for field in fields {
        // The state and the position must be right; an optional field that is garbled (a
        // noisy line) is dropped rather than costing the whole report.
        let Some((key, value)) = field.split_once(':') else {
            continue;
        };
        match key {
            "MPos" | "WPos" => {
                s.kind = if key == "MPos" {
                    PosKind::Machine
                } else {
                    PosKind::Work
                };
                s.pos = three(value)?;
                have_pos = true;
            }
            "WCO" => s.wco = three(value),
            "FS" => {
                let (f, sp) = value.split_once(',').unwrap_or((value, ""));
                s.feed = number(f);
                s.spindle_speed = number(sp);
            }
            "F" => s.feed = number(value),
            "Ov" => {
                s.spindle_on.get_or_insert(false);
            }
            "A" => s.spindle_on = Some(value.contains(['S', 'C'])),
            "Pn" => {
                for (pin, l) in s.limit_pins.iter_mut().zip(AXIS_LETTERS) {
                    *pin = value.contains(l);
                }
            }
            _ => {}
        }
    }
    have_pos.then_some(s)
}

/// A finite number.
fn number(text: &str) -> Option<f64> {
    text.trim().parse::<f64>().ok().filter(|v| v.is_finite())
}

/// The first three of a comma-separated list of numbers (further axes are dropped).
fn three(text: &str) -> Option<[f64; 3]> {
    let mut pos = [0.0; 3];
    let mut values = text.split(',');
    for p in pos.iter_mut() {
        *p = number(values.next()?)?;
    }
    Some(pos)
}

/// A command line for the controller (answered by `ok` or `error:N`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// `G53 G0 X-12.500`: rapid move of one axis to a machine coordinate (so work offsets
    /// set on the controller do not matter), 3 decimals.
    Move { axis: char, machine: f64 },
    /// `$H` (all axes) or `$HX` (one axis).
    Home(Option<char>),
    /// `$X`: clear an alarm without homing.
    Unlock,
    /// `M3 S1000`: laser on at `power` (0..=1000).
    LaserOn { power: u32 },
    /// `M5`: laser off.
    LaserOff,
    /// `$$`: list the settings.
    Settings,
    /// `$I`: build info (`[VER:...]`, `[OPT:...]`).
    BuildInfo,
    /// `$G`: parser state (`[GC:...]`).
    ParserState,
}

impl Command {
    /// The command text, without the line end.
    pub fn line(&self) -> String {
        match *self {
            Command::Move { axis, machine } => {
                let mut s = String::from("G53 G0 ");
                let value = if machine.abs() < 0.0005 { 0.0 } else { machine };
                let _ = write!(s, "{}{value:.3}", axis.to_ascii_uppercase());
                s
            }
            Command::Home(None) => "$H".into(),
            Command::Home(Some(axis)) => format!("$H{}", axis.to_ascii_uppercase()),
            Command::Unlock => "$X".into(),
            Command::LaserOn { power } => format!("M3 S{power}"),
            Command::LaserOff => "M5".into(),
            Command::Settings => "$$".into(),
            Command::BuildInfo => "$I".into(),
            Command::ParserState => "$G".into(),
        }
    }

    /// The bytes on the wire: the text and `\n`.
    pub fn bytes(&self) -> Vec<u8> {
        let mut b = self.line().into_bytes();
        b.push(b'\n');
        b
    }
}

/// Single-byte real-time commands: not lines, never answered by `ok`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Realtime {
    /// `?`: one status report.
    Status,
    /// `!`: feed hold (decelerate and stop, position kept).
    FeedHold,
    /// `~`: resume after a hold.
    CycleStart,
    /// `0x18` (Ctrl-X): soft reset; prints the banner again.
    SoftReset,
}

impl Realtime {
    /// The byte on the wire.
    pub const fn byte(self) -> u8 {
        match self {
            Realtime::Status => b'?',
            Realtime::FeedHold => b'!',
            Realtime::CycleStart => b'~',
            Realtime::SoftReset => 0x18,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_lines_of_protocols_md() {
        assert_eq!(parse_line("ok\r"), Reply::Ok);
        assert_eq!(parse_line("error:9"), Reply::Error(9));
        assert_eq!(parse_line("ALARM:3"), Reply::Alarm(3));
        assert_eq!(
            parse_line("Grbl 1.1h ['$' for help]"),
            Reply::Banner {
                version: "1.1h".into()
            }
        );
        assert_eq!(
            parse_line("[MSG:'$H'|'$X' to unlock]"),
            Reply::Message("MSG:'$H'|'$X' to unlock".into())
        );
        assert_eq!(
            parse_line("$100=88.889"),
            Reply::Setting {
                n: 100,
                value: 88.889
            }
        );
        assert_eq!(
            parse_line("<Idle|MPos:1.000,2.000,0.000|FS:0,0>"),
            Reply::Status(Status {
                state: State::Idle,
                pos: [1.0, 2.0, 0.0],
                kind: PosKind::Machine,
                feed: Some(0.0),
                spindle_speed: Some(0.0),
                ..Status::default()
            })
        );
    }

    #[test]
    fn status_takes_wpos_extra_fields_and_more_axes() {
        let Reply::Status(s) =
            parse_line("<Hold:1|WPos:-1.5,2,3,4.5|Bf:15,128|FS:0,0|Pn:XYZ|WCO:0,0,0>")
        else {
            panic!("not a status")
        };
        assert_eq!(s.state, State::Hold(1));
        assert_eq!(s.pos, [-1.5, 2.0, 3.0]);
        assert_eq!(s.kind, PosKind::Work);
        assert_eq!(s.axis('y'), Some(2.0));
        assert_eq!(s.axis('A'), None);
        for state in ["Door:3", "Jog", "Check", "Home", "Sleep", "Run", "Alarm"] {
            let line = format!("<{state}|MPos:0,0,0>");
            assert!(matches!(parse_line(&line), Reply::Status(_)), "{line}");
        }
    }

    #[test]
    fn status_reads_the_optional_fields_of_real_grbl() {
        let Reply::Status(s) =
            parse_line("<Idle|WPos:-6.000,0.000,0.000|FS:0,1000|Pn:Z|WCO:5.000,0.000,0.000>")
        else {
            panic!("not a status")
        };
        assert_eq!(s.kind, PosKind::Work);
        assert_eq!(s.wco, Some([5.0, 0.0, 0.0]));
        assert_eq!((s.feed, s.spindle_speed), (Some(0.0), Some(1000.0)));
        assert_eq!(s.limit_pins, [false, false, true]);
        assert_eq!(s.spindle_on, None, "no Ov: field, so the output is unknown");
        let Reply::Status(s) = parse_line("<Idle|MPos:0,0,0|FS:0,1000|Ov:100,100,100|A:S>") else {
            panic!("not a status")
        };
        assert_eq!(s.spindle_on, Some(true));
        let Reply::Status(s) = parse_line("<Run|MPos:0,0,0|FS:1800,0|Ov:100,100,100>") else {
            panic!("not a status")
        };
        assert_eq!((s.spindle_on, s.feed), (Some(false), Some(1800.0)));
        // The emulators print what the parser reads.
        assert_eq!(parse_line(&Reply::Status(s).to_line()), Reply::Status(s));
    }

    #[test]
    fn malformed_lines_are_other() {
        for bad in [
            "<Idle|MPos:1,2>",
            "<Idle|FS:0,0>",
            "<Walk|MPos:0,0,0>",
            "<Idle|MPos:a,0,0>",
            "<Idle|MPos:inf,0,0>",
            "error:x",
            "ALARM:",
            "okay",
            "$1x=2",
            "Grbl",
            "",
        ] {
            assert!(matches!(parse_line(bad), Reply::Other(_)), "{bad:?}");
        }
    }

    #[test]
    fn encodes_commands_and_realtime_bytes() {
        assert_eq!(
            Command::Move {
                axis: 'x',
                machine: -12.5
            }
            .bytes(),
            b"G53 G0 X-12.500\n"
        );
        assert_eq!(
            Command::Move {
                axis: 'Z',
                machine: -0.0001
            }
            .line(),
            "G53 G0 Z0.000"
        );
        assert_eq!(Command::Home(Some('y')).line(), "$HY");
        assert_eq!(Command::Home(None).line(), "$H");
        assert_eq!(Command::Unlock.line(), "$X");
        assert_eq!(
            Command::LaserOn {
                power: LASER_FULL_POWER
            }
            .line(),
            "M3 S1000"
        );
        assert_eq!(Command::LaserOff.line(), "M5");
        assert_eq!(Command::Settings.line(), "$$");
        assert_eq!(Realtime::SoftReset.byte(), 0x18);
        assert_eq!(Realtime::Status.byte(), b'?');
        assert_eq!(Realtime::FeedHold.byte(), b'!');
        assert_eq!(Realtime::CycleStart.byte(), b'~');
    }
}
