//! The HID relay switch-bank driver. hidapi calls block, so the transport lives on its own
//! std thread and the async driver sends it requests over a channel, waiting for each reply
//! with a timeout. The transport is a trait so the simulator can plug in an emulated board.
//!
//! Relay states set through the driver are remembered; after an I/O failure the transport is
//! reopened on the next request, the board's states are read back and any that a reset lost
//! are re-sent before the request goes out.

use std::ffi::CString;
use std::io;
use std::sync::mpsc;

use thiserror::Error;
use tokio::sync::oneshot;

use super::codec::{
    self, HidCommand, HidState, MAX_CHANNELS, PRODUCT_ID, REPORT_ID, REPORT_LEN, VENDOR_ID,
};
use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::switch_bank::SwitchBankDriver;

/// Longest wait for the transport thread to answer one request.
const REQUEST_TIMEOUT_S: f64 = 0.5;

/// Feature-report access to one board, shaped like hidapi: every buffer starts with the report
/// id (0 for these boards) followed by the 8 data bytes, and `get_feature_report` returns the
/// number of bytes filled including the report id (9). Calls may block briefly.
pub trait HidTransport {
    /// Sends a feature report: `data` is the report id 0 and 8 data bytes.
    fn send_feature_report(&mut self, data: &[u8]) -> io::Result<()>;
    /// Reads the feature report into `buf` (9 bytes, `buf[0]` = report id 0 on entry); returns
    /// the bytes filled, report id included.
    fn get_feature_report(&mut self, buf: &mut [u8]) -> io::Result<usize>;
}

/// A board found by [`list_hid_relays`] (for `stagehand devices`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HidRelayInfo {
    /// The hidraw device node, e.g. `/dev/hidraw3`.
    pub path: String,
    /// The board's 5-character serial, `None` if the board could not be opened (permissions).
    pub serial: Option<String>,
    /// Relays according to the product string `USBRelayN`, if it says.
    pub channels: Option<u32>,
}

/// Every dcttech-compatible relay board on the USB buses. Never panics: without access to
/// `/dev/hidraw*` or sysfs the list is just shorter or empty.
pub fn list_hid_relays() -> Vec<HidRelayInfo> {
    std::panic::catch_unwind(|| enumerate().into_iter().map(|(info, _)| info).collect())
        .unwrap_or_default()
}

/// The boards and, for those that opened, their transport.
fn enumerate() -> Vec<(HidRelayInfo, Option<HidapiTransport>)> {
    let Ok(api) = hidapi::HidApi::new() else {
        return Vec::new();
    };
    let mut seen: Vec<CString> = Vec::new();
    let mut boards = Vec::new();
    for dev in api.device_list() {
        if dev.vendor_id() != VENDOR_ID || dev.product_id() != PRODUCT_ID {
            continue;
        }
        if seen.iter().any(|p| p.as_c_str() == dev.path()) {
            continue;
        }
        seen.push(dev.path().to_owned());
        let mut transport = dev
            .open_device(&api)
            .ok()
            .map(|device| HidapiTransport { device });
        let serial = transport
            .as_mut()
            .and_then(|t| read_state(t))
            .map(|s| s.serial);
        if serial.is_none() {
            transport = None;
        }
        boards.push((
            HidRelayInfo {
                path: dev.path().to_string_lossy().into_owned(),
                serial,
                channels: dev.product_string().and_then(codec::channels_from_product),
            },
            transport,
        ));
    }
    boards
}

/// The state report of a board through any transport; `None` if it cannot be read.
fn read_state(t: &mut dyn HidTransport) -> Option<HidState> {
    let mut buf = [0u8; REPORT_LEN + 1];
    buf[0] = REPORT_ID;
    let n = t.get_feature_report(&mut buf).ok()?;
    HidState::parse(codec::data_of(&buf, n).ok()?).ok()
}

/// Why no board could be opened.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum HidOpenError {
    /// hidapi panicked while listing devices.
    #[error("enumerating USB HID devices failed (panic in hidapi); check /sys and /dev/hidraw*")]
    Enumerate,
    /// The board is there but this user may not open it.
    #[error(
        "found the board at {0} but cannot open it; add a udev rule giving your user access to it (e.g. SUBSYSTEM==\"hidraw\", ATTRS{{idVendor}}==\"16c0\", ATTRS{{idProduct}}==\"05df\", MODE=\"0660\", GROUP=\"plugdev\")"
    )]
    NoAccess(String),
    /// No board matches `wanted` (a serial or path; `None`: any board); `found` lists the
    /// boards there are (`path (serial …)`).
    #[error("{}", not_found(.wanted.as_deref(), .found))]
    NotFound {
        /// The serial or path asked for.
        wanted: Option<String>,
        /// The boards found instead.
        found: Vec<String>,
    },
}

/// The message of [`HidOpenError::NotFound`].
fn not_found(wanted: Option<&str>, found: &[String]) -> String {
    let what = match wanted {
        Some(w) => format!("no USB relay board (16c0:05df) with serial or path `{w}`"),
        None => "no USB relay board (16c0:05df) found".to_string(),
    };
    if found.is_empty() {
        format!("{what}; check the USB cable, `lsusb` and access to /dev/hidraw*")
    } else {
        format!("{what}; found: {}", found.join(", "))
    }
}

/// The real transport: a hidraw device through hidapi.
pub struct HidapiTransport {
    device: hidapi::HidDevice,
}

impl HidapiTransport {
    /// Opens a board: `selector` is its 5-character serial, a `/dev/hidrawN` path, or `None`
    /// for the first board found. Returns the transport and what was opened, or a message
    /// saying what was found instead.
    pub fn open(selector: Option<&str>) -> Result<(Self, HidRelayInfo), HidOpenError> {
        let want = selector.map(str::trim).filter(|s| !s.is_empty());
        let boards = std::panic::catch_unwind(enumerate).map_err(|_| HidOpenError::Enumerate)?;
        let mut found = Vec::new();
        for (info, transport) in boards {
            let hit = match want {
                None => true,
                Some(w) if w.starts_with('/') => info.path == w,
                Some(w) => info.serial.as_deref() == Some(w),
            };
            match (hit, transport) {
                (true, Some(t)) => return Ok((t, info)),
                (true, None) => return Err(HidOpenError::NoAccess(info.path)),
                (false, _) => found.push(format!(
                    "{} (serial {})",
                    info.path,
                    info.serial.as_deref().unwrap_or("unreadable")
                )),
            }
        }
        Err(HidOpenError::NotFound {
            wanted: want.map(str::to_string),
            found,
        })
    }
}

impl HidTransport for HidapiTransport {
    fn send_feature_report(&mut self, data: &[u8]) -> io::Result<()> {
        self.device.send_feature_report(data).map_err(hid_io)
    }

    fn get_feature_report(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.device.get_feature_report(buf).map_err(hid_io)
    }
}

fn hid_io(e: hidapi::HidError) -> io::Error {
    match e {
        hidapi::HidError::IoError { error } => error,
        other => io::Error::other(other.to_string()),
    }
}

/// Opens (or reopens) the transport; an error is the reason, reported as `PortUnavailable`.
pub type HidOpener = Box<dyn FnMut() -> Result<Box<dyn HidTransport + Send>, HidOpenError> + Send>;

enum Request {
    Set(u32, bool),
    Read,
}

type Job = (Request, oneshot::Sender<DeviceResult<Vec<bool>>>);

/// The switch-bank driver of a dcttech HID relay board.
pub struct HidRelayBank {
    device: String,
    channels: u32,
    jobs: mpsc::Sender<Job>,
}

impl HidRelayBank {
    /// A bank `device` of `channels` relays over `transport` (an emulated board, say). `port`
    /// names the transport in errors. After an I/O error the same transport is tried again
    /// on the next request.
    pub fn new(
        device: &str,
        port: &str,
        channels: u32,
        transport: Box<dyn HidTransport + Send>,
    ) -> DeviceResult<Self> {
        Self::spawn(device, port, channels, Some(transport), None)
    }

    /// Like [`HidRelayBank::new`], but the transport is opened by `opener` on the first
    /// request and reopened by it after every I/O error.
    pub fn with_opener(
        device: &str,
        port: &str,
        channels: u32,
        opener: HidOpener,
    ) -> DeviceResult<Self> {
        Self::spawn(device, port, channels, None, Some(opener))
    }

    /// The real board: `serial` is its 5-character serial (as `stagehand devices` lists it), a
    /// `/dev/hidrawN` path, or `None` for the first board found. Opens it now, so a missing
    /// board is a `PortUnavailable` error at once; later failures reopen the same serial.
    pub fn open(device: &str, serial: Option<&str>, channels: u32) -> DeviceResult<Self> {
        let label = format!("usb-hid:{}", serial.unwrap_or("16c0:05df"));
        let (transport, info) = HidapiTransport::open(serial).map_err(|reason| {
            DeviceError::new(
                device.to_string(),
                DeviceErrorKind::PortUnavailable {
                    port: label.clone(),
                    reason: reason.to_string(),
                },
            )
        })?;
        if let Some(n) = info.channels.filter(|&n| n != channels) {
            tracing::warn!(device, path = %info.path, "the board says it has {n} relays, the rig file {channels}");
        }
        let pin = info
            .serial
            .clone()
            .filter(|s| !s.is_empty() && !s.contains('?'));
        let port = match &pin {
            Some(s) => format!("usb-hid:{s} ({})", info.path),
            None => format!("usb-hid:{}", info.path),
        };
        let reopen = pin.unwrap_or(info.path);
        let opener: HidOpener = Box::new(move || {
            HidapiTransport::open(Some(&reopen))
                .map(|(t, _)| Box::new(t) as Box<dyn HidTransport + Send>)
        });
        Self::spawn(
            device,
            &port,
            channels,
            Some(Box::new(transport)),
            Some(opener),
        )
    }

    fn spawn(
        device: &str,
        port: &str,
        channels: u32,
        transport: Option<Box<dyn HidTransport + Send>>,
        opener: Option<HidOpener>,
    ) -> DeviceResult<Self> {
        if channels == 0 || channels > MAX_CHANNELS {
            return Err(DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Other {
                    message: format!(
                        "a USB HID relay board has 1 to {MAX_CHANNELS} channels, the rig file says {channels}"
                    ),
                },
            ));
        }
        let (jobs, rx) = mpsc::channel::<Job>();
        let mut worker = Worker {
            device: device.to_string(),
            port: port.to_string(),
            channels,
            transport,
            opener,
            failed: false,
            wanted: [None; MAX_CHANNELS as usize],
        };
        std::thread::Builder::new()
            .name(format!("hid-relay {device}"))
            .spawn(move || {
                // It switches the trigger line: raised like the runtime's threads.
                crate::realtime::raise_this_thread();
                while let Ok((req, reply)) = rx.recv() {
                    let _ = reply.send(worker.handle(req));
                }
            })
            .map_err(|e| {
                DeviceError::new(
                    device.to_string(),
                    DeviceErrorKind::Other {
                        message: format!("cannot start the USB HID thread: {e}"),
                    },
                )
            })?;
        Ok(Self {
            device: device.to_string(),
            channels,
            jobs,
        })
    }

    async fn request(&self, req: Request, what: &str) -> DeviceResult<Vec<bool>> {
        let gone = || DeviceError::new(self.device.clone(), DeviceErrorKind::Gone);
        let (reply, rx) = oneshot::channel();
        self.jobs.send((req, reply)).map_err(|_| gone())?;
        match tokio::time::timeout(duration_s(REQUEST_TIMEOUT_S), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(gone()),
            Err(_) => Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Timeout {
                    request: what.to_string(),
                    timeout_s: REQUEST_TIMEOUT_S,
                },
            )),
        }
    }
}

impl SwitchBankDriver for HidRelayBank {
    async fn set(&mut self, channel: u32, on: bool) -> DeviceResult<()> {
        if channel == 0 || channel > self.channels {
            return Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::NoSuchChannel {
                    channel,
                    channels: self.channels,
                },
            ));
        }
        let what = format!("relay {channel} {}", if on { "on" } else { "off" });
        self.request(Request::Set(channel, on), &what)
            .await
            .map(|_| ())
    }

    async fn read_all(&mut self) -> DeviceResult<Vec<bool>> {
        self.request(Request::Read, "read relay states").await
    }
}

/// The transport thread's state.
struct Worker {
    device: String,
    port: String,
    channels: u32,
    transport: Option<Box<dyn HidTransport + Send>>,
    opener: Option<HidOpener>,
    /// An I/O error happened since the last good request: restore states before the next.
    failed: bool,
    wanted: [Option<bool>; MAX_CHANNELS as usize],
}

impl Worker {
    fn handle(&mut self, req: Request) -> DeviceResult<Vec<bool>> {
        if self.transport.is_none() {
            let opener = self
                .opener
                .as_mut()
                .ok_or_else(|| DeviceError::new(self.device.clone(), DeviceErrorKind::Gone))?;
            let t = opener().map_err(|reason| {
                DeviceError::new(
                    self.device.clone(),
                    DeviceErrorKind::PortUnavailable {
                        port: self.port.clone(),
                        reason: reason.to_string(),
                    },
                )
            })?;
            self.transport = Some(t);
        }
        let r = self.failed_restore().and_then(|()| match req {
            Request::Set(ch, on) => {
                let cmd = if on {
                    HidCommand::On(ch as u8)
                } else {
                    HidCommand::Off(ch as u8)
                };
                self.send(cmd)?;
                if let Some(slot) = self.wanted.get_mut(ch as usize - 1) {
                    *slot = Some(on);
                }
                Ok(Vec::new())
            }
            Request::Read => Ok(self.state()?.channels(self.channels)),
        });
        if let Err(DeviceError {
            kind: DeviceErrorKind::Disconnected { .. },
            ..
        }) = &r
        {
            self.failed = true;
            if self.opener.is_some() {
                self.transport = None;
            }
        }
        r
    }

    /// After a failure: reads the board and re-sends every state we set that it lost.
    fn failed_restore(&mut self) -> DeviceResult<()> {
        if !self.failed {
            return Ok(());
        }
        let wanted: Vec<(u32, bool)> = self
            .wanted
            .iter()
            .enumerate()
            .filter_map(|(i, w)| w.map(|on| (i as u32 + 1, on)))
            .collect();
        if !wanted.is_empty() {
            let actual = self.state()?.channels(MAX_CHANNELS);
            let lost: Vec<(u32, bool)> = wanted
                .into_iter()
                .filter(|&(ch, on)| actual.get(ch as usize - 1) != Some(&on))
                .collect();
            if lost.is_empty() {
                tracing::info!(device = %self.device, port = %self.port, "USB relay board back; relay states intact");
            } else {
                tracing::warn!(
                    device = %self.device,
                    port = %self.port,
                    channels = ?lost,
                    "USB relay board back with relays in other states than we set (did it reset?); restoring them"
                );
                for (ch, on) in lost {
                    let cmd = if on {
                        HidCommand::On(ch as u8)
                    } else {
                        HidCommand::Off(ch as u8)
                    };
                    self.send(cmd)?;
                }
            }
        }
        self.failed = false;
        Ok(())
    }

    fn transport(&mut self) -> DeviceResult<&mut (dyn HidTransport + Send)> {
        match self.transport.as_deref_mut() {
            Some(t) => Ok(t),
            None => Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Disconnected {
                    port: self.port.clone(),
                    reason: "the board is not open".into(),
                },
            )),
        }
    }

    fn lost(&self, e: impl std::fmt::Display) -> DeviceError {
        DeviceError::new(
            self.device.clone(),
            DeviceErrorKind::Disconnected {
                port: self.port.clone(),
                reason: e.to_string(),
            },
        )
    }

    fn send(&mut self, cmd: HidCommand) -> DeviceResult<()> {
        let buf = codec::with_report_id(cmd.encode());
        self.transport()?
            .send_feature_report(&buf)
            .map_err(|e| self.lost(format!("sending {cmd:?} failed: {e}")))
    }

    fn state(&mut self) -> DeviceResult<HidState> {
        let mut buf = [0u8; REPORT_LEN + 1];
        buf[0] = REPORT_ID;
        let n = self
            .transport()?
            .get_feature_report(&mut buf)
            .map_err(|e| self.lost(format!("reading the relay states failed: {e}")))?;
        let data = codec::data_of(&buf, n).map_err(|e| self.protocol(e.to_string()))?;
        HidState::parse(data).map_err(|e| self.protocol(e.to_string()))
    }

    fn protocol(&self, message: String) -> DeviceError {
        DeviceError::new(
            self.device.clone(),
            DeviceErrorKind::Protocol {
                port: self.port.clone(),
                message,
            },
        )
    }
}
