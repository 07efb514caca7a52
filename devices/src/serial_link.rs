//! One serial port as the drivers see it: open by path (a `/dev/serial/by-id/...` link, a
//! `/dev/ttyACM0` or an emulator's pty), write bytes, read lines or up to a marker, every read
//! bounded by a timeout, every failure a typed error naming the device and the port.
//!
//! A link that fails is closed; the driver reopens it (with its protocol's handshake) on its
//! next request, which is how a port that disappears and comes back is recovered.

use serial2_tokio::SerialPort;

use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};

/// Longest line a device may send before the bytes are taken for garbage.
const MAX_LINE: usize = 1024;

/// A serial port owned by one driver; closed until [`SerialLink::open`] succeeds.
pub struct SerialLink {
    device: String,
    path: String,
    baud: u32,
    port: Option<SerialPort>,
    /// Bytes read but not yet returned as a line.
    pending: Vec<u8>,
}

impl SerialLink {
    /// A link to `path` at `baud`, not yet open.
    pub fn new(device: &str, path: &str, baud: u32) -> Self {
        Self {
            device: device.to_string(),
            path: path.to_string(),
            baud,
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

    /// Opens the port (raw, 8N1 at the link's baud rate) and discards anything stale in it.
    pub fn open(&mut self) -> DeviceResult<()> {
        self.close();
        let port = SerialPort::open(&self.path, self.baud).map_err(|e| {
            DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::PortUnavailable {
                    port: self.path.clone(),
                    reason: e.to_string(),
                },
            )
        })?;
        // A pty or a USB CDC port may hold bytes from before; they belong to nobody.
        let _ = port.discard_buffers();
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

    fn port(&mut self) -> DeviceResult<&SerialPort> {
        if self.port.is_none() {
            return Err(DeviceError::new(
                self.device.clone(),
                DeviceErrorKind::Disconnected {
                    port: self.path.clone(),
                    reason: "the port is not open".into(),
                },
            ));
        }
        Ok(self.port.as_ref().expect("checked above"))
    }

    /// Writes every byte, or fails with `Disconnected` (closing the link).
    pub async fn write(&mut self, bytes: &[u8], timeout_s: f64) -> DeviceResult<()> {
        let port = self.port()?;
        match tokio::time::timeout(duration_s(timeout_s), port.write_all(bytes)).await {
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
        if let Some(p) = &self.port {
            let _ = p.discard_input_buffer();
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
        let port = self.port()?;
        match tokio::time::timeout_at(deadline, port.read(&mut buf)).await {
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
