//! A child `stagehand run` is killed with SIGKILL at random points, then `stagehand resume`
//! finishes the run: every frame is present exactly once and byte-identical to an
//! uninterrupted run with the same seed.

use crate::common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::*;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

fn run_args(rig: &std::path::Path, out: &std::path::Path) -> Vec<String> {
    let seq = root().join("sequences/btf.rhai");
    [
        "run",
        seq.to_str().unwrap(),
        "--rig",
        rig.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--seed",
        "5",
        "--yes",
        "--set",
        "views=2",
        "--set",
        "lights=2",
        "--set",
        "lamps=3",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn only_run_dir(out: &std::path::Path) -> std::path::PathBuf {
    let dirs: Vec<_> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    assert_eq!(
        dirs.len(),
        1,
        "exactly one run directory in {}",
        out.display()
    );
    dirs[0].clone()
}

/// A small deterministic generator for kill times (no extra dependency).
fn next(state: &mut u64) -> f64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    (*state % 10_000) as f64 / 10_000.0
}

#[test]
fn kill_at_random_points_then_resume_loses_and_duplicates_nothing() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let rig = small_rig_file(tmp.path(), "lightstage", 160, 120);

    // The uninterrupted reference run, timed to choose kill points inside it.
    let reference_out = tmp.path().join("reference");
    let started = Instant::now();
    let status = Command::new(BIN)
        .args(run_args(&rig, &reference_out))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .unwrap();
    let full = started.elapsed();
    assert!(status.success(), "reference run failed");
    let reference = disk_checksums(&only_run_dir(&reference_out));
    assert!(!reference.is_empty());

    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    for round in 0..3 {
        let out = tmp.path().join(format!("killed-{round}"));
        let mut child = Command::new(BIN)
            .args(run_args(&rig, &out))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let at = full.mul_f64(0.15 + 0.7 * next(&mut rng));
        std::thread::sleep(at);
        let killed = child.try_wait().unwrap().is_none();
        let _ = child.kill(); // SIGKILL on Unix
        let _ = child.wait();
        let dir = only_run_dir(&out);
        // Resume until done (the first resume should finish it).
        let resumed = Command::new(BIN)
            .args(["resume", dir.to_str().unwrap(), "--yes"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        assert!(
            resumed.status.success(),
            "round {round}: resume failed: {}",
            String::from_utf8_lossy(&resumed.stderr)
        );
        let got = disk_checksums(&dir);
        let differing: Vec<&String> = got
            .iter()
            .zip(&reference)
            .filter(|(g, r)| g != r)
            .map(|(g, _)| &g.0)
            .take(10)
            .collect();
        assert!(
            got.len() == reference.len() && differing.is_empty(),
            "round {round} (killed after {at:?}, mid-run: {killed}): {} frames vs {} in the uninterrupted run; first differing: {differing:?}",
            got.len(),
            reference.len()
        );
        let conn = db(&dir);
        assert_eq!(
            count(
                &conn,
                "SELECT (SELECT count(*) FROM frames) + (SELECT count(*) FROM ground_truth)"
            ) as usize,
            reference.len(),
            "round {round}: one row per file (frames and ground truth)"
        );
        assert_eq!(
            count(
                &conn,
                "SELECT count(*) FROM (SELECT path FROM frames GROUP BY path HAVING count(*) > 1)"
            ),
            0
        );
        assert_eq!(
            count(&conn, "SELECT count(*) FROM runs WHERE status='done'"),
            1
        );
        // No temp files are left behind.
        let leftovers = std::fs::read_dir(dir.join("frames"))
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .contains("tmp")
            })
            .count();
        assert_eq!(leftovers, 0);
        // And `stagehand verify` agrees: nothing damaged, missing, stray or left over.
        let verified = Command::new(BIN)
            .args(["verify", dir.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(
            verified.status.success(),
            "round {round}: verify after resume: {}",
            String::from_utf8_lossy(&verified.stdout)
        );
    }
    let _ = Duration::ZERO;
}
