//! The cart driver over the serial IR bridge: each drive command becomes a single-output PWM
//! Power Functions word sent as `PF hhhh`, confirmed by `OK hhhh`.
//!
//! The link opens lazily with a `ver` → `IRBRIDGE …` handshake, and again after any failure.
//! The bridge reports end stops unsolicited (`END -`, `END +`); the driver remembers them and
//! refuses to drive further into an end stop until the cart has been driven away from it.

use tokio::time::Instant;

use super::power_functions::{self, Output, PfWord, Pwm};
use crate::cart::{CartDriver, Drive};
use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::{CartSpec, IR_BRIDGE_BAUD};
use crate::serial_link::{SerialLink, TransportOpener};

/// Longest wait for `OK hhhh` (the bridge repeats the IR message before answering).
const REPLY_TIMEOUT_S: f64 = 1.0;
/// Longest handshake: an Arduino resets when the port opens and boots for about a second.
const HANDSHAKE_S: f64 = 2.0;
/// `ver` is re-sent this often during the handshake (the first may reach a booting board).
const VER_RETRY_S: f64 = 0.4;
/// How long to look for unsolicited lines before a command.
const DRAIN_S: f64 = 0.005;
/// Line end of the bridge, both ways.
const LF: &[u8] = b"\n";

/// Which end stop an `END` line reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum End {
    Minus,
    Plus,
}

impl End {
    fn name(self) -> &'static str {
        match self {
            End::Minus => "- end",
            End::Plus => "+ end",
        }
    }
}

fn parse_end(line: &str) -> Option<End> {
    match line.trim() {
        "END -" => Some(End::Minus),
        "END +" => Some(End::Plus),
        _ => None,
    }
}

/// The LEGO cart behind an IR bridge on a serial port.
pub struct IrBridgeCart {
    link: SerialLink,
    channel: u8,
    output: Output,
    step: u8,
    /// Toggle bit of the last word sent; flipped for every new word.
    toggle: bool,
    /// The link is open and answered the handshake.
    ready: bool,
    /// The bridge reported the − end stop and the cart has not been driven forward since.
    at_minus: bool,
    /// The bridge reported the + end stop and the cart has not been driven back since.
    at_plus: bool,
}

impl IrBridgeCart {
    /// A cart `device` behind the bridge on `port` at `baud`, its receiver on PF `channel`
    /// (1–4), the motor on `output`, running at PWM `step` (1–7). Nothing is opened yet.
    pub fn new(
        device: &str,
        port: &str,
        baud: u32,
        channel: u8,
        output: Output,
        step: u8,
    ) -> DeviceResult<Self> {
        Self::over(SerialLink::new(device, port, baud), channel, output, step)
    }

    /// Like [`IrBridgeCart::new`], over the streams `open` hands it (one per connect) instead
    /// of a serial port; `port` names them in errors. Lets a test run a fake bridge on the
    /// other end of `tokio::io::duplex`, on tokio's paused clock.
    pub fn with_transport(
        device: &str,
        port: &str,
        open: TransportOpener,
        channel: u8,
        output: Output,
        step: u8,
    ) -> DeviceResult<Self> {
        let link = SerialLink::with_transport(device, port, open);
        Self::over(link, channel, output, step)
    }

    fn over(link: SerialLink, channel: u8, output: Output, step: u8) -> DeviceResult<Self> {
        let bad = |message: String| {
            DeviceError::new(
                link.device().to_string(),
                DeviceErrorKind::Other { message },
            )
        };
        if !(1..=4).contains(&channel) {
            return Err(bad(format!(
                "ir_channel is {channel}; Power Functions channels are 1 to 4"
            )));
        }
        if !(1..=7).contains(&step) {
            return Err(bad(format!(
                "ir_speed_step is {step}; PWM steps are 1 to 7"
            )));
        }
        Ok(Self {
            link,
            channel,
            output,
            step,
            toggle: false,
            ready: false,
            at_minus: false,
            at_plus: false,
        })
    }

    /// The cart of an `ir-bridge` cart spec (port, baud default 9600, channel, output, step).
    pub fn from_spec(spec: &CartSpec) -> DeviceResult<Self> {
        let bad =
            |message: String| DeviceError::new(spec.id.clone(), DeviceErrorKind::Other { message });
        let port = spec.port.as_deref().ok_or_else(|| {
            bad("an ir-bridge cart needs `port = \"/dev/serial/by-id/...\"` in the rig file".into())
        })?;
        let output = Output::parse(&spec.ir_output).ok_or_else(|| {
            bad(format!(
                "ir_output is `{}`; the Power Functions outputs are `A` and `B`",
                spec.ir_output
            ))
        })?;
        Self::new(
            &spec.id,
            port,
            spec.baud.unwrap_or(IR_BRIDGE_BAUD),
            spec.ir_channel,
            output,
            spec.ir_speed_step,
        )
    }

    fn end_stop(&self, end: End) -> DeviceError {
        DeviceError::new(
            self.link.device().to_string(),
            DeviceErrorKind::EndStop { end: end.name() },
        )
    }

    fn note_end(&mut self, end: End) {
        tracing::info!(device = %self.link.device(), end = end.name(), "cart reached an end stop");
        match end {
            End::Minus => self.at_minus = true,
            End::Plus => self.at_plus = true,
        }
    }

    fn fail<T>(&mut self, e: DeviceError) -> DeviceResult<T> {
        self.link.close();
        self.ready = false;
        Err(e)
    }

    /// Opens the port and waits for `IRBRIDGE` in answer to `ver`, re-sending `ver` while the
    /// bridge boots. Leaves the link closed on failure.
    async fn connect(&mut self) -> DeviceResult<()> {
        self.ready = false;
        self.link.open()?;
        let deadline = Instant::now() + duration_s(HANDSHAKE_S);
        let mut other: Option<String> = None;
        while Instant::now() < deadline {
            if let Err(e) = self.link.write(b"ver\n", VER_RETRY_S).await {
                return self.fail(e);
            }
            let until = (Instant::now() + duration_s(VER_RETRY_S)).min(deadline);
            loop {
                let left = until
                    .saturating_duration_since(Instant::now())
                    .as_secs_f64();
                if left <= 0.0 {
                    break;
                }
                match self.link.read_line(LF, "ver", left).await {
                    Ok(line) if line.starts_with("IRBRIDGE") => {
                        tracing::info!(device = %self.link.device(), port = %self.link.path(), version = %line, "IR bridge connected");
                        self.ready = true;
                        return Ok(());
                    }
                    Ok(line) => match parse_end(&line) {
                        Some(end) => self.note_end(end),
                        None => other = Some(line),
                    },
                    Err(DeviceError {
                        kind: DeviceErrorKind::Timeout { .. },
                        ..
                    }) => break,
                    Err(e) => return self.fail(e),
                }
            }
        }
        let e = match other {
            Some(line) => self.link.protocol(format!(
                "`ver` answered `{}`, expected `IRBRIDGE x.y`; is this the IR bridge at the right baud rate?",
                line.escape_debug()
            )),
            None => DeviceError::new(self.link.device().to_string(), DeviceErrorKind::Timeout { request: "ver".into(), timeout_s: HANDSHAKE_S }),
        };
        self.fail(e)
    }

    /// Reads lines that arrived while idle, noting end stops.
    async fn drain(&mut self) -> DeviceResult<()> {
        self.link.read_available(DRAIN_S).await?;
        while self.link.has_line(LF) {
            match self.link.read_line(LF, "drain", 0.0).await {
                Ok(line) => match parse_end(&line) {
                    Some(end) => self.note_end(end),
                    None => {
                        tracing::debug!(device = %self.link.device(), line = %line, "ignoring a stray line from the IR bridge")
                    }
                },
                Err(DeviceError {
                    kind: DeviceErrorKind::Timeout { .. },
                    ..
                }) => break,
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Sends one PWM command (flipping the toggle bit) and waits for its `OK`. `towards` is
    /// the end stop the command drives into: an `END` for it while waiting is an `EndStop`.
    async fn send(&mut self, pwm: Pwm, towards: Option<End>) -> DeviceResult<()> {
        self.toggle = !self.toggle;
        let Some(word) = PfWord::single_output(self.channel, self.output, pwm, self.toggle) else {
            return Err(DeviceError::new(
                self.link.device().to_string(),
                DeviceErrorKind::Other {
                    message: format!("cannot encode {pwm:?} on channel {}", self.channel),
                },
            ));
        };
        let hex = power_functions::to_hex(word.encode());
        let request = format!("PF {hex}");
        if let Err(e) = self
            .link
            .write(format!("{request}\n").as_bytes(), REPLY_TIMEOUT_S)
            .await
        {
            return self.fail(e);
        }
        let deadline = Instant::now() + duration_s(REPLY_TIMEOUT_S);
        let mut hit: Option<End> = None;
        loop {
            let left = deadline
                .saturating_duration_since(Instant::now())
                .as_secs_f64();
            let line = match self.link.read_line(LF, &request, left).await {
                Ok(line) => line,
                Err(e) => {
                    let e = match hit {
                        Some(end) => self.end_stop(end),
                        None => e,
                    };
                    return self.fail(e);
                }
            };
            if let Some(end) = parse_end(&line) {
                self.note_end(end);
                if Some(end) == towards {
                    hit = Some(end);
                }
                continue;
            }
            if let Some(echo) = line.strip_prefix("OK ") {
                if power_functions::parse_hex(echo) != Some(word.encode()) {
                    let e = self.link.protocol(format!(
                        "sent `{request}`, the bridge confirmed `{}`",
                        line.escape_debug()
                    ));
                    return self.fail(e);
                }
                return match hit {
                    Some(end) => Err(self.end_stop(end)),
                    None => Ok(()),
                };
            }
            if line.starts_with("IRBRIDGE") {
                continue; // a late answer to a handshake `ver`
            }
            let e = if line.starts_with("ERR") {
                self.link.protocol(format!(
                    "the bridge rejected `{request}` with `{}`",
                    line.escape_debug()
                ))
            } else {
                self.link.protocol(format!(
                    "expected `OK {hex}` after `{request}`, got `{}`",
                    line.escape_debug()
                ))
            };
            return self.fail(e);
        }
    }
}

impl CartDriver for IrBridgeCart {
    /// `Forward`/`Reverse` run the motor at the configured step (refused with `EndStop` while
    /// the cart sits at that end); `Stop` brakes, then lets the motor float.
    async fn drive(&mut self, drive: Drive) -> DeviceResult<()> {
        if !self.ready || !self.link.is_open() {
            self.connect().await?;
        }
        if let Err(e) = self.drain().await {
            return self.fail(e);
        }
        match drive {
            Drive::Forward => {
                if self.at_plus {
                    return Err(self.end_stop(End::Plus));
                }
                self.at_minus = false;
                self.send(Pwm::Forward(self.step), Some(End::Plus)).await
            }
            Drive::Reverse => {
                if self.at_minus {
                    return Err(self.end_stop(End::Minus));
                }
                self.at_plus = false;
                self.send(Pwm::Backward(self.step), Some(End::Minus)).await
            }
            Drive::Stop => {
                self.send(Pwm::Brake, None).await?;
                self.send(Pwm::Float, None).await
            }
        }
    }
}
