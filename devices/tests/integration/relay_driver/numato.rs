//! The Numato-style relay board (`NumatoBoard`, `RelaySerialBank`) and what is wired to it
//! (`GpioTrigger`, `SwitchLaser`) against a fake board: a task on a duplex stream, on tokio's
//! paused clock, except the pty smoke test (`switch_laser_powers_its_channel`).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use stagehand_devices::laser::LaserDriver;
use stagehand_devices::relay_serial::{NumatoBoard, RelaySerialBank};
use stagehand_devices::rig::{Backend, SwitchBankSpec};
use stagehand_devices::switch_bank::{SwitchBankDriver, SwitchBankHandle};
use stagehand_devices::switch_wired::{GpioTrigger, SwitchLaser};
use stagehand_devices::trigger::TriggerDriver;
use stagehand_devices::{DeviceError, DeviceErrorKind};
use tokio::time::Instant;

use crate::fake_port::{ByteFake, Port, duplex_port, pty_port};

/// What the duplex fake's port is called in errors.
const PORT: &str = "fake:numato";

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

/// A fake board serving a port; it stops when dropped.
struct FakeBoard {
    port: Port,
    _fake: ByteFake,
}

impl FakeBoard {
    /// The driver of board `lamps` on this port, with a watchdog of `watchdog_s`.
    fn board(&self, watchdog_s: f64) -> Arc<NumatoBoard> {
        NumatoBoard::with_transport("lamps", PORT, self.port.opener(), watchdog_s)
    }
}

/// A fake board on a duplex port, and its state.
fn numato_fake() -> (FakeBoard, Arc<Mutex<Numato>>) {
    let state = Arc::new(Mutex::new(Numato::default()));
    let s = state.clone();
    let (port, device) = duplex_port();
    let fake = ByteFake::spawn(device, move |b| s.lock().unwrap().on_byte(b));
    (FakeBoard { port, _fake: fake }, state)
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

#[tokio::test(start_paused = true)]
async fn relay_bank_switches_reads_and_restores_states_after_a_board_reset() {
    let (dev, fake) = numato_fake();
    let board = dev.board(0.0);
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

#[tokio::test(start_paused = true)]
async fn a_board_that_is_not_numato_or_silent_or_missing_is_a_typed_error() {
    let (dev, fake) = numato_fake();
    fake.lock().unwrap().version = Some("Grbl 1.1h".into());
    let board = dev.board(0.0);
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
    let board = silent.board(0.0);
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

#[tokio::test(start_paused = true)]
async fn keepalive_renews_the_watchdog_while_idle_and_ends_with_the_board() {
    let (dev, fake) = numato_fake();
    // Watchdog 0.3 s: a keepalive every 0.1 s while idle.
    let board = dev.board(0.3);
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
    // Idle: a keepalive 0.1 s after the last activity, each renewing it: at 0.1, 0.2, ... 0.6 s.
    tokio::time::sleep(Duration::from_millis(650)).await;
    let n = count("ver") - 1;
    assert_eq!(n, 6, "{n} keepalives in 0.65 s");
    assert_eq!(count("relay readall"), 0);
    // Every command counts as activity: busy, the board gets no keepalive.
    let before = count("ver");
    for _ in 0..10 {
        board.set_relay(1, false).await.unwrap();
        tokio::time::sleep(Duration::from_millis(30)).await;
    }
    assert_eq!(
        count("ver") - before,
        0,
        "{} keepalives while busy",
        count("ver") - before
    );
    // While a relay is on the keepalive reads the relays back instead.
    board.set_relay(1, true).await.unwrap();
    let vers = count("ver");
    tokio::time::sleep(Duration::from_millis(350)).await;
    assert_eq!(count("ver") - vers, 0);
    // At 0.1, 0.2 and 0.3 s.
    assert_eq!(count("relay readall"), 3);
    let after = fake.lock().unwrap().log.len();
    drop(board);
    tokio::time::sleep(Duration::from_millis(550)).await;
    assert_eq!(
        fake.lock().unwrap().log.len(),
        after,
        "the keepalive outlived the board"
    );
    assert_eq!(fake.lock().unwrap().relays, 0b10);
}

#[tokio::test(start_paused = true)]
async fn a_silent_reset_is_found_restored_and_reported_once() {
    let (dev, fake) = numato_fake();
    let board = dev.board(0.3);
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

#[tokio::test(start_paused = true)]
async fn the_trigger_refuses_to_fire_into_lamps_a_reset_switched_off() {
    let (dev, fake) = numato_fake();
    // No keepalive: only the check before the pulse can notice.
    let board = dev.board(0.0);
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

#[tokio::test(start_paused = true)]
async fn gpio_trigger_pulses_its_line_on_the_shared_board() {
    let (dev, fake) = numato_fake();
    let board = dev.board(0.0);
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
        // Exactly the 30 ms asked for, on the paused clock.
        let width = pair[1].0 - pair[0].0;
        assert_eq!(width, Duration::from_millis(30));
    }
    assert_eq!(f.gpio, 0);
    assert_eq!(f.relays, 1);
    // One handshake for both users of the board.
    assert_eq!(f.commands(0).iter().filter(|c| *c == "ver").count(), 1);
    drop(f);
    assert!(GpioTrigger::new("trigger", board.clone(), 32, 0.001).is_err());
    assert!(GpioTrigger::new("trigger", board, 1, f64::NAN).is_err());
}

/// The pty smoke test: the board's serial path, from the rig file's port, over a real
/// pseudo-terminal on the real clock (no timing asserted).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn switch_laser_powers_its_channel() {
    let fake = Arc::new(Mutex::new(Numato::default()));
    let (path, device, _slave) = pty_port();
    let _board = {
        let fake = fake.clone();
        ByteFake::spawn(device, move |b| fake.lock().unwrap().on_byte(b))
    };
    let spec = SwitchBankSpec {
        id: "power".into(),
        backend: Backend::RelaySerial,
        port: Some(path),
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
