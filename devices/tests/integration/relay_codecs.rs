//! Codecs of the switched-output drivers: Numato text commands and replies, dcttech HID feature
//! reports, LEGO Power Functions words and their IR timing. Property tests for round trips and
//! for parsers fed arbitrary bytes; byte-stream snapshots for what goes on the wire.

use proptest::prelude::*;

use stagehand_devices::hid_relay::codec::{self as hid, HidCommand, HidState};
use stagehand_devices::ir_cart::power_functions::{
    self as pf, Output, PfWord, Pwm, check_nibble, decode_ir_timing, ir_timing,
};
use stagehand_devices::relay_serial::codec::{self as numato, Command};

/// Bytes with control characters shown as escapes, one item per line.
fn escaped(bytes: &[u8]) -> String {
    bytes.escape_ascii().to_string()
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

// ---------------------------------------------------------------- Numato

fn any_command() -> impl Strategy<Value = Command> {
    let idx = 0..=numato::MAX_INDEX;
    prop_oneof![
        Just(Command::Ver),
        Just(Command::IdGet),
        Just(Command::RelayReadAll),
        Just(Command::Reset),
        idx.clone().prop_map(Command::RelayOn),
        idx.clone().prop_map(Command::RelayOff),
        idx.clone().prop_map(Command::RelayRead),
        idx.clone().prop_map(Command::GpioSet),
        idx.clone().prop_map(Command::GpioClear),
        idx.prop_map(Command::GpioRead),
        (1u8..=8, any::<u32>()).prop_map(|(digits, m)| {
            let mask = if digits == 8 {
                m
            } else {
                m & ((1 << (4 * digits)) - 1)
            };
            Command::RelayWriteAll { mask, digits }
        }),
    ]
}

/// What a board sends back for `cmd`: the echo, `\n\r`, the reply and `\n\r` (no prompt).
fn board_answer(text: &str, reply: Option<&str>) -> String {
    match reply {
        Some(r) => format!("{text}\r\n\r{r}\n\r"),
        None => format!("{text}\r\n\r"),
    }
}

proptest! {
    #[test]
    fn numato_commands_round_trip(cmd in any_command()) {
        let bytes = cmd.encode().unwrap();
        prop_assert_eq!(bytes.last(), Some(&b'\r'));
        let text = std::str::from_utf8(&bytes[..bytes.len() - 1]).unwrap();
        prop_assert_eq!(Command::parse(text), Some(cmd));
    }

    #[test]
    fn numato_indices_round_trip(i in 0u32..=31) {
        let c = numato::index_char(i).unwrap();
        prop_assert!(c.is_ascii_digit() || c.is_ascii_uppercase());
        prop_assert_eq!(numato::parse_index_char(c), Some(i));
    }

    #[test]
    fn numato_rejects_indices_beyond_v(i in 32u32..) {
        prop_assert_eq!(numato::index_char(i), None);
        prop_assert!(Command::RelayOn(i).encode().is_err());
        prop_assert!(Command::GpioSet(i).text().is_err());
    }

    #[test]
    fn numato_reply_of_an_answer_is_the_reply(
        cmd in any_command(),
        reply in "[0-9A-Za-z]{1,8}",
    ) {
        let text = cmd.text().unwrap();
        let answer = board_answer(&text, cmd.expects_reply().then_some(reply.as_str()));
        let parsed = numato::parse_reply(&answer, &text, cmd.expects_reply()).unwrap();
        prop_assert_eq!(parsed, cmd.expects_reply().then_some(reply));
        // A reply where none is due, or none where one is due, is an error.
        let wrong = board_answer(&text, (!cmd.expects_reply()).then_some("x"));
        prop_assert!(numato::parse_reply(&wrong, &text, cmd.expects_reply()).is_err());
    }

    #[test]
    fn numato_masks_round_trip(states in proptest::collection::vec(any::<bool>(), 1..=32)) {
        let n = states.len() as u32;
        let mask = numato::mask_of(&states);
        let text = format!("{mask:0w$x}", w = usize::from(numato::mask_digits(n)));
        prop_assert_eq!(numato::parse_mask(&text, n).unwrap(), states.clone());
        prop_assert_eq!(numato::parse_mask(&text.to_uppercase(), n).unwrap(), states);
    }

    #[test]
    fn numato_parsers_never_panic(raw in ".{0,64}", cmd in "[a-z ]{0,16}", n in 0u32..64) {
        let _ = numato::parse_reply(&raw, &cmd, true);
        let _ = numato::parse_reply(&raw, &cmd, false);
        let _ = numato::parse_mask(&raw, n);
        let _ = numato::parse_version(&raw);
        let _ = numato::parse_on_off(&raw);
        let _ = numato::parse_level(&raw);
        let _ = Command::parse(&raw);
    }

    #[test]
    fn numato_parsers_never_panic_on_bytes(raw in proptest::collection::vec(any::<u8>(), 0..64)) {
        let text = String::from_utf8_lossy(&raw);
        let _ = numato::parse_reply(&text, "ver", true);
        let _ = numato::parse_mask(&text, 8);
    }
}

#[test]
fn numato_versions_are_eight_characters() {
    assert_eq!(numato::parse_version("00000008").unwrap(), "00000008");
    assert!(numato::parse_version("0008").is_err());
    assert!(numato::parse_version("Grbl 1.1h").is_err());
    assert!(numato::parse_version("0000000 8").is_err());
}

#[test]
fn numato_mask_parsing() {
    assert_eq!(
        numato::parse_mask("05", 4).unwrap(),
        vec![true, false, true, false]
    );
    assert_eq!(numato::parse_mask("ff", 3).unwrap(), vec![true; 3]);
    assert!(numato::parse_mask("xz", 8).is_err());
    assert!(numato::parse_mask("", 8).is_err());
    assert!(numato::parse_mask("123456789", 8).is_err());
    assert_eq!(numato::mask_digits(8), 2);
    assert_eq!(numato::mask_digits(16), 4);
    assert_eq!(numato::mask_digits(32), 8);
}

#[test]
fn numato_command_bytes() {
    let cmds = [
        Command::Ver,
        Command::IdGet,
        Command::RelayOn(0),
        Command::RelayOff(7),
        Command::RelayOn(10),
        Command::RelayOff(31),
        Command::RelayRead(3),
        Command::RelayReadAll,
        Command::RelayWriteAll {
            mask: 0xa5,
            digits: 2,
        },
        Command::RelayWriteAll {
            mask: 0x1,
            digits: 8,
        },
        Command::Reset,
        Command::GpioSet(2),
        Command::GpioClear(2),
        Command::GpioRead(15),
    ];
    let stream: Vec<String> = cmds
        .iter()
        .map(|c| format!("{c:?} => {}", escaped(&c.encode().unwrap())))
        .collect();
    insta::assert_snapshot!("numato_command_bytes", stream.join("\n"));
}

// ---------------------------------------------------------------- dcttech HID

fn any_hid_command() -> impl Strategy<Value = HidCommand> {
    prop_oneof![
        Just(HidCommand::AllOn),
        Just(HidCommand::AllOff),
        (1u8..=255).prop_map(HidCommand::On),
        (1u8..=255).prop_map(HidCommand::Off),
    ]
}

proptest! {
    #[test]
    fn hid_commands_round_trip(cmd in any_hid_command()) {
        let data = cmd.encode();
        prop_assert_eq!(HidCommand::decode(&data), Some(cmd));
        let buf = hid::with_report_id(data);
        prop_assert_eq!(buf[0], 0);
        prop_assert_eq!(&buf[1..], &data[..]);
    }

    #[test]
    fn hid_states_round_trip(serial in "[0-9A-Z]{5}", mask in any::<u8>()) {
        let state = HidState { serial, mask };
        let data = state.encode();
        prop_assert_eq!(HidState::parse(&data).unwrap(), state.clone());
        let channels = state.channels(8);
        for (i, on) in channels.iter().enumerate() {
            prop_assert_eq!(*on, mask & (1 << i) != 0);
        }
    }

    #[test]
    fn hid_parsers_never_panic(data in proptest::collection::vec(any::<u8>(), 0..16), n in 0usize..32) {
        let _ = HidCommand::decode(&data);
        let _ = HidState::parse(&data);
        let _ = hid::data_of(&data, n);
        if let Ok(s) = HidState::parse(&data) {
            prop_assert!(s.serial.len() <= hid::SERIAL_LEN);
            let _ = s.channels(40);
        }
    }
}

#[test]
fn hid_report_bytes() {
    let cmds = [
        HidCommand::On(1),
        HidCommand::Off(1),
        HidCommand::On(8),
        HidCommand::Off(8),
        HidCommand::AllOn,
        HidCommand::AllOff,
    ];
    let mut lines: Vec<String> = cmds
        .iter()
        .map(|c| format!("{c:?} => {}", hex(&hid::with_report_id(c.encode()))))
        .collect();
    let state = HidState {
        serial: "QWERT".into(),
        mask: 0b1000_0101,
    };
    lines.push(format!(
        "state {state:?} => {}",
        hex(&hid::with_report_id(state.encode()))
    ));
    insta::assert_snapshot!("hid_report_bytes", lines.join("\n"));
}

#[test]
fn hid_state_of_a_real_report() {
    // Serial "HURTM", relays 1 and 3 on; bytes 5 and 6 are unspecified.
    let data = [b'H', b'U', b'R', b'T', b'M', 0x00, 0x01, 0b101];
    let s = HidState::parse(&data).unwrap();
    assert_eq!(s.serial, "HURTM");
    assert_eq!(s.channels(4), vec![true, false, true, false]);
    // Short serials are NUL- or space-padded; unprintable bytes do not make a parse fail.
    let data = [b'A', b'B', 0, 0, 0, 0, 0, 0];
    assert_eq!(HidState::parse(&data).unwrap().serial, "AB");
    let data = [b'A', b'B', b' ', b' ', b' ', 0, 0, 0];
    assert_eq!(HidState::parse(&data).unwrap().serial, "AB");
    let data = [0xff, b'B', b'C', b'D', b'E', 0, 0, 1];
    assert_eq!(HidState::parse(&data).unwrap().serial, "?BCDE");
}

// ---------------------------------------------------------------- Power Functions

fn any_word() -> impl Strategy<Value = PfWord> {
    (
        any::<bool>(),
        any::<bool>(),
        1u8..=4,
        any::<bool>(),
        0u8..=7,
        0u8..=15,
    )
        .prop_map(|(t, e, c, a, m, d)| PfWord::new(t, e, c, a, m, d).unwrap())
}

fn any_pwm() -> impl Strategy<Value = Pwm> {
    prop_oneof![
        Just(Pwm::Float),
        Just(Pwm::Brake),
        (1u8..=7).prop_map(Pwm::Forward),
        (1u8..=7).prop_map(Pwm::Backward),
    ]
}

proptest! {
    #[test]
    fn pf_words_round_trip(w in any_word()) {
        let word = w.encode();
        prop_assert_eq!(PfWord::decode(word), Ok(w));
        let [n1, n2, n3] = w.nibbles();
        prop_assert_eq!(word & 0xF, u16::from(0xF ^ n1 ^ n2 ^ n3));
        prop_assert_eq!(pf::parse_hex(&pf::to_hex(word)), Some(word));
    }

    #[test]
    fn pf_decode_accepts_exactly_the_words_with_a_good_check_nibble(word in any::<u16>()) {
        let n = |s: u16| ((word >> s) & 0xF) as u8;
        let good = check_nibble(n(12), n(8), n(4)) == n(0);
        match PfWord::decode(word) {
            Ok(w) => {
                prop_assert!(good);
                prop_assert_eq!(w.encode(), word);
            }
            Err(e) => {
                prop_assert!(!good);
                prop_assert_eq!(e.word, word);
                prop_assert_eq!(e.expected, check_nibble(n(12), n(8), n(4)));
            }
        }
    }

    #[test]
    fn pf_single_output_round_trips(
        channel in 1u8..=4,
        b in any::<bool>(),
        pwm in any_pwm(),
        toggle in any::<bool>(),
    ) {
        let output = if b { Output::B } else { Output::A };
        let w = PfWord::single_output(channel, output, pwm, toggle).unwrap();
        let back = PfWord::decode(w.encode()).unwrap();
        prop_assert_eq!(back.as_single_output(), Some((output, pwm)));
        prop_assert_eq!(back.channel(), channel);
        prop_assert_eq!(back.toggle(), toggle);
        prop_assert_eq!(Pwm::from_nibble(pwm.nibble().unwrap()), pwm);
        // Flipping the toggle changes exactly the top bit of the data and the check nibble.
        let flipped = w.with_toggle(!toggle).encode() ^ w.encode();
        prop_assert_eq!(flipped & 0xFFF0, 0x8000);
    }

    #[test]
    fn pf_ir_timing_round_trips(word in any::<u16>()) {
        let train = ir_timing(word);
        prop_assert_eq!(train.len(), 18);
        prop_assert!(train.iter().all(|&(mark, _)| mark == pf::MARK_US));
        prop_assert_eq!(decode_ir_timing(&train), Some(word));
        let ones = train[1..17].iter().filter(|&&(_, p)| p == pf::HIGH_PAUSE_US).count();
        prop_assert_eq!(ones as u32, word.count_ones());
    }

    #[test]
    fn pf_ir_decoder_never_panics(train in proptest::collection::vec((any::<u32>(), any::<u32>()), 0..24)) {
        let _ = decode_ir_timing(&train);
    }

    #[test]
    fn pf_hex_parser_never_panics(s in ".{0,8}") {
        if let Some(w) = pf::parse_hex(&s) {
            prop_assert_eq!(pf::to_hex(w), s.trim().to_uppercase());
        }
    }
}

#[test]
fn pf_known_words() {
    // Channel 1, output A, forward step 7: nibbles 0x0, 0x4, 0x7; check = F^0^4^7 = C.
    let w = PfWord::single_output(1, Output::A, Pwm::Forward(7), false).unwrap();
    assert_eq!(w.nibbles(), [0x0, 0x4, 0x7]);
    assert_eq!(w.encode(), 0x047C);
    // Channel 1, output B, brake: nibbles 0x0, 0x5, 0x8; check = F^0^5^8 = 2.
    let w = PfWord::single_output(1, Output::B, Pwm::Brake, false).unwrap();
    assert_eq!(w.encode(), 0x0582);
    // Channel 4 (CC = 11), toggle set, output A, float: nibble 1 = 1011 = B; F^B^4^0 = 0.
    let w = PfWord::single_output(4, Output::A, Pwm::Float, true).unwrap();
    assert_eq!(w.encode(), 0xB400);
    // Channel 2, output A, backward step 7 = data 1001; F^1^4^9 = 3.
    let w = PfWord::single_output(2, Output::A, Pwm::Backward(7), false).unwrap();
    assert_eq!(w.encode(), 0x1493);
    // Backward step 1 is data 1111.
    assert_eq!(Pwm::Backward(1).nibble(), Some(0xF));
    // The word IRremote's LEGO demo sends ("channel 1, blue forward, red backward", combo
    // direct mode 001): its check nibble must verify.
    let w = PfWord::decode(0x0197).unwrap();
    assert_eq!((w.channel(), w.mode(), w.data()), (1, 1, 9));
    assert_eq!(w.as_single_output(), None);
    // A wrong check nibble is refused.
    let e = PfWord::decode(0x047B).unwrap_err();
    assert_eq!(e.expected, 0xC);
    assert!(e.to_string().contains("047B"), "{e}");
    // Bad fields are refused rather than wrapped.
    assert_eq!(PfWord::single_output(0, Output::A, Pwm::Float, false), None);
    assert_eq!(PfWord::single_output(5, Output::A, Pwm::Float, false), None);
    assert_eq!(
        PfWord::single_output(1, Output::A, Pwm::Forward(8), false),
        None
    );
    assert_eq!(
        PfWord::single_output(1, Output::A, Pwm::Backward(0), false),
        None
    );
    assert_eq!(Output::parse("b"), Some(Output::B));
    assert_eq!(Output::parse("C"), None);
}

#[test]
fn pf_bridge_lines() {
    // What the cart driver sends for each motor command on each channel and output.
    let mut lines = Vec::new();
    for channel in 1..=4 {
        for output in [Output::A, Output::B] {
            for pwm in [
                Pwm::Forward(7),
                Pwm::Forward(3),
                Pwm::Backward(7),
                Pwm::Backward(3),
                Pwm::Brake,
                Pwm::Float,
            ] {
                let words: Vec<String> = [false, true]
                    .iter()
                    .map(|&t| {
                        let w = PfWord::single_output(channel, output, pwm, t).unwrap();
                        escaped(format!("PF {}\n", pf::to_hex(w.encode())).as_bytes())
                    })
                    .collect();
                lines.push(format!(
                    "ch{channel} {output:?} {pwm:?}: {}",
                    words.join("  toggled: ")
                ));
            }
        }
    }
    insta::assert_snapshot!("pf_bridge_lines", lines.join("\n"));
}

#[test]
fn pf_ir_train() {
    let train = ir_timing(0x047C);
    let text: Vec<String> = train
        .iter()
        .map(|(mark, space)| format!("{mark} {space}"))
        .collect();
    insta::assert_snapshot!("pf_ir_train_047c", text.join("\n"));
    let total: u32 = train.iter().map(|(m, s)| m + s).sum();
    // 18 marks, 2 start/stop pauses, 6 ones and 10 zeros (0x047C has 6 set bits).
    assert_eq!(0x047Cu16.count_ones(), 6);
    assert_eq!(total, 18 * 158 + 2 * 1026 + 6 * 553 + 10 * 263);
}
