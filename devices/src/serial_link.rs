//! One serial port as the drivers see it: open by path (a `/dev/serial/by-id/...` link, a
//! `/dev/ttyACM0` or an emulator's pty), write bytes, read lines or up to a marker, every read
//! bounded by a timeout, every failure a typed error naming the device and the port.
//!
//! A link can also run over any async byte stream ([`Transport`]) that a [`TransportOpener`]
//! hands it on each (re)open: one end of `tokio::io::duplex`, so a test's fake device runs as a
//! task on tokio's (paused) clock, or a network serial bridge. Everything above the bytes is
//! the same code either way.
//!
//! A link that fails is closed; the driver reopens it (with its protocol's handshake) on its
//! next request, which is how a port that disappears and comes back is recovered.

use std::pin::Pin;
use std::task::{Context, Poll, Waker};

use serial2_tokio::SerialPort;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};

/// An async byte stream a link can run over instead of a serial port.
pub trait Transport: AsyncRead + AsyncWrite + Unpin + Send {}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> Transport for T {}

/// Opens a fresh stream each time the link opens (first use, and after every failure); an
/// error is reported as `PortUnavailable`, like a serial port path that does not open.
pub type TransportOpener = Box<dyn FnMut() -> std::io::Result<Box<dyn Transport>> + Send>;

/// Longest line a device may send before the bytes are taken for garbage.
const MAX_LINE: usize = 1024;

/// What a link opens: a serial port by path, or whatever stream an opener hands it.
enum Endpoint {
    Serial { baud: u32 },
    Stream(TransportOpener),
}

/// An open link.
enum Port {
    Serial(SerialPort),
    Stream(Box<dyn Transport>),
}

impl Port {
    fn io(&mut self) -> &mut dyn Transport {
        match self {
            Port::Serial(p) => p,
            Port::Stream(s) => s.as_mut(),
        }
    }
}

/// A serial port owned by one driver; closed until [`SerialLink::open`] succeeds.
pub struct SerialLink {
    device: String,
    path: String,
    endpoint: Endpoint,
    port: Option<Port>,
    /// Bytes read but not yet returned as a line.
    pending: Vec<u8>,
}

impl SerialLink {
    /// A link to `path` at `baud`, not yet open.
    pub fn new(device: &str, path: &str, baud: u32) -> Self {
        Self::with_endpoint(device, path, Endpoint::Serial { baud })
    }

    /// A link over the streams `open` hands it (one per open), named `name` in errors where a
    /// serial link names its path; not yet open.
    pub fn with_transport(device: &str, name: &str, open: TransportOpener) -> Self {
        Self::with_endpoint(device, name, Endpoint::Stream(open))
    }

    fn with_endpoint(device: &str, path: &str, endpoint: Endpoint) -> Self {
        Self {
            device: device.to_string(),
            path: path.to_string(),
            endpoint,
            port: None,
            pending: Vec::new(),
        }
    }

    pub fn device(&self) -> &str {
        &self.device
    }

    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn is_open(&self) -> bool {
        self.port.is_some()
    }

    /// Opens the port (raw, 8N1 at the link's baud rate) and discards anything stale in it;
    /// a stream link asks its opener for a new stream instead.
    pub fn open(&mut self) -> DeviceResult<()> {
        self.close();
        let opened = match &mut self.endpoint {
            Endpoint::Serial { baud } => SerialPort::open(&self.path, *baud).map(|port| {
                // A pty or a USB CDC port may hold bytes from before; they belong to nobody.
                let _ = port.discard_buffers();
                Port::Serial(port)
            }),
            Endpoint::Stream(open) => open().map(|mut stream| {
                drain_ready(stream.as_mut());
                Port::Stream(stream)
            }),
        };
        let port = opened.map_err(|e| {
            DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::PortUnavailable {
                    port: self.path.clone(),
                    reason: e.to_string(),
                },
            )
        })?;
        self.port = Some(port);
        Ok(())
    }

    /// Closes the port; the next request must reopen it.
    pub fn close(&mut self) {
        self.port = None;
        self.pending.clear();
    }

    /// A `Disconnected` error for `reason`, closing the link.
    pub fn lost(&mut self, reason: impl Into<String>) -> DeviceError {
        self.close();
        DeviceError::new(
            self.device.clone(),
            DeviceErrorKind::Disconnected {
                port: self.path.clone(),
                reason: reason.into(),
            },
        )
    }

    /// A `Protocol` error about `message`. The link stays open: the caller decides whether
    /// to resynchronise or close.
    pub fn protocol(&self, message: impl Into<String>) -> DeviceError {
        DeviceError::new(
            self.device.clone(),
            DeviceErrorKind::Protocol {
                port: self.path.clone(),
                message: message.into(),
            },
        )
    }

    fn io(&mut self) -> DeviceResult<&mut dyn Transport> {
        match &mut self.port {
            Some(port) => Ok(port.io()),
            None => Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Disconnected {
                    port: self.path.clone(),
                    reason: "the port is not open".into(),
                },
            )),
        }
    }

    /// Writes every byte, or fails with `Disconnected` (closing the link).
    pub async fn write(&mut self, bytes: &[u8], timeout_s: f64) -> DeviceResult<()> {
        let io = self.io()?;
        let write = async {
            io.write_all(bytes).await?;
            io.flush().await
        };
        match tokio::time::timeout(duration_s(timeout_s), write).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(self.lost(format!("write failed: {e}"))),
            Err(_) => Err(self.lost(format!(
                "could not write {} bytes within {timeout_s:.3} s",
                bytes.len()
            ))),
        }
    }

    /// Reads until one of `terminators` and returns the text before it (lossy UTF-8), skipping
    /// empty lines. Fails with `Timeout` naming `request`, `Disconnected` when the port goes
    /// away, and `Protocol` for an over-long line (garbage on the wire).
    pub async fn read_line(
        &mut self,
        terminators: &[u8],
        request: &str,
        timeout_s: f64,
    ) -> DeviceResult<String> {
        let deadline = tokio::time::Instant::now() + duration_s(timeout_s);
        loop {
            while let Some(i) = self.pending.iter().position(|b| terminators.contains(b)) {
                let line: Vec<u8> = self.pending.drain(..=i).collect();
                let text = String::from_utf8_lossy(&line[..i]).trim().to_string();
                if !text.is_empty() {
                    return Ok(text);
                }
            }
            if self.pending.len() > MAX_LINE {
                self.pending.clear();
                return Err(self.protocol(format!(
                    "more than {MAX_LINE} bytes without a line end in reply to `{request}`"
                )));
            }
            self.fill(deadline, request, timeout_s).await?;
        }
    }

    /// Reads until `marker` (inclusive) and returns everything before it (lossy UTF-8).
    pub async fn read_until(
        &mut self,
        marker: &[u8],
        request: &str,
        timeout_s: f64,
    ) -> DeviceResult<String> {
        let deadline = tokio::time::Instant::now() + duration_s(timeout_s);
        loop {
            if let Some(i) = find(&self.pending, marker) {
                let chunk: Vec<u8> = self.pending.drain(..i + marker.len()).collect();
                return Ok(String::from_utf8_lossy(&chunk[..i]).to_string());
            }
            if self.pending.len() > MAX_LINE {
                self.pending.clear();
                return Err(self.protocol(format!(
                    "more than {MAX_LINE} bytes without the end marker in reply to `{request}`"
                )));
            }
            self.fill(deadline, request, timeout_s).await?;
        }
    }

    /// Drops every byte read so far and whatever the OS holds (resynchronising after garbage).
    pub fn discard_input(&mut self) {
        self.pending.clear();
        match &mut self.port {
            Some(Port::Serial(p)) => {
                let _ = p.discard_input_buffer();
            }
            Some(Port::Stream(s)) => drain_ready(s.as_mut()),
            None => {}
        }
    }

    /// Reads whatever arrives within `timeout_s` without waiting for a line (for draining
    /// unsolicited messages such as a banner after a reset).
    pub async fn read_available(&mut self, timeout_s: f64) -> DeviceResult<()> {
        let deadline = tokio::time::Instant::now() + duration_s(timeout_s);
        match self.fill(deadline, "drain", timeout_s).await {
            Ok(())
            | Err(DeviceError {
                kind: DeviceErrorKind::Timeout { .. },
                ..
            }) => Ok(()),
            Err(e) => Err(e),
        }
    }

    /// True if a complete line ending in one of `terminators` is already buffered.
    pub fn has_line(&self, terminators: &[u8]) -> bool {
        self.pending.iter().any(|b| terminators.contains(b))
    }

    async fn fill(
        &mut self,
        deadline: tokio::time::Instant,
        request: &str,
        timeout_s: f64,
    ) -> DeviceResult<()> {
        let mut buf = [0u8; 256];
        let io = self.io()?;
        match tokio::time::timeout_at(deadline, io.read(&mut buf)).await {
            Ok(Ok(0)) => Err(self.lost("the port closed (end of file)")),
            Ok(Ok(n)) => {
                self.pending.extend_from_slice(&buf[..n]);
                Ok(())
            }
            Ok(Err(e)) => Err(self.lost(format!("read failed: {e}"))),
            Err(_) => Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Timeout {
                    request: request.to_string(),
                    timeout_s,
                },
            )),
        }
    }
}

/// Drops the bytes a stream has ready now without waiting for more: a stream's counterpart of
/// discarding a serial port's input buffer.
fn drain_ready(io: &mut dyn Transport) {
    let mut cx = Context::from_waker(Waker::noop());
    let mut buf = [0u8; 256];
    loop {
        let mut chunk = ReadBuf::new(&mut buf);
        match Pin::new(&mut *io).poll_read(&mut cx, &mut chunk) {
            Poll::Ready(Ok(())) if !chunk.filled().is_empty() => {}
            _ => break,
        }
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || haystack.len() < needle.len() {
        return None;
    }
    haystack.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::os::fd::AsRawFd;

    /// A pty pair: the master end (blocking) and the slave's path.
    fn pty() -> (serial2::SerialPort, serial2::SerialPort, String) {
        let (master, slave) = serial2::SerialPort::pair().unwrap();
        let path = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd())).unwrap();
        (master, slave, path.to_str().unwrap().to_string())
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn reads_lines_times_out_and_notices_garbage_over_a_pty() {
        let (master, slave, path) = pty();
        let mut link = SerialLink::new("grbl", &path, 115_200);
        link.open().unwrap();
        master
            .write_all(b"\r\nGrbl 1.1h ['$' for help]\r\nok\r\n")
            .unwrap();
        assert_eq!(
            link.read_line(b"\r\n", "banner", 1.0).await.unwrap(),
            "Grbl 1.1h ['$' for help]"
        );
        assert_eq!(link.read_line(b"\r\n", "x", 1.0).await.unwrap(), "ok");
        let e = link.read_line(b"\n", "status", 0.05).await.unwrap_err();
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
        link.write(b"?", 1.0).await.unwrap();
        let mut b = [0u8; 1];
        master.read_exact(&mut b).unwrap();
        assert_eq!(&b, b"?");
        master.write_all(&[b'x'; 2000]).unwrap();
        let e = link.read_line(b"\n", "status", 1.0).await.unwrap_err();
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
        drop(master);
        drop(slave);
        let e = loop {
            if let Err(e) = link.read_line(b"\n", "status", 1.0).await {
                break e;
            }
        };
        assert!(
            matches!(
                e,
                DeviceError {
                    kind: DeviceErrorKind::Disconnected { .. },
                    ..
                } | DeviceError {
                    kind: DeviceErrorKind::Protocol { .. },
                    ..
                }
            ),
            "{e}"
        );
    }

    /// A link over duplex streams, each new one handed to the test through `ends`; `refuse`
    /// makes the opener fail (a port that is gone).
    fn stream_link(
        refuse: std::sync::Arc<std::sync::atomic::AtomicBool>,
    ) -> (
        SerialLink,
        tokio::sync::mpsc::UnboundedReceiver<tokio::io::DuplexStream>,
    ) {
        let (tx, ends) = tokio::sync::mpsc::unbounded_channel();
        let open: TransportOpener = Box::new(move || {
            if refuse.load(std::sync::atomic::Ordering::Relaxed) {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no such device",
                ));
            }
            let (ours, theirs) = tokio::io::duplex(4096);
            tx.send(theirs)
                .map_err(|_| std::io::Error::other("nobody serves this port"))?;
            Ok(Box::new(ours) as Box<dyn Transport>)
        });
        (SerialLink::with_transport("grbl", "fake:grbl", open), ends)
    }

    #[tokio::test(start_paused = true)]
    async fn a_stream_link_reads_discards_times_out_on_the_virtual_clock_and_reopens() {
        let refuse = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (mut link, mut ends) = stream_link(refuse.clone());
        link.open().unwrap();
        let mut dev = ends.recv().await.unwrap();
        dev.write_all(b"stale\r\n").await.unwrap();
        link.discard_input();
        dev.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\nok\r\n")
            .await
            .unwrap();
        assert_eq!(
            link.read_line(b"\r\n", "banner", 1.0).await.unwrap(),
            "Grbl 1.1h ['$' for help]"
        );
        assert_eq!(link.read_line(b"\r\n", "x", 1.0).await.unwrap(), "ok");
        // Nothing comes: the timeout is exactly the one asked for, on the paused clock.
        let t0 = tokio::time::Instant::now();
        let e = link.read_line(b"\n", "status", 0.25).await.unwrap_err();
        assert!(matches!(e.kind, DeviceErrorKind::Timeout { .. }), "{e}");
        assert_eq!(t0.elapsed(), std::time::Duration::from_millis(250));
        link.write(b"?", 1.0).await.unwrap();
        let mut b = [0u8; 1];
        dev.read_exact(&mut b).await.unwrap();
        assert_eq!(&b, b"?");
        // The device end goes away: end of file, the link is closed.
        drop(dev);
        let e = link.read_line(b"\n", "status", 1.0).await.unwrap_err();
        assert!(
            matches!(e.kind, DeviceErrorKind::Disconnected { .. }),
            "{e}"
        );
        assert!(!link.is_open());
        // Reopening asks the opener for a new stream; a refusal is a missing port.
        link.open().unwrap();
        assert!(ends.recv().await.is_some());
        refuse.store(true, std::sync::atomic::Ordering::Relaxed);
        let e = link.open().unwrap_err();
        assert!(
            matches!(&e.kind, DeviceErrorKind::PortUnavailable { port, .. } if port == "fake:grbl"),
            "{e}"
        );
    }

    #[test]
    fn a_missing_port_names_device_and_path() {
        let mut link = SerialLink::new("lamps", "/dev/serial/by-id/nope", 9600);
        let e = link.open().unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("lamps") && text.contains("/dev/serial/by-id/nope"),
            "{text}"
        );
        assert!(matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::PortUnavailable { .. },
                ..
            }
        ));
    }
}
