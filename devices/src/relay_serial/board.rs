//! One Numato-style relay board on one serial port, shared by everything wired to it (the
//! relay bank, a GPIO trigger) through an `Arc`, plus the switch-bank driver on top of it.
//!
//! The link opens lazily with a `ver` handshake on first use and again after any failure. A
//! keepalive task renews the board's watchdog while idle. Relay states set through the board
//! are remembered and compared with `relay readall` after a reconnect, by the keepalive while
//! a relay is on, and before every trigger pulse; states the board lost (a reset, a lapsed
//! watchdog) are re-sent. A loss found without a reconnect is reported as an error on the
//! next request, because whatever the relays powered was off for a while.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Weak};

use tokio::sync::{Mutex, MutexGuard};
use tokio::time::Instant;

use super::codec::{self, Command, MAX_INDEX};
use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::{RELAY_SERIAL_BAUD, SwitchBankSpec};
use crate::serial_link::{SerialLink, TransportOpener};
use crate::switch_bank::SwitchBankDriver;

/// Longest wait for the board's answer to one command.
const COMMAND_TIMEOUT_S: f64 = 0.5;
/// Wait for the prompt after the bare `\r` that clears a half-received line at the board.
const FLUSH_TIMEOUT_S: f64 = 0.1;
/// Shortest keepalive period, whatever the watchdog says.
const MIN_KEEPALIVE_S: f64 = 0.05;
/// Relays a board can have (channel characters `0`–`V`).
const RELAYS: usize = MAX_INDEX as usize + 1;

/// A Numato-style board on one port; share it as `Arc<NumatoBoard>` between the relay bank
/// and the GPIO trigger so they take turns on the one link.
pub struct NumatoBoard {
    device: String,
    port: String,
    watchdog_s: f64,
    me: Weak<NumatoBoard>,
    inner: Mutex<Inner>,
    epoch: Instant,
    /// Microseconds since `epoch` of the last command (ours or the keepalive's).
    last_activity_us: AtomicU64,
    keepalive_started: AtomicBool,
    connects: AtomicU64,
}

struct Inner {
    link: SerialLink,
    /// The link is open and answered the handshake.
    ready: bool,
    /// Relay states last set successfully through this board, by relay index.
    wanted: [Option<bool>; RELAYS],
    /// Relays the keepalive found in the wrong state (and restored), not yet reported.
    lost: Option<String>,
}

impl NumatoBoard {
    /// A board `device` (the bank's id, used in errors) on `port` at `baud`, not yet opened.
    /// `watchdog_s` is the board's lease; a keepalive goes out at a third of it while idle
    /// (0 or less: no keepalive).
    pub fn new(device: &str, port: &str, baud: u32, watchdog_s: f64) -> Arc<Self> {
        Self::over(SerialLink::new(device, port, baud), watchdog_s)
    }

    /// Like [`NumatoBoard::new`], over the streams `open` hands it (one per connect) instead
    /// of a serial port; `port` names them in errors. Lets a test run a fake board on the
    /// other end of `tokio::io::duplex`, on tokio's paused clock.
    pub fn with_transport(
        device: &str,
        port: &str,
        open: TransportOpener,
        watchdog_s: f64,
    ) -> Arc<Self> {
        Self::over(SerialLink::with_transport(device, port, open), watchdog_s)
    }

    fn over(link: SerialLink, watchdog_s: f64) -> Arc<Self> {
        Arc::new_cyclic(|me| NumatoBoard {
            device: link.device().to_string(),
            port: link.path().to_string(),
            watchdog_s,
            me: me.clone(),
            inner: Mutex::new(Inner {
                link,
                ready: false,
                wanted: [None; RELAYS],
                lost: None,
            }),
            epoch: Instant::now(),
            last_activity_us: AtomicU64::new(0),
            keepalive_started: AtomicBool::new(false),
            connects: AtomicU64::new(0),
        })
    }

    /// The board of a `relay-serial` switch bank: its port, baud (default 19200) and watchdog.
    pub fn from_spec(spec: &SwitchBankSpec) -> DeviceResult<Arc<Self>> {
        let port = spec.port.as_deref().ok_or_else(|| DeviceError::new(spec.id.clone(), DeviceErrorKind::Other { message: "a relay-serial bank needs `port = \"/dev/serial/by-id/...\"` in the rig file"
                .into() }))?;
        Ok(Self::new(
            &spec.id,
            port,
            spec.baud.unwrap_or(RELAY_SERIAL_BAUD),
            spec.watchdog_s,
        ))
    }

    /// Name used in errors (the bank's id).
    pub fn device(&self) -> &str {
        &self.device
    }

    /// The serial port path.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// How many times the link has been opened and handshaken (1 after the first use).
    pub fn connects(&self) -> u64 {
        self.connects.load(Ordering::Relaxed)
    }

    /// Sends `cmd` (connecting first if needed) and returns its reply text, if it has one.
    /// Any failure closes the link; the next command reconnects.
    pub async fn command(&self, cmd: Command) -> DeviceResult<Option<String>> {
        let mut inner = self.lock().await;
        self.run(&mut inner, cmd).await
    }

    /// The firmware version (`ver`).
    pub async fn version(&self) -> DeviceResult<String> {
        let text = self.reply_text(Command::Ver).await?;
        codec::parse_version(&text).map_err(|e| self.protocol(e.to_string()))
    }

    /// Switches relay `relay` (from 0, as the board numbers them) on or off, and remembers the
    /// state so that it is restored after a reconnect.
    pub async fn set_relay(&self, relay: u32, on: bool) -> DeviceResult<()> {
        let cmd = if on {
            Command::RelayOn(relay)
        } else {
            Command::RelayOff(relay)
        };
        let mut inner = self.lock().await;
        self.run(&mut inner, cmd).await?;
        if let Some(slot) = inner.wanted.get_mut(relay as usize) {
            *slot = Some(on);
        }
        Ok(())
    }

    /// Reads the states of relays `0..relays` with `relay readall`, relay 0 first.
    pub async fn read_relays(&self, relays: u32) -> DeviceResult<Vec<bool>> {
        let text = self.reply_text(Command::RelayReadAll).await?;
        codec::parse_mask(&text, relays).map_err(|e| self.protocol(e.to_string()))
    }

    /// Checks that every relay is as last set (nothing to check while all are off: a reset
    /// only switches relays off). Relays in the wrong state are restored and the call fails
    /// with a `Protocol` error, because what they power was off for a while. The GPIO
    /// trigger calls this before every pulse.
    pub async fn verify_relays(&self) -> DeviceResult<()> {
        let mut inner = self.lock().await;
        if inner.lost.is_none() && !inner.wanted.contains(&Some(true)) {
            return Ok(());
        }
        if let Some(lost) = inner.lost.take() {
            return Err(self.protocol(lost));
        }
        if !inner.ready || !inner.link.is_open() {
            self.connect(&mut inner).await?;
        }
        match self.restore_lost(&mut inner).await {
            Ok(None) => Ok(()),
            Ok(Some(lost)) => Err(self.protocol(lost)),
            Err(e) => {
                inner.link.close();
                inner.ready = false;
                Err(e)
            }
        }
    }

    /// Drives GPIO line `line` (from 0) high.
    pub async fn gpio_set(&self, line: u32) -> DeviceResult<()> {
        self.command(Command::GpioSet(line)).await.map(|_| ())
    }

    /// Drives GPIO line `line` (from 0) low.
    pub async fn gpio_clear(&self, line: u32) -> DeviceResult<()> {
        self.command(Command::GpioClear(line)).await.map(|_| ())
    }

    /// Reads GPIO line `line` (from 0).
    pub async fn gpio_read(&self, line: u32) -> DeviceResult<bool> {
        let text = self.reply_text(Command::GpioRead(line)).await?;
        codec::parse_level(&text).map_err(|e| self.protocol(e.to_string()))
    }

    async fn reply_text(&self, cmd: Command) -> DeviceResult<String> {
        match self.command(cmd).await? {
            Some(text) => Ok(text),
            None => Err(self.protocol(format!("no reply text to {cmd:?}"))),
        }
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

    async fn lock(&self) -> MutexGuard<'_, Inner> {
        let guard = self.inner.lock().await;
        self.touch();
        guard
    }

    fn touch(&self) {
        let us = self.epoch.elapsed().as_micros().min(u128::from(u64::MAX)) as u64;
        self.last_activity_us.store(us, Ordering::Relaxed);
    }

    fn last_activity(&self) -> Instant {
        self.epoch + std::time::Duration::from_micros(self.last_activity_us.load(Ordering::Relaxed))
    }

    /// Connects if needed, then sends `cmd`; closes the link on any failure.
    async fn run(&self, inner: &mut Inner, cmd: Command) -> DeviceResult<Option<String>> {
        if let Some(lost) = inner.lost.take() {
            return Err(self.protocol(lost));
        }
        if !inner.ready || !inner.link.is_open() {
            self.connect(inner).await?;
        }
        let r = transact(&mut inner.link, cmd).await;
        if r.is_err() {
            inner.link.close();
            inner.ready = false;
        }
        r
    }

    /// Opens the port, handshakes with `ver`, restores the wanted relay states after a
    /// reconnect and starts the keepalive. On failure the link is left closed.
    async fn connect(&self, inner: &mut Inner) -> DeviceResult<()> {
        inner.ready = false;
        let r = self.try_connect(inner).await;
        if r.is_err() {
            inner.link.close();
        }
        r
    }

    async fn try_connect(&self, inner: &mut Inner) -> DeviceResult<()> {
        let link = &mut inner.link;
        link.open()?;
        // A half-received line at the board would garble our first command: end it.
        link.write(&[codec::COMMAND_END], COMMAND_TIMEOUT_S).await?;
        match link
            .read_until(&[codec::PROMPT], "\\r", FLUSH_TIMEOUT_S)
            .await
        {
            Ok(_)
            | Err(DeviceError {
                kind: DeviceErrorKind::Timeout { .. },
                ..
            }) => {}
            Err(e) => return Err(e),
        }
        link.discard_input();
        let version = transact(link, Command::Ver).await?.unwrap_or_default();
        codec::parse_version(&version).map_err(|e| link.protocol(e.to_string()))?;
        let n = self.connects.fetch_add(1, Ordering::Relaxed) + 1;
        if n == 1 {
            tracing::info!(device = %self.device, port = %self.port, %version, "relay board connected");
        } else {
            self.restore(inner).await?;
        }
        inner.ready = true;
        self.start_keepalive();
        Ok(())
    }

    /// After a reconnect: reads every relay and re-sends the states we last set that differ.
    async fn restore(&self, inner: &mut Inner) -> DeviceResult<()> {
        if inner.wanted.iter().all(Option::is_none) {
            tracing::info!(device = %self.device, port = %self.port, "relay board reconnected");
            return Ok(());
        }
        if self.restore_lost(inner).await?.is_none() {
            tracing::info!(device = %self.device, port = %self.port, "relay board reconnected; relay states intact");
        }
        Ok(())
    }

    /// Reads every relay (`relay readall`) and re-sends the states we last set that differ.
    /// Returns a description of what was restored, `None` if every relay was as set.
    async fn restore_lost(&self, inner: &mut Inner) -> DeviceResult<Option<String>> {
        let link = &mut inner.link;
        let text = transact(link, Command::RelayReadAll)
            .await?
            .unwrap_or_default();
        let actual =
            codec::parse_mask(&text, RELAYS as u32).map_err(|e| link.protocol(e.to_string()))?;
        let lost: Vec<(u32, bool)> = inner
            .wanted
            .iter()
            .enumerate()
            .filter_map(|(i, w)| w.map(|on| (i as u32, on)))
            .filter(|&(i, on)| actual.get(i as usize) != Some(&on))
            .collect();
        if lost.is_empty() {
            return Ok(None);
        }
        let names: Vec<String> = lost
            .iter()
            .map(|(i, on)| format!("relay {i} {}", if *on { "on" } else { "off" }))
            .collect();
        tracing::warn!(
            device = %self.device,
            port = %self.port,
            relays = ?names,
            "relay board lost the relay states we set (did it reset or its watchdog lapse?); restoring them"
        );
        for &(relay, on) in &lost {
            let cmd = if on {
                Command::RelayOn(relay)
            } else {
                Command::RelayOff(relay)
            };
            transact(link, cmd).await?;
        }
        Ok(Some(format!(
            "the board had lost relay states (reset or lapsed watchdog); restored {}; what they power was off for a while, so retake the step",
            names.join(", ")
        )))
    }

    /// Starts (once) the task that sends `ver` while the board is idle, renewing its watchdog.
    /// The task holds only a `Weak`, so it ends when the last user drops the board.
    fn start_keepalive(&self) {
        if !self.watchdog_s.is_finite() || self.watchdog_s <= 0.0 {
            return;
        }
        if self.keepalive_started.swap(true, Ordering::Relaxed) {
            return;
        }
        let period = duration_s((self.watchdog_s / 3.0).max(MIN_KEEPALIVE_S));
        let weak = self.me.clone();
        tokio::spawn(async move {
            loop {
                let wake = match weak.upgrade() {
                    Some(board) => {
                        (board.last_activity() + period).max(Instant::now() + period / 4)
                    }
                    None => return,
                };
                tokio::time::sleep_until(wake).await;
                let Some(board) = weak.upgrade() else { return };
                if board.last_activity().elapsed() >= period {
                    board.keepalive().await;
                }
            }
        });
    }

    /// One keepalive, only if the link is up and nobody is using it: `ver`, or while a relay
    /// is on `relay readall` (it renews the lease just as well), restoring lost states and
    /// keeping the loss for the next request to report.
    async fn keepalive(&self) {
        let Ok(mut inner) = self.inner.try_lock() else {
            return;
        };
        self.touch();
        if !inner.ready || !inner.link.is_open() {
            return;
        }
        let r = if inner.wanted.contains(&Some(true)) {
            match self.restore_lost(&mut inner).await {
                Ok(Some(lost)) => {
                    inner.lost.get_or_insert(lost);
                    Ok(())
                }
                Ok(None) => Ok(()),
                Err(e) => Err(e),
            }
        } else {
            transact(&mut inner.link, Command::Ver).await.map(|_| ())
        };
        if let Err(e) = r {
            tracing::warn!(device = %self.device, port = %self.port, error = %e, "relay board keepalive failed; reconnecting on the next command");
            inner.link.close();
            inner.ready = false;
        }
    }
}

/// One command and its answer up to the prompt, on an open link.
async fn transact(link: &mut SerialLink, cmd: Command) -> DeviceResult<Option<String>> {
    let text = cmd.text().map_err(|e| {
        DeviceError::new(
            link.device().to_string(),
            DeviceErrorKind::Other {
                message: e.to_string(),
            },
        )
    })?;
    let mut bytes = text.clone().into_bytes();
    bytes.push(codec::COMMAND_END);
    link.discard_input();
    link.write(&bytes, COMMAND_TIMEOUT_S).await?;
    let raw = link
        .read_until(&[codec::PROMPT], &text, COMMAND_TIMEOUT_S)
        .await?;
    codec::parse_reply(&raw, &text, cmd.expects_reply()).map_err(|e| link.protocol(e.to_string()))
}

/// The switch-bank driver of a relay-serial board: channel c (from 1) is relay c−1.
pub struct RelaySerialBank {
    board: Arc<NumatoBoard>,
    channels: u32,
}

impl RelaySerialBank {
    /// A bank of `channels` relays (1 to 32) on `board`.
    pub fn new(board: Arc<NumatoBoard>, channels: u32) -> DeviceResult<Self> {
        if channels == 0 || channels > RELAYS as u32 {
            return Err(DeviceError::new(
                board.device().to_string(),
                DeviceErrorKind::Other {
                    message: format!(
                        "a relay-serial board has 1 to {RELAYS} channels, the rig file says {channels}"
                    ),
                },
            ));
        }
        Ok(Self { board, channels })
    }

    /// The board this bank switches (to share with a GPIO trigger).
    pub fn board(&self) -> &Arc<NumatoBoard> {
        &self.board
    }
}

impl SwitchBankDriver for RelaySerialBank {
    async fn set(&mut self, channel: u32, on: bool) -> DeviceResult<()> {
        if channel == 0 || channel > self.channels {
            return Err(DeviceError::new(
                self.board.device().to_string(),
                DeviceErrorKind::NoSuchChannel {
                    channel,
                    channels: self.channels,
                },
            ));
        }
        self.board.set_relay(channel - 1, on).await
    }

    async fn read_all(&mut self) -> DeviceResult<Vec<bool>> {
        self.board.read_relays(self.channels).await
    }
}
