//! The dataset every test of this module serves: quickstart run once per test binary by the
//! CLI engine in-process (small simulated light stage, virtual clock, one camera frame stalled
//! so the run records a dropped frame, a device error and a reconnect), a copy whose index rows
//! and files point outside it, a copy with damaged frame files, and secrets beside them that
//! must never be served.

use crate::common;

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use stagehand::executor::{AutoConfirm, RunControl};
use stagehand::session::{self, Wiring};
use stagehand::storage::RunStatus;
use tokio::sync::broadcast;

/// Marker inside files that must never be served.
pub(super) const SECRET: &str = "TOP-SECRET-daemon-frames-test";

/// A data directory with one real run and one tampered copy of it.
pub(super) struct Dataset {
    pub(super) data: PathBuf,
    pub(super) run_id: String,
    pub(super) run_dir: PathBuf,
    /// A copy of the run whose index rows / files point outside it: (frame id, how).
    pub(super) evil_id: String,
    pub(super) evil_frames: Vec<(i64, &'static str)>,
    /// A copy of the run with damaged frame files: (frame id, its path, how).
    pub(super) damaged_id: String,
    pub(super) damaged_frames: Vec<(i64, String, &'static str)>,
}

/// The dataset, made by the first test that asks.
pub(super) fn dataset() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        // The daemon's recorder, installed before the executor runs so its metrics land there.
        stagehand::daemon::metrics_handle();
        std::thread::spawn(make_dataset)
            .join()
            .expect("dataset thread")
    })
}

fn make_dataset() -> Dataset {
    // A static is never dropped, so a temporary directory would outlive every test run: the
    // dataset lives in one fixed directory under the build's test scratch space instead,
    // replaced by each run.
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("daemon_frames-dataset");
    match std::fs::remove_dir_all(&root) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => panic!("cannot clear {}: {e}", root.display()),
    }
    let data = root.join("data");
    let runs = data.join("runs");
    std::fs::create_dir_all(&runs).expect("runs dir");
    let prepared = session::prepare(
        common::script("quickstart.rhai"),
        &[],
        common::small_rig("lightstage", 32, 24),
    )
    .expect("quickstart prepares");
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, &runs, 7).expect("create run");
    let run_dir = store.dir().to_path_buf();
    let summary = runtime
        .block_on(async move {
            let (tx, _) = broadcast::channel(1024);
            let wiring = Wiring {
                events: tx,
                control: RunControl::new(),
                operator: Arc::new(AutoConfirm),
                reserve_bytes: 0,
            };
            let rig = session::open_rig(&prepared.rig, 7, None).expect("open rig");
            // One frame cam1 never delivers: a MissingFrame fault, recovery, and the step again.
            rig.world
                .as_ref()
                .expect("simulated rig")
                .stall_camera("cam1", 1);
            session::run(prepared, store, rig, wiring).await
        })
        .expect("quickstart runs");
    assert_eq!(summary.status, RunStatus::Done);
    let run_id = file_name(&run_dir);

    // Tokens now, so the daemons the tests start concurrently all load the same file.
    stagehand::daemon::auth::Tokens::load_or_create(&data).expect("tokens");

    // Secrets outside the run, and a tampered copy of the run pointing at them.
    std::fs::write(root.join("secret.txt"), SECRET).expect("secret");
    std::fs::write(runs.join("secret.txt"), SECRET).expect("secret in runs");
    let evil_id = "evil-run".to_string();
    let evil = runs.join(&evil_id);
    copy_dir(&run_dir, &evil);
    std::fs::write(evil.join("secret.txt"), SECRET).expect("secret in run");
    let conn = rusqlite::Connection::open(evil.join("index.sqlite")).expect("open copy");
    let ids: Vec<(i64, String)> = conn
        .prepare("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 5")
        .and_then(|mut s| {
            s.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?
                .collect::<Result<_, _>>()
        })
        .expect("frame ids");
    let outside = root.join("secret.txt");
    let mut evil_frames = Vec::new();
    for ((id, path), (how, new_path)) in ids.iter().zip([
        ("absolute path", outside.display().to_string()),
        ("dot-dot path", "../secret.txt".to_string()),
        ("dot-dot inside frames", "frames/../secret.txt".to_string()),
        ("deep dot-dot", "frames/../../../secret.txt".to_string()),
        ("symlink in frames/", String::new()),
    ]) {
        if new_path.is_empty() {
            // Replace the frame file by a symlink pointing outside the run.
            let file = evil.join(path);
            std::fs::remove_file(&file).expect("remove frame");
            std::os::unix::fs::symlink(&outside, &file).expect("plant symlink");
        } else {
            conn.execute(
                "UPDATE frames SET path = ?1 WHERE id = ?2",
                rusqlite::params![new_path, id],
            )
            .expect("tamper");
        }
        evil_frames.push((*id, how));
    }
    drop(conn);
    // A run directory that is a symlink to a run elsewhere is not a run.
    let elsewhere = root.join("elsewhere");
    copy_dir(&run_dir, &elsewhere);
    std::os::unix::fs::symlink(&elsewhere, runs.join("linked-run")).expect("link run");
    let (damaged_id, damaged_frames) = damage_a_copy(&run_dir, &runs);
    Dataset {
        data,
        run_id,
        run_dir,
        evil_id,
        evil_frames,
        damaged_id,
        damaged_frames,
    }
}

/// Copies the run to `damaged-run` and damages frame files there: a raw PNG replaced by
/// garbage, an HDR EXR with one flipped byte, a raw PNG deleted.
fn damage_a_copy(run_dir: &Path, runs: &Path) -> (String, Vec<(i64, String, &'static str)>) {
    let id = "damaged-run".to_string();
    let copy = runs.join(&id);
    copy_dir(run_dir, &copy);
    let conn = common::db(&copy);
    let row = |sql: &str| -> (i64, String) {
        conn.query_row(sql, [], |r| Ok((r.get(0)?, r.get(1)?)))
            .expect("frame row")
    };
    let garbage = row("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 1");
    let flipped = row("SELECT id, path FROM frames WHERE kind = 'hdr' ORDER BY id LIMIT 1");
    let missing = row("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id DESC LIMIT 1");
    std::fs::write(copy.join(&garbage.1), b"not a PNG at all").expect("garbage");
    let mut bytes = std::fs::read(copy.join(&flipped.1)).expect("hdr file");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(copy.join(&flipped.1), bytes).expect("flip a byte");
    std::fs::remove_file(copy.join(&missing.1)).expect("delete");
    let frames = vec![
        (garbage.0, garbage.1, "raw PNG replaced by garbage"),
        (flipped.0, flipped.1, "HDR EXR with a flipped byte"),
        (missing.0, missing.1, "raw PNG deleted"),
    ];
    (id, frames)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .and_then(|n| n.to_str())
        .expect("utf-8 name")
        .to_string()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

/// The run's index, read-only, for the expected answers.
pub(super) fn db(d: &Dataset) -> rusqlite::Connection {
    common::db(&d.run_dir)
}

/// The one number `sql` answers on the run's index.
pub(super) fn sql_i64(d: &Dataset, sql: &str) -> i64 {
    db(d).query_row(sql, [], |r| r.get(0)).expect("query")
}
