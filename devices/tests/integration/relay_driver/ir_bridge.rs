//! The LEGO cart behind the serial IR bridge (`IrBridgeCart`) against a fake bridge: a task on
//! a duplex stream, on tokio's paused clock, except the pty smoke test
//! (`cart_sends_toggling_pf_words_and_stops_with_brake_then_float`).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use stagehand_devices::cart::{CartDriver, Drive};
use stagehand_devices::ir_cart::{IrBridgeCart, Output};
use stagehand_devices::{DeviceError, DeviceErrorKind};

use crate::fake_port::{ByteFake, Port, duplex_port, pty_port};

/// What the duplex fake's port is called in errors.
const PORT: &str = "fake:ir-bridge";

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

/// A fake bridge serving a port; it stops when dropped.
struct FakeBridge {
    port: Port,
    fake: ByteFake,
}

impl FakeBridge {
    /// The cart on PF channel 2, output B, step 5, behind this bridge.
    fn cart(&self) -> IrBridgeCart {
        IrBridgeCart::with_transport("cart", PORT, self.port.opener(), 2, Output::B, 5).unwrap()
    }

    /// Makes the bridge send `bytes` unsolicited.
    fn send(&self, bytes: &[u8]) {
        self.fake.send(bytes);
    }
}

/// A fake bridge on a duplex port, and its state.
fn bridge_fake() -> (FakeBridge, Arc<Mutex<Bridge>>) {
    let state = Arc::new(Mutex::new(Bridge::default()));
    let s = state.clone();
    let (port, device) = duplex_port();
    let fake = ByteFake::spawn(device, move |b| s.lock().unwrap().on_byte(b));
    (FakeBridge { port, fake }, state)
}

/// The pty smoke test: the cart's serial path over a real pseudo-terminal on the real clock
/// (no timing asserted).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cart_sends_toggling_pf_words_and_stops_with_brake_then_float() {
    let fake = Arc::new(Mutex::new(Bridge::default()));
    let (path, device, _slave) = pty_port();
    let _bridge = {
        let fake = fake.clone();
        ByteFake::spawn(device, move |b| fake.lock().unwrap().on_byte(b))
    };
    let mut cart = IrBridgeCart::new("cart", &path, 9600, 2, Output::B, 5).unwrap();
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

#[tokio::test(start_paused = true)]
async fn end_stops_refuse_driving_further_until_driven_back() {
    let (dev, fake) = bridge_fake();
    let mut cart = dev.cart();
    cart.drive(Drive::Forward).await.unwrap();
    // The cart closes its + switch while idle: the next forward drive is refused unsent.
    dev.send(b"END +\n");
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

#[tokio::test(start_paused = true)]
async fn a_wrong_confirmation_is_a_protocol_error_and_the_next_drive_reconnects() {
    let (dev, fake) = bridge_fake();
    let mut cart = dev.cart();
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

#[tokio::test(start_paused = true)]
async fn a_port_that_is_no_bridge_fails_the_handshake() {
    let (dev, fake) = bridge_fake();
    fake.lock().unwrap().banner = Some("Grbl 1.1h ['$' for help]".into());
    let mut cart = dev.cart();
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
    assert!(
        IrBridgeCart::with_transport("cart", PORT, dev.port.opener(), 5, Output::A, 7).is_err()
    );
    assert!(
        IrBridgeCart::with_transport("cart", PORT, dev.port.opener(), 1, Output::A, 0).is_err()
    );
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
