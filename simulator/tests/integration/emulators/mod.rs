//! The firmware emulators at the byte level: a raw serial port on each emulator's link, the
//! World checked for what the bytes did, and every fault provoked and observed.

mod grbl;
mod ir_hid;
mod numato;

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

fn lamp(w: &World, id: &str, t: f64) -> f64 {
    // Lamps warm up for 0.8 s: look a second ahead of `t` to see whether one is on.
    w.snapshot_at(t + 1.0).lamps[id]
}
