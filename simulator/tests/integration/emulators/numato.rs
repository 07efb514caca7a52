//! The Numato relay board emulator: relays and the watchdog, disconnects and resets,
//! garbage and slow replies, the trigger line firing the cameras.

use super::*;

fn numato_config(watchdog_s: f64) -> NumatoConfig {
    NumatoConfig {
        watchdog_s,
        trigger_line: Some(2),
        ..NumatoConfig::from_rig(&lightstage(), "lamps").expect("lamps bank")
    }
}

#[test]
fn numato_relays_switch_lamps_and_watchdog_lapses() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let mut wire = Host::new(NumatoEmulator::stepped(
        Arc::clone(&w),
        numato_config(0.6),
        Faults::none(),
    ));
    wire.send(b"ver\r");
    assert_eq!(wire.expect(">", 1.0), "ver\r\n\r00000008\n\r>");
    assert_eq!(wire.numato("relay on 0"), "");
    assert_eq!(wire.numato("relay on 7"), "");
    assert_eq!(lamp(&w, "lamp1", wire.now()), 1.0);
    assert_eq!(lamp(&w, "lamp8", wire.now()), 1.0);
    assert_eq!(lamp(&w, "lamp2", wire.now()), 0.0);
    assert_eq!(wire.numato("relay read 0"), "on");
    assert_eq!(wire.numato("relay read 1"), "off");
    assert_eq!(wire.numato("relay readall"), "81");
    assert_eq!(wire.numato("relay off 7"), "");
    assert_eq!(lamp(&w, "lamp8", wire.now()), 0.0);
    assert_eq!(wire.numato("relay writeall 06"), "");
    assert_eq!(wire.numato("relay readall"), "06");
    assert_eq!(
        (
            lamp(&w, "lamp1", wire.now()),
            lamp(&w, "lamp2", wire.now()),
            lamp(&w, "lamp3", wire.now())
        ),
        (0.0, 1.0, 1.0)
    );
    assert_eq!(
        wire.numato("bogus"),
        "",
        "unknown command: echo, \\n\\r, prompt"
    );
    assert_eq!(
        wire.numato("relay on 9"),
        "",
        "no relay 9 on an 8-relay board"
    );
    assert_eq!(wire.numato("gpio set 3"), "");
    assert_eq!(wire.numato("gpio read 3"), "1");
    assert_eq!(wire.numato("id get").len(), 8);
    // The lease lapses 0.6 s after the last command.
    wire.advance(0.9);
    assert_eq!(lamp(&w, "lamp2", wire.now()), 0.0);
    assert_eq!(wire.numato("relay readall"), "00");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn numato_disconnect_repoints_the_link_and_board_reset_clears_relays() {
    let _turn = crate::grbl_peer::alongside();
    let dir = tempfile::tempdir().unwrap();
    let w = world(lightstage());
    let faults = Faults::new([
        Fault::Disconnect {
            after_commands: 2,
            for_s: 0.4,
        },
        Fault::BoardReset { after_commands: 4 },
    ]);
    let h = NumatoEmulator::spawn(
        Arc::clone(&w),
        numato_config(0.0),
        dir.path(),
        "relay0",
        Arc::clone(&faults),
    )
    .expect("spawn numato");
    let first_pts = std::fs::read_link(h.path()).unwrap();
    let mut wire = Wire::open(h.path(), 19_200);
    assert_eq!(wire.numato("relay on 1").await, "");
    assert_eq!(wire.numato("ver").await, "00000008");
    // The pty is gone: the host's read ends, and the link is missing until re-enumeration.
    let mut buf = [0u8; 16];
    let r = tokio::time::timeout(Duration::from_secs(1), wire.port.read(&mut buf)).await;
    assert!(
        matches!(r, Ok(Ok(0)) | Ok(Err(_))),
        "read on a vanished pty: {r:?}"
    );
    assert!(
        std::fs::symlink_metadata(h.path()).is_err(),
        "link removed while unplugged"
    );
    // Re-plugged 0.4 s later: wait for the re-plug itself (bounded), not for a fixed time.
    let replugged = tokio::time::timeout(Duration::from_secs(10), async {
        while h.stats().disconnects() < 1 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    assert!(replugged.is_ok(), "the board came back");
    assert_eq!(h.stats().disconnects(), 1);
    let second_pts = std::fs::read_link(h.path()).expect("link back");
    assert_ne!(first_pts, second_pts);
    let mut wire = Wire::open(h.path(), 19_200);
    assert_eq!(
        wire.numato("relay readall").await,
        "02",
        "the board kept its relays"
    );
    assert_eq!(lamp(&w, "lamp2", now(&w)), 1.0);
    assert_eq!(wire.numato("relay on 2").await, ""); // command 4, then a silent power cycle
    assert_eq!(wire.drain(0.1).await, "");
    assert_eq!(lamp(&w, "lamp2", now(&w)), 0.0);
    assert_eq!(lamp(&w, "lamp3", now(&w)), 0.0);
    assert_eq!(wire.numato("relay readall").await, "00");
    assert!(faults.all_fired());
}

#[test]
fn numato_garbage_and_slow_reply() {
    let _turn = crate::grbl_peer::alongside();
    let w = world(lightstage());
    let faults = Faults::new([
        Fault::Garbage {
            after_commands: 1,
            bytes: b"\xff\x00#!noise".to_vec(),
        },
        Fault::SlowReply {
            nth_command: 2,
            delay_s: 0.4,
        },
    ]);
    let mut wire = Host::new(NumatoEmulator::stepped(
        Arc::clone(&w),
        numato_config(0.0),
        Arc::clone(&faults),
    ));
    assert_eq!(wire.numato("ver"), "00000008");
    let noise = wire.drain(0.2);
    assert_eq!(noise.as_bytes(), "\u{fffd}\0#!noise".as_bytes());
    wire.send(b"ver\r");
    let t0 = wire.now();
    wire.expect("ver\r", 0.3); // the echo comes at once
    wire.expect(">", 1.0);
    let late = wire.now() - t0;
    assert!(late > 0.35, "reply after {late} s");
    assert_eq!(faults.fired().len(), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn numato_trigger_line_fires_cameras_with_announced_ids_and_stalls() {
    let _turn = crate::grbl_peer::alongside();
    let dir = tempfile::tempdir().unwrap();
    let w = world(lightstage());
    let faults = Faults::new([Fault::StallCamera {
        camera: "cam1".into(),
        frames: 1,
    }]);
    let h = NumatoEmulator::spawn(
        Arc::clone(&w),
        numato_config(0.0),
        dir.path(),
        "relay0",
        Arc::clone(&faults),
    )
    .expect("spawn numato");
    assert!(
        faults.all_fired(),
        "StallCamera applies to the World at spawn"
    );
    let spec = w.rig().cameras[0].clone();
    let mut cam = SimCamera::new(spec, Arc::clone(&w));
    cam.configure(0.001, 1.0).await.unwrap();
    cam.arm().await.unwrap();
    let mut wire = Wire::open(h.path(), 19_200);
    // The line carries no id: the camera tags the frame with the id the host announced.
    cam.expect(42, 0.001).await.unwrap();
    let mut edges = Vec::new();
    for _ in 0..2 {
        edges.push(now(&w));
        assert_eq!(wire.numato("gpio set 2").await, "");
        assert_eq!(wire.numato("gpio set 2").await, "", "no edge while high");
        assert_eq!(wire.numato("gpio clear 2").await, "");
    }
    let frame = tokio::time::timeout(Duration::from_secs(3), cam.next_frame())
        .await
        .expect("a frame")
        .expect("frame ok");
    assert!(
        frame.rig_time_s > edges[1],
        "the frame is the second edge's"
    );
    assert_eq!(
        frame.trigger_id, 42,
        "the first pulse's frame was dropped by the stall"
    );
    let more = tokio::time::timeout(Duration::from_millis(300), cam.next_frame()).await;
    assert!(more.is_err(), "two edges, one stalled: exactly one frame");
}
