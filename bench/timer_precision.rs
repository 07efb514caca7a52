//! How late a wait ends in real time (issue 16: the simulated rig must keep the real rig's
//! pace, and every simulated device's exposure, readout, travel and settling is a wait): the
//! rig clock's wait (`stagehand_devices::clock::sleep`, a kernel timer) side by side with
//! tokio's `sleep` (a timer wheel of millisecond ticks), alternated on one multi-threaded
//! runtime as the daemon runs, at the durations a sweep line waits (a 2 ms command latency, a
//! 20 ms exposure, a 67 ms readout).
//!
//! Run: `cargo bench --bench timer_precision [-- WAITS]` (default 100 waits per duration and
//! timer). Prints one JSON object per duration and timer: the overshoot's median, 99th
//! percentile and maximum in microseconds.

use std::time::{Duration, Instant};

/// Overshoot percentiles in µs: (median, p99, max).
fn summary(mut late_us: Vec<f64>) -> (f64, f64, f64) {
    late_us.sort_by(f64::total_cmp);
    let at = |q: f64| late_us[((late_us.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99), at(1.0))
}

fn main() {
    let waits: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(100)
        .max(1);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        for ms in [2u64, 20, 67] {
            let d = Duration::from_millis(ms);
            let (mut tokio_late, mut clock_late) = (Vec::new(), Vec::new());
            for _ in 0..waits {
                let t0 = Instant::now();
                tokio::time::sleep(d).await;
                tokio_late.push((t0.elapsed() - d).as_secs_f64() * 1e6);
                let t0 = Instant::now();
                stagehand_devices::clock::sleep(d).await;
                clock_late.push((t0.elapsed() - d).as_secs_f64() * 1e6);
            }
            for (timer, late) in [
                ("tokio::time::sleep", tokio_late),
                ("clock::sleep", clock_late),
            ] {
                let (median, p99, max) = summary(late);
                println!(
                    "{}",
                    serde_json::json!({
                        "bench": "timer_precision",
                        "timer": timer,
                        "wait_ms": ms,
                        "waits": waits,
                        "late_median_us": median,
                        "late_p99_us": p99,
                        "late_max_us": max,
                    })
                );
            }
        }
    });
}
