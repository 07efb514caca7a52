//! The device end of a fake serial port, shared by the driver tests. A fake device is a tokio
//! task serving the streams its driver opens: ends of `tokio::io::duplex` handed over by the
//! driver's [`TransportOpener`] (so the fake, the driver and every timer run on tokio's paused
//! clock and no test waits for the wall clock), or the master side of a real pty (the one smoke
//! test per driver that keeps the serial path covered).

use std::io;
use std::os::fd::AsRawFd;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use stagehand_devices::serial_link::{Transport, TransportOpener};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{Notify, mpsc};

/// Room in each direction of a duplex stream (far more than any reply of the fakes).
const DUPLEX_BYTES: usize = 64 * 1024;

/// The test's side of a duplex port: opens streams for the driver, pulls the plug.
#[derive(Clone)]
pub struct Port {
    streams: mpsc::UnboundedSender<Box<dyn Transport>>,
    plug: Arc<Plug>,
}

#[derive(Default)]
struct Plug {
    unplugged: AtomicBool,
    changed: Notify,
}

impl Port {
    /// An opener for a driver: each open hands the device end a new duplex stream; once
    /// unplugged, opening fails as a vanished `/dev/serial/by-id` link does.
    pub fn opener(&self) -> TransportOpener {
        let port = self.clone();
        Box::new(move || {
            if port.plug.unplugged.load(Ordering::SeqCst) {
                return Err(io::Error::new(io::ErrorKind::NotFound, "no such device"));
            }
            let (driver, device) = tokio::io::duplex(DUPLEX_BYTES);
            port.streams
                .send(Box::new(device))
                .map_err(|_| io::Error::new(io::ErrorKind::NotFound, "the fake device is gone"))?;
            Ok(Box::new(driver) as Box<dyn Transport>)
        })
    }

    /// Pulls the cable: the open stream ends (the driver reads end of file) and the port no
    /// longer opens.
    pub fn unplug(&self) {
        self.plug.unplugged.store(true, Ordering::SeqCst);
        self.plug.changed.notify_one();
    }
}

/// The device's side of a port: the newest stream the driver opened.
pub struct DeviceEnd {
    incoming: mpsc::UnboundedReceiver<Box<dyn Transport>>,
    /// More streams may come (some opener still exists).
    openable: bool,
    conn: Option<Box<dyn Transport>>,
    plug: Arc<Plug>,
}

impl DeviceEnd {
    fn new(incoming: mpsc::UnboundedReceiver<Box<dyn Transport>>, plug: Arc<Plug>) -> Self {
        Self {
            incoming,
            openable: true,
            conn: None,
            plug,
        }
    }

    /// Waits for bytes from the driver on the newest stream (a new stream replaces the old
    /// one, as a reopened port does); `None` once no byte can ever come (unplugged, or every
    /// stream closed and nobody left to open another). Cancel-safe.
    pub async fn read(&mut self, buf: &mut [u8]) -> Option<usize> {
        loop {
            if self.plug.unplugged.load(Ordering::SeqCst) {
                self.conn = None;
                return None;
            }
            let conn = &mut self.conn;
            tokio::select! {
                biased;
                () = self.plug.changed.notified() => {}
                stream = self.incoming.recv(), if self.openable => match stream {
                    Some(stream) => *conn = Some(stream),
                    None => self.openable = false,
                },
                r = read_from(conn, buf) => match r {
                    Ok(n) if n > 0 => return Some(n),
                    _ => {
                        *conn = None;
                        if !self.openable {
                            return None;
                        }
                    }
                },
            }
        }
    }

    /// Sends `bytes` to the driver on the current stream; without one they are lost, as on a
    /// line nobody listens to.
    pub async fn write(&mut self, bytes: &[u8]) {
        if let Some(conn) = &mut self.conn
            && conn.write_all(bytes).await.is_err()
        {
            self.conn = None;
        }
    }
}

async fn read_from(conn: &mut Option<Box<dyn Transport>>, buf: &mut [u8]) -> io::Result<usize> {
    match conn {
        Some(conn) => conn.read(buf).await,
        None => std::future::pending().await,
    }
}

/// A port over `tokio::io::duplex`: the test's side and the device's.
pub fn duplex_port() -> (Port, DeviceEnd) {
    let (streams, incoming) = mpsc::unbounded_channel();
    let plug = Arc::new(Plug::default());
    (
        Port {
            streams,
            plug: plug.clone(),
        },
        DeviceEnd::new(incoming, plug),
    )
}

/// A real pty pair: the slave's path for the driver, the device end (the master side) for the
/// fake, and the slave itself, which the test keeps open so the pty never hangs up while the
/// driver has it closed (between a failure and the reconnect).
pub fn pty_port() -> (String, DeviceEnd, serial2::SerialPort) {
    let (master, slave) = serial2::SerialPort::pair().expect("a pty pair");
    let path = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd()))
        .expect("the pty's path")
        .to_str()
        .expect("a UTF-8 pty path")
        .to_string();
    let (near, far) = tokio::io::duplex(DUPLEX_BYTES);
    bridge(master, far);
    let (streams, incoming) = mpsc::unbounded_channel::<Box<dyn Transport>>();
    let _ = streams.send(Box::new(near));
    (path, DeviceEnd::new(incoming, Arc::default()), slave)
}

/// Carries bytes both ways between a pty master and a duplex stream. The master is blocking
/// I/O, so two std threads do its reads and writes (safe code: tokio's reactor would need an
/// `unsafe` registration of the fd); a task does the stream's side. All of it ends when the
/// stream's other end is dropped.
fn bridge(mut master: serial2::SerialPort, mut far: tokio::io::DuplexStream) {
    master
        .set_read_timeout(Duration::from_millis(10))
        .expect("a read timeout");
    let writer = master
        .try_clone()
        .expect("a second handle on the pty master");
    let (from_pty, mut to_stream) = mpsc::unbounded_channel::<Vec<u8>>();
    let (to_pty, for_pty) = std::sync::mpsc::channel::<Vec<u8>>();
    std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        loop {
            match master.read(&mut buf) {
                Ok(n) if n > 0 => {
                    if from_pty.send(buf[..n].to_vec()).is_err() {
                        return;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                    if from_pty.is_closed() {
                        return;
                    }
                }
                _ => return,
            }
        }
    });
    std::thread::spawn(move || {
        for bytes in for_pty {
            if writer.write_all(&bytes).is_err() {
                return;
            }
        }
    });
    tokio::spawn(async move {
        let mut buf = [0u8; 256];
        loop {
            tokio::select! {
                Some(bytes) = to_stream.recv() => {
                    if far.write_all(&bytes).await.is_err() {
                        return;
                    }
                }
                n = far.read(&mut buf) => match n {
                    Ok(n) if n > 0 => {
                        if to_pty.send(buf[..n].to_vec()).is_err() {
                            return;
                        }
                    }
                    _ => return,
                },
            }
        }
    });
}

/// A byte-at-a-time fake device running as a task: `on_byte` answers every byte the driver
/// writes; [`ByteFake::send`] makes it say something unsolicited. Aborted when dropped.
pub struct ByteFake {
    outbox: mpsc::UnboundedSender<Vec<u8>>,
    task: tokio::task::JoinHandle<()>,
}

impl ByteFake {
    /// Serves `device` with `on_byte` until the port is gone or the fake is dropped.
    pub fn spawn(
        mut device: DeviceEnd,
        mut on_byte: impl FnMut(u8) -> Vec<u8> + Send + 'static,
    ) -> Self {
        let (outbox, mut unsolicited) = mpsc::unbounded_channel::<Vec<u8>>();
        let task = tokio::spawn(async move {
            let mut buf = [0u8; 256];
            loop {
                tokio::select! {
                    Some(bytes) = unsolicited.recv() => device.write(&bytes).await,
                    n = device.read(&mut buf) => {
                        let Some(n) = n else { return };
                        let out: Vec<u8> = buf[..n].iter().flat_map(|&b| on_byte(b)).collect();
                        if !out.is_empty() {
                            device.write(&out).await;
                        }
                    }
                }
            }
        });
        Self { outbox, task }
    }

    /// Makes the device send `bytes` unsolicited.
    pub fn send(&self, bytes: &[u8]) {
        let _ = self.outbox.send(bytes.to_vec());
    }
}

impl Drop for ByteFake {
    fn drop(&mut self) {
        self.task.abort();
    }
}
