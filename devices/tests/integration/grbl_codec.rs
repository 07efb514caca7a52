//! Property tests and snapshots of the GRBL 1.1 codec: round trips of the lines the controller
//! prints, a parser that never panics, and the exact bytes of every command the driver sends.
//! (The byte streams of whole exchanges — handshake, homing, a move, stop, laser — are
//! snapshotted in `grbl_driver.rs`, where the fake controller records them.)

use proptest::prelude::*;

use stagehand_devices::grbl::codec::{
    Command, PosKind, Realtime, Reply, State, Status, parse_bytes, parse_line,
};
use stagehand_devices::grbl::codes::{alarm_meaning, error_meaning};

fn state() -> impl Strategy<Value = State> {
    prop_oneof![
        Just(State::Idle),
        Just(State::Run),
        (0u8..=1).prop_map(State::Hold),
        Just(State::Jog),
        Just(State::Alarm),
        (0u8..=3).prop_map(State::Door),
        Just(State::Check),
        Just(State::Home),
        Just(State::Sleep),
    ]
}

/// Positions as GRBL prints them: multiples of 0.001.
fn coord() -> impl Strategy<Value = f64> {
    (-9_999_999i64..=9_999_999).prop_map(|m| m as f64 / 1000.0)
}

proptest! {
    #[test]
    fn status_reports_round_trip(
        state in state(),
        pos in [coord(), coord(), coord()],
        work in any::<bool>(),
    ) {
        let kind = if work { PosKind::Work } else { PosKind::Machine };
        let status = Reply::Status(Status { state, pos, kind, feed: Some(0.0), spindle_speed: Some(0.0), ..Status::default() });
        let line = status.to_line();
        prop_assert_eq!(parse_line(&line), status.clone());
        prop_assert_eq!(parse_line(&format!("{line}\r\n")), status);
    }

    #[test]
    fn status_reports_with_extra_fields_and_axes_keep_xyz(
        state in state(),
        pos in [coord(), coord(), coord()],
        extra in prop::collection::vec(coord(), 0..3),
        prefix in prop::sample::select(vec!["", "|Bf:15,128", "|Ov:100,100,100"]),
        suffix in prop::sample::select(vec!["", "|FS:0,0", "|WCO:0.000,0.000,0.000|Pn:XZ"]),
    ) {
        let mut coords: Vec<String> = pos.iter().map(|v| format!("{v:.3}")).collect();
        coords.extend(extra.iter().map(|v| format!("{v:.3}")));
        let line = format!("<{}{prefix}|MPos:{}{suffix}>", state.text(), coords.join(","));
        let Reply::Status(s) = parse_line(&line) else {
            return Err(TestCaseError::fail(format!("not a status: {line}")));
        };
        prop_assert_eq!(s.state, state);
        prop_assert_eq!(s.pos, pos);
    }

    #[test]
    fn error_and_alarm_lines_round_trip(code in any::<u32>()) {
        for reply in [Reply::Error(code), Reply::Alarm(code)] {
            prop_assert_eq!(parse_line(&reply.to_line()), reply);
        }
        prop_assert!(!error_meaning(code).is_empty());
        prop_assert!(!alarm_meaning(code).is_empty());
    }

    #[test]
    fn settings_and_banners_round_trip(n in 0u32..200, value in coord(), version in "[0-9]\\.[0-9][a-z]?") {
        let s = Reply::Setting { n, value };
        prop_assert_eq!(parse_line(&s.to_line()), s);
        let b = Reply::Banner { version };
        prop_assert_eq!(parse_line(&b.to_line()), b);
    }

    #[test]
    fn parser_never_panics_on_bytes(bytes in prop::collection::vec(any::<u8>(), 0..200)) {
        let _ = parse_bytes(&bytes);
    }

    #[test]
    fn parser_never_panics_on_grbl_like_text(text in "[<>|:,.\\-0-9A-Za-z$=\\[\\] ]{0,80}") {
        let _ = parse_line(&text);
        let _ = parse_line(&format!("<{text}>"));
        let _ = parse_line(&format!("<Idle|MPos:{text}>"));
    }

    #[test]
    fn moves_encode_three_decimals_and_parse_back(deg in -100_000.0f64..100_000.0, axis in prop::sample::select(vec!['X', 'Y', 'Z'])) {
        let line = Command::Move { axis, machine: deg }.line();
        let number = line.strip_prefix(&format!("G53 G0 {axis}")).unwrap();
        let decimals = number.split_once('.').map(|(_, d)| d.len());
        prop_assert_eq!(decimals, Some(3), "{}", line);
        let back: f64 = number.parse().unwrap();
        prop_assert!((back - deg).abs() <= 0.0005 + 1e-9, "{} vs {}", line, deg);
    }
}

/// Bytes as text: printable ASCII as is, anything else as `<0xNN>`, `\n` visible.
fn show(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|&b| match b {
            b'\n' => "\\n".to_string(),
            b if b.is_ascii_graphic() || b == b' ' => (b as char).to_string(),
            b => format!("<0x{b:02x}>"),
        })
        .collect()
}

#[test]
fn command_bytes() {
    let commands = [
        Command::Move {
            axis: 'X',
            machine: 12.5,
        },
        Command::Move {
            axis: 'y',
            machine: -3.25,
        },
        Command::Move {
            axis: 'Z',
            machine: 359.9996,
        },
        Command::Home(Some('X')),
        Command::Home(None),
        Command::Unlock,
        Command::LaserOn { power: 1000 },
        Command::LaserOff,
        Command::Settings,
    ];
    let text: Vec<String> = commands.iter().map(|c| show(&c.bytes())).collect();
    insta::assert_snapshot!(text.join("\n"), @r"
    G53 G0 X12.500\n
    G53 G0 Y-3.250\n
    G53 G0 Z360.000\n
    $HX\n
    $H\n
    $X\n
    M3 S1000\n
    M5\n
    $$\n
    ");
}

#[test]
fn realtime_bytes() {
    let bytes: Vec<u8> = [
        Realtime::Status,
        Realtime::FeedHold,
        Realtime::CycleStart,
        Realtime::SoftReset,
    ]
    .iter()
    .map(|r| r.byte())
    .collect();
    insta::assert_snapshot!(show(&bytes), @"?!~<0x18>");
}
