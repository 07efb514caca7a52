//! Shared helpers for the integration tests: small simulated rigs, running sequences through
//! the library on the paused-clock runtime, and reading datasets back.

#![allow(dead_code)]

pub mod api;
pub mod calibration;

use std::future::Future;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use stagehand::executor::{Answer, AutoConfirm, Event, Operator, RunControl, Summary};
use stagehand::rig::Emulation;
use stagehand::rig::RigSource;
use stagehand::script::ScriptSource;
use stagehand::session::{self, DEFAULT_RESERVE_BYTES, Prepared, SessionError, Wiring};
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER};
use tokio::sync::broadcast;

/// A folder for a `static` that several tests of this binary share. A static is never dropped,
/// so a `TempDir` in one outlived every run (about 400 MB a run for the dipole tests): the
/// folder sits under Cargo's target tmp dir, named after this process, and each process first
/// removes the folders of processes that are gone.
pub fn static_dir(name: &str) -> PathBuf {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let prefix = format!("{name}-");
    if cfg!(target_os = "linux")
        && let Ok(entries) = std::fs::read_dir(root)
    {
        for entry in entries.flatten() {
            let file = entry.file_name();
            let pid = file
                .to_str()
                .and_then(|f| f.strip_prefix(&prefix))
                .and_then(|p| p.parse::<u32>().ok());
            if pid.is_some_and(|pid| !Path::new(&format!("/proc/{pid}")).exists()) {
                let _ = std::fs::remove_dir_all(entry.path());
            }
        }
    }
    let dir = root.join(format!("{prefix}{}", std::process::id()));
    // A reused process id's leftovers.
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a folder under the target tmp dir");
    dir
}

/// Repository root (where `sequences/` lives).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The built-in rig with cameras shrunk to `w`×`h` and ground truth written beside every
/// capture (`sim.ground_truth = true`).
pub fn small_rig_with_ground_truth(name: &str, w: u32, h: u32) -> RigSource {
    let rig = small_rig(name, w, h);
    let text = rig
        .text
        .replacen("[sim]\n", "[sim]\nground_truth = true\n", 1);
    assert_ne!(text, rig.text, "the rig has a [sim] table");
    RigSource::from_text(&text, &format!("test:{name}+ground_truth")).expect("rig parses")
}

/// The built-in rig with cameras shrunk to `w`×`h` so tests render fast.
pub fn small_rig(name: &str, w: u32, h: u32) -> RigSource {
    let text = match name {
        "reflectometer" => BUILTIN_REFLECTOMETER,
        _ => BUILTIN_LIGHTSTAGE,
    };
    let text = text
        .replace("width = 1024", &format!("width = {w}"))
        .replace("height = 768", &format!("height = {h}"));
    RigSource::from_text(&text, &format!("test:{name}")).expect("built-in rig parses")
}

/// Writes the small rig to a file (for CLI tests).
pub fn small_rig_file(dir: &Path, name: &str, w: u32, h: u32) -> PathBuf {
    let rig = small_rig(name, w, h);
    let path = dir.join(format!("{name}-{w}x{h}.toml"));
    std::fs::write(&path, rig.text).expect("write rig");
    path
}

pub fn script(name: &str) -> ScriptSource {
    ScriptSource::from_file(&root().join("sequences").join(name)).expect("sequence exists")
}

pub fn sets(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// Records every prompt and answers with `answer_at(step)`.
pub struct ScriptedOperator {
    pub prompts: Mutex<Vec<(usize, String)>>,
    pub abort_at: Option<usize>,
}

impl ScriptedOperator {
    pub fn new(abort_at: Option<usize>) -> Arc<Self> {
        Arc::new(Self {
            prompts: Mutex::new(Vec::new()),
            abort_at,
        })
    }
}

impl Operator for ScriptedOperator {
    fn confirm<'a>(
        &'a self,
        step: usize,
        message: &'a str,
    ) -> Pin<Box<dyn Future<Output = Answer> + Send + 'a>> {
        self.prompts
            .lock()
            .unwrap()
            .push((step, message.to_string()));
        let answer = if self.abort_at == Some(step) {
            Answer::Abort
        } else {
            Answer::Continue
        };
        Box::pin(async move { answer })
    }
}

/// A finished run: its directory, its summary (or error) and every event it emitted.
pub struct Outcome {
    pub dir: PathBuf,
    pub result: Result<Summary, SessionError>,
    pub events: Vec<Event>,
}

/// Runs `prepared` into a new run under `out` on the runtime the rig needs.
pub fn run_prepared(
    prepared: Prepared,
    out: &Path,
    seed: u64,
    operator: Arc<dyn Operator>,
    control: RunControl,
) -> Outcome {
    run_prepared_with(prepared, out, seed, operator, control, None)
}

/// Like [`run_prepared`], optionally with the serial devices emulated (see
/// `stagehand::rig::Emulation`).
pub fn run_prepared_with(
    prepared: Prepared,
    out: &Path,
    seed: u64,
    operator: Arc<dyn Operator>,
    control: RunControl,
    emulation: Option<Emulation>,
) -> Outcome {
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, out, seed).expect("create run");
    let dir = store.dir().to_path_buf();
    let (result, events) = runtime.block_on(async move {
        let (tx, mut rx) = broadcast::channel(100_000);
        let collector = tokio::spawn(async move {
            let mut all = Vec::new();
            while let Ok(e) = rx.recv().await {
                let end = matches!(e, Event::RunFinished { .. });
                all.push(e);
                if end {
                    break;
                }
            }
            all
        });
        let wiring = Wiring {
            events: tx,
            control,
            operator,
            reserve_bytes: DEFAULT_RESERVE_BYTES,
        };
        let rig = session::open_rig(&prepared.rig, seed, emulation.as_ref()).expect("open rig");
        let r = session::run(prepared, store, rig, wiring).await;
        (r, collector.await.unwrap_or_default())
    });
    Outcome {
        dir,
        result,
        events,
    }
}

/// Builds and runs a sequence with `--set` overrides on a small rig; confirms every prompt.
pub fn run_sequence(
    seq: &str,
    rig: RigSource,
    overrides: &[(&str, &str)],
    out: &Path,
    seed: u64,
) -> Outcome {
    let prepared = session::prepare(script(seq), &sets(overrides), rig).expect("sequence prepares");
    run_prepared(
        prepared,
        out,
        seed,
        Arc::new(AutoConfirm),
        RunControl::new(),
    )
}

/// Resumes a run through the library.
pub fn resume(dir: &Path, operator: Arc<dyn Operator>) -> Result<Summary, SessionError> {
    let reopened = session::reopen(dir)?;
    let runtime = session::runtime_for(&reopened.rig).expect("runtime");
    runtime.block_on(async move {
        let (tx, _) = broadcast::channel(1024);
        let wiring = Wiring {
            events: tx,
            control: RunControl::new(),
            operator,
            reserve_bytes: DEFAULT_RESERVE_BYTES,
        };
        session::resume(reopened, wiring, None).await
    })
}

/// Every raw frame's path and decoded pixels, in path order. (Compare pixels, not files: the
/// files' metadata holds the rig time, which differs between runs in real time.)
pub fn raw_pixels(dir: &Path) -> Vec<(String, Vec<u16>)> {
    let conn = db(dir);
    let mut stmt = conn
        .prepare("SELECT path FROM frames WHERE kind = 'raw' ORDER BY path")
        .expect("query");
    let paths: Vec<String> = stmt
        .query_map([], |r| r.get(0))
        .expect("rows")
        .collect::<Result<_, _>>()
        .expect("paths");
    paths
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(dir.join(&p)).expect("frame file");
            let png = stagehand::storage::png16::decode_png16(&p, &bytes).expect("decodes");
            (p, png.pixels)
        })
        .collect()
}

/// Opens a run's index read-only.
pub fn db(dir: &Path) -> rusqlite::Connection {
    rusqlite::Connection::open_with_flags(
        dir.join("index.sqlite"),
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
    )
    .expect("open index")
}

/// (path, sha256) of every file the index records (frames and the ground truth beside them),
/// sorted by path.
pub fn checksums(dir: &Path) -> Vec<(String, String)> {
    let conn = db(dir);
    let mut stmt = conn
        .prepare(
            "SELECT path, sha256 FROM frames UNION ALL SELECT path, sha256 FROM ground_truth
             ORDER BY path",
        )
        .unwrap();
    stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(|r| r.unwrap())
        .collect()
}

/// sha256 of every file under frames/ (frames and ground truth), recomputed from disk, sorted
/// by name.
pub fn disk_checksums(dir: &Path) -> Vec<(String, String)> {
    use sha2::{Digest, Sha256};
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir.join("frames")).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name().to_string_lossy().to_string();
        let bytes = std::fs::read(entry.path()).unwrap();
        let hex: String = Sha256::digest(&bytes)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        out.push((name, hex));
    }
    out.sort();
    out
}

pub fn count(conn: &rusqlite::Connection, sql: &str) -> i64 {
    conn.query_row(sql, [], |r| r.get(0)).unwrap()
}

/// Starts a daemon in-process on a free loopback port, with its data in `data` and the
/// repository's sequences as built-in scripts; `rig` is a rig file (the built-in light stage
/// when `None`). Call inside a multi-threaded tokio runtime.
pub async fn start_daemon(
    data: &Path,
    rig: Option<&Path>,
) -> Result<stagehand::daemon::RunningDaemon, stagehand::daemon::DaemonError> {
    stagehand::daemon::start(stagehand::daemon::ServeOptions {
        rig: rig.map(|r| r.display().to_string()),
        listen: "127.0.0.1:0".parse().expect("address"),
        data: data.to_path_buf(),
        scripts: Some(root().join("sequences")),
        seed: 1,
        emulation: None,
    })
    .await
}

/// The daemon tests' setup: a daemon on the light stage with 32×24 cameras and the
/// repository's sequences, its rig file and data in a fresh temporary directory (kept alive
/// by the second value).
pub async fn small_daemon() -> (stagehand::daemon::RunningDaemon, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("temp dir");
    let rig = small_rig_file(dir.path(), "lightstage", 32, 24);
    let d = start_daemon(&dir.path().join("data"), Some(&rig))
        .await
        .expect("daemon starts");
    (d, dir)
}

/// A daemon on the built-in (full-size) light stage, its data in a fresh temporary directory.
pub async fn builtin_daemon() -> (stagehand::daemon::RunningDaemon, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = start_daemon(dir.path(), None).await.expect("daemon starts");
    (d, dir)
}

/// Runs blocking HTTP calls off the async workers (the daemon under test shares the runtime).
pub async fn blocking<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    tokio::task::spawn_blocking(f).await.expect("no panic")
}

/// Polls `cond` every 20 ms until it holds; `limit_s` only guards against a hang.
pub fn eventually(limit_s: u64, what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(limit_s);
    while !cond() {
        assert!(
            std::time::Instant::now() < deadline,
            "never happened: {what}"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}
