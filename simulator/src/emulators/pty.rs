//! A pseudo-terminal pair that stands in for a USB serial device: the emulator owns the master
//! end, drivers open the slave end through a stable symlink (like socat's `link=` or a
//! `/dev/serial/by-id/...` link), and the device can be unplugged and plugged back in.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};

use tokio::io::unix::AsyncFd;

/// One live pty pair.
struct Pair {
    /// The emulator's end (non-blocking, registered with tokio).
    master: AsyncFd<File>,
    /// Our own handle on the slave, so the pty does not hang up when the driver closes it;
    /// also used to drop output that nobody reads.
    slave: serial2::SerialPort,
    /// `/dev/pts/N` of the slave.
    pts: PathBuf,
}

/// The device end of an emulated serial port, published at a stable path.
pub struct EmulatedPort {
    link: PathBuf,
    pair: Option<Pair>,
}

impl EmulatedPort {
    /// Creates a pty pair and publishes its slave as `<dir>/<name>` (a symlink). Must be called
    /// inside a tokio runtime.
    pub fn create(dir: &Path, name: &str) -> io::Result<Self> {
        let mut port = Self {
            link: dir.join(name),
            pair: None,
        };
        port.plug()?;
        Ok(port)
    }

    /// The stable path drivers open (the symlink).
    pub fn path(&self) -> &Path {
        &self.link
    }

    /// The pty the link points at now, if the device is plugged in.
    pub fn pts(&self) -> Option<&Path> {
        self.pair.as_ref().map(|p| p.pts.as_path())
    }

    /// True while the device is plugged in.
    pub fn is_connected(&self) -> bool {
        self.pair.is_some()
    }

    /// Removes the device: the pty closes (the driver's reads and writes fail) and the link
    /// disappears, as udev removes a `/dev/serial/by-id` link.
    pub fn unplug(&mut self) {
        let _ = std::fs::remove_file(&self.link);
        self.pair = None;
    }

    /// Plugs the device (back) in: a new pty pair, and the link atomically re-pointed at it
    /// (the new link is written beside it and renamed over it).
    pub fn plug(&mut self) -> io::Result<()> {
        self.pair = None;
        let (master, slave) = serial2::SerialPort::pair()?;
        let pts = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd()))?;
        let master = File::from(OwnedFd::from(master));
        // SAFETY: `File` owns its descriptor, returns the same one from every `as_raw_fd` call
        // and keeps it open until the `AsyncFd` (which owns the `File`) is dropped.
        let master = unsafe { AsyncFd::register(master) }?;
        let file_name = self
            .link
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "port".into());
        let tmp = self
            .link
            .with_file_name(format!(".{file_name}.{}.tmp", std::process::id()));
        let _ = std::fs::remove_file(&tmp);
        std::os::unix::fs::symlink(&pts, &tmp)?;
        std::fs::rename(&tmp, &self.link)?;
        self.pair = Some(Pair { master, slave, pts });
        Ok(())
    }

    /// Reads what the driver sent. Fails with `NotConnected` while unplugged.
    pub async fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        let pair = self.pair.as_ref().ok_or(io::ErrorKind::NotConnected)?;
        loop {
            let mut guard = pair.master.readable().await?;
            match guard.try_io(|f| f.get_ref().read(buf)) {
                Ok(r) => return r,
                Err(_would_block) => continue,
            }
        }
    }

    /// Writes every byte to the driver. Fails with `NotConnected` while unplugged. Waits while
    /// the pty is full; bound it with a timeout and call [`EmulatedPort::drop_unread`].
    pub async fn write_all(&self, mut bytes: &[u8]) -> io::Result<()> {
        let pair = self.pair.as_ref().ok_or(io::ErrorKind::NotConnected)?;
        while !bytes.is_empty() {
            let mut guard = pair.master.writable().await?;
            match guard.try_io(|f| f.get_ref().write(bytes)) {
                Ok(Ok(0)) => return Err(io::ErrorKind::WriteZero.into()),
                Ok(Ok(n)) => bytes = &bytes[n..],
                Ok(Err(e)) => return Err(e),
                Err(_would_block) => continue,
            }
        }
        Ok(())
    }

    /// Writes what fits into the pty now, without waiting (for output at power-on, before the
    /// emulator's task runs). Returns the bytes written.
    pub fn write_now(&self, bytes: &[u8]) -> io::Result<usize> {
        let pair = self.pair.as_ref().ok_or(io::ErrorKind::NotConnected)?;
        pair.master.get_ref().write(bytes)
    }

    /// Bytes sent to the driver that it has not read yet (0 while unplugged).
    pub fn unread(&self) -> usize {
        let Some(p) = &self.pair else { return 0 };
        let mut n: libc::c_int = 0;
        // SAFETY: FIONREAD on a valid tty descriptor writes one c_int through the pointer.
        let r = unsafe { libc::ioctl(p.slave.as_raw_fd(), libc::FIONREAD, &mut n) };
        if r < 0 { 0 } else { n.max(0) as usize }
    }

    /// Throws away output the driver has not read (nobody has the port open, or the driver
    /// stopped reading), so the emulator never blocks on a full pty.
    pub fn drop_unread(&self) {
        if let Some(p) = &self.pair {
            let _ = p.slave.discard_input_buffer();
        }
    }
}

impl Drop for EmulatedPort {
    fn drop(&mut self) {
        // Only remove the link if it still names our pty (another emulator may own it now).
        if let (Some(p), Ok(target)) = (&self.pair, std::fs::read_link(&self.link))
            && target == p.pts
        {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}
