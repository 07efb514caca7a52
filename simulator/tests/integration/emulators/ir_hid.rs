//! The IR bridge (the reflectometer cart) and the HID relay board emulators.

use super::*;

fn pf(word: u16) -> String {
    format!("PF {word:04X}\n")
}

/// A single-output PWM word for channel 1, output A, step -7..=7.
fn pwm_word(step: i8) -> u16 {
    let (n1, n2) = (0u16, 0b0100u16);
    let n3 = (step as i16).rem_euclid(16) as u16;
    let l = 0xF ^ n1 ^ n2 ^ n3;
    n1 << 12 | n2 << 8 | n3 << 4 | l
}

#[test]
fn ir_bridge_drives_the_cart_to_its_end_stops() {
    let _turn = crate::grbl_peer::alongside();
    let mut rig = parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").unwrap();
    let cart = rig.cart.as_mut().expect("cart");
    cart.travel_mm = 6.0; // 0.5 s at 12 mm/s
    let cart = cart.clone();
    let w = world(rig);
    let mut wire = Host::new(IrBridgeEmulator::stepped(
        Arc::clone(&w),
        &cart,
        Faults::none(),
    ));
    wire.send(b"ver\n");
    assert_eq!(wire.expect("\n", 1.0), "IRBRIDGE 1.0\n");
    assert_eq!(pwm_word(7), 0x047C);
    // Backward at the − end: the switch is already closed.
    wire.send(pf(pwm_word(-7)).as_bytes());
    assert_eq!(wire.expect("END -\n", 1.0), "OK 0492\nEND -\n");
    wire.send(pf(pwm_word(7)).as_bytes());
    assert_eq!(wire.expect("\n", 1.0), "OK 047C\n");
    wire.advance(0.25);
    let mid = w.snapshot_at(wire.now()).cart_mm;
    assert!(mid > 1.0 && mid < 5.0, "cart at {mid}");
    assert_eq!(wire.expect("END +\n", 1.0), "END +\n");
    wire.advance(0.1);
    assert_eq!(w.snapshot_at(wire.now()).cart_mm, 6.0);
    // Another output or channel does not move the cart; a bad check nibble or syntax is refused.
    wire.send(b"PF 047D\n");
    assert_eq!(wire.expect("\n", 1.0), "ERR checksum 047D\n");
    wire.send(b"PF 04\n");
    assert_eq!(wire.expect("\n", 1.0), "ERR syntax\n");
    wire.send(b"hello\n");
    assert_eq!(wire.expect("\n", 1.0), "ERR syntax\n");
    // Channel 2 (CC = 01), output A, backward step 7: check nibble 0xF ^ 1 ^ 4 ^ 9 = 3.
    wire.send(pf(0x1493).as_bytes());
    assert!(wire.expect("\n", 1.0).starts_with("OK "));
    wire.advance(0.15);
    assert_eq!(w.snapshot_at(wire.now()).cart_mm, 6.0);
    // Float stops the cart where it is.
    wire.send(pf(pwm_word(-7)).as_bytes());
    wire.expect("\n", 1.0);
    wire.advance(0.15);
    wire.send(pf(pwm_word(0)).as_bytes());
    wire.expect("\n", 1.0);
    let stopped = w.snapshot_at(wire.now()).cart_mm;
    wire.advance(0.15);
    assert_eq!(w.snapshot_at(wire.now()).cart_mm, stopped);
    assert!(stopped > 3.0 && stopped < 5.5, "{stopped}");
    assert_eq!(wire.drain(0.7), "", "no end stop after a float");
}

/// The IR bridge's smoke test over a real pty (the cart's physics run on the test's clock in
/// `ir_bridge_drives_the_cart_to_its_end_stops`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ir_bridge_answers_over_its_pty() {
    let _turn = crate::grbl_peer::alongside();
    let dir = tempfile::tempdir().unwrap();
    let rig = parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").unwrap();
    let cart = rig.cart.clone().expect("cart");
    let w = world(rig);
    let h = IrBridgeEmulator::spawn(Arc::clone(&w), &cart, dir.path(), "ir0", Faults::none())
        .expect("spawn");
    let mut wire = Wire::open(h.path(), 9_600);
    wire.send(b"ver\n").await;
    assert_eq!(wire.expect("\n", 1.0).await, "IRBRIDGE 1.0\n");
    // Backward at the − end: the switch is already closed.
    wire.send(pf(pwm_word(-7)).as_bytes()).await;
    assert_eq!(wire.expect("END -\n", 1.0).await, "OK 0492\nEND -\n");
    wire.send(b"PF 04\n").await;
    assert_eq!(wire.expect("\n", 1.0).await, "ERR syntax\n");
}

#[test]
fn hid_board_speaks_dcttech_feature_reports() {
    let _turn = crate::grbl_peer::alongside();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let _guard = rt.enter();
    let w = world(lightstage());
    let faults = Faults::new([Fault::BoardReset { after_commands: 3 }]);
    let mut board = HidRelayBoard::new(Arc::clone(&w), "lamps", 8, "AB12C", Arc::clone(&faults));
    assert_eq!(board.product(), "USBRelay8");
    board
        .send_feature_report(&[0, 0xFF, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    board
        .send_feature_report(&[0, 0xFF, 3, 0, 0, 0, 0, 0, 0])
        .unwrap();
    assert_eq!(
        (
            lamp(&w, "lamp1", now(&w)),
            lamp(&w, "lamp2", now(&w)),
            lamp(&w, "lamp3", now(&w))
        ),
        (1.0, 0.0, 1.0)
    );
    let mut buf = [0u8; 9];
    assert_eq!(board.get_feature_report(&mut buf).unwrap(), 9);
    assert_eq!(&buf[1..6], b"AB12C");
    assert_eq!(buf[8], 0b101);
    board
        .send_feature_report(&[0, 0xFD, 1, 0, 0, 0, 0, 0, 0])
        .unwrap(); // then a power glitch
    assert!(faults.all_fired());
    board.get_feature_report(&mut buf).unwrap();
    assert_eq!(buf[8], 0);
    assert_eq!(lamp(&w, "lamp3", now(&w)), 0.0);
    board
        .send_feature_report(&[0, 0xFE, 0, 0, 0, 0, 0, 0, 0])
        .unwrap();
    board.get_feature_report(&mut buf).unwrap();
    assert_eq!(buf[8], 0xFF);
    board
        .send_feature_report(&[0, 0xFC, 0, 0, 0, 0, 0, 0, 0])
        .unwrap();
    board.get_feature_report(&mut buf).unwrap();
    assert_eq!(buf[8], 0);
    assert!(board.send_feature_report(&[1, 0xFF]).is_err());
    assert!(board.get_feature_report(&mut [0u8; 4]).is_err());
}

proptest! {
    #[test]
    fn pf_decoder_never_panics_and_checks_every_word(word in any::<u16>()) {
        let _turn = crate::grbl_peer::alongside();
        let n = [word >> 12 & 0xF, word >> 8 & 0xF, word >> 4 & 0xF, word & 0xF];
        let valid = n[3] == 0xF ^ n[0] ^ n[1] ^ n[2];
        prop_assert_eq!(decode_pf(word).is_some(), valid);
    }

    #[test]
    fn pf_single_output_pwm_round_trips(step in -7i8..=7) {
        let _turn = crate::grbl_peer::alongside();
        use stagehand_simulator::emulators::ir_bridge::PfCommand;
        prop_assert_eq!(decode_pf(pwm_word(step)), Some(PfCommand::Pwm { channel: 0, output: 0, step }));
    }
}
