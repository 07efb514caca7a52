//! Renderer throughput: frames per second for a full 8-camera step of the built-in light stage
//! (1024×768 cameras), as the acquisition loop renders it — one `render` call per camera, the
//! 8 cameras concurrently on a rayon pool — for each quality preset, for the `bumps` sample lit
//! by one lamp (lamp1 at 10°, so shadows are on) and scanned by the laser (lamps off), each
//! from a new view every step; and, at one view, a laser sweep and a lamp sequence (only the
//! light changes: what depends on the geometry alone is reused), and the lamp sequence of
//! `btf.rhai` (`bracket`: each lamp an HDR bracket of three exposures, a step per exposure,
//! the bracket's exposures sharing one trace; use a multiple of 3 steps).
//!
//! Every preset runs in a fresh process (this binary re-executes itself with
//! `STAGEHAND_RENDER_BENCH_CHILD=<preset>`), so the memory peak (`VmHWM` from
//! /proc/self/status) is that preset's own. Within a preset, each scene is timed on pools of 1
//! and 2 threads (`rayon::ThreadPoolBuilder` + `install`) for the scaling figure. Each step
//! turns the turntable by 15° so the per-world-state work (preview visibility maps) is
//! included, as in a capture sequence; the sample itself is built once, in an untimed warm-up
//! step (its time is reported as "cold").
//!
//! Run: `cargo bench -p stagehand-simulator --bench render` or `bench/render.sh`. Subsets:
//!
//! - `STAGEHAND_RENDER_BENCH=preview,standard` — presets (default: all three);
//! - `STAGEHAND_RENDER_BENCH_SCENES=lamp` — any of `lamp`, `laser`, `sweep`, `lamps`,
//!   `bracket` (default: all);
//! - `STAGEHAND_RENDER_BENCH_THREADS=2` — pool sizes (default: `1,2`);
//! - `STAGEHAND_RENDER_BENCH_REPS=3` — timed steps per row (default: 5 preview, 3 standard,
//!   1 reference).
//!
//! Prints a Markdown table; wall time depends on other load on the machine, so the CPU time
//! of all threads per step (Linux schedstat) is printed beside it.

use std::collections::BTreeMap;
use std::process::Command;
use std::time::Instant;

use rayon::prelude::*;
use serde_json::{Value, json};
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, RigSpec, parse_rig};
use stagehand_simulator::render::Renderer;
use stagehand_simulator::render::config::SimSpec;
use stagehand_simulator::world_snapshot::{LaserBeam, WorldSnapshot};

/// Environment variable that makes this binary measure one preset and print JSON lines.
const CHILD_ENV: &str = "STAGEHAND_RENDER_BENCH_CHILD";
/// Prefix of the child's result lines.
const RESULT_PREFIX: &str = "RESULT ";
/// Presets in the order they are measured and printed.
const PRESETS: [&str; 3] = ["preview", "standard", "reference"];
/// Turntable step between timed steps, degrees.
const TURNTABLE_STEP_DEG: f64 = 15.0;

fn main() {
    // `cargo bench` passes `--bench`; a libtest filter argument is not supported.
    if let Ok(preset) = std::env::var(CHILD_ENV) {
        if let Err(e) = child(&preset) {
            eprintln!("render bench ({preset}): {e}");
            std::process::exit(1);
        }
        return;
    }
    if let Err(e) = parent() {
        eprintln!("render bench: {e}");
        std::process::exit(1);
    }
}

/// Comma-separated list from `var`, or `default`.
fn list(var: &str, default: &[&str]) -> Vec<String> {
    match std::env::var(var) {
        Ok(v) if !v.trim().is_empty() => v
            .split(',')
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect(),
        _ => default.iter().map(|s| s.to_string()).collect(),
    }
}

/// Runs every selected preset in its own process and prints the table.
fn parent() -> Result<(), Box<dyn std::error::Error>> {
    let presets = list("STAGEHAND_RENDER_BENCH", &PRESETS);
    for p in &presets {
        if !PRESETS.contains(&p.as_str()) {
            return Err(format!("unknown preset `{p}`; use preview, standard, reference").into());
        }
    }
    let exe = std::env::current_exe()?;
    let mut rows: Vec<Value> = Vec::new();
    let mut peaks: BTreeMap<String, f64> = BTreeMap::new();
    for preset in &presets {
        eprintln!("== {preset} (fresh process)");
        let out = Command::new(&exe)
            .env(CHILD_ENV, preset)
            .stderr(std::process::Stdio::inherit())
            .output()?;
        if !out.status.success() {
            // Keep what the earlier presets measured.
            print_table(&rows, &peaks);
            return Err(format!("the {preset} run failed ({})", out.status).into());
        }
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            let Some(text) = line.strip_prefix(RESULT_PREFIX) else {
                continue;
            };
            let v: Value = serde_json::from_str(text)?;
            if let Some(mib) = v["vm_hwm_mib"].as_f64() {
                peaks.insert(preset.clone(), mib);
            } else {
                rows.push(v);
            }
        }
    }
    print_table(&rows, &peaks);
    Ok(())
}

/// The Markdown table: one row per preset, scene and pool size.
fn print_table(rows: &[Value], peaks: &BTreeMap<String, f64>) {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!();
    println!(
        "8-camera step of the built-in light stage (8 × 1024×768), `bumps` sample, {cores} cores"
    );
    println!();
    println!(
        "| preset | scene | threads | steps | cold step s | step s (mean) | step s (best) | steps/s | frames/s | CPU s/step | speed-up | peak RSS MiB |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let preset = r["preset"].as_str().unwrap_or("?");
        let scene = r["scene"].as_str().unwrap_or("?");
        let threads = r["threads"].as_u64().unwrap_or(0);
        let mean = r["step_s_mean"].as_f64().unwrap_or(f64::NAN);
        // Speed-up against the 1-thread row of the same preset and scene.
        let one = rows
            .iter()
            .find(|o| o["preset"] == r["preset"] && o["scene"] == r["scene"] && o["threads"] == 1);
        let speedup = one
            .and_then(|o| o["step_s_mean"].as_f64())
            .map_or("–".to_string(), |t1| format!("{:.2}×", t1 / mean));
        println!(
            "| {preset} | {scene} | {threads} | {} | {:.3} | {mean:.3} | {:.3} | {:.2} | {:.1} | {:.2} | {speedup} | {} |",
            r["steps"].as_u64().unwrap_or(0),
            r["cold_step_s"].as_f64().unwrap_or(f64::NAN),
            r["step_s_best"].as_f64().unwrap_or(f64::NAN),
            1.0 / mean,
            8.0 / mean,
            r["cpu_s_per_step"].as_f64().unwrap_or(f64::NAN),
            peaks
                .get(preset)
                .map_or("–".to_string(), |m| format!("{m:.0}")),
        );
    }
    println!();
    println!(
        "steps/s = full 8-camera steps per second (frames/s ÷ 8); peak RSS = VmHWM of the preset's own process; speed-up = 1-thread step time ÷ this row's."
    );
}

/// The built-in light stage at full resolution with the `bumps` sample at `preset`.
fn rig(preset: &str) -> Result<RigSpec, Box<dyn std::error::Error>> {
    let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml")?;
    SimSpec::edit(&mut rig, |s| s.sample = "bumps".into())?;
    SimSpec::edit(&mut rig, |s| s.quality = preset.into())?;
    Ok(rig)
}

/// Scenes measured: a new view per step (`lamp`, `laser`: the turntable turns 15° between
/// steps) or a sequence at one view (`sweep`: the laser tilts by 0.05° a step; `lamps`: one
/// lamp after another; `bracket`: one lamp after another, each for the three exposures of
/// [`BRACKET_S`]), where only the light changes.
const SCENES: [&str; 5] = ["lamp", "laser", "sweep", "lamps", "bracket"];

/// The HDR bracket of `sequences/btf.rhai`, in seconds.
const BRACKET_S: [f64; 3] = [0.005, 0.02, 0.08];

/// The exposure of step `rep` of `scene`: the bracket's in turn for `bracket` (the warm-up
/// step the last one's), else 20 ms.
fn exposure_s(scene: &str, rep: usize) -> f64 {
    match (scene, rep) {
        ("bracket", 0) => BRACKET_S[2],
        ("bracket", _) => BRACKET_S[(rep - 1) % 3],
        _ => 0.02,
    }
}

/// The world for step `rep` (0 = the untimed warm-up) of `scene`.
fn world(scene: &str, rep: usize) -> WorldSnapshot {
    let new_view = matches!(scene, "lamp" | "laser");
    let turntable_deg = if new_view {
        TURNTABLE_STEP_DEG * rep as f64
    } else {
        0.0
    };
    let lamp = match scene {
        "lamp" => Some("lamp1".to_string()),
        "lamps" => Some(format!("lamp{}", rep % 8 + 1)),
        // The warm-up under lamp8; then lamp1's bracket, lamp2's, … (lamp8 again at step 22).
        "bracket" if rep == 0 => Some("lamp8".to_string()),
        "bracket" => Some(format!("lamp{}", (rep - 1) / 3 % 8 + 1)),
        _ => None,
    };
    WorldSnapshot {
        rig_time_s: 0.0,
        axes: BTreeMap::from([
            ("turntable".to_string(), turntable_deg),
            ("light_arc".to_string(), 60.0),
        ]),
        lamps: lamp.iter().map(|l| (l.clone(), 1.0)).collect(),
        laser: lamp.is_none().then_some(LaserBeam {
            colour_nm: 650,
            tilt_deg: if scene == "sweep" {
                2.0 - 0.05 * rep as f64
            } else {
                2.0
            },
            mount_elevation_deg: 45.0,
        }),
        cart_mm: 0.0,
        fixture: "bumps".into(),
        fixture_pose: Default::default(),
    }
}

/// One 8-camera step: every camera rendered once for `exposure_s`, concurrently, on the
/// current rayon pool.
fn step(
    renderer: &Renderer,
    rig: &RigSpec,
    world: &WorldSnapshot,
    exposure_s: f64,
    seed: u64,
) -> Result<(), String> {
    rig.cameras.par_iter().enumerate().try_for_each(|(k, cam)| {
        let frame = renderer
            .render(world, &cam.id, exposure_s, 1.0, seed * 8 + k as u64)
            .map_err(|e| e.to_string())?;
        std::hint::black_box(&frame.pixels);
        Ok(())
    })
}

/// Measures one preset and prints its JSON result lines.
fn child(preset: &str) -> Result<(), Box<dyn std::error::Error>> {
    let rig = rig(preset)?;
    let scenes = list("STAGEHAND_RENDER_BENCH_SCENES", &SCENES);
    let threads: Vec<usize> = list("STAGEHAND_RENDER_BENCH_THREADS", &["1", "2"])
        .iter()
        .map(|s| s.parse::<usize>())
        .collect::<Result<_, _>>()?;
    let reps: usize = match std::env::var("STAGEHAND_RENDER_BENCH_REPS") {
        Ok(v) => v.parse()?,
        Err(_) => match preset {
            "preview" => 5,
            "standard" => 3,
            _ => 1,
        },
    };
    for scene in &scenes {
        if !SCENES.contains(&scene.as_str()) {
            return Err(format!("unknown scene `{scene}`; use {}", SCENES.join(", ")).into());
        }
        for &n in &threads {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build()?;
            // A fresh renderer per row: the cold step builds the sample in this pool.
            let renderer = Renderer::new(&rig)?;
            let result = pool.install(|| -> Result<Value, String> {
                let cold = Instant::now();
                step(&renderer, &rig, &world(scene, 0), exposure_s(scene, 0), 0)?;
                let cold_s = cold.elapsed().as_secs_f64();
                let mut times = Vec::with_capacity(reps);
                let cpu0 = cpu_s();
                for rep in 0..reps {
                    let w = world(scene, rep + 1);
                    let t = Instant::now();
                    let exposure = exposure_s(scene, rep + 1);
                    step(&renderer, &rig, &w, exposure, rep as u64 + 1)?;
                    times.push(t.elapsed().as_secs_f64());
                }
                let cpu = cpu_s().zip(cpu0).map_or(f64::NAN, |(b, a)| b - a);
                let mean = times.iter().sum::<f64>() / times.len().max(1) as f64;
                let best = times.iter().copied().fold(f64::INFINITY, f64::min);
                Ok(json!({
                    "preset": preset,
                    "scene": scene,
                    "threads": n,
                    "steps": reps,
                    "cold_step_s": cold_s,
                    "step_s_mean": mean,
                    "step_s_best": best,
                    "cpu_s_per_step": cpu / reps.max(1) as f64,
                    "step_s": times,
                }))
            })?;
            let steps: Vec<String> = result["step_s"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|t| format!("{:.3}", t.as_f64().unwrap_or(f64::NAN)))
                .collect();
            eprintln!(
                "{preset} {scene} {n} thread(s): cold {:.2} s, step {:.3} s (each: {})",
                result["cold_step_s"].as_f64().unwrap_or(f64::NAN),
                result["step_s_mean"].as_f64().unwrap_or(f64::NAN),
                steps.join(" ")
            );
            println!("{RESULT_PREFIX}{result}");
        }
    }
    println!("{RESULT_PREFIX}{}", json!({ "vm_hwm_mib": vm_hwm_mib() }));
    Ok(())
}

/// Peak resident set size of this process (VmHWM) in MiB; NaN off Linux.
fn vm_hwm_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// CPU time of every thread of this process so far, in seconds (None off Linux).
fn cpu_s() -> Option<f64> {
    let mut ns = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let text = std::fs::read_to_string(task.ok()?.path().join("schedstat")).ok()?;
        ns += text.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(ns as f64 / 1e9)
}
