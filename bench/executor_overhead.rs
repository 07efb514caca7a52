//! Executor overhead per step, measured on the simulated rig (virtual clock, so devices cost
//! no wall time): a 10,000-step plan without frames, the same with tiny frames flowing through
//! rendering and the writer, and the plan estimate's error on `btf.rhai`.
//!
//! Run: `cargo bench --bench executor_overhead` (or `bench/run.sh`, which also runs the
//! Bluesky peer and prints the ratio). Prints one JSON object per measurement.

mod support;

use std::collections::BTreeMap;

use stagehand::plan::{Action, Plan};
use stagehand::rig::RigSource;
use stagehand::script::ScriptSource;
use stagehand::session::{self, Prepared};
use stagehand_devices::rig::BUILTIN_LIGHTSTAGE;
use support::{prepared_from_plan, step};

/// The built-in light stage with `w`×`h` cameras and `sample` on the turntable.
fn rig(w: u32, h: u32, sample: &str) -> RigSource {
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", &format!("width = {w}"))
        .replace("height = 768", &format!("height = {h}"))
        .replace("sample = \"bumps\"", &format!("sample = \"{sample}\""));
    RigSource::from_text(&text, "bench:lightstage").expect("rig")
}

/// `n` steps: alternating small turntable moves and lamp switches, plus (with `capture_every`)
/// a one-exposure capture on every camera every `capture_every` steps.
fn synthetic_plan(n: usize, capture_every: Option<usize>) -> Plan {
    let mut steps = Vec::with_capacity(n);
    for i in 0..n {
        let action = match capture_every {
            Some(k) if i % k == k - 1 => Action::Capture {
                exposures_s: vec![0.001],
                cameras: (1..=8).map(|c| format!("cam{c}")).collect(),
                gain: 1.0,
                hdr: false,
                label: String::new(),
                min_interval_s: 0.0,
            },
            _ if i % 2 == 0 => Action::Move {
                targets: BTreeMap::from([("turntable".to_string(), (i % 360) as f64 * 0.5)]),
            },
            _ => Action::Lamps {
                states: BTreeMap::from([(format!("lamp{}", 1 + i % 8), i % 4 == 1)]),
            },
        };
        steps.push(step(i, action));
    }
    Plan {
        script: "synthetic".into(),
        params: BTreeMap::new(),
        steps,
    }
}

struct Measured {
    wall_s: f64,
    rig_s: f64,
    estimated_s: f64,
    frames: usize,
}

fn run(prepared: Prepared, out: &std::path::Path) -> Measured {
    let estimated_s = prepared.estimate.rig_time_s;
    let (_, summary, wall_s) = support::run(prepared, out);
    Measured {
        wall_s,
        rig_s: summary.rig_time_s,
        estimated_s,
        frames: summary.frames_written,
    }
}

fn scratch() -> tempfile::TempDir {
    // Prefer memory-backed storage so the figures measure the executor, not the disk.
    let shm = std::path::Path::new("/dev/shm");
    if shm.is_dir() {
        tempfile::tempdir_in(shm).expect("tempdir")
    } else {
        tempfile::tempdir().expect("tempdir")
    }
}

fn main() {
    let n: usize = std::env::var("STAGEHAND_BENCH_STEPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    // STAGEHAND_BENCH=no_frames|frames|btf runs one measurement (for profiling).
    let only = std::env::var("STAGEHAND_BENCH").ok();
    let wanted = |name: &str| only.as_deref().is_none_or(|o| o == name);

    if wanted("no_frames") {
        let tmp = scratch();
        let m = run(
            prepared_from_plan(synthetic_plan(n, None), rig(16, 12, "flat")),
            tmp.path(),
        );
        println!(
            "{}",
            serde_json::json!({"bench": "executor_no_frames", "steps": n, "wall_s": m.wall_s, "us_per_step": m.wall_s * 1e6 / n as f64, "rig_time_s": m.rig_s})
        );
    }
    if wanted("frames") {
        let tmp = scratch();
        let m = run(
            prepared_from_plan(synthetic_plan(n, Some(4)), rig(16, 12, "flat")),
            tmp.path(),
        );
        println!(
            "{}",
            serde_json::json!({"bench": "executor_frames_flowing", "steps": n, "frames": m.frames, "camera": "16x12", "sample": "flat", "wall_s": m.wall_s, "us_per_step": m.wall_s * 1e6 / n as f64})
        );
    }
    if wanted("btf") {
        // Plan estimate against the simulated rig time for the full btf.rhai (12×12×8 × bracket).
        let tmp = scratch();
        let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/sequences/btf.rhai"));
        let script = ScriptSource::from_file(path).expect("btf.rhai");
        let prepared = session::prepare(script, &[], rig(8, 6, "bumps")).expect("btf prepares");
        let steps = prepared.plan.steps.len();
        let m = run(prepared, tmp.path());
        let error = (m.estimated_s - m.rig_s) / m.rig_s;
        println!(
            "{}",
            serde_json::json!({"bench": "btf_estimate", "steps": steps, "frames": m.frames, "estimated_rig_s": m.estimated_s, "simulated_rig_s": m.rig_s, "relative_error": error, "wall_s": m.wall_s})
        );
    }
}
