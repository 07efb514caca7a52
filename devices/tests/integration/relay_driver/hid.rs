//! The dcttech USB HID relay bank against an in-memory board (`HidTransport`). The driver does
//! its blocking hidapi calls on a std thread, invisible to tokio's paused clock, so these tests
//! run on the real clock; none of them asserts a timing.

use std::io;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use stagehand_devices::hid_relay::{self, HidOpenError, HidRelayBank, HidTransport};
use stagehand_devices::switch_bank::SwitchBankDriver;
use stagehand_devices::{DeviceError, DeviceErrorKind};

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
