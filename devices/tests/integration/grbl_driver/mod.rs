//! Drives `GrblController` (and its axis and laser drivers) against a small scripted fake
//! GRBL 1.1 controller, and snapshots the exact bytes the driver sends.
//!
//! The fake is a tokio task on the other end of a `tokio::io::duplex` stream, and the tests run
//! on tokio's paused clock: the fake's motion, the driver's polls, timeouts and keepalive all
//! happen at exact virtual instants, so no test races the wall clock and timings are asserted
//! exactly. One smoke test runs the same fake over a real pty (`streams.rs`).

mod faults;
mod motion;
mod streams;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use stagehand_devices::grbl::GrblController;
use stagehand_devices::rig::{AxisRole, AxisSpec, Backend, GRBL_BAUD};
use tokio::task::JoinHandle;
use tokio::time::Instant;

use crate::fake_port::{DeviceEnd, Port, duplex_port, pty_port};

/// What a duplex fake's port is called in errors.
const FAKE_PORT: &str = "fake:grbl";

const STEPS: f64 = 3200.0 / 360.0 * 16.0;

/// What the fake does; tests change it between requests.
struct Script {
    banner: String,
    steps: [f64; 3],
    /// Homing enabled: starts (and restarts) in Alarm until `$H`.
    homing_lock: bool,
    /// Degrees per second of every move (0: moves complete at once).
    speed: f64,
    /// Raise `ALARM:N` halfway through the next move.
    alarm_on_move: Option<u32>,
    /// Answer the next line with `error:N`.
    reject_next: Option<u32>,
    /// Answer the next `?` with garbage.
    garbage_on_status: bool,
    /// Answer the next `?` with a status report cut short (its tail lost).
    cut_status: bool,
    /// Stop answering anything.
    mute: bool,
    /// Seconds a feed hold takes to bring a move to rest (`Hold:1`, still moving), as a slow
    /// board decelerates; 0: at once.
    hold_decel_s: f64,
}

impl Default for Script {
    fn default() -> Self {
        Self {
            banner: "Grbl 1.1h ['$' for help]".into(),
            steps: [STEPS; 3],
            homing_lock: true,
            speed: 0.0,
            alarm_on_move: None,
            reject_next: None,
            garbage_on_status: false,
            cut_status: false,
            mute: false,
            hold_decel_s: 0.0,
        }
    }
}

/// One queued move of the fake's planner (moves run one after another).
struct Seg {
    axis: usize,
    from: f64,
    to: f64,
    start: Instant,
    dur: f64,
}

/// What the fake knows: shared with the test for assertions.
#[derive(Default)]
struct Seen {
    bytes: Vec<u8>,
    resets: u32,
    laser_on: bool,
}

struct Machine {
    base: [f64; 3],
    segs: Vec<Seg>,
    alarm: bool,
    hold: bool,
    /// A feed hold still decelerating: the motion comes to rest at this instant.
    hold_until: Option<Instant>,
    alarm_at: Option<(Instant, u32)>,
}

impl Machine {
    fn pos(&self, now: Instant) -> [f64; 3] {
        let mut p = self.base;
        for s in &self.segs {
            let t = now.saturating_duration_since(s.start).as_secs_f64();
            if s.dur <= 0.0 || t >= s.dur {
                p[s.axis] = s.to;
            } else {
                p[s.axis] = s.from + (s.to - s.from) * (t / s.dur);
                break;
            }
        }
        p
    }

    fn moving(&self, now: Instant) -> bool {
        self.segs
            .last()
            .is_some_and(|s| now.saturating_duration_since(s.start).as_secs_f64() < s.dur)
    }

    /// Stops all motion where it is.
    fn freeze(&mut self, now: Instant) {
        self.base = self.pos(now);
        self.segs.clear();
        self.hold_until = None;
    }

    /// Completes a decelerating hold whose time has come.
    fn settle_hold(&mut self, now: Instant) {
        if let Some(t) = self.hold_until.filter(|&t| t <= now) {
            self.freeze(t);
        }
    }

    fn end(&self) -> (Instant, [f64; 3]) {
        let far = Instant::now() + Duration::from_secs(3600);
        match self.segs.last() {
            Some(s) => (s.start + Duration::from_secs_f64(s.dur), self.pos(far)),
            None => (Instant::now(), self.base),
        }
    }
}

/// A running fake controller and what the test needs to drive and inspect it.
struct Fake {
    script: Arc<Mutex<Script>>,
    seen: Arc<Mutex<Seen>>,
    task: JoinHandle<()>,
    /// The port as errors name it: [`FAKE_PORT`], or the pty's path.
    path: String,
    /// The duplex port (`None` on a pty).
    port: Option<Port>,
    /// The pty's slave end, kept open (`None` on a duplex port).
    _slave: Option<serial2::SerialPort>,
}

impl Fake {
    /// A fake controller on a duplex port, for tests on the paused clock.
    fn start(script: Script) -> Fake {
        let (port, device) = duplex_port();
        Self::serve(script, device, FAKE_PORT.into(), Some(port), None)
    }

    /// A fake controller on a real pty (the smoke test of the serial path).
    fn start_on_pty(script: Script) -> Fake {
        let (path, device, slave) = pty_port();
        Self::serve(script, device, path, None, Some(slave))
    }

    fn serve(
        script: Script,
        device: DeviceEnd,
        path: String,
        port: Option<Port>,
        slave: Option<serial2::SerialPort>,
    ) -> Fake {
        let script = Arc::new(Mutex::new(script));
        let seen = Arc::new(Mutex::new(Seen::default()));
        let task = tokio::spawn(run_fake(device, script.clone(), seen.clone()));
        Fake {
            script,
            seen,
            task,
            path,
            port,
            _slave: slave,
        }
    }

    /// A controller for X and Y on the fake's port, keepalive off (tests that want it switch
    /// it on).
    fn controller(&self) -> Arc<GrblController> {
        let axes = vec![axis("turntable", "X"), axis("arc", "Y")];
        let ctl = match &self.port {
            Some(port) => {
                GrblController::with_transport("turntable", FAKE_PORT, port.opener(), axes)
            }
            None => GrblController::new("turntable", &self.path, GRBL_BAUD, axes),
        };
        ctl.set_keepalive(false);
        ctl
    }

    /// Pulls the cable (duplex ports only).
    fn unplug(&self) {
        self.port.as_ref().expect("a duplex port").unplug();
    }

    fn script(&self) -> std::sync::MutexGuard<'_, Script> {
        self.script.lock().unwrap()
    }

    /// The bytes received so far, cleared.
    fn take_bytes(&self) -> Vec<u8> {
        std::mem::take(&mut self.seen.lock().unwrap().bytes)
    }

    fn resets(&self) -> u32 {
        self.seen.lock().unwrap().resets
    }

    fn laser_on(&self) -> bool {
        self.seen.lock().unwrap().laser_on
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Waits until `at`, or forever.
async fn until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// The fake controller: answers what the driver sends, raises a scheduled alarm on time.
async fn run_fake(mut port: DeviceEnd, script: Arc<Mutex<Script>>, seen: Arc<Mutex<Seen>>) {
    let mut m = Machine {
        base: [5.0, 7.0, 0.0],
        segs: Vec::new(),
        alarm: script.lock().unwrap().homing_lock,
        hold: false,
        hold_until: None,
        alarm_at: None,
    };
    let mut line = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let n = tokio::select! {
            n = port.read(&mut buf) => match n {
                Some(n) => n,
                None => return,
            },
            () = until(m.alarm_at.map(|(at, _)| at)) => {
                if let Some((_, code)) = m.alarm_at.take() {
                    m.freeze(Instant::now());
                    m.alarm = true;
                    port.write(format!("ALARM:{code}\r\n").as_bytes()).await;
                }
                continue;
            }
        };
        seen.lock().unwrap().bytes.extend_from_slice(&buf[..n]);
        if script.lock().unwrap().mute {
            continue;
        }
        let mut out = String::new();
        let mut send = |text: &str| out.push_str(text);
        for &b in &buf[..n] {
            let now = Instant::now();
            m.settle_hold(now);
            match b {
                0x18 => {
                    line.clear();
                    let was_moving = m.moving(now);
                    m.freeze(now);
                    m.alarm_at = None;
                    let s = script.lock().unwrap();
                    {
                        let mut seen = seen.lock().unwrap();
                        seen.resets += 1;
                        seen.laser_on = false;
                    }
                    send(&format!("\r\n{}\r\n", s.banner));
                    // A reset while the axes move (a hold still decelerating included) loses
                    // the position.
                    if was_moving {
                        m.alarm = true;
                        send("ALARM:3\r\n");
                    }
                    m.hold = false;
                    if m.alarm {
                        send("[MSG:'$H'|'$X' to unlock]\r\n");
                    }
                }
                b'?' => {
                    let mut s = script.lock().unwrap();
                    if s.garbage_on_status {
                        s.garbage_on_status = false;
                        send("\x07\x01 line noise %%%\r\n");
                        continue;
                    }
                    if s.cut_status {
                        s.cut_status = false;
                        send("<Run|MPos:-0.998,-12.495,-0.998|FS:1200,0,\r\n");
                        continue;
                    }
                    let state = if m.alarm {
                        "Alarm"
                    } else if m.hold_until.is_some() {
                        "Hold:1"
                    } else if m.hold {
                        "Hold:0"
                    } else if m.moving(now) {
                        "Run"
                    } else {
                        "Idle"
                    };
                    let p = m.pos(now);
                    let on = seen.lock().unwrap().laser_on;
                    let (speed, acc) = if on { (1000, "|A:S") } else { (0, "") };
                    send(&format!(
                        "<{state}|MPos:{:.3},{:.3},{:.3}|FS:0,{speed}|Pn:X|Ov:100,100,100{acc}>\r\n",
                        p[0], p[1], p[2]
                    ));
                }
                b'!' => {
                    if m.moving(now) && !m.hold {
                        let decel = script.lock().unwrap().hold_decel_s;
                        if decel > 0.0 {
                            m.hold_until = Some(now + Duration::from_secs_f64(decel));
                        } else {
                            m.freeze(now);
                        }
                        m.alarm_at = None;
                        m.hold = true;
                    }
                }
                b'~' => m.hold = false,
                b'\n' => {
                    let text = String::from_utf8_lossy(&line).trim().to_string();
                    line.clear();
                    let reply = answer(&text, &mut m, &script, &seen, now);
                    send(&reply);
                }
                b'\r' => {}
                _ => line.push(b),
            }
        }
        if !out.is_empty() {
            port.write(out.as_bytes()).await;
        }
    }
}

/// The reply text (with line ends) to one command line.
fn answer(
    text: &str,
    m: &mut Machine,
    script: &Mutex<Script>,
    seen: &Mutex<Seen>,
    now: Instant,
) -> String {
    let mut s = script.lock().unwrap();
    if let Some(code) = s.reject_next.take() {
        return format!("error:{code}\r\n");
    }
    if text == "$I" {
        // A build with single-axis homing (`$HX`).
        return "[VER:1.1h.20190830:]\r\n[OPT:VH,15,128]\r\nok\r\n".into();
    }
    if text == "$$" {
        let mut r = String::from("$10=1\r\n$22=1\r\n$27=1.000\r\n$32=0\r\n");
        for (i, v) in s.steps.iter().enumerate() {
            r += &format!("$10{i}={v:.3}\r\n");
        }
        return r + "$110=1800.000\r\nok\r\n";
    }
    if let Some(letter) = text.strip_prefix("$H") {
        if m.moving(now) {
            return "error:8\r\n".into();
        }
        let i = match letter {
            "X" => 0,
            "Y" => 1,
            "Z" => 2,
            _ => return "error:3\r\n".into(),
        };
        // Homed: pulled off the switch to machine −$27, in whole steps as GRBL sets it.
        m.base[i] = -(1.0f64 * 142.222).round() / 142.222;
        m.alarm = false;
        return "ok\r\n".into();
    }
    if text == "M5" {
        seen.lock().unwrap().laser_on = false;
        return "ok\r\n".into();
    }
    if text == "M3 S1000" {
        if m.alarm {
            return "error:9\r\n".into();
        }
        seen.lock().unwrap().laser_on = true;
        return "ok\r\n".into();
    }
    if let Some(rest) = text.strip_prefix("G53 G0 ") {
        if m.alarm {
            return "error:9\r\n".into();
        }
        let i = match rest.chars().next() {
            Some('X') => 0,
            Some('Y') => 1,
            Some('Z') => 2,
            _ => return "error:20\r\n".into(),
        };
        let Ok(to) = rest[1..].parse::<f64>() else {
            return "error:2\r\n".into();
        };
        let (start, pos) = m.end();
        let start = start.max(now);
        let dur = if s.speed > 0.0 {
            (to - pos[i]).abs() / s.speed
        } else {
            0.0
        };
        m.segs.push(Seg {
            axis: i,
            from: pos[i],
            to,
            start,
            dur,
        });
        if let Some(code) = s.alarm_on_move.take() {
            m.alarm_at = Some((start + Duration::from_secs_f64(dur / 2.0), code));
        }
        return "ok\r\n".into();
    }
    "error:20\r\n".into()
}

fn axis(id: &str, letter: &str) -> AxisSpec {
    AxisSpec {
        id: id.into(),
        backend: Backend::Grbl,
        port: None,
        role: AxisRole::Other,
        speed_deg_s: 30.0,
        accel_deg_s2: 60.0,
        min_deg: 0.0,
        max_deg: 360.0,
        backlash_deg: 0.0,
        settle_s: 0.0,
        homing_speed_deg_s: 20.0,
        steps_per_deg: STEPS,
        controller_axis: Some(letter.into()),
        baud: None,
        home_deg: 0.0,
        machine_sign: 1.0,
    }
}

/// Positions read back carry GRBL's 3-decimal print of a machine coordinate whose home is a
/// whole number of steps (−0.998439…), so they are within half a thousandth of a degree.
fn assert_near(got: f64, want: f64) {
    assert!((got - want).abs() < 1e-3, "{got} is not {want}");
}

/// The byte stream as one token per line: real-time bytes in `<>`, lines with a visible `\n`.
fn show(bytes: &[u8]) -> String {
    let mut out = String::new();
    let mut line = String::new();
    for &b in bytes {
        match b {
            b'\n' => {
                out += &format!("{line}\\n\n");
                line.clear();
            }
            0x18 if line.is_empty() => out += "<0x18>\n",
            b'?' | b'!' | b'~' if line.is_empty() => out += &format!("<{}>\n", b as char),
            b if b.is_ascii_graphic() || b == b' ' => line.push(b as char),
            b => line += &format!("<0x{b:02x}>"),
        }
    }
    if !line.is_empty() {
        out += &format!("{line}(unterminated)\n");
    }
    out
}
