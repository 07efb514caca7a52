//! Frames to disk at the rig's full rate (issue 16): the built-in light stage's 8 cameras at
//! full size (1024×768, 16-bit) deliver the simulator's test pattern (`sim.frames =
//! "pattern"`: no rendering), paced at RATE captures a second, through the whole path a run
//! takes: trigger accounting, the writer, PNG encoding, fsync, rename and the index. It runs in
//! real time on a multi-threaded runtime, as the daemon does, so a slow writer shows as late
//! captures (the writer's memory budget is full and the next capture waits for it) and a
//! missing frame as a device fault.
//!
//! A capture is late when its trigger (the frames' `rig_time_s` in the index: when they were
//! exposed) comes more than 10 % of the period after the previous one's. The intervals between
//! the steps' ends (frames read out and handed to the writer) are reported beside them.
//!
//! Frames are deleted once written (the benchmark's disk would not hold ten minutes of them);
//! their sizes are counted first.
//!
//! Run: `cargo bench --bench frame_pipeline -- [SECONDS [RATES [WxH]]]`, e.g.
//! `-- 600 15` (the ten minutes at the seed's 15 Hz) or `-- 60 7.5,15,30`.
//! Prints one JSON object per rate. `STAGEHAND_FRAME_MEMORY=default` leaves the allocator's
//! settings alone (see `stagehand_dataset::frame_memory`). The runtime's threads run at
//! `SCHED_FIFO` 10 where the system allows it, as `stagehand` does by default;
//! `STAGEHAND_REALTIME_PRIORITY=N` (or `off`) runs them as `stagehand --realtime-priority N`
//! (or `off`) does.

// Shared with the other benchmarks; this one runs on its own real-time runtime, not `support::run`.
mod stats;
#[allow(dead_code)]
mod support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use stagehand::executor::{AutoConfirm, Event, RunControl};
use stagehand::plan::{Action, Plan};
use stagehand::rig::RigSource;
use stagehand::session::{self, Wiring};
use stagehand_devices::rig::BUILTIN_LIGHTSTAGE;
use stats::{percentile, sorted};
use support::{prepared_from_plan, step};

/// Exposure of every capture: short, so the rate is the pipeline's, not the exposure's.
const EXPOSURE_S: f64 = 0.0005;
/// A capture starting this much later than its period after the last is late.
const LATE_FRACTION: f64 = 0.1;

/// The light stage at `w`×`h`, 16-bit, its cameras reading out fast enough for `rate`
/// captures a second, delivering the test pattern.
fn rig(w: u32, h: u32, rate: f64) -> RigSource {
    // Readout takes 1/fps after the exposure. A quarter of the period: the cameras are not
    // what is measured, and the step's own device round trips must fit beside the readout.
    let fps = 4.0 * rate;
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", &format!("width = {w}"))
        .replace("height = 768", &format!("height = {h}"))
        .replace("bit_depth = 12", "bit_depth = 16")
        .replace("fps = 15.0", &format!("fps = {fps}"))
        .replacen("[sim]\n", "[sim]\nframes = \"pattern\"\n", 1);
    RigSource::from_text(&text, "bench:lightstage-pattern").expect("rig")
}

/// `n` captures on every camera, each at least 1/`rate` s after the last.
fn plan(n: usize, rate: f64) -> Plan {
    let steps = (0..n)
        .map(|i| {
            step(
                i,
                Action::Capture {
                    exposures_s: vec![EXPOSURE_S],
                    cameras: (1..=8).map(|c| format!("cam{c}")).collect(),
                    gain: 1.0,
                    hdr: false,
                    label: String::new(),
                    min_interval_s: 1.0 / rate,
                },
            )
        })
        .collect();
    Plan {
        script: "frame-pipeline".into(),
        params: BTreeMap::new(),
        steps,
    }
}

/// The intervals between successive events of a run, against the planned period.
struct Intervals {
    /// Intervals longer than the period by more than [`LATE_FRACTION`].
    late: usize,
    worst_s: f64,
    /// The 99th and 99.9th percentiles: finer than the late count for comparing
    /// builds, since a late capture is rare.
    p99_s: f64,
    p999_s: f64,
}

impl Intervals {
    fn between(times: &[f64], period: f64) -> Self {
        let sorted = sorted(times.windows(2).map(|w| w[1] - w[0]).collect());
        Intervals {
            late: sorted
                .iter()
                .filter(|i| **i > period * (1.0 + LATE_FRACTION))
                .count(),
            worst_s: sorted.last().copied().unwrap_or(0.0),
            p99_s: percentile(&sorted, 0.99),
            p999_s: percentile(&sorted, 0.999),
        }
    }

    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "late": self.late,
            "worst_s": self.worst_s,
            "p99_s": self.p99_s,
            "p999_s": self.p999_s,
        })
    }
}

/// Each capture step's trigger in rig time, from the run's index: the earliest frame's
/// `rig_time_s` (every camera's frame carries its trigger's time).
fn trigger_times(run_dir: &Path) -> Vec<f64> {
    let db = rusqlite::Connection::open_with_flags(
        run_dir.join(stagehand_dataset::layout::INDEX),
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
    )
    .expect("run index");
    let mut stmt = db
        .prepare("SELECT MIN(rig_time_s) FROM frames GROUP BY step ORDER BY step")
        .expect("query");
    stmt.query_map([], |row| row.get(0))
        .expect("frames")
        .collect::<Result<_, _>>()
        .expect("trigger times")
}

/// A line of /proc/self/status in kB (VmRSS, VmHWM).
fn status_kb(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Deletes the written frames under `dir` (final names only: a temp file is the writer's),
/// adding their sizes to `bytes`.
fn sweep_frames(dir: &Path, bytes: &AtomicU64) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "png")
            && let Ok(meta) = entry.metadata()
            && std::fs::remove_file(&path).is_ok()
        {
            bytes.fetch_add(meta.len(), Ordering::Relaxed);
        }
    }
}

/// What one rate's run measured.
struct Measured {
    steps: usize,
    frames: usize,
    wall_s: f64,
    achieved_hz: f64,
    /// Between the triggers of successive captures: when the frames were exposed.
    triggers: Intervals,
    /// Between the ends of successive capture steps (frames read out and handed to the writer).
    ends: Intervals,
    faults: usize,
    max_queue_steps: usize,
    disk_bytes: u64,
    rss_mib: Vec<f64>,
    peak_mib: f64,
}

fn measure(seconds: f64, rate: f64, (w, h): (u32, u32), out: &Path) -> Measured {
    let n = (seconds * rate).round().max(2.0) as usize;
    let prepared = prepared_from_plan(plan(n, rate), rig(w, h, rate));
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .on_thread_start(stagehand_devices::realtime::raise_this_thread)
        .build()
        .expect("runtime");
    let store = session::create_run(&prepared, out, 1).expect("run dir");
    let run_dir: PathBuf = store.dir().to_path_buf();
    let frames_dir = run_dir.join(stagehand_dataset::layout::FRAMES_DIR);
    let done = Arc::new(AtomicBool::new(false));
    let disk_bytes = Arc::new(AtomicU64::new(0));
    // Memory every second; written frames deleted as they land.
    let sampler = {
        let (done, disk_bytes, frames_dir) = (done.clone(), disk_bytes.clone(), frames_dir.clone());
        std::thread::spawn(move || {
            let mut rss = Vec::new();
            while !done.load(Ordering::Relaxed) {
                rss.push(status_kb("VmRSS:") as f64 / 1024.0);
                sweep_frames(&frames_dir, &disk_bytes);
                std::thread::sleep(Duration::from_secs(1));
            }
            rss
        })
    };
    let started = Instant::now();
    let (summary, events) = runtime.block_on(async move {
        let (events, mut rx) = tokio::sync::broadcast::channel(1 << 16);
        // Queue depth (steps captured, not yet durable) and each capture's end in rig time.
        let listener = tokio::spawn(async move {
            let (mut finished, mut durable, mut max_queue, mut faults) = (0usize, 0usize, 0, 0);
            let mut ends = Vec::new();
            while let Ok(event) = rx.recv().await {
                match event {
                    Event::StepFinished { rig_time_s, .. } => {
                        finished += 1;
                        ends.push(rig_time_s);
                    }
                    Event::StepDurable { .. } => durable += 1,
                    Event::DeviceFault { .. } => faults += 1,
                    Event::RunFinished { .. } => break,
                    _ => {}
                }
                max_queue = max_queue.max(finished.saturating_sub(durable));
            }
            (ends, max_queue, faults)
        });
        let wiring = Wiring {
            events,
            control: RunControl::new(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        let rig = session::open_rig(&prepared.rig, 1, None).expect("rig opens");
        // On a worker, as the daemon runs it.
        let summary = tokio::spawn(session::run(prepared, store, rig, wiring))
            .await
            .expect("run task")
            .expect("run");
        (summary, listener.await.expect("listener"))
    });
    let wall_s = started.elapsed().as_secs_f64();
    done.store(true, Ordering::Relaxed);
    let rss_mib = sampler.join().expect("sampler");
    sweep_frames(&frames_dir, &disk_bytes);
    let (ends, max_queue_steps, faults) = events;
    let period = 1.0 / rate;
    let span = ends.last().copied().unwrap_or(0.0) - ends.first().copied().unwrap_or(0.0);
    Measured {
        steps: summary.steps_done,
        frames: summary.frames_written,
        wall_s,
        achieved_hz: if span > 0.0 {
            (ends.len() - 1) as f64 / span
        } else {
            0.0
        },
        triggers: Intervals::between(&trigger_times(&run_dir), period),
        ends: Intervals::between(&ends, period),
        faults,
        max_queue_steps,
        disk_bytes: disk_bytes.load(Ordering::Relaxed),
        rss_mib,
        peak_mib: status_kb("VmHWM:") as f64 / 1024.0,
    }
}

/// Set to `default` to leave glibc's allocator settings as they are, for the side-by-side
/// figure; otherwise the benchmark keeps frame memory as `stagehand` does at start.
const ALLOCATOR_ENV: &str = "STAGEHAND_FRAME_MEMORY";
/// A priority (1–99) or `off`, to run as `stagehand --realtime-priority` does; unset, the
/// default priority, as `stagehand` without the option.
const REALTIME_ENV: &str = "STAGEHAND_REALTIME_PRIORITY";

fn main() {
    // As `stagehand`'s main does, before any thread starts.
    let allocator = if std::env::var(ALLOCATOR_ENV).is_ok_and(|v| v == "default") {
        "glibc defaults"
    } else if stagehand_dataset::keep_frame_memory() {
        "frame memory kept"
    } else {
        "frame memory not kept (not glibc)"
    };
    let realtime = std::env::var(REALTIME_ENV).ok().map(|v| {
        stagehand_devices::realtime::parse_choice(&v)
            .unwrap_or_else(|e| panic!("{REALTIME_ENV}={v}: {e}"))
    });
    stagehand_devices::realtime::choose(realtime);
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let seconds: f64 = args.first().and_then(|a| a.parse().ok()).unwrap_or(600.0);
    let rates: Vec<f64> = args
        .get(1)
        .map_or("15", String::as_str)
        .split(',')
        .map(|r| {
            r.parse()
                .expect("RATES: comma-separated captures per second")
        })
        .collect();
    let (w, h) = args
        .get(2)
        .and_then(|s| s.split_once('x'))
        .map_or((1024, 768), |(w, h)| {
            (w.parse().expect("width"), h.parse().expect("height"))
        });
    for rate in rates {
        let tmp = tempfile::tempdir().expect("scratch");
        let m = measure(seconds, rate, (w, h), tmp.path());
        let raw_mb = m.frames as f64 * f64::from(w * h) * 3.0 * 2.0 / 1e6;
        let quarter = |q: usize| m.rss_mib.get(m.rss_mib.len() * q / 4).copied();
        println!(
            "{}",
            serde_json::json!({
                "bench": "frame_pipeline",
                "cameras": 8,
                "size": format!("{w}x{h}"),
                "bit_depth": 16,
                "format": "png16 fast",
                "allocator": allocator,
                // The priority the runtime's threads ran at (none if the system refused).
                "realtime_priority": stagehand_devices::realtime::priority()
                    .filter(|_| !stagehand_devices::realtime::refused()),
                "scratch": tmp.path(),
                "rate_hz": rate,
                "seconds": seconds,
                "steps": m.steps,
                "frames": m.frames,
                "wall_s": m.wall_s,
                "captures_per_s": m.achieved_hz,
                "frames_per_s": m.frames as f64 / m.wall_s,
                "raw_mb_per_s": raw_mb / m.wall_s,
                "disk_mb_per_s": m.disk_bytes as f64 / 1e6 / m.wall_s,
                "compression": m.disk_bytes as f64 / 1e6 / raw_mb.max(1e-9),
                "late_captures": m.triggers.late,
                "trigger_intervals": m.triggers.json(),
                "step_end_intervals": m.ends.json(),
                "device_faults": m.faults,
                "max_queue_steps": m.max_queue_steps,
                "rss_mib_quarters": [quarter(1), quarter(2), quarter(3), m.rss_mib.last()],
                "peak_rss_mib": m.peak_mib,
            })
        );
    }
}
