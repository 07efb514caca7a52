//! `stagehand verify` on a 10,000-frame run: a run of 1,250 captures on all 8 cameras of the
//! simulated light stage (64×48 cameras, virtual clock) is made once, then verified three times
//! with [`stagehand::storage::verify::verify_run`] (what the CLI and the API call). The baseline,
//! measured in the same run on the same files: reading and hashing every recorded file on one
//! thread (what `sha256sum frames/*` does), so the ratio shows what the parallel check with
//! decoding and the plan and layout checks cost against plain hashing.
//!
//! Run: `cargo bench --bench verify` (release) or `bench/verify.sh` (also times the CLI).
//! Knobs: `STAGEHAND_VERIFY_FRAMES` (default 10000, a multiple of 8),
//! `STAGEHAND_VERIFY_SIZE` (`WxH`, default `64x48`), `STAGEHAND_VERIFY_KEEP` (a directory: the
//! run is made there and kept, for timing `stagehand verify` on it). Prints one JSON line.

mod support;

use std::collections::BTreeMap;
use std::time::Instant;

use sha2::{Digest, Sha256};
use stagehand::plan::{Action, Plan};
use stagehand::rig::RigSource;
use stagehand::storage::verify::verify_run;
use stagehand_devices::rig::BUILTIN_LIGHTSTAGE;
use support::step;

/// One lamp on, then `captures` one-exposure captures on every camera.
fn plan(captures: usize) -> Plan {
    let mut steps = vec![step(
        0,
        Action::Lamps {
            states: BTreeMap::from([("lamp1".to_string(), true)]),
        },
    )];
    for i in 0..captures {
        steps.push(step(
            i + 1,
            Action::Capture {
                exposures_s: vec![0.001],
                cameras: (1..=8).map(|c| format!("cam{c}")).collect(),
                gain: 1.0,
                hdr: false,
                label: format!("capture {i}"),
                min_interval_s: 0.0,
            },
        ));
    }
    Plan {
        script: "verify-bench".into(),
        params: BTreeMap::new(),
        steps,
    }
}

fn main() {
    let frames: usize = std::env::var("STAGEHAND_VERIFY_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    let size = std::env::var("STAGEHAND_VERIFY_SIZE").unwrap_or_else(|_| "64x48".into());
    let (w, h) = size.split_once('x').expect("STAGEHAND_VERIFY_SIZE is WxH");
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", &format!("width = {w}"))
        .replace("height = 768", &format!("height = {h}"));
    let rig = RigSource::from_text(&text, "bench:lightstage").expect("rig");
    let plan = plan(frames / 8);
    let prepared = support::prepared_from_plan(plan, rig);
    let tmp = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).expect("scratch");
    let out = std::env::var_os("STAGEHAND_VERIFY_KEEP")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| tmp.path().to_path_buf());

    let made = Instant::now();
    let (dir, summary, _) = support::run(prepared, &out);
    let made_s = made.elapsed().as_secs_f64();
    assert_eq!(summary.frames_written, frames, "frames written");

    let mut times = Vec::new();
    let mut report = None;
    for _ in 0..3 {
        let t = Instant::now();
        report = Some(verify_run(&dir).expect("verify"));
        times.push(t.elapsed().as_secs_f64());
    }
    let report = report.expect("three verifications");
    assert!(report.ok, "{}", report.render());
    assert_eq!(report.files_checked, frames);
    times.sort_by(f64::total_cmp);

    // Baseline: every recorded file read and hashed on one thread.
    let t = Instant::now();
    let mut bytes = 0u64;
    for entry in std::fs::read_dir(dir.join("frames")).expect("frames dir") {
        let data = std::fs::read(entry.expect("entry").path()).expect("read");
        bytes += data.len() as u64;
        std::hint::black_box(Sha256::digest(&data));
    }
    let baseline_s = t.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({
            "bench": "verify",
            "frames": frames,
            "camera": size,
            "bytes": report.bytes_checked,
            "run_dir": dir.display().to_string(),
            "make_run_s": made_s,
            "verify_s_min": times[0],
            "verify_s_median": times[1],
            "frames_per_s": frames as f64 / times[1],
            "mib_per_s": report.bytes_checked as f64 / (1 << 20) as f64 / times[1],
            "baseline_sha256_one_thread_s": baseline_s,
            "baseline_bytes": bytes,
            "ratio_verify_to_baseline": times[1] / baseline_s,
        })
    );
}
