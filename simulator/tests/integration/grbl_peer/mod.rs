//! The real GRBL 1.1h firmware as a test peer, kept outside this repository (the unmodified
//! firmware compiled with grbl-sim, served on a pty by its `serve.py`; found through
//! `$STAGEHAND_GRBL_PEER`, else `shared/peers/grbl` beside the checkout), built once into the target
//! directory. Tests that need it call [`Board::start`]; without the peer they are skipped with a
//! message, unless `STAGEHAND_REQUIRE_PEERS=1` (set by CI), which makes a missing peer a failure.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, RwLock, RwLockReadGuard, RwLockWriteGuard};

/// Settings of the test boards: homing, soft limits, no laser mode, 142.222 steps per unit,
/// 30 units/s, 60 units/s², travel 400/400/100, seek 40 units/s, locate 10 units/s.
pub const SETTINGS: &str = "$22=1 $20=1 $32=0 $23=0 $27=1 $24=600 $25=2400 \
    $100=142.222 $101=142.222 $102=142.222 $110=1800 $111=1800 $112=1800 \
    $120=60 $121=60 $122=60 $130=400 $131=400 $132=100";

/// Accelerations of 600 units/s² (`$120`–`$122`) instead of [`SETTINGS`]' 60: for tests about
/// the protocol, whose homing cycles and moves then take a fraction of the wall time.
pub const FAST: &str = "$120=600 $121=600 $122=600";

/// Where each axis's homing switch sits, in units of travel from the power-on position.
pub const SWITCH_AT: f64 = 5.0;

/// [`SETTINGS`] followed by `extra` as (`$N`, value) pairs, for an emulator set up alike.
pub fn settings(extra: &str) -> Vec<(u32, f64)> {
    format!("{SETTINGS} {extra}")
        .split_whitespace()
        .filter_map(|s| {
            let (k, v) = s.strip_prefix('$')?.split_once('=')?;
            Some((k.parse().ok()?, v.parse().ok()?))
        })
        .collect()
}

/// A two-thread runtime for a test that talks to a board (and perhaps an emulator).
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

/// The two builds of `build.sh`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Build {
    /// Stock `config.h`: `$H` only.
    Stock,
    /// `HOMING_SINGLE_AXIS_COMMANDS`: `$HX`, `$HY`, `$HZ`.
    SingleAxis,
}

impl Build {
    fn file(self) -> &'static str {
        match self {
            Build::Stock => "grbl-1.1h",
            Build::SingleAxis => "grbl-1.1h-single-axis",
        }
    }
}

/// True when CI demands the peers (a missing one is then a failure, not a skip).
pub fn required() -> bool {
    std::env::var("STAGEHAND_REQUIRE_PEERS").is_ok_and(|v| v == "1")
}

/// Turns of a test binary that holds real-firmware tests: those run one at a time and
/// alone, every other test of the binary beside any but them.
static TURNS: RwLock<()> = RwLock::new(());

/// A test's turn ([`exclusive`] or [`alongside`]), held until dropped.
pub enum Turn {
    /// A real-firmware test's: nothing else runs.
    Alone(RwLockWriteGuard<'static, ()>),
    /// Any other test's: runs beside others, never beside a real-firmware test.
    Shared(RwLockReadGuard<'static, ()>),
}

/// Real-firmware tests run one at a time and alone in their test binary: grbl-sim simulates
/// the AVR in real time and must not starve (a starved simulator reports false homing
/// alarms), so no other test loads the CPU meanwhile.
pub fn exclusive() -> Turn {
    Turn::Alone(TURNS.write().unwrap_or_else(|e| e.into_inner()))
}

/// Every other test of a binary with real-firmware tests takes this first: it may run beside
/// other tests, but waits while a real-firmware test runs.
pub fn alongside() -> Turn {
    Turn::Shared(TURNS.read().unwrap_or_else(|e| e.into_inner()))
}

/// The workspace root: the nearest folder above the crate holding `Cargo.lock`.
fn workspace() -> PathBuf {
    let mut dir = Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf();
    while !dir.join("Cargo.lock").is_file() {
        match dir.parent() {
            Some(p) => dir = p.to_path_buf(),
            None => return PathBuf::from(env!("CARGO_MANIFEST_DIR")),
        }
    }
    dir
}

/// The peer's folder: `$STAGEHAND_GRBL_PEER`, or `shared/peers/grbl` beside the checkout.
fn peer_dir() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("STAGEHAND_GRBL_PEER") {
        return Some(PathBuf::from(p));
    }
    let ws = workspace();
    [
        ws.join("../shared/peers/grbl"),
        PathBuf::from("/work/shared/peers/grbl"),
    ]
    .into_iter()
    .find(|p| p.join("build.sh").is_file())
}

/// The firmware binary of `build`, built on first use; `None` (with the reason) if the peer
/// or a C compiler is missing.
fn firmware(build: Build) -> Result<PathBuf, String> {
    static BUILD: Mutex<()> = Mutex::new(());
    let _once = BUILD.lock().unwrap_or_else(|e| e.into_inner());
    let target = std::env::var("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|_| workspace().join("target"));
    let out = target.join("grbl-peer");
    let bin = out.join(build.file());
    if bin.is_file() {
        return Ok(bin);
    }
    let peer = peer_dir().ok_or("the GRBL peer (shared/peers/grbl) is not on this machine")?;
    let status = Command::new("bash")
        .arg(peer.join("build.sh"))
        .arg(&out)
        .stdout(Stdio::null())
        .status()
        .map_err(|e| format!("cannot run build.sh: {e}"))?;
    if !status.success() || !bin.is_file() {
        return Err(format!(
            "{} failed ({status})",
            peer.join("build.sh").display()
        ));
    }
    Ok(bin)
}

/// A real board on a pty: `serve.py` running the firmware, its EEPROM in a temp folder.
pub struct Board {
    pub build: Build,
    pub link: PathBuf,
    firmware: PathBuf,
    serve: PathBuf,
    dir: tempfile::TempDir,
    child: Option<Child>,
}

impl Board {
    /// Powers on a board of `build` with [`SETTINGS`] and then `extra` settings stored in its
    /// EEPROM (as a configured board is powered on: in Alarm with homing enabled). `None` when
    /// the peer is missing and not required.
    pub fn start(build: Build, extra: &str) -> Option<Board> {
        let firmware = match firmware(build) {
            Ok(f) => f,
            Err(why) if !required() => {
                eprintln!(
                    "skipped: {why} (set STAGEHAND_GRBL_PEER, or STAGEHAND_REQUIRE_PEERS=1 to fail)"
                );
                return None;
            }
            Err(why) => panic!("STAGEHAND_REQUIRE_PEERS=1 but {why}"),
        };
        let serve = peer_dir()
            .expect("the peer folder that built the firmware")
            .join("serve.py");
        let dir = tempfile::tempdir().expect("temp dir");
        let link = dir.path().join("ttyGRBL");
        let mut board = Board {
            build,
            link,
            firmware,
            serve,
            dir,
            child: None,
        };
        // A board configured with these settings once before: its EEPROM, copied, boots with
        // them as a configured board does.
        let eeprom = board.configured_eeprom(extra);
        std::fs::copy(&eeprom, board.dir.path().join("EEPROM.DAT")).expect("copy the EEPROM");
        board.power_on("");
        Some(board)
    }

    /// The EEPROM of a board of this build after [`SETTINGS`] and `extra` were sent to it,
    /// made once (a power-on that writes them; `serve.py` takes a second to boot the firmware)
    /// and kept beside the firmware, named by the build and the settings.
    fn configured_eeprom(&mut self, extra: &str) -> PathBuf {
        use std::hash::{Hash, Hasher};
        let settings = format!("{SETTINGS} {extra}");
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        settings.hash(&mut hasher);
        let dir = self.firmware.with_file_name("eeprom");
        let file = dir.join(format!(
            "{}-{:016x}.DAT",
            self.build.file(),
            hasher.finish()
        ));
        if file.is_file() {
            return file;
        }
        self.power_on(&settings);
        self.power_off();
        std::fs::create_dir_all(&dir).expect("the EEPROM folder");
        // Written whole, then renamed: another test binary may read it meanwhile.
        let partial = tempfile::NamedTempFile::new_in(&dir).expect("the EEPROM folder");
        std::fs::copy(self.dir.path().join("EEPROM.DAT"), partial.path()).expect("keep the EEPROM");
        partial.persist(&file).expect("keep the EEPROM");
        file
    }

    /// Starts serve.py with `settings`. A board that does not boot (serve.py saw no banner:
    /// grbl-sim once printed nothing in 10 s on an idle machine, in the clean-clone CI of
    /// bef3307) is powered on once more, as one would a real board; a second failure panics.
    fn power_on(&mut self, settings: &str) {
        if let Err(first) = self.try_power_on(settings) {
            eprintln!("the board did not boot ({first}); powering it on again");
            if let Err(again) = self.try_power_on(settings) {
                panic!("{again}");
            }
        }
    }

    fn try_power_on(&mut self, settings: &str) -> Result<(), String> {
        // grbl-sim simulates the AVR in real time on one core: above the test's own threads
        // (a renderer on both cores) it keeps answering as a board does. Without the right to
        // raise priority, `nice` says so and runs it at the normal one.
        let mut child = Command::new("nice")
            .args(["-n", "-10", "python3"])
            .arg(&self.serve)
            .arg("--firmware")
            .arg(&self.firmware)
            .arg("--link")
            .arg(&self.link)
            .arg("--dir")
            .arg(self.dir.path())
            .arg("--log")
            .arg(self.dir.path().join("traffic.log"))
            .arg("--settings")
            .arg(settings)
            .arg("--switch-deg")
            .arg(SWITCH_AT.to_string())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start serve.py");
        let mut line = String::new();
        let out = child.stdout.take().expect("stdout");
        let n = BufReader::new(out).read_line(&mut line).unwrap_or(0);
        if n == 0 || line.trim().parse::<u32>().is_err() {
            let _ = child.kill();
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut err);
            }
            let _ = child.wait();
            return Err(format!("serve.py did not start: {line}{err}"));
        }
        self.child = Some(child);
        Ok(())
    }

    /// Stops serve.py (SIGTERM: it removes the link and stops the firmware), as a board
    /// unplugged: the port disappears.
    pub fn power_off(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = Command::new("kill")
                .arg("-TERM")
                .arg(child.id().to_string())
                .status();
            let _ = child.wait();
        }
    }

    /// Plugs the board back in: the same link path, the same EEPROM, power-on state.
    pub fn power_on_again(&mut self) {
        self.power_off();
        self.power_on("");
    }

    /// Every byte both ways so far, for failure messages.
    pub fn traffic(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("traffic.log")).unwrap_or_default()
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        self.power_off();
    }
}
