//! Drives `GrblController` (and its axis and laser drivers) against a small scripted fake
//! GRBL 1.1 controller on a pty pair, and snapshots the exact bytes the driver sends.

use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stagehand_devices::axis::{AxisDriver, AxisHandle};
use stagehand_devices::grbl::{GrblAxis, GrblController, GrblLaser};
use stagehand_devices::laser::LaserDriver;
use stagehand_devices::rig::{AxisRole, AxisSpec, Backend, GRBL_BAUD};
use stagehand_devices::{DeviceError, DeviceErrorKind};

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
    /// Stop answering anything.
    mute: bool,
    /// Close the master end (the port disappears).
    unplug: bool,
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
            mute: false,
            unplug: false,
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
    }

    fn end(&self) -> (Instant, [f64; 3]) {
        let far = Instant::now() + Duration::from_secs(3600);
        match self.segs.last() {
            Some(s) => (s.start + Duration::from_secs_f64(s.dur), self.pos(far)),
            None => (Instant::now(), self.base),
        }
    }
}

struct Fake {
    script: Arc<Mutex<Script>>,
    seen: Arc<Mutex<Seen>>,
    quit: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    path: String,
    _slave: serial2::SerialPort,
}

impl Fake {
    fn start(script: Script) -> Fake {
        let (mut master, slave) = serial2::SerialPort::pair().unwrap();
        let path = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd()))
            .unwrap()
            .to_str()
            .unwrap()
            .to_string();
        master.set_read_timeout(Duration::from_millis(5)).unwrap();
        let script = Arc::new(Mutex::new(script));
        let seen = Arc::new(Mutex::new(Seen::default()));
        let quit = Arc::new(AtomicBool::new(false));
        let thread = {
            let (script, seen, quit) = (script.clone(), seen.clone(), quit.clone());
            std::thread::spawn(move || run_fake(master, script, seen, quit))
        };
        Fake {
            script,
            seen,
            quit,
            thread: Some(thread),
            path,
            _slave: slave,
        }
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
        self.quit.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run_fake(
    master: serial2::SerialPort,
    script: Arc<Mutex<Script>>,
    seen: Arc<Mutex<Seen>>,
    quit: Arc<AtomicBool>,
) {
    let mut m = Machine {
        base: [5.0, 7.0, 0.0],
        segs: Vec::new(),
        alarm: script.lock().unwrap().homing_lock,
        hold: false,
        alarm_at: None,
    };
    let mut line = Vec::new();
    let mut buf = [0u8; 256];
    let send = |text: &str| {
        let _ = master.write_all(text.as_bytes());
    };
    while !quit.load(Ordering::Relaxed) {
        let now = Instant::now();
        if script.lock().unwrap().unplug {
            return;
        }
        if let Some((at, code)) = m.alarm_at
            && now >= at
        {
            m.freeze(now);
            m.alarm = true;
            m.alarm_at = None;
            send(&format!("ALARM:{code}\r\n"));
        }
        let n = match master.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(_) => return,
        };
        seen.lock().unwrap().bytes.extend_from_slice(&buf[..n]);
        if script.lock().unwrap().mute {
            continue;
        }
        for &b in &buf[..n] {
            let now = Instant::now();
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
                    if was_moving && !m.hold {
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
                    let state = if m.alarm {
                        "Alarm"
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
                    if m.moving(now) {
                        m.freeze(now);
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

/// A controller for X and Y on the fake's port, keepalive off (tests that want it switch it on).
fn controller(fake: &Fake) -> Arc<GrblController> {
    let ctl = GrblController::new(
        "turntable",
        &fake.path,
        GRBL_BAUD,
        vec![axis("turntable", "X"), axis("arc", "Y")],
    );
    ctl.set_keepalive(false);
    ctl
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn byte_streams_of_handshake_home_move_stop_and_laser() {
    let fake = Fake::start(Script::default());
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let mut laser = GrblLaser::new(ctl.clone(), "laser");

    // The handshake (reset, banner, `$I`, `$$`, `?`), then the position's own `?`. Machine 5
    // is 5.998° before homing: the map puts 0° at machine −`$27` in whole steps (−0.998),
    // where homing ends.
    assert_near(x.position().await.unwrap(), 5.998);
    insta::assert_snapshot!(show(&fake.take_bytes()), @r"
    <0x18>
    $I\n
    $$\n
    <?>
    <?>
    ");

    assert_near(x.home().await.unwrap(), 0.0);
    insta::assert_snapshot!(show(&fake.take_bytes()), @r"
    $HX\n
    <?>
    ");

    assert_near(x.move_to(12.5).await.unwrap(), 12.5);
    insta::assert_snapshot!(show(&fake.take_bytes()), @r"
    G53 G0 X11.502\n
    <?>
    ");

    // Nothing moving: a stop only reads the position (a feed hold and reset are for motion).
    assert_near(x.stop().await.unwrap(), 12.5);
    insta::assert_snapshot!(show(&fake.take_bytes()), @r"
    <?>
    ");

    laser.set_emission(true, 520).await.unwrap();
    assert!(fake.laser_on());
    laser.set_emission(false, 520).await.unwrap();
    assert!(!fake.laser_on());
    insta::assert_snapshot!(show(&fake.take_bytes()), @r"
    M3 S1000\n
    <?>
    M5\n
    <?>
    ");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn homes_moves_and_reports_positions_through_the_axis_handle() {
    let fake = Fake::start(Script {
        speed: 200.0,
        ..Script::default()
    });
    let ctl = controller(&fake);
    ctl.set_keepalive(true);
    let spec = axis("turntable", "X");
    let mut x = GrblAxis::new(ctl.clone(), &spec).unwrap();
    let e = x.move_to(10.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { device, kind: DeviceErrorKind::NotHomed } if device == "turntable"),
        "{e}"
    );
    assert!(!ctl.is_homed('X').await);

    let handle = AxisHandle::spawn(spec, x);
    assert_near(handle.home().await.unwrap(), 0.0);
    assert!(ctl.is_homed('X').await && !ctl.is_homed('Y').await);
    let t0 = Instant::now();
    let p = handle.move_to(40.0).await.unwrap();
    assert!((p - 40.0).abs() < 1e-3, "{p}");
    assert!(
        t0.elapsed() >= Duration::from_millis(150),
        "waited for the move to finish, not just for `ok`"
    );
    assert!((handle.position().await.unwrap() - 40.0).abs() < 1e-3);
    let p = handle.move_to(12.345).await.unwrap();
    assert!((p - 12.345).abs() < 1e-3, "{p}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_axes_queue_their_moves_on_one_controller() {
    let fake = Fake::start(Script {
        speed: 300.0,
        ..Script::default()
    });
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let mut y = GrblAxis::new(ctl.clone(), &axis("arc", "Y")).unwrap();
    x.home().await.unwrap();
    y.home().await.unwrap();
    let (px, py) = tokio::join!(x.move_to(60.0), y.move_to(90.0));
    assert!((px.unwrap() - 60.0).abs() < 1e-3);
    assert!((py.unwrap() - 90.0).abs() < 1e-3);
    let s = ctl.status("test").await.unwrap();
    // The status is in machine coordinates: 60° and 90° are machine 59.002 and 89.002 (home
    // at −0.998, the pull-off of 1 in whole steps).
    assert_eq!(&s.pos[..2], &[59.002, 89.002]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_banner_is_the_wrong_firmware() {
    let fake = Fake::start(Script {
        banner: "Grbl 0.9j ['$' for help]".into(),
        ..Script::default()
    });
    let mut x = GrblAxis::new(controller(&fake), &axis("turntable", "X")).unwrap();
    let e = x.position().await.unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Protocol { .. },
                ..
            }
        ),
        "{text}"
    );
    assert!(
        text.contains("wrong firmware banner `Grbl 0.9j") && text.contains("expected GRBL 1.1"),
        "{text}"
    );
    assert!(
        text.contains("turntable") && text.contains(&fake.path),
        "{text}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_steps_per_degree_say_which_setting_to_change() {
    let fake = Fake::start(Script {
        steps: [STEPS, 80.0, 250.0],
        ..Script::default()
    });
    let mut y = GrblAxis::new(controller(&fake), &axis("arc", "Y")).unwrap();
    let e = y.home().await.unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Misconfigured { .. },
                ..
            }
        ),
        "{text}"
    );
    assert!(text.contains("`$101=142.222`"), "{text}");
    assert!(text.starts_with("arc:"), "{text}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_error_reply_is_rejected_with_its_meaning() {
    let fake = Fake::start(Script::default());
    let ctl = controller(&fake);
    let mut laser = GrblLaser::new(ctl.clone(), "laser");
    // In Alarm after connecting: G-code is locked out.
    let e = laser.set_emission(true, 520).await.unwrap_err();
    assert_eq!(
        e,
        DeviceError::new(
            "laser",
            DeviceErrorKind::Rejected {
                command: "M3 S1000".into(),
                code: 9,
                meaning: "G-code lock".into()
            }
        )
    );
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    fake.script().reject_next = Some(20);
    let e = x.move_to(3.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Rejected { code: 20, command, .. }, .. } if command == "G53 G0 X2.002"),
        "{e}"
    );
    // The flow counter was freed by the error: the next line goes through.
    assert_near(x.move_to(3.0).await.unwrap(), 3.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_alarm_during_a_move_loses_the_homing() {
    let fake = Fake::start(Script {
        speed: 200.0,
        ..Script::default()
    });
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    fake.script().alarm_on_move = Some(1);
    let e = x.move_to(100.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::HardLimit { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.is_recoverable());
    assert!(!ctl.is_homed('X').await);
    let e = x.move_to(10.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            }
        ),
        "{e}"
    );

    x.home().await.unwrap();
    fake.script().alarm_on_move = Some(2);
    let e = x.move_to(100.0).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Alarm { code: 2, meaning, .. }, .. } if meaning.contains("Soft limit")),
        "{e}"
    );
    x.home().await.unwrap();
    assert_near(x.move_to(10.0).await.unwrap(), 10.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_resynchronises_and_the_position_is_unverified_afterwards() {
    let fake = Fake::start(Script::default());
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    x.move_to(20.0).await.unwrap();
    assert_eq!(fake.resets(), 1);
    fake.script().garbage_on_status = true;
    let e = x.position().await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Protocol { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("line noise"), "{e}");
    // The next request reconnects with a handshake (soft reset) ...
    assert_near(x.position().await.unwrap(), 20.0);
    assert_eq!(fake.resets(), 2);
    // ... and refuses to move at a position it has not verified.
    let e = x.move_to(30.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NotHomed,
                ..
            }
        ),
        "{e}"
    );
    x.home().await.unwrap();
    assert_near(x.move_to(30.0).await.unwrap(), 30.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mute_controller_times_out_and_an_unplugged_port_is_disconnected() {
    let fake = Fake::start(Script::default());
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.position().await.unwrap();
    fake.script().mute = true;
    // A timeout, not a hang (how quickly it comes is the driver's timeout, not a test bound).
    let e = x.position().await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Timeout { .. },
                ..
            }
        ),
        "{e}"
    );
    // Reconnecting to a mute controller: no banner.
    let e = x.position().await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Timeout { request, .. }, .. } if request.contains("banner")),
        "{e}"
    );
    fake.script().unplug = true;
    std::thread::sleep(Duration::from_millis(50));
    let e = x.position().await.unwrap_err();
    assert!(e.is_recoverable(), "{e}");
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Disconnected { .. },
                ..
            } | DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            } | DeviceError {
                kind: DeviceErrorKind::Timeout { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("turntable"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_during_a_move_keeps_the_position() {
    let fake = Fake::start(Script {
        speed: 100.0,
        ..Script::default()
    });
    let ctl = controller(&fake);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.home().await.unwrap();
    let mut mover = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    let moving = tokio::spawn(async move { mover.move_to(100.0).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let p = x.stop().await.unwrap();
    assert!(p > 5.0 && p < 95.0, "stopped on the way: {p}");
    let e = moving.await.unwrap().unwrap_err();
    assert!(e.to_string().contains("interrupted"), "{e}");
    // The reset came in Hold:0: still homed, the position is where it stopped.
    assert!(ctl.is_homed('X').await);
    assert_near(x.position().await.unwrap(), p);
    assert!((x.move_to(p + 5.0).await.unwrap() - (p + 5.0)).abs() < 1e-3);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_keepalive_polls_only_while_idle_and_enabled() {
    let fake = Fake::start(Script::default());
    let ctl = controller(&fake);
    ctl.set_keepalive(true);
    let mut x = GrblAxis::new(ctl.clone(), &axis("turntable", "X")).unwrap();
    x.position().await.unwrap();
    fake.take_bytes();
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let polls = fake.take_bytes().iter().filter(|b| **b == b'?').count();
    assert!((2..=3).contains(&polls), "{polls} keepalive polls in 1.3 s");
    ctl.set_keepalive(false);
    tokio::time::sleep(Duration::from_millis(700)).await;
    assert!(fake.take_bytes().is_empty());
}

#[test]
fn an_axis_needs_a_letter_the_controller_serves() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let ctl = GrblController::new("t", "/dev/null", GRBL_BAUD, vec![axis("t", "X")]);
        let e = GrblAxis::new(ctl.clone(), &axis("tilt", "Q"))
            .err()
            .unwrap();
        assert!(e.to_string().contains("controller_axis"), "{e}");
        let e = GrblAxis::new(ctl.clone(), &axis("tilt", "Z"))
            .err()
            .unwrap();
        assert!(e.to_string().starts_with("tilt:"), "{e}");
        assert_eq!(
            GrblAxis::new(ctl, &axis("t", "x")).ok().map(|a| a.letter()),
            Some('X')
        );
    });
}
