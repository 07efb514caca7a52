//! The root crate's integration tests, one binary (CI links it once, not once per file): each
//! former test file is a module; `common` holds the shared helpers and the daemon tests' setup,
//! and `grbl_peer` (the real GRBL 1.1h firmware on a pty) is the simulator tests' own module.
//!
//! Tests of different modules run side by side in the test threads. Each one keeps to its own
//! temporary directories, ports chosen by the kernel and its own child processes; the
//! real-firmware tests run one at a time through `grbl_peer::exclusive`.
//!
//! The tests' own runtimes are never real-time, so their blocking clients use tokio's
//! `spawn_blocking` directly (`clippy.toml` steers the daemon's code to `realtime`'s).
#![allow(clippy::disallowed_methods)]

mod bad_input;
mod calibration;
mod calibration_colour;
mod common;
mod control;
mod daemon_api;
mod daemon_bad_input;
mod daemon_devices;
mod daemon_frames;
mod daemon_remote;
mod daemon_runs;
mod depth;
mod determinism;
mod dipole;
mod dipole_model;
mod emulated_rig;
mod ground_truth;
mod kill_resume;
mod laser_geometry;
mod pacing;
mod process;
mod real_grbl_quickstart;
mod realtime;
mod rectification;
mod reflectometer;
mod run_state;
mod sequences;
mod sim_tradeoff;
mod verify_retake;
mod ward_model;

#[path = "../../simulator/tests/integration/grbl_peer/mod.rs"]
mod grbl_peer;

/// Every test of this binary takes its turn first (`grbl_peer::alongside` or `exclusive`): a
/// test that does not may load the CPU beside a real-firmware test and starve grbl-sim (CI
/// failed so: the Ward model tests ran beside the real-GRBL quickstart, whose board fell
/// silent mid-move).
#[test]
fn every_test_takes_its_turn() {
    let _turn = grbl_peer::alongside();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/integration");
    let mut files = vec![dir];
    let mut missing = Vec::new();
    let mut tests = 0;
    while let Some(path) = files.pop() {
        if path.is_dir() {
            files.extend(
                std::fs::read_dir(&path)
                    .expect("read the test folder")
                    .map(|e| e.expect("a folder entry").path()),
            );
            continue;
        }
        if path.extension().is_none_or(|e| e != "rs") {
            continue;
        }
        let text = std::fs::read_to_string(&path).expect("read a test file");
        for (i, line) in text.lines().enumerate() {
            let attribute = line.trim_start();
            if !(attribute.starts_with("#[test]") || attribute.starts_with("#[tokio::test")) {
                continue;
            }
            tests += 1;
            // The first statement of the body: the line after the one that opens it.
            let mut rest = text.lines().skip(i + 1);
            let opens = rest.by_ref().find(|l| l.trim_end().ends_with('{'));
            let first = rest.find(|l| {
                let t = l.trim();
                !t.is_empty() && !t.starts_with("//")
            });
            let takes = first.is_some_and(|l| {
                l.contains("grbl_peer::alongside()") || l.contains("grbl_peer::exclusive()")
            });
            if !takes {
                missing.push(format!(
                    "{}:{}: {}",
                    path.display(),
                    i + 1,
                    opens.unwrap_or("").trim()
                ));
            }
        }
    }
    assert!(tests > 50, "only {tests} tests found");
    assert!(
        missing.is_empty(),
        "tests that do not take their turn first:\n{}",
        missing.join("\n")
    );
}
