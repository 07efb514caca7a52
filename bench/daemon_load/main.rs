//! Daemon load benchmark on loopback: a run on the small simulated light stage (real time,
//! about 30 s) while 200 SSE clients follow `/api/events`, one more SSE client never reads,
//! and 1,000 `GET /api/status` requests per second arrive on an open-loop schedule over 20
//! keep-alive connections. The same run also goes once without load first, so the executor's
//! step timing can be compared.
//!
//! Reports missed steps (steps of the plan not durable at the end; target 0), the executor's
//! step wall times loaded vs unloaded, p50/p99/max latency of `/api/status` (measured from each
//! request's scheduled time, so a slow server cannot hide queueing), the achieved request rate,
//! SSE clients still connected at the end, the events each received and their resyncs.
//!
//! Run: `cargo bench --bench daemon_load`. Knobs (environment): `STAGEHAND_LOAD_SSE` (200),
//! `STAGEHAND_LOAD_RPS` (1000), `STAGEHAND_LOAD_CONNS` (20), `STAGEHAND_LOAD_POSITIONS` (40,
//! turntable positions of the run; about 0.7 s each). Prints a table, then one JSON line.

mod clients;
#[path = "../stats.rs"]
mod stats;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use reqwest::Method;
use serde_json::json;
use stagehand::client::{Body, Client, EventStream, StartRun};
use stagehand::daemon::{self, RunningDaemon, ServeOptions};
use stagehand_devices::rig::BUILTIN_LIGHTSTAGE;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::sync::watch;

use stats::{percentile, sorted};

type BoxError = Box<dyn std::error::Error + Send + Sync>;
type Result<T, E = BoxError> = std::result::Result<T, E>;

/// The run: one lamp on, then a small turntable step and a capture on every camera at each
/// position.
const SCRIPT: &str = r#"// Load benchmark: one lamp, then a turntable step and a capture at each position.
let positions = param("positions", 40);
let exposure_s = param("exposure_s", 0.02);
home();
lamps_off();
only_lamp(lamps()[0]);
for i in 0..positions {
    move_to(#{turntable: (i * 3) % 360});
    capture(exposure_s);
}
lamps_off();
home();
"#;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A client of the daemon under test.
fn client(addr: SocketAddr, token: &str) -> Result<Client> {
    Ok(Client::new(&addr.to_string(), Some(token))?)
}

use clients::*;

// ------------------------------------------------------------------------------ the runs

/// One run's outcome, from the API and the run's index.
#[derive(Debug, Default, Clone)]
struct RunResult {
    run_id: String,
    status: String,
    steps_total: usize,
    steps_done: usize,
    frames: u64,
    wall_s: f64,
    /// Executor wall time of each done step (rig time is real time in the daemon), by index.
    step_s: Vec<(usize, String, f64)>,
}

async fn run_once(client: &Client, d: &RunningDaemon, positions: usize) -> Result<RunResult> {
    let started = Instant::now();
    let set = BTreeMap::from([("positions".to_string(), json!(positions.to_string()))]);
    let start = StartRun {
        script: "load".into(),
        set: Some(set),
        seed: None,
    };
    let run_id = client.start_run(&start).await?.run_id;
    wait_run_end(client, &run_id).await?;
    let wall_s = started.elapsed().as_secs_f64();
    let detail = client.run(&run_id).await?.run;
    let step_s = step_times(&d.state.runs_dir().join(&run_id))?;
    Ok(RunResult {
        status: detail.status.to_string(),
        steps_total: detail.steps_total,
        steps_done: detail.steps_done,
        frames: detail.frames as u64,
        wall_s,
        step_s,
        run_id,
    })
}

async fn wait_run_end(client: &Client, run_id: &str) -> Result<()> {
    let deadline = Instant::now() + Duration::from_secs(600);
    loop {
        tokio::time::sleep(Duration::from_millis(250)).await;
        let active = client.active_run().await?;
        if active.is_none_or(|r| r.run_id != run_id) {
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err(format!("run {run_id} still active after 10 min").into());
        }
    }
}

/// Each done step's executor wall time from the run's index.
fn step_times(dir: &Path) -> Result<Vec<(usize, String, f64)>> {
    let db = rusqlite::Connection::open_with_flags(
        dir.join("index.sqlite"),
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
    )?;
    let mut q = db.prepare(
        "SELECT idx, kind, rig_time_end_s - rig_time_start_s FROM steps \
         WHERE status = 'done' AND rig_time_end_s IS NOT NULL ORDER BY idx",
    )?;
    let rows = q
        .query_map([], |r| {
            Ok((r.get::<_, i64>(0)? as usize, r.get(1)?, r.get(2)?))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

// ------------------------------------------------------------------------------------ main

struct Setup {
    _tmp: tempfile::TempDir,
    rig: PathBuf,
    scripts: PathBuf,
    data: PathBuf,
}

fn setup() -> Result<Setup> {
    let tmp = tempfile::tempdir()?;
    let rig = tmp.path().join("lightstage-small.toml");
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", "width = 64")
        .replace("height = 768", "height = 48");
    std::fs::write(&rig, text)?;
    let scripts = tmp.path().join("scripts");
    std::fs::create_dir_all(&scripts)?;
    std::fs::write(scripts.join("load.rhai"), SCRIPT)?;
    let data = tmp.path().join("data");
    Ok(Setup {
        rig,
        scripts,
        data,
        _tmp: tmp,
    })
}

fn main() -> Result<()> {
    let sse_n = env_usize("STAGEHAND_LOAD_SSE", 200);
    let rps = env_usize("STAGEHAND_LOAD_RPS", 1000).max(1);
    let conns = env_usize("STAGEHAND_LOAD_CONNS", 20).max(1);
    let positions = env_usize("STAGEHAND_LOAD_POSITIONS", 40);
    let burst = env_usize("STAGEHAND_LOAD_BURST", 3000);
    let s = setup()?;

    // The daemon on its own multi-threaded runtime, the load on another.
    let daemon_rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("daemon")
        .build()?;
    let load_rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("load")
        .build()?;
    let d = daemon_rt.block_on(daemon::start(ServeOptions {
        rig: Some(s.rig.display().to_string()),
        listen: "127.0.0.1:0".parse()?,
        data: s.data.clone(),
        scripts: Some(s.scripts.clone()),
        seed: 1,
        emulation: None,
    }))?;
    let addr = d.addr;
    let token = d.state.tokens.operator.clone();
    eprintln!(
        "daemon on {addr}; {} cores; run: load.rhai, {positions} positions on the 64×48 light stage",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );

    // 0. A short warm-up run (first renders, SQLite, page cache) so order does not bias.
    eprintln!("warm-up run…");
    let api = client(addr, &token)?;
    load_rt.block_on(run_once(&api, &d, 2))?;

    // 1. The run without load.
    eprintln!("run 1/2: no load…");
    let quiet = load_rt.block_on(run_once(&api, &d, positions))?;
    eprintln!(
        "  {} in {:.1} s, {}/{} steps",
        quiet.status, quiet.wall_s, quiet.steps_done, quiet.steps_total
    );

    // 2. The same run under load.
    eprintln!(
        "run 2/2: {sse_n} SSE clients + 1 stalled, {rps} status req/s over {conns} connections…"
    );
    let (stop_tx, stop_rx) = watch::channel(false);
    let status_clients = (0..conns)
        .map(|_| client(addr, &token))
        .collect::<Result<Vec<_>>>()?;
    let counters: Vec<Arc<Counters>> = (0..sse_n).map(|_| Arc::default()).collect();
    let stalled_counters: Arc<Counters> = Arc::default();
    let (loaded, run_seen, endings, stalled_end, status, load_s, seq) = load_rt.block_on(async {
        let ready = Arc::new(AtomicUsize::new(0));
        let sse_tasks: Vec<_> = counters
            .iter()
            .map(|c| {
                tokio::spawn(sse_client(
                    api.clone(),
                    ready.clone(),
                    c.clone(),
                    stop_rx.clone(),
                ))
            })
            .collect();
        let stalled = tokio::spawn(stalled_client(
            addr,
            token.clone(),
            stalled_counters.clone(),
            stop_rx.clone(),
        ));
        let t = Instant::now();
        while ready.load(Ordering::SeqCst) < sse_n && t.elapsed() < Duration::from_secs(30) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        eprintln!(
            "  {} of {sse_n} SSE clients connected in {:.2} s",
            ready.load(Ordering::SeqCst),
            t.elapsed().as_secs_f64()
        );
        let seq_before = d.state.hub.recent().last().map_or(0, |e| e.seq);

        // The status load runs from the run's start to its end.
        let (load_stop_tx, load_stop_rx) = watch::channel(false);
        let interval = Duration::from_secs_f64(conns as f64 / rps as f64);
        let start = tokio::time::Instant::now() + Duration::from_millis(100);
        let status_tasks: Vec<_> = status_clients
            .into_iter()
            .enumerate()
            .map(|(i, c)| {
                let offset = interval.mul_f64(i as f64 / conns as f64);
                tokio::spawn(status_client(
                    c,
                    start + offset,
                    interval,
                    load_stop_rx.clone(),
                ))
            })
            .collect();
        let load_started = Instant::now();
        let loaded = run_once(&api, &d, positions).await;
        let _ = load_stop_tx.send(true);
        let load_s = load_started.elapsed().as_secs_f64();
        let mut status = StatusStats::default();
        for t in status_tasks {
            if let Ok(s) = t.await {
                status.latencies_s.extend(s.latencies_s);
                status.errors += s.errors;
                status.non_200 += s.non_200;
            }
        }
        // Let the last events reach the SSE clients.
        tokio::time::sleep(Duration::from_secs(1)).await;
        let seq_after = d.state.hub.recent().last().map_or(0, |e| e.seq);
        let run_seen: Vec<Seen> = counters.iter().map(|c| c.seen()).collect();

        // A burst of events faster than clients can take them: they fall behind and are
        // resynchronised (the publisher never waits).
        let t = Instant::now();
        for i in 0..burst {
            d.state.hub.publish(
                stagehand::daemon::events::EventKind::Warning,
                json!({"message": format!("load benchmark burst {i}/{burst}")}),
            );
        }
        let publish_s = t.elapsed().as_secs_f64();
        eprintln!(
            "  burst of {burst} events published in {:.1} ms",
            publish_s * 1e3
        );
        tokio::time::sleep(Duration::from_secs(3)).await;
        let _ = stop_tx.send(true);
        let mut endings = Vec::new();
        for t in sse_tasks {
            endings.push(t.await.unwrap_or_default());
        }
        let stalled = stalled.await.unwrap_or_default();
        (
            loaded,
            run_seen,
            endings,
            stalled,
            status,
            load_s,
            seq_after - seq_before,
        )
    });
    let all_seen: Vec<Seen> = counters.iter().map(|c| c.seen()).collect();
    let loaded = loaded?;
    eprintln!(
        "  {} in {:.1} s, {}/{} steps",
        loaded.status, loaded.wall_s, loaded.steps_done, loaded.steps_total
    );

    report(Report {
        quiet: &quiet,
        loaded: &loaded,
        run_seen: &run_seen,
        all_seen: &all_seen,
        endings: &endings,
        stalled: (stalled_counters.seen(), &stalled_end),
        status: &status,
        load_s,
        published: seq,
        burst,
        sse_n,
        rps,
    });
    daemon_rt.block_on(d.shutdown());
    Ok(())
}

// ------------------------------------------------------------------------------ statistics

/// Mean step time by kind.
fn by_kind(r: &RunResult) -> std::collections::BTreeMap<String, (usize, f64)> {
    let mut m = std::collections::BTreeMap::<String, (usize, f64)>::new();
    for (_, kind, s) in &r.step_s {
        let e = m.entry(kind.clone()).or_default();
        e.0 += 1;
        e.1 += s;
    }
    m
}

/// Everything the report prints.
struct Report<'a> {
    quiet: &'a RunResult,
    loaded: &'a RunResult,
    /// Per SSE client, after the run (before the burst).
    run_seen: &'a [Seen],
    /// Per SSE client, at the end (after the burst).
    all_seen: &'a [Seen],
    endings: &'a [Ending],
    stalled: (Seen, &'a Ending),
    status: &'a StatusStats,
    load_s: f64,
    /// Events the hub published during the loaded run.
    published: u64,
    burst: usize,
    sse_n: usize,
    rps: usize,
}

fn min_p50_max(v: Vec<f64>) -> (f64, f64, f64) {
    let v = sorted(v);
    (
        v.first().copied().unwrap_or(f64::NAN),
        percentile(&v, 0.5),
        v.last().copied().unwrap_or(f64::NAN),
    )
}

fn report(r: Report) {
    let (quiet, loaded) = (r.quiet, r.loaded);
    let missed = loaded.steps_total.saturating_sub(loaded.steps_done);
    let missed_quiet = quiet.steps_total.saturating_sub(quiet.steps_done);
    let total = |r: &RunResult| r.step_s.iter().map(|(_, _, s)| s).sum::<f64>();
    let (tq, tl) = (total(quiet), total(loaded));
    let steps_q = sorted(quiet.step_s.iter().map(|(_, _, s)| *s).collect());
    let steps_l = sorted(loaded.step_s.iter().map(|(_, _, s)| *s).collect());
    let lat = sorted(r.status.latencies_s.clone());
    let ms = |s: f64| s * 1e3;
    let achieved = lat.len() as f64 / r.load_s;
    let connected = r.endings.iter().filter(|e| e.connected_at_end).count();
    let ev = min_p50_max(r.run_seen.iter().map(|s| s.events as f64).collect());
    let run_ev = min_p50_max(r.run_seen.iter().map(|s| s.run_events as f64).collect());
    let run_resyncs: usize = r.run_seen.iter().map(|s| s.resyncs).sum();
    let burst_resyncs: Vec<usize> = r
        .all_seen
        .iter()
        .zip(r.run_seen)
        .map(|(a, b)| a.resyncs - b.resyncs)
        .collect();
    let burst_events = min_p50_max(
        r.all_seen
            .iter()
            .zip(r.run_seen)
            .map(|(a, b)| (a.events - b.events) as f64)
            .collect(),
    );
    let errors: Vec<&str> = r
        .endings
        .iter()
        .filter_map(|e| e.error.as_deref())
        .collect();
    let row2 = |name: &str, a: String, b: String| println!("{name:<44} {a:>16} {b:>16}");
    let row = |name: &str, v: String| println!("{name:<44} {v:>33}");
    let line = || println!("{:-<78}", "");

    println!();
    println!(
        "daemon load: {} SSE clients + 1 stalled, {} GET /api/status per second, during a run",
        r.sse_n, r.rps
    );
    line();
    row2("", "no load".into(), "under load".into());
    row2("run status", quiet.status.clone(), loaded.status.clone());
    row2(
        "steps done / total",
        format!("{}/{}", quiet.steps_done, quiet.steps_total),
        format!("{}/{}", loaded.steps_done, loaded.steps_total),
    );
    row2(
        "missed steps (target 0)",
        missed_quiet.to_string(),
        missed.to_string(),
    );
    row2(
        "frames",
        quiet.frames.to_string(),
        loaded.frames.to_string(),
    );
    row2(
        "run wall time, s",
        format!("{:.2}", quiet.wall_s),
        format!("{:.2}", loaded.wall_s),
    );
    row2(
        "executor step time, total s",
        format!("{tq:.3}"),
        format!("{tl:.3}"),
    );
    row2(
        "executor step time p50, ms",
        format!("{:.1}", ms(percentile(&steps_q, 0.5))),
        format!("{:.1}", ms(percentile(&steps_l, 0.5))),
    );
    row2(
        "executor step time p99, ms",
        format!("{:.1}", ms(percentile(&steps_q, 0.99))),
        format!("{:.1}", ms(percentile(&steps_l, 0.99))),
    );
    let (kq, kl) = (by_kind(quiet), by_kind(loaded));
    for (kind, (n, sum)) in &kq {
        let l = kl.get(kind).map_or(f64::NAN, |(m, s)| s / *m as f64);
        row2(
            &format!("  mean `{kind}` step ({n}), ms"),
            format!("{:.1}", ms(sum / *n as f64)),
            format!("{:.1}", ms(l)),
        );
    }
    row(
        "step wall-time ratio, loaded / unloaded",
        format!("{:.3}", tl / tq),
    );
    line();
    row("GET /api/status requests", lat.len().to_string());
    row("achieved rate, req/s", format!("{achieved:.1}"));
    row(
        "latency p50 / p99 / max, ms",
        format!(
            "{:.2} / {:.2} / {:.2}",
            ms(percentile(&lat, 0.5)),
            ms(percentile(&lat, 0.99)),
            ms(lat.last().copied().unwrap_or(f64::NAN))
        ),
    );
    row(
        "errors / non-200",
        format!("{} / {}", r.status.errors, r.status.non_200),
    );
    line();
    row("events published during the run", r.published.to_string());
    row(
        "events received per client min/p50/max",
        format!("{:.0} / {:.0} / {:.0}", ev.0, ev.1, ev.2),
    );
    row(
        "  of which `run` events min/p50/max",
        format!("{:.0} / {:.0} / {:.0}", run_ev.0, run_ev.1, run_ev.2),
    );
    row("resyncs during the run", run_resyncs.to_string());
    row(
        &format!("burst of {} events after the run: received", r.burst),
        format!(
            "{:.0} / {:.0} / {:.0}",
            burst_events.0, burst_events.1, burst_events.2
        ),
    );
    row(
        "  resyncs (total / clients with any)",
        format!(
            "{} / {}",
            burst_resyncs.iter().sum::<usize>(),
            burst_resyncs.iter().filter(|&&n| n > 0).count()
        ),
    );
    row(
        "SSE clients connected at the end",
        format!("{connected}/{}", r.endings.len()),
    );
    let (stalled, stalled_end) = r.stalled;
    row(
        "stalled client: connected / read after / resyncs",
        format!(
            "{} / {} / {}",
            stalled_end.connected_at_end, stalled.events, stalled.resyncs
        ),
    );
    if let Some(e) = &stalled_end.error {
        println!("stalled client: {e}");
    }
    if !errors.is_empty() {
        println!("SSE errors: {} (first: {})", errors.len(), errors[0]);
    }
    println!(
        "{}",
        json!({
            "bench": "daemon_load",
            "sse_clients": r.sse_n,
            "target_rps": r.rps,
            "missed_steps": missed,
            "steps_total": loaded.steps_total,
            "step_time_ratio": tl / tq,
            "run_wall_s": {"quiet": quiet.wall_s, "loaded": loaded.wall_s},
            "status_requests": lat.len(),
            "achieved_rps": achieved,
            "status_latency_ms": {
                "p50": ms(percentile(&lat, 0.5)),
                "p99": ms(percentile(&lat, 0.99)),
                "max": ms(lat.last().copied().unwrap_or(f64::NAN)),
            },
            "status_errors": r.status.errors,
            "sse_connected_at_end": connected,
            "events_published": r.published,
            "events_per_client": {"min": ev.0, "p50": ev.1, "max": ev.2},
            "resyncs_during_run": run_resyncs,
            "burst": {"events": r.burst, "resyncs": burst_resyncs.iter().sum::<usize>()},
            "stalled_client": {"events": stalled.events, "resyncs": stalled.resyncs},
            "runs": [quiet.run_id, loaded.run_id],
        })
    );
}
