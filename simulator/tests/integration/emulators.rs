//! The firmware emulators at the byte level: a raw serial port on each emulator's link, the
//! World checked for what the bytes did, and every fault provoked and observed.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use proptest::prelude::*;
use serial2_tokio::SerialPort;
use stagehand_devices::camera::CameraDriver;
use stagehand_devices::clock::RigClock;
use stagehand_devices::rig::{
    AxisSpec, BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig,
};
use stagehand_simulator::World;
use stagehand_simulator::emulators::grbl::GrblBuild;
use stagehand_simulator::emulators::ir_bridge::decode_pf;
use stagehand_simulator::emulators::{
    EmulatorHandle, Fault, Faults, GrblEmulator, HidRelayBoard, IrBridgeEmulator, NumatoConfig,
    NumatoEmulator, SteppedEmulator,
};
use stagehand_simulator::sim_devices::SimCamera;

fn lightstage() -> RigSpec {
    parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("built-in rig parses")
}

fn world(rig: RigSpec) -> Arc<World> {
    World::new(Arc::new(rig), RigClock::starting_at(0.0), 7).expect("world")
}

/// The light stage's axes on one controller: turntable X, light arc Y, laser tilt Z.
fn grbl_axes(rig: &RigSpec) -> Vec<AxisSpec> {
    rig.axes
        .iter()
        .zip(["X", "Y", "Z"])
        .map(|(a, l)| AxisSpec {
            controller_axis: Some(l.to_string()),
            ..a.clone()
        })
        .collect()
}

/// The World's rig time (the pty tests run on its clock).
fn now(w: &World) -> f64 {
    w.clock().now_s()
}

/// The host end of a wire: a raw serial port and what it has read but not yet consumed.
struct Wire {
    port: SerialPort,
    got: Vec<u8>,
}

impl Wire {
    fn open(path: &Path, baud: u32) -> Wire {
        let port = SerialPort::open(path, baud).expect("open the emulator's link");
        let _ = port.discard_buffers();
        Wire {
            port,
            got: Vec::new(),
        }
    }

    async fn send(&self, bytes: &[u8]) {
        self.port.write_all(bytes).await.expect("write");
    }

    /// Reads until `needle` arrives and returns everything up to and including it.
    async fn expect(&mut self, needle: &str, timeout_s: f64) -> String {
        let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(timeout_s);
        loop {
            if let Some(i) = find(&self.got, needle.as_bytes()) {
                let chunk: Vec<u8> = self.got.drain(..i + needle.len()).collect();
                return String::from_utf8_lossy(&chunk).into_owned();
            }
            let mut buf = [0u8; 256];
            match tokio::time::timeout_at(deadline, self.port.read(&mut buf)).await {
                Ok(Ok(n)) if n > 0 => self.got.extend_from_slice(&buf[..n]),
                Ok(r) => panic!(
                    "port failed waiting for {needle:?}: {r:?}; got {:?}",
                    self.text()
                ),
                Err(_) => panic!("no {needle:?} within {timeout_s} s; got {:?}", self.text()),
            }
        }
    }

    /// Everything that arrives within `seconds` (consumed).
    async fn drain(&mut self, seconds: f64) -> String {
        let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(seconds);
        let mut buf = [0u8; 256];
        while let Ok(Ok(n)) = tokio::time::timeout_at(deadline, self.port.read(&mut buf)).await {
            if n == 0 {
                break;
            }
            self.got.extend_from_slice(&buf[..n]);
        }
        let s = self.text();
        self.got.clear();
        s
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(&self.got).into_owned()
    }

    /// Sends a GRBL line and returns the reply lines up to and including `ok`/`error:N`.
    async fn grbl(&mut self, line: &str) -> String {
        self.send(format!("{line}\n").as_bytes()).await;
        let deadline = tokio::time::Instant::now() + Duration::from_secs(2);
        loop {
            let text = self.text();
            if let Some(end) = grbl_reply_end(&text) {
                self.got.drain(..end + 2);
                return text[..end].to_string();
            }
            let mut buf = [0u8; 256];
            match tokio::time::timeout_at(deadline, self.port.read(&mut buf)).await {
                Ok(Ok(n)) if n > 0 => self.got.extend_from_slice(&buf[..n]),
                other => panic!("no reply to {line:?}: {other:?}; got {text:?}"),
            }
        }
    }

    async fn status(&mut self) -> String {
        self.send(b"?").await;
        let s = self.expect(">\r\n", 1.0).await;
        let start = s.rfind('<').expect("status report");
        s[start..s.len() - 2].to_string()
    }

    /// Sends a relay-board command and returns the reply text between echo and prompt.
    async fn numato(&mut self, cmd: &str) -> String {
        self.send(format!("{cmd}\r").as_bytes()).await;
        let raw = self.expect(">", 1.0).await;
        numato_reply(cmd, &raw)
    }
}

/// The reply text of relay-board command `cmd` between its echo and the prompt.
fn numato_reply(cmd: &str, raw: &str) -> String {
    let expected_echo = format!("{cmd}\r\n\r");
    let rest = raw
        .strip_prefix(&expected_echo)
        .unwrap_or_else(|| panic!("echo of {cmd:?} missing in {raw:?}"));
    rest.trim_end_matches('>')
        .trim_end_matches("\n\r")
        .to_string()
}

/// Where the first complete GRBL reply in `text` ends: the index of the `\r\n` after its
/// `ok` or `error:N` line.
fn grbl_reply_end(text: &str) -> Option<usize> {
    text.match_indices("\r\n").map(|(i, _)| i).find(|&i| {
        let start = text[..i].rfind('\n').map_or(0, |j| j + 1);
        let l = &text[start..i];
        l == "ok" || l.starts_with("error:")
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// The host end of a stepped emulator (no pty): bytes in, replies read at exact rig times.
/// Waiting for a reply moves the emulator's clock to the instant it is due, so every
/// assertion about the World is at a simulated time the test chose, never after a
/// wall-clock wait.
struct Host {
    em: SteppedEmulator,
    got: String,
}

impl Host {
    fn new(em: SteppedEmulator) -> Host {
        Host {
            em,
            got: String::new(),
        }
    }

    fn now(&self) -> f64 {
        self.em.now()
    }

    fn send(&mut self, bytes: &[u8]) {
        self.em.send(bytes);
    }

    /// Lets `seconds` of rig time pass.
    fn advance(&mut self, seconds: f64) {
        self.em.advance(seconds);
    }

    /// Moves the clock to the next output or firmware event, failing past `deadline`.
    fn step_until(&mut self, deadline: f64, waiting_for: &str) {
        let now = self.em.now();
        let next = [self.em.next_output(), self.em.next_event()]
            .into_iter()
            .flatten()
            .filter(|&t| t > now)
            .fold(f64::INFINITY, f64::min);
        assert!(
            next <= deadline,
            "no {waiting_for:?} by rig time {deadline}; got {:?}",
            self.got
        );
        self.em.advance_to(next);
    }

    /// Reads until `needle` arrives (within `timeout_s` of rig time) and returns everything
    /// up to and including it.
    fn expect(&mut self, needle: &str, timeout_s: f64) -> String {
        let deadline = self.now() + timeout_s;
        loop {
            self.got.push_str(&self.em.read());
            if let Some(i) = self.got.find(needle) {
                return self.got.drain(..i + needle.len()).collect();
            }
            self.step_until(deadline, needle);
        }
    }

    /// Everything said within the next `seconds` of rig time (consumed).
    fn drain(&mut self, seconds: f64) -> String {
        self.advance(seconds);
        self.got.push_str(&self.em.read());
        std::mem::take(&mut self.got)
    }

    /// Sends a GRBL line and returns the reply lines up to and including `ok`/`error:N`.
    fn grbl(&mut self, line: &str) -> String {
        self.send(format!("{line}\n").as_bytes());
        let deadline = self.now() + 30.0;
        loop {
            self.got.push_str(&self.em.read());
            let text = self.got.clone();
            if let Some(end) = grbl_reply_end(&text) {
                self.got.drain(..end + 2);
                return text[..end].to_string();
            }
            self.step_until(deadline, line);
        }
    }

    fn status(&mut self) -> String {
        self.send(b"?");
        let s = self.expect(">\r\n", 1.0);
        let start = s.rfind('<').expect("status report");
        s[start..s.len() - 2].to_string()
    }

    /// Sends a relay-board command and returns the reply text between echo and prompt.
    fn numato(&mut self, cmd: &str) -> String {
        self.send(format!("{cmd}\r").as_bytes());
        let raw = self.expect(">", 1.0);
        numato_reply(cmd, &raw)
    }
}

fn spawn_grbl(w: &Arc<World>, dir: &Path, faults: Arc<Faults>) -> EmulatorHandle {
    let axes = grbl_axes(w.rig());
    GrblEmulator::spawn(Arc::clone(w), &axes, dir, "grbl0", faults).expect("spawn grbl")
}

fn stepped_grbl(w: &Arc<World>, faults: Arc<Faults>) -> Host {
    let axes = grbl_axes(w.rig());
    Host::new(
        GrblEmulator::stepped(Arc::clone(w), &axes, faults, GrblBuild::default())
            .expect("grbl board"),
    )
}

/// Resets the controller for a fresh banner, and unlocks it.
fn grbl_ready(mut host: Host) -> Host {
    // The power-on banner went out before the host opened the port.
    host.drain(0.0);
    host.send(&[0x18]);
    host.expect("[MSG:'$H'|'$X' to unlock]\r\n", 1.0);
    assert_eq!(host.grbl("$X"), "[MSG:Caution: Unlocked]\r\nok");
    host
}

/// Like [`grbl_ready`], with the pull-off `$27` set to 0 so machine coordinates equal the
/// World's degrees after homing (home 0° at machine 0).
fn grbl_ready_at_origin(host: Host) -> Host {
    let mut host = grbl_ready(host);
    assert_eq!(host.grbl("$27=0"), "ok");
    host
}

/// `deg` quantised to the light stage's default microsteps.
fn q(deg: f64) -> f64 {
    let steps = 3200.0 / 360.0 * 16.0;
    (deg * steps).round() / steps
}

fn axis(w: &World, id: &str, t: f64) -> f64 {
    w.snapshot_at(t).axes[id]
}

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

fn numato_config(watchdog_s: f64) -> NumatoConfig {
    NumatoConfig {
        watchdog_s,
        trigger_line: Some(2),
        ..NumatoConfig::from_rig(&lightstage(), "lamps").expect("lamps bank")
    }
}

fn lamp(w: &World, id: &str, t: f64) -> f64 {
    // Lamps warm up for 0.8 s: look a second ahead of `t` to see whether one is on.
    w.snapshot_at(t + 1.0).lamps[id]
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
