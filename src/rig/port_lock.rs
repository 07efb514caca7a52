//! Device ownership: an advisory lock (`flock`) per real port, so one process owns the rig.
//!
//! When the real serial or HID ports of a rig are opened (not simulated devices, not emulated
//! ports), a lock file per port is locked in a shared lock directory and holds the owner's pid,
//! command line and, for the daemon, its URL. A second opener (a CLI `run` while the daemon
//! holds the rig, or a second daemon) is refused with [`PortBusy`], which names the holder and
//! tells how to reach the daemon instead. The lock is released when the [`PortLock`] is dropped
//! or the process dies (the kernel drops `flock` locks with the last descriptor).

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};

use sha2::{Digest, Sha256};

/// Overrides the lock directory (tests, or a lab that keeps it elsewhere).
pub const LOCK_DIR_ENV: &str = "STAGEHAND_LOCK_DIR";

/// The lock directory every user of the rig shares: `$STAGEHAND_LOCK_DIR`, else
/// `/tmp/stagehand-locks` (created world-writable with the sticky bit, like `/tmp`, because the
/// devices are shared between users, so their locks must be too).
pub fn lock_dir() -> PathBuf {
    std::env::var_os(LOCK_DIR_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/tmp/stagehand-locks"))
}

/// Who holds a lock, as written in its lock file.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Holder {
    pub pid: Option<u32>,
    /// The holder's command line, e.g. `stagehand serve --listen 127.0.0.1:8080`.
    pub command: Option<String>,
    /// The daemon's URL, once it listens.
    pub url: Option<String>,
}

impl Holder {
    fn parse(text: &str) -> Holder {
        let mut h = Holder::default();
        for line in text.lines() {
            match line.split_once('=') {
                Some(("pid", v)) => h.pid = v.trim().parse().ok(),
                Some(("command", v)) => h.command = Some(v.trim().to_string()),
                Some(("url", v)) if !v.trim().is_empty() => h.url = Some(v.trim().to_string()),
                _ => {}
            }
        }
        h
    }

    fn render(&self) -> String {
        let mut s = String::new();
        if let Some(pid) = self.pid {
            s.push_str(&format!("pid={pid}\n"));
        }
        if let Some(c) = &self.command {
            s.push_str(&format!("command={}\n", c.replace('\n', " ")));
        }
        if let Some(u) = &self.url {
            s.push_str(&format!("url={u}\n"));
        }
        s
    }
}

/// A port another process (or another part of this one) holds.
#[derive(Debug, Clone)]
pub struct PortBusy {
    /// The port as the rig file names it.
    pub port: String,
    /// The lock file.
    pub lock: PathBuf,
    pub holder: Holder,
}

impl std::fmt::Display for PortBusy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let who = match (&self.holder.pid, &self.holder.command) {
            (Some(pid), Some(cmd)) => format!("pid {pid} (`{cmd}`)"),
            (Some(pid), None) => format!("pid {pid}"),
            (None, Some(cmd)) => format!("`{cmd}`"),
            (None, None) => "another process".to_string(),
        };
        write!(f, "port {} is in use by {who}", self.port)?;
        match &self.holder.url {
            Some(url) => write!(
                f,
                "; the daemon at {url} owns this rig; use `stagehand run --remote {url} script.rhai`"
            ),
            None => write!(
                f,
                "; wait for it to finish or stop it (lock file {})",
                self.lock.display()
            ),
        }
    }
}

/// Why a port could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum PortLockError {
    #[error("{0}")]
    Busy(PortBusy),
    #[error("cannot lock port {port} with {}: {reason}", lock.display())]
    Io {
        port: String,
        lock: PathBuf,
        reason: String,
    },
}

/// An exclusive lock on one port, held until dropped.
#[derive(Debug)]
pub struct PortLock {
    port: String,
    path: PathBuf,
    /// Held, never read: the lock lives as long as this descriptor.
    _file: Arc<Mutex<File>>,
}

impl PortLock {
    /// The port as the rig file names it.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// What this process writes in its lock files (its URL is added by [`record_url`]).
static OWNER: Mutex<Option<Holder>> = Mutex::new(None);
/// The lock files this process holds, to rewrite when the daemon learns its URL.
static HELD: Mutex<Vec<Weak<Mutex<File>>>> = Mutex::new(Vec::new());

fn owner() -> Holder {
    let mut owner = OWNER.lock().unwrap_or_else(|p| p.into_inner());
    owner
        .get_or_insert_with(|| Holder {
            pid: Some(std::process::id()),
            command: Some(command_line()),
            url: None,
        })
        .clone()
}

/// `stagehand <args>` of this process.
fn command_line() -> String {
    let mut args = std::env::args();
    let exe = args
        .next()
        .and_then(|a| {
            Path::new(&a)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
        })
        .unwrap_or_else(|| "stagehand".into());
    std::iter::once(exe)
        .chain(args)
        .collect::<Vec<_>>()
        .join(" ")
}

/// Records the daemon's URL in every lock file this process holds (and in the ones it takes
/// later), so a CLI `run` that finds the rig busy can say where the daemon is. Call it once
/// the daemon listens.
pub fn record_url(url: &str) {
    let holder = {
        let mut owner = OWNER.lock().unwrap_or_else(|p| p.into_inner());
        let mut h = owner.clone().unwrap_or_else(|| Holder {
            pid: Some(std::process::id()),
            command: Some(command_line()),
            url: None,
        });
        h.url = Some(url.to_string());
        *owner = Some(h.clone());
        h
    };
    let mut held = HELD.lock().unwrap_or_else(|p| p.into_inner());
    held.retain(|w| w.strong_count() > 0);
    for file in held.iter().filter_map(Weak::upgrade) {
        let mut file = file.lock().unwrap_or_else(|p| p.into_inner());
        if let Err(e) = write_holder(&mut file, &holder) {
            tracing::warn!("cannot record the daemon's URL in a port lock file: {e}");
        }
    }
}

/// [`record_url`] for the address the daemon listens on: an unspecified address (`0.0.0.0`,
/// `::`) is recorded as loopback, where a CLI on the same machine reaches it.
pub fn record_listen_addr(addr: std::net::SocketAddr) {
    let mut addr = addr;
    if addr.ip().is_unspecified() {
        addr.set_ip(match addr.ip() {
            std::net::IpAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::IpAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    record_url(&format!("http://{addr}"));
}

fn write_holder(file: &mut File, holder: &Holder) -> std::io::Result<()> {
    file.set_len(0)?;
    file.seek(SeekFrom::Start(0))?;
    file.write_all(holder.render().as_bytes())?;
    file.flush()
}

/// The name a port is locked under: its canonical path (symlinks like `/dev/serial/by-id/…`
/// resolved, so two names of one device share a lock), or the name itself when it is not a
/// path (a HID serial number, a camera id).
pub fn canonical_port(port: &str) -> String {
    if port.starts_with('/')
        && let Ok(p) = std::fs::canonicalize(port)
    {
        return p.display().to_string();
    }
    port.to_string()
}

/// The lock file of a (canonical) port inside `dir`: readable name plus a short hash so that
/// different names never share a file.
pub fn lock_file_for(dir: &Path, canonical: &str) -> PathBuf {
    let readable: String = canonical
        .trim_start_matches('/')
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_') {
                c
            } else {
                '_'
            }
        })
        .take(80)
        .collect();
    let hash = Sha256::digest(canonical.as_bytes());
    let short: String = hash.iter().take(4).map(|b| format!("{b:02x}")).collect();
    dir.join(format!("{readable}-{short}.lock"))
}

/// Locks `port` in the default lock directory (see [`lock_dir`]).
pub fn lock(port: &str) -> Result<PortLock, PortLockError> {
    lock_in(&lock_dir(), port)
}

/// Locks `port` in `dir` (non-blocking): the holder's pid, command and URL go in the file.
pub fn lock_in(dir: &Path, port: &str) -> Result<PortLock, PortLockError> {
    let canonical = canonical_port(port);
    let path = lock_file_for(dir, &canonical);
    let io_err = |what: &str, e: std::io::Error| PortLockError::Io {
        port: port.to_string(),
        lock: path.clone(),
        reason: format!("{what}: {e}"),
    };
    ensure_dir(dir).map_err(|e| io_err("cannot create the lock directory", e))?;
    let mut file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .read(true)
        .write(true)
        .mode(0o666)
        .open(&path)
        .map_err(|e| io_err("open", e))?;
    // Non-blocking exclusive `flock`; the kernel drops it with the last descriptor.
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            return Err(PortLockError::Busy(PortBusy {
                port: port.to_string(),
                lock: path,
                holder: Holder::parse(&text),
            }));
        }
        Err(std::fs::TryLockError::Error(err)) => return Err(io_err("flock", err)),
    }
    // Others of the rig's users must be able to take the lock after us.
    let _ = file.set_permissions(std::fs::Permissions::from_mode(0o666));
    write_holder(&mut file, &owner()).map_err(|e| io_err("write", e))?;
    tracing::debug!(port, lock = %path.display(), "port locked");
    let file = Arc::new(Mutex::new(file));
    let mut held = HELD.lock().unwrap_or_else(|p| p.into_inner());
    held.retain(|w| w.strong_count() > 0);
    held.push(Arc::downgrade(&file));
    Ok(PortLock {
        port: port.to_string(),
        path,
        _file: file,
    })
}

/// Creates the lock directory; a fresh one is world-writable with the sticky bit.
fn ensure_dir(dir: &Path) -> std::io::Result<()> {
    if dir.is_dir() {
        return Ok(());
    }
    match std::fs::create_dir_all(dir) {
        Ok(()) => {
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o1777));
            Ok(())
        }
        Err(_) if dir.is_dir() => Ok(()),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type TestResult = Result<(), Box<dyn std::error::Error>>;

    #[test]
    fn a_second_locker_is_refused_and_the_lock_is_released_on_drop() -> TestResult {
        let dir = tempfile::tempdir()?;
        let first = lock_in(dir.path(), "/dev/ttyNOPE-test0")?;
        // Another open file description (as another process would have) is refused.
        let second = lock_in(dir.path(), "/dev/ttyNOPE-test0");
        let Err(PortLockError::Busy(busy)) = second else {
            return Err(format!("second locker admitted: {second:?}").into());
        };
        assert_eq!(busy.port, "/dev/ttyNOPE-test0");
        assert_eq!(busy.holder.pid, Some(std::process::id()));
        assert!(busy.holder.command.is_some());
        let text = busy.to_string();
        assert!(text.contains("/dev/ttyNOPE-test0"), "{text}");
        assert!(text.contains(&std::process::id().to_string()), "{text}");
        // Another port is independent.
        let other = lock_in(dir.path(), "/dev/ttyNOPE-test1")?;
        drop(first);
        let again = lock_in(dir.path(), "/dev/ttyNOPE-test0")?;
        assert_eq!(again.port(), "/dev/ttyNOPE-test0");
        drop(other);
        Ok(())
    }

    #[test]
    fn the_refusal_names_the_daemon_and_how_to_reach_it() {
        let busy = PortBusy {
            port: "/dev/ttyUSB0".into(),
            lock: "/tmp/x.lock".into(),
            holder: Holder::parse(
                "pid=42\ncommand=stagehand serve --listen 127.0.0.1:8080\nurl=http://127.0.0.1:8080\n",
            ),
        };
        let text = busy.to_string();
        assert!(text.contains("pid 42"), "{text}");
        assert!(text.contains("stagehand serve"), "{text}");
        assert!(
            text.contains("the daemon at http://127.0.0.1:8080 owns this rig; use `stagehand run --remote http://127.0.0.1:8080 script.rhai`"),
            "{text}"
        );
    }

    #[test]
    fn holder_text_round_trips() {
        let h = Holder {
            pid: Some(7),
            command: Some("stagehand run a.rhai".into()),
            url: Some("http://[::1]:9".into()),
        };
        assert_eq!(Holder::parse(&h.render()), h);
        assert_eq!(Holder::parse("garbage"), Holder::default());
    }

    #[test]
    fn symlinked_names_of_one_port_share_a_lock_file() -> TestResult {
        let dir = tempfile::tempdir()?;
        let target = dir.path().join("ttyFAKE0");
        std::fs::write(&target, b"")?;
        let link = dir.path().join("by-id-link");
        std::os::unix::fs::symlink(&target, &link)?;
        let locks = dir.path().join("locks");
        let a = lock_file_for(&locks, &canonical_port(&target.display().to_string()));
        let b = lock_file_for(&locks, &canonical_port(&link.display().to_string()));
        assert_eq!(a, b);
        let c = lock_file_for(&locks, "hid:ABC");
        assert_ne!(a, c);
        assert!(
            c.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("hid_ABC-"))
        );
        Ok(())
    }
}
