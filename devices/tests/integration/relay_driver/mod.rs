//! The switched-output drivers against small scripted fakes: a Numato-style relay board and an
//! IR bridge on pty pairs, and an in-memory dcttech HID board. The fakes parse the wire text on
//! their own (not with the crate's codecs), so a misreading on either side fails a test.

use std::io;
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stagehand_devices::cart::{CartDriver, Drive};
use stagehand_devices::hid_relay::{self, HidOpenError, HidRelayBank, HidTransport};
use stagehand_devices::ir_cart::{IrBridgeCart, Output};
use stagehand_devices::laser::LaserDriver;
use stagehand_devices::relay_serial::{NumatoBoard, RelaySerialBank};
use stagehand_devices::rig::{Backend, SwitchBankSpec};
use stagehand_devices::switch_bank::{SwitchBankDriver, SwitchBankHandle};
use stagehand_devices::switch_wired::{GpioTrigger, SwitchLaser};
use stagehand_devices::trigger::TriggerDriver;
use stagehand_devices::{DeviceError, DeviceErrorKind};

// ---------------------------------------------------------------- pty fake plumbing

/// A fake device on the master side of a pty, run on a std thread until dropped.
struct Pty {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// Bytes the test wants the device to send unsolicited.
    outbox: Arc<Mutex<Vec<u8>>>,
    _slave: serial2::SerialPort,
}

impl Drop for Pty {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Pty {
    fn send(&self, bytes: &[u8]) {
        self.outbox.lock().unwrap().extend_from_slice(bytes);
    }
}

/// Runs `on_byte` for every byte the driver writes; what it returns goes back to the driver.
fn run_fake(mut on_byte: impl FnMut(u8) -> Vec<u8> + Send + 'static) -> Pty {
    let (mut master, slave) = serial2::SerialPort::pair().unwrap();
    let path = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd()))
        .unwrap()
        .to_str()
        .unwrap()
        .to_string();
    master.set_read_timeout(Duration::from_millis(10)).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let outbox = Arc::new(Mutex::new(Vec::new()));
    let thread = {
        let stop = stop.clone();
        let outbox = outbox.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            while !stop.load(Ordering::Relaxed) {
                let pending = std::mem::take(&mut *outbox.lock().unwrap());
                if !pending.is_empty() && master.write_all(&pending).is_err() {
                    return;
                }
                match master.read(&mut buf) {
                    Ok(0) => std::thread::sleep(Duration::from_millis(5)),
                    Ok(n) => {
                        let mut out = Vec::new();
                        for &b in &buf[..n] {
                            out.extend(on_byte(b));
                        }
                        if !out.is_empty() && master.write_all(&out).is_err() {
                            return;
                        }
                    }
                    Err(e)
                        if matches!(
                            e.kind(),
                            io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
                        ) => {}
                    Err(_) => std::thread::sleep(Duration::from_millis(5)),
                }
            }
        })
    };
    Pty {
        path,
        stop,
        thread: Some(thread),
        outbox,
        _slave: slave,
    }
}

// ---------------------------------------------------------------- fake Numato board

#[derive(Default)]
struct Numato {
    relays: u32,
    gpio: u32,
    /// Every command line received (including empty ones), with its arrival time.
    log: Vec<(Instant, String)>,
    /// Swallow every byte without an answer (a hung or unplugged board).
    mute: bool,
    /// Answer `ver` with this instead of `00000008`.
    version: Option<String>,
    line: Vec<u8>,
}

fn index(w: &str) -> Option<u32> {
    let mut cs = w.chars();
    let c = cs.next()?;
    if cs.next().is_some() {
        return None;
    }
    match c {
        '0'..='9' => Some(c as u32 - '0' as u32),
        'A'..='V' => Some(c as u32 - 'A' as u32 + 10),
        _ => None,
    }
}

impl Numato {
    fn answer(&mut self, text: &str) -> Option<String> {
        let words: Vec<&str> = text.split(' ').collect();
        match words.as_slice() {
            ["ver"] => Some(self.version.clone().unwrap_or_else(|| "00000008".into())),
            ["relay", "on", n] => {
                self.relays |= 1 << index(n)?;
                None
            }
            ["relay", "off", n] => {
                self.relays &= !(1 << index(n)?);
                None
            }
            ["relay", "readall"] => Some(format!("{:02x}", self.relays & 0xff)),
            ["gpio", "set", n] => {
                self.gpio |= 1 << index(n)?;
                None
            }
            ["gpio", "clear", n] => {
                self.gpio &= !(1 << index(n)?);
                None
            }
            _ => None,
        }
    }

    fn on_byte(&mut self, b: u8) -> Vec<u8> {
        if self.mute {
            return Vec::new();
        }
        let mut out = vec![b];
        if b == b'\r' {
            let text = String::from_utf8_lossy(&std::mem::take(&mut self.line))
                .trim()
                .to_string();
            self.log.push((Instant::now(), text.clone()));
            out.extend_from_slice(b"\n\r");
            if let Some(reply) = self.answer(&text) {
                out.extend_from_slice(reply.as_bytes());
                out.extend_from_slice(b"\n\r");
            }
            out.push(b'>');
        } else {
            self.line.push(b);
        }
        out
    }

    /// The non-empty command lines received since `from`.
    fn commands(&self, from: usize) -> Vec<String> {
        self.log[from.min(self.log.len())..]
            .iter()
            .map(|(_, l)| l.clone())
            .filter(|l| !l.is_empty())
            .collect()
    }
}

fn numato_fake() -> (Pty, Arc<Mutex<Numato>>) {
    let state = Arc::new(Mutex::new(Numato::default()));
    let s = state.clone();
    (run_fake(move |b| s.lock().unwrap().on_byte(b)), state)
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

// ---------------------------------------------------------------- Numato tests

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relay_bank_switches_reads_and_restores_states_after_a_board_reset() {
    let (pty, fake) = numato_fake();
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.0);
    let mut bank = RelaySerialBank::new(board.clone(), 8).unwrap();

    bank.set(1, true).await.unwrap();
    bank.set(3, true).await.unwrap();
    bank.set(2, false).await.unwrap();
    assert_eq!(fake.lock().unwrap().relays, 0b101);
    assert_eq!(
        fake.lock().unwrap().commands(0),
        strings(&["ver", "relay on 0", "relay on 2", "relay off 1"])
    );
    let states = bank.read_all().await.unwrap();
    assert_eq!(
        states,
        vec![true, false, true, false, false, false, false, false]
    );
    let e = bank.set(9, true).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NoSuchChannel { channel: 9, .. },
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(board.connects(), 1);

    // The board hangs and loses power: the command times out, the link closes.
    {
        let mut f = fake.lock().unwrap();
        f.mute = true;
        f.relays = 0;
    }
    let e = bank.set(4, true).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Timeout { request, .. }, .. } if request == "relay on 3"),
        "{e}"
    );
    // It comes back: the next command reconnects, finds the relays off, restores them first.
    let mark = fake.lock().unwrap().log.len();
    fake.lock().unwrap().mute = false;
    bank.set(4, true).await.unwrap();
    assert_eq!(board.connects(), 2);
    assert_eq!(
        fake.lock().unwrap().commands(mark),
        strings(&[
            "ver",
            "relay readall",
            "relay on 0",
            "relay on 2",
            "relay on 3"
        ])
    );
    assert_eq!(fake.lock().unwrap().relays, 0b1101);

    // A reconnect to a board that kept its states re-sends nothing.
    fake.lock().unwrap().mute = true;
    assert!(bank.read_all().await.is_err());
    fake.lock().unwrap().mute = false;
    let mark = fake.lock().unwrap().log.len();
    bank.set(8, true).await.unwrap();
    assert_eq!(
        fake.lock().unwrap().commands(mark),
        strings(&["ver", "relay readall", "relay on 7"])
    );
    assert_eq!(fake.lock().unwrap().relays, 0b1000_1101);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_board_that_is_not_numato_or_silent_or_missing_is_a_typed_error() {
    let (pty, fake) = numato_fake();
    fake.lock().unwrap().version = Some("Grbl 1.1h".into());
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.0);
    let e = board.version().await.unwrap_err();
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
    assert!(e.to_string().contains("Grbl 1.1h"), "{e}");
    assert_eq!(board.connects(), 0);
    // Right firmware: the next request connects.
    fake.lock().unwrap().version = None;
    assert_eq!(board.version().await.unwrap(), "00000008");
    assert_eq!(board.connects(), 1);

    let (silent, state) = numato_fake();
    state.lock().unwrap().mute = true;
    let board = NumatoBoard::new("lamps", &silent.path, 19_200, 0.0);
    let e = board.gpio_set(1).await.unwrap_err();
    assert!(
        matches!(&e, DeviceError { kind: DeviceErrorKind::Timeout { request, .. }, .. } if request == "ver"),
        "{e}"
    );

    let board = NumatoBoard::new("lamps", "/dev/serial/by-id/no-such-board", 19_200, 3.0);
    let mut bank = RelaySerialBank::new(board, 8).unwrap();
    let e = bank.set(1, true).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("no-such-board"), "{e}");
    assert!(RelaySerialBank::new(NumatoBoard::new("x", "/dev/null", 1, 0.0), 33).is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keepalive_renews_the_watchdog_while_idle_and_ends_with_the_board() {
    let (pty, fake) = numato_fake();
    // Watchdog 0.3 s: a keepalive every 0.1 s while idle.
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.3);
    board.set_relay(0, false).await.unwrap();
    let count = |what: &str| {
        fake.lock()
            .unwrap()
            .commands(0)
            .iter()
            .filter(|c| *c == what)
            .count()
    };
    assert_eq!(count("ver"), 1);
    tokio::time::sleep(Duration::from_millis(650)).await;
    let n = count("ver") - 1;
    assert!((4..=8).contains(&n), "{n} keepalives in 0.65 s");
    assert_eq!(count("relay readall"), 0);
    // Every command counts as activity: busy, the board gets no keepalive.
    let before = count("ver");
    for _ in 0..10 {
        board.set_relay(1, false).await.unwrap();
        tokio::time::sleep(Duration::from_millis(30)).await;
    }
    assert!(
        count("ver") - before <= 1,
        "{} keepalives while busy",
        count("ver") - before
    );
    // While a relay is on the keepalive reads the relays back instead.
    board.set_relay(1, true).await.unwrap();
    let vers = count("ver");
    tokio::time::sleep(Duration::from_millis(350)).await;
    assert!(count("ver") - vers <= 1);
    assert!(count("relay readall") >= 2, "{}", count("relay readall"));
    drop(board);
    tokio::time::sleep(Duration::from_millis(150)).await;
    let after = fake.lock().unwrap().log.len();
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert_eq!(
        fake.lock().unwrap().log.len(),
        after,
        "the keepalive outlived the board"
    );
    assert_eq!(fake.lock().unwrap().relays, 0b10);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_reset_is_found_restored_and_reported_once() {
    let (pty, fake) = numato_fake();
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.3);
    let mut bank = RelaySerialBank::new(board.clone(), 8).unwrap();
    bank.set(2, true).await.unwrap();
    bank.set(5, true).await.unwrap();
    // The board resets without dropping the link (or its watchdog lapsed): all relays off.
    fake.lock().unwrap().relays = 0;
    tokio::time::sleep(Duration::from_millis(300)).await;
    // The keepalive found and restored them at once ...
    assert_eq!(fake.lock().unwrap().relays, 0b1_0010);
    // ... and the next request reports the loss (the lamps were dark for a while), once.
    let e = bank.set(3, true).await.unwrap_err();
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
    assert!(e.to_string().contains("relay 1 on, relay 4 on"), "{e}");
    bank.set(3, true).await.unwrap();
    assert_eq!(fake.lock().unwrap().relays, 0b1_0110);
    assert_eq!(board.connects(), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_trigger_refuses_to_fire_into_lamps_a_reset_switched_off() {
    let (pty, fake) = numato_fake();
    // No keepalive: only the check before the pulse can notice.
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.0);
    let mut bank = RelaySerialBank::new(board.clone(), 8).unwrap();
    let mut trigger = GpioTrigger::new("trigger", board.clone(), 0, 0.001).unwrap();
    // Nothing on: nothing to check, no extra round trip.
    trigger.fire(1).await.unwrap();
    assert_eq!(
        fake.lock().unwrap().commands(0),
        strings(&["ver", "gpio set 0", "gpio clear 0"])
    );
    bank.set(1, true).await.unwrap();
    trigger.fire(2).await.unwrap();
    fake.lock().unwrap().relays = 0;
    let mark = fake.lock().unwrap().log.len();
    let e = trigger.fire(3).await.unwrap_err();
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
    assert_eq!(
        fake.lock().unwrap().commands(mark),
        strings(&["relay readall", "relay on 0"])
    );
    assert_eq!(fake.lock().unwrap().relays, 1);
    trigger.fire(3).await.unwrap();
    assert_eq!(fake.lock().unwrap().gpio, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gpio_trigger_pulses_its_line_on_the_shared_board() {
    let (pty, fake) = numato_fake();
    let board = NumatoBoard::new("lamps", &pty.path, 19_200, 0.0);
    let mut bank = RelaySerialBank::new(board.clone(), 8).unwrap();
    let mut trigger = GpioTrigger::new("trigger", board.clone(), 11, 0.03).unwrap();
    bank.set(1, true).await.unwrap();
    trigger.fire(7).await.unwrap();
    trigger.fire(8).await.unwrap();
    let f = fake.lock().unwrap();
    let pulses: Vec<&(Instant, String)> = f
        .log
        .iter()
        .filter(|(_, l)| l.starts_with("gpio"))
        .collect();
    let lines: Vec<&str> = pulses.iter().map(|(_, l)| l.as_str()).collect();
    assert_eq!(
        lines,
        ["gpio set B", "gpio clear B", "gpio set B", "gpio clear B"]
    );
    for pair in pulses.chunks(2) {
        let width = pair[1].0 - pair[0].0;
        assert!(
            width >= Duration::from_millis(30) && width < Duration::from_millis(500),
            "{width:?}"
        );
    }
    assert_eq!(f.gpio, 0);
    assert_eq!(f.relays, 1);
    // One handshake for both users of the board.
    assert_eq!(f.commands(0).iter().filter(|c| *c == "ver").count(), 1);
    drop(f);
    assert!(GpioTrigger::new("trigger", board.clone(), 32, 0.001).is_err());
    assert!(GpioTrigger::new("trigger", board, 1, f64::NAN).is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn switch_laser_powers_its_channel() {
    let (pty, fake) = numato_fake();
    let spec = SwitchBankSpec {
        id: "power".into(),
        backend: Backend::RelaySerial,
        port: Some(pty.path.clone()),
        channels: 4,
        baud: None,
        watchdog_s: 0.0,
    };
    let board = NumatoBoard::from_spec(&spec).unwrap();
    let bank = SwitchBankHandle::spawn(spec, RelaySerialBank::new(board, 4).unwrap());
    let mut laser = SwitchLaser::new("laser", bank.clone(), 3);
    laser.set_emission(true, 520).await.unwrap();
    assert_eq!(fake.lock().unwrap().relays, 0b100);
    assert_eq!(bank.states(), vec![false, false, true, false]);
    laser.fitted(650, 30.0).await.unwrap();
    assert_eq!(fake.lock().unwrap().relays, 0b100);
    laser.set_emission(false, 650).await.unwrap();
    assert_eq!(fake.lock().unwrap().relays, 0);
    let mut bad = SwitchLaser::new("laser", bank, 5);
    let e = bad.set_emission(true, 520).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NoSuchChannel { .. },
                ..
            }
        ),
        "{e}"
    );
}

// ---------------------------------------------------------------- in-memory HID board

#[derive(Default)]
struct HidBoard {
    serial: String,
    mask: u8,
    unplugged: bool,
    reports: Vec<Vec<u8>>,
}

#[derive(Clone, Default)]
struct FakeHid(Arc<Mutex<HidBoard>>);

impl HidTransport for FakeHid {
    fn send_feature_report(&mut self, data: &[u8]) -> io::Result<()> {
        let mut b = self.0.lock().unwrap();
        if b.unplugged {
            return Err(io::Error::other("device unplugged"));
        }
        b.reports.push(data.to_vec());
        // hidapi layout: report id 0, then the 8 data bytes.
        match data {
            [0, 0xFF, ch @ 1..=8, ..] => b.mask |= 1 << (ch - 1),
            [0, 0xFD, ch @ 1..=8, ..] => b.mask &= !(1 << (ch - 1)),
            [0, 0xFE, ..] => b.mask = 0xFF,
            [0, 0xFC, ..] => b.mask = 0,
            _ => {}
        }
        Ok(())
    }

    fn get_feature_report(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let b = self.0.lock().unwrap();
        if b.unplugged {
            return Err(io::Error::other("device unplugged"));
        }
        assert_eq!(buf[0], 0, "report id");
        assert!(buf.len() >= 9);
        buf[1..9].fill(0);
        buf[1..1 + b.serial.len().min(5)]
            .copy_from_slice(&b.serial.as_bytes()[..b.serial.len().min(5)]);
        buf[8] = b.mask;
        Ok(9)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hid_bank_switches_reads_and_restores_after_an_unplug() {
    let fake = FakeHid::default();
    fake.0.lock().unwrap().serial = "ABCDE".into();
    let mut bank = HidRelayBank::new("uv", "emulated", 4, Box::new(fake.clone())).unwrap();
    bank.set(1, true).await.unwrap();
    bank.set(3, true).await.unwrap();
    assert_eq!(fake.0.lock().unwrap().mask, 0b101);
    assert_eq!(
        fake.0.lock().unwrap().reports[0],
        vec![0, 0xFF, 1, 0, 0, 0, 0, 0, 0]
    );
    assert_eq!(
        bank.read_all().await.unwrap(),
        vec![true, false, true, false]
    );
    bank.set(3, false).await.unwrap();
    assert_eq!(
        fake.0.lock().unwrap().reports[2],
        vec![0, 0xFD, 3, 0, 0, 0, 0, 0, 0]
    );
    bank.set(3, true).await.unwrap();
    let e = bank.set(5, true).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::NoSuchChannel { .. },
                ..
            }
        ),
        "{e}"
    );

    // Unplugged: a typed error naming the port; plugged back in after a reset: restored.
    fake.0.lock().unwrap().unplugged = true;
    let e = bank.set(2, true).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Disconnected { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("emulated"), "{e}");
    {
        let mut b = fake.0.lock().unwrap();
        b.unplugged = false;
        b.mask = 0;
        b.reports.clear();
    }
    bank.set(2, true).await.unwrap();
    let b = fake.0.lock().unwrap();
    assert_eq!(b.mask, 0b111);
    let ops: Vec<(u8, u8)> = b.reports.iter().map(|r| (r[1], r[2])).collect();
    assert_eq!(ops, [(0xFF, 1), (0xFF, 3), (0xFF, 2)]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hid_bank_reopens_through_its_opener() {
    let fake = FakeHid::default();
    let opens = Arc::new(AtomicUsize::new(0));
    let opener = {
        let fake = fake.clone();
        let opens = opens.clone();
        Box::new(move || {
            opens.fetch_add(1, Ordering::Relaxed);
            if fake.0.lock().unwrap().unplugged {
                Err(HidOpenError::NotFound {
                    wanted: None,
                    found: Vec::new(),
                })
            } else {
                Ok(Box::new(fake.clone()) as Box<dyn HidTransport + Send>)
            }
        })
    };
    let mut bank = HidRelayBank::with_opener("uv", "usb-hid:test", 2, opener).unwrap();
    assert_eq!(opens.load(Ordering::Relaxed), 0, "opens lazily");
    bank.set(2, true).await.unwrap();
    assert_eq!(opens.load(Ordering::Relaxed), 1);
    bank.set(1, false).await.unwrap();
    assert_eq!(opens.load(Ordering::Relaxed), 1);
    fake.0.lock().unwrap().unplugged = true;
    let e = bank.read_all().await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Disconnected { .. },
                ..
            }
        ),
        "{e}"
    );
    let e = bank.read_all().await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(opens.load(Ordering::Relaxed), 2);
    {
        let mut b = fake.0.lock().unwrap();
        b.unplugged = false;
        b.mask = 0;
    }
    assert_eq!(bank.read_all().await.unwrap(), vec![false, true]);
    assert_eq!(opens.load(Ordering::Relaxed), 3);
    assert!(HidRelayBank::new("uv", "x", 9, Box::new(fake)).is_err());
}

#[test]
fn hid_enumeration_never_panics_and_a_missing_board_is_port_unavailable() {
    let boards = hid_relay::list_hid_relays();
    for b in &boards {
        assert!(!b.path.is_empty());
    }
    // No board has a 6-character serial.
    let e = match HidRelayBank::open("uv", Some("NOSUCH"), 8) {
        Ok(_) => panic!("opened a board with serial NOSUCH"),
        Err(e) => e,
    };
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("NOSUCH"), "{e}");
}

// ---------------------------------------------------------------- fake IR bridge

#[derive(Default)]
struct Bridge {
    /// Words received in `PF hhhh` lines, in order.
    words: Vec<u16>,
    lines: Vec<String>,
    /// Confirm every word as `OK 0000`.
    wrong_ok: bool,
    /// Answer `ver` with this instead of `IRBRIDGE 1.0`.
    banner: Option<String>,
    /// Sent before the next `OK`.
    before_ok: Option<String>,
    line: Vec<u8>,
}

impl Bridge {
    fn on_byte(&mut self, b: u8) -> Vec<u8> {
        if b != b'\n' {
            self.line.push(b);
            return Vec::new();
        }
        let text = String::from_utf8_lossy(&std::mem::take(&mut self.line))
            .trim()
            .to_string();
        self.lines.push(text.clone());
        let reply = if text == "ver" {
            self.banner.clone().unwrap_or_else(|| "IRBRIDGE 1.0".into())
        } else if let Some(hex) = text.strip_prefix("PF ") {
            match u16::from_str_radix(hex, 16) {
                Ok(w) if hex.len() == 4 && hex == hex.to_uppercase() => {
                    let n = |s: u16| (w >> s) & 0xF;
                    if 0xF ^ n(12) ^ n(8) ^ n(4) == n(0) {
                        self.words.push(w);
                        let ok = if self.wrong_ok {
                            "OK 0000".to_string()
                        } else {
                            format!("OK {hex}")
                        };
                        match self.before_ok.take() {
                            Some(pre) => format!("{pre}\n{ok}"),
                            None => ok,
                        }
                    } else {
                        format!("ERR checksum {hex}")
                    }
                }
                _ => "ERR syntax".into(),
            }
        } else {
            "ERR syntax".into()
        };
        format!("{reply}\n").into_bytes()
    }
}

fn bridge_fake() -> (Pty, Arc<Mutex<Bridge>>) {
    let state = Arc::new(Mutex::new(Bridge::default()));
    let s = state.clone();
    (run_fake(move |b| s.lock().unwrap().on_byte(b)), state)
}

fn cart(path: &str) -> IrBridgeCart {
    IrBridgeCart::new("cart", path, 9600, 2, Output::B, 5).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cart_sends_toggling_pf_words_and_stops_with_brake_then_float() {
    let (pty, fake) = bridge_fake();
    let mut cart = cart(&pty.path);
    cart.drive(Drive::Forward).await.unwrap();
    cart.drive(Drive::Stop).await.unwrap();
    cart.drive(Drive::Reverse).await.unwrap();
    cart.drive(Drive::Stop).await.unwrap();
    let f = fake.lock().unwrap();
    assert_eq!(f.lines[0], "ver");
    assert_eq!(f.lines.iter().filter(|l| *l == "ver").count(), 1);
    let words = &f.words;
    assert_eq!(words.len(), 6);
    for w in words {
        // Channel 2 (CC = 01), escape 0, address 0, single output B (mode 101).
        assert_eq!((w >> 12) & 0b0111, 0b0001, "{w:04X}");
        assert_eq!((w >> 8) & 0xF, 0b0101, "{w:04X}");
    }
    let data: Vec<u16> = words.iter().map(|w| (w >> 4) & 0xF).collect();
    // Forward step 5, brake, float, backward step 5 (= 1011), brake, float.
    assert_eq!(data, [5, 8, 0, 0b1011, 8, 0]);
    for pair in words.windows(2) {
        assert_ne!(
            pair[0] & 0x8000,
            pair[1] & 0x8000,
            "toggle bit did not flip"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn end_stops_refuse_driving_further_until_driven_back() {
    let (pty, fake) = bridge_fake();
    let mut cart = cart(&pty.path);
    cart.drive(Drive::Forward).await.unwrap();
    // The cart closes its + switch while idle: the next forward drive is refused unsent.
    pty.send(b"END +\n");
    tokio::time::sleep(Duration::from_millis(100)).await;
    let sent = fake.lock().unwrap().words.len();
    let e = cart.drive(Drive::Forward).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::EndStop { end: "+ end", .. },
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(fake.lock().unwrap().words.len(), sent);
    cart.drive(Drive::Stop).await.unwrap();
    cart.drive(Drive::Reverse).await.unwrap();
    cart.drive(Drive::Forward).await.unwrap();

    // The − switch closes while the bridge confirms a reverse drive: surfaced at once.
    fake.lock().unwrap().before_ok = Some("END -".into());
    let e = cart.drive(Drive::Reverse).await.unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::EndStop { end: "- end", .. },
                ..
            }
        ),
        "{e}"
    );
    // The OK after the END line was consumed: stopping works and the link stays up.
    cart.drive(Drive::Stop).await.unwrap();
    let sent = fake.lock().unwrap().words.len();
    assert!(cart.drive(Drive::Reverse).await.is_err());
    assert_eq!(fake.lock().unwrap().words.len(), sent);
    assert_eq!(
        fake.lock()
            .unwrap()
            .lines
            .iter()
            .filter(|l| *l == "ver")
            .count(),
        1
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_confirmation_is_a_protocol_error_and_the_next_drive_reconnects() {
    let (pty, fake) = bridge_fake();
    let mut cart = cart(&pty.path);
    fake.lock().unwrap().wrong_ok = true;
    let e = cart.drive(Drive::Forward).await.unwrap_err();
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
    assert!(e.to_string().contains("OK 0000"), "{e}");
    fake.lock().unwrap().wrong_ok = false;
    cart.drive(Drive::Stop).await.unwrap();
    let f = fake.lock().unwrap();
    assert_eq!(f.lines.iter().filter(|l| *l == "ver").count(), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_that_is_no_bridge_fails_the_handshake() {
    let (pty, fake) = bridge_fake();
    fake.lock().unwrap().banner = Some("Grbl 1.1h ['$' for help]".into());
    let mut cart = cart(&pty.path);
    // A refused handshake, not a hang (how quickly is the driver's timeout, not a test bound).
    let e = cart.drive(Drive::Forward).await.unwrap_err();
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
    assert!(e.to_string().contains("IRBRIDGE"), "{e}");
    assert!(fake.lock().unwrap().words.is_empty());
    assert!(IrBridgeCart::new("cart", &pty.path, 9600, 5, Output::A, 7).is_err());
    assert!(IrBridgeCart::new("cart", &pty.path, 9600, 1, Output::A, 0).is_err());
    let e = IrBridgeCart::new("cart", "/dev/serial/by-id/no-bridge", 9600, 1, Output::A, 7)
        .unwrap()
        .drive(Drive::Stop)
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            }
        ),
        "{e}"
    );
}
