//! The GRBL emulator at the byte level: banner, settings, moves, hold/resume, buffer
//! overflow while homing, laser output, alarms and line noise.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
/// The GRBL emulator's smoke test over a real pty (the others run it on the test's clock).
async fn grbl_banner_alarm_lock_and_settings() {
    let _turn = crate::grbl_peer::alongside();
    let dir = tempfile::tempdir().unwrap();
    let w = world(lightstage());
    let h = spawn_grbl(&w, dir.path(), Faults::none());
    let mut wire = Wire::open(h.path(), 115_200);
    wire.send(&[0x18]).await;
    let banner = wire.expect("unlock]\r\n", 1.0).await;
    assert_eq!(
        banner,
        "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n"
    );
    // The first report after a reset carries the work offset, the next the overrides.
    assert_eq!(
        wire.status().await,
        "<Alarm|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"
    );
    assert_eq!(wire.grbl("G90 G0 X12.5").await, "error:9");
    assert_eq!(wire.grbl("M3 S1000").await, "error:9");
    let settings = wire.grbl("$$").await;
    for line in [
        "$22=1",
        "$32=0",
        "$100=142.222",
        "$101=142.222",
        "$110=1800.000",
        "$111=1200.000",
        "$112=600.000",
        "$120=60.000",
        "$122=200.000",
    ] {
        assert!(
            settings.lines().any(|l| l == line),
            "{line} missing from {settings}"
        );
    }
    assert!(settings.ends_with("\r\nok"));
    assert_eq!(wire.grbl("$X").await, "[MSG:Caution: Unlocked]\r\nok");
    assert_eq!(
        wire.status().await,
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"
    );
    assert_eq!(wire.grbl("G0 Q1").await, "error:20");
    assert_eq!(wire.grbl("G0 X").await, "error:2");
    assert_eq!(wire.grbl("G0 \u{7}X1").await, "error:1");
    // Real GRBL reads an unknown `$` letter as a bad setting number.
    assert_eq!(wire.grbl("$Q").await, "error:2");
    assert_eq!(h.stats().overflows(), 0);
}

#[test]
fn grbl_moves_drive_the_world_in_order() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let h = stepped_grbl(&w, Faults::none());
    let mut wire = grbl_ready_at_origin(h);
    assert_eq!(wire.grbl("$H"), "ok");
    // 12.5° on the turntable (30°/s, 60°/s²) is a 0.913 s triangle; the 5° back leg follows.
    let t0 = wire.now();
    assert_eq!(wire.grbl("G90 G0 X12.5"), "ok");
    assert_eq!(wire.grbl("G0 X5"), "ok");
    assert!(wire.now() - t0 < 0.1, "ok comes when the move is queued");
    assert!(wire.status().starts_with("<Run|"));
    wire.advance(0.45);
    let mid = axis(&w, "turntable", wire.now());
    assert!(mid > 1.0 && mid < 12.0, "turntable mid-move at {mid}");
    let mut status = wire.status();
    let deadline = t0 + 3.0;
    while !status.starts_with("<Idle") && wire.now() < deadline {
        wire.advance(0.05);
        status = wire.status();
    }
    // Positions are whole microsteps: 5° is 711 steps of 1/142.222°, reported as 4.999.
    assert!(
        status.starts_with(&format!("<Idle|MPos:{:.3},0.000,0.000|FS:0,0", q(5.0))),
        "{status}"
    );
    assert_eq!(format!("{:.3}", q(5.0)), "4.999");
    let elapsed = wire.now() - t0;
    assert!(
        elapsed > 0.913 + 0.707 - 0.05,
        "the moves ran one after another ({elapsed} s)"
    );
    // The last leg went negative: the load lags by the backlash, as with SimAxis.
    // (The board's `$100` is 142.222, the rig's steps 142.2222…: a few 1e-6° apart.)
    assert!((axis(&w, "turntable", wire.now()) - (q(5.0) + 0.05)).abs() < 1e-4);
    // Targets are quantised to microsteps.
    assert_eq!(wire.grbl("G0 Z1.00001"), "ok");
    wire.advance(0.3);
    // The World lands on the rig's microstep grid (as SimAxis does).
    let steps = w.rig().axes[2].steps_per_deg;
    let z = axis(&w, "laser_tilt", wire.now());
    assert!(
        (z * steps - (z * steps).round()).abs() < 1e-6 && (z - 1.0).abs() < 0.01,
        "{z}"
    );
    // The laser follows the spindle.
    assert_eq!(wire.grbl("M3 S1000"), "ok");
    assert_eq!(
        w.snapshot_at(wire.now()).laser.map(|l| l.colour_nm),
        Some(650)
    );
    assert_eq!(wire.grbl("M5"), "ok");
    assert!(w.snapshot_at(wire.now()).laser.is_none());
}

#[test]
fn grbl_hold_resume_and_reset() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let h = stepped_grbl(&w, Faults::none());
    let mut wire = grbl_ready_at_origin(h);
    assert_eq!(wire.grbl("$H"), "ok");
    assert_eq!(wire.grbl("G0 X30"), "ok");
    wire.advance(0.4);
    wire.send(b"!");
    let held = wire.status();
    assert!(held.starts_with("<Hold:0|"), "{held}");
    let p = axis(&w, "turntable", wire.now());
    wire.advance(0.2);
    assert_eq!(
        axis(&w, "turntable", wire.now()),
        p,
        "held axes stand still"
    );
    assert!(p > 0.5 && p < 30.0);
    // A reset while held keeps the position and leaves the controller usable.
    wire.send(&[0x18]);
    let after = wire.expect("]\r\n", 1.0);
    assert!(!after.contains("ALARM"), "{after}");
    assert!(wire.status().starts_with("<Idle|"));
    assert_eq!(axis(&w, "turntable", wire.now()), p);
    // Resume finishes a held move.
    assert_eq!(wire.grbl("G0 X10"), "ok");
    wire.advance(0.1);
    wire.send(b"!");
    assert!(wire.status().starts_with("<Hold:0|"));
    wire.send(b"~");
    wire.advance(1.5);
    let status = wire.status();
    assert!(
        status.starts_with(&format!("<Idle|MPos:{:.3},0.000,0.000|FS:0,0", q(10.0))),
        "{status}"
    );
    // A reset during a move loses the position: ALARM:3, banner, homing lock.
    assert_eq!(wire.grbl("G0 X40"), "ok");
    wire.advance(0.3);
    wire.send(&[0x18]);
    let text = wire.expect("unlock]\r\n", 1.0);
    assert!(text.starts_with("ALARM:3\r\n\r\nGrbl 1.1h"), "{text}");
    assert!(wire.status().starts_with("<Alarm|"));
    let stopped = axis(&w, "turntable", wire.now());
    wire.advance(0.2);
    assert_eq!(axis(&w, "turntable", wire.now()), stopped);
    assert!(stopped > 10.0 && stopped < 40.0);
    assert_eq!(wire.grbl("G0 X0"), "error:9");
}

#[test]
fn grbl_counts_receive_buffer_overflow_while_homing() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let h = stepped_grbl(&w, Faults::none());
    let mut wire = grbl_ready_at_origin(h);
    assert_eq!(wire.grbl("G0 X-20"), "ok");
    wire.advance(1.3);
    // Homing from −20° at 40°/s blocks the parser for 0.5 s (plus the locate phase); 30 lines
    // of 6 bytes overflow the 127-byte buffer by 53 bytes. A `?` meanwhile is answered only
    // when the cycle ends, as real GRBL does.
    wire.send(b"$H\n?");
    assert_eq!(wire.drain(0.2), "", "silent while homing");
    wire.send("G0 X0\n".repeat(30).as_bytes());
    wire.advance(0.8);
    assert_eq!(wire.em.stats().overflows(), 53);
    let replies = wire.drain(0.2);
    assert!(replies.starts_with("<Home|MPos:0.000,"), "{replies}");
    assert_eq!(replies.matches("ok\r\n").count(), 1 + 21, "{replies}");
}

#[test]
fn grbl_has_no_watchdog_and_laser_mode_keeps_the_output_off_when_idle() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let h = stepped_grbl(&w, Faults::none());
    let mut wire = grbl_ready(h);
    // `$32=0`: the output follows M3 at once, reported as `A:S` and the spindle speed, and
    // stays on however long the host is silent (real GRBL has no watchdog).
    assert_eq!(wire.grbl("M3 S1000"), "ok");
    // This report is due to carry `WCO:`, which defers `Ov:` (and `A:`) to the next one.
    let status = wire.status();
    assert!(status.contains("|FS:0,1000|WCO:"), "{status}");
    let status = wire.status();
    assert!(
        status.contains("|FS:0,1000|") && status.ends_with("|A:S>"),
        "{status}"
    );
    wire.advance(3.5);
    assert!(w.snapshot_at(wire.now()).laser.is_some(), "no watchdog");
    assert_eq!(wire.grbl("M5"), "ok");
    let status = wire.status();
    assert!(
        status.contains("|FS:0,0|") && status.ends_with("|Ov:100,100,100>"),
        "{status}"
    );
    assert!(w.snapshot_at(wire.now()).laser.is_none());
    // Laser mode: M3 in idle leaves the output off (only G1 motion would light it).
    assert_eq!(wire.grbl("$32=1"), "ok");
    assert_eq!(wire.grbl("M3 S1000"), "ok");
    let status = wire.status();
    assert!(
        status.contains("|FS:0,0|") && !status.contains("A:S"),
        "{status}"
    );
    assert!(w.snapshot_at(wire.now()).laser.is_none());
}

#[test]
fn grbl_alarm_during_move_and_dropped_reply() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let faults = Faults::new([
        Fault::AlarmDuringMove {
            nth_move: 2,
            code: 1,
        },
        Fault::DropReply { nth_command: 3 },
    ]);
    let h = stepped_grbl(&w, Arc::clone(&faults));
    let mut wire = grbl_ready(h); // command 1: $X
    assert_eq!(wire.grbl("$H"), "ok"); // command 2
    wire.send(b"G0 X5\n"); // command 3: carried out, no reply
    assert_eq!(wire.drain(0.4), "");
    assert_eq!(faults.fired().len(), 1);
    assert_eq!(wire.grbl("G0 X25"), "ok"); // move 2
    let text = wire.expect("[MSG:Reset to continue]\r\n", 2.0);
    assert_eq!(text, "ALARM:1\r\n[MSG:Reset to continue]\r\n");
    assert!(faults.all_fired());
    let stopped = axis(&w, "turntable", wire.now());
    assert!(
        stopped > 5.5 && stopped < 24.5,
        "stopped halfway, at {stopped}"
    );
    // Locked out until a reset: not even `?` is answered (a critical alarm in GRBL).
    wire.send(b"?");
    assert_eq!(wire.drain(0.3), "");
    wire.send(b"$X\n");
    assert_eq!(wire.drain(0.3), "");
    wire.send(&[0x18]);
    wire.expect("unlock]\r\n", 1.0);
    assert_eq!(wire.grbl("$X"), "[MSG:Caution: Unlocked]\r\nok");
}

#[test]
fn grbl_survives_line_noise() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let h = stepped_grbl(&w, Faults::none());
    let mut wire = grbl_ready(h);
    let mut x: u32 = 0x1234_5678;
    let noise: Vec<u8> = (0..600)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x % 256) as u8
        })
        .filter(|b| !matches!(b, b'?' | b'!' | b'~' | 0x18))
        .collect();
    for chunk in noise.chunks(40) {
        wire.send(chunk);
        wire.send(b"\n");
    }
    wire.drain(0.3);
    assert_eq!(wire.grbl("$X").lines().last(), Some("ok"));
    assert!(wire.status().starts_with('<'));
}
