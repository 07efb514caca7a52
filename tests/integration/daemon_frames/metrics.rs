//! The executor's Prometheus metrics at `/api/metrics`: the dataset's run counted, and a run
//! started over the API counted exactly once.

use std::time::Duration;

use super::*;
use dataset::sql_i64;
use stagehand::daemon::ServeOptions;

/// The value of the first sample line of `name` whose labels contain all of `labels`.
fn sample(text: &str, name: &str, labels: &[&str]) -> Option<f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter(|l| {
            l.starts_with(name) && matches!(l.as_bytes().get(name.len()), Some(b'{') | Some(b' '))
        })
        .find(|l| labels.iter().all(|x| l.contains(x)))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn executor_metrics_reach_the_metrics_endpoint() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let a = api.get("/api/metrics");
        assert_eq!(a.status, 200);
        let m = a.text();
        let frames = sql_i64(d, "SELECT count(*) FROM frames") as f64;
        let captures = sql_i64(d, "SELECT count(*) FROM steps WHERE kind = 'capture'") as f64;
        let get = |name: &str, labels: &[&str]| {
            sample(&m, name, labels).unwrap_or_else(|| panic!("{name} {labels:?} missing:\n{m}"))
        };
        // Counters are process-wide: other runs in this binary may add to them.
        assert!(get("stagehand_frames_written_total", &[]) >= frames);
        assert!(get("stagehand_steps_total", &["kind=\"capture\""]) >= captures);
        assert!(get("stagehand_step_seconds_count", &["kind=\"capture\""]) >= captures);
        let sum = get("stagehand_step_seconds_sum", &["kind=\"capture\""]);
        assert!(sum.is_finite() && sum >= 0.0);
        assert!(
            get(
                "stagehand_step_seconds",
                &["kind=\"capture\"", "quantile=\"0.5\""]
            ) >= 0.0
        );
        assert!(get("stagehand_runs_total", &["status=\"done\""]) >= 1.0);
        // The stalled cam1 frame: dropped, a device error, a reconnect.
        assert!(
            get(
                "stagehand_frames_dropped_total",
                &["device=\"cam1\"", "reason=\"missing\""]
            ) >= 1.0
        );
        assert!(get("stagehand_device_errors_total", &["device=\"cam1\""]) >= 1.0);
        assert!(get("stagehand_reconnects_total", &["device=\"cam1\""]) >= 1.0);
        assert!(m.contains("# HELP stagehand_step_seconds"), "described");
    })
    .await;
}

/// A run started over the API on a small simulated rig (real time): its frames are listed and
/// served, it becomes each camera's latest frame, and the metrics count its steps, frames and
/// run exactly once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_run_is_listed_served_and_counted() {
    // Alone: the metrics are the process's, and a run of another test beside this one would
    // count its frames and steps too.
    let _turn = crate::grbl_peer::exclusive();
    // The shared dataset first, so its (in-process) run is not counted below.
    let _ = dataset();
    let tmp = tempfile::tempdir().expect("temp dir");
    let rig = common::small_rig_file(tmp.path(), "lightstage", 32, 24);
    let daemon = stagehand::daemon::start(ServeOptions {
        rig: Some(rig.display().to_string()),
        listen: "127.0.0.1:0".parse().expect("address"),
        data: tmp.path().join("data"),
        scripts: None,
        seed: 1,
        emulation: None,
    })
    .await
    .expect("daemon starts");
    let api = Api::new(&daemon);
    let operator = daemon.state.tokens.operator.clone();
    tokio::task::spawn_blocking(move || {
        let metric = |m: &str, name: &str, labels: &[&str]| sample(m, name, labels).unwrap_or(0.0);
        let before = api.get("/api/metrics").text();
        let script = "home();\nonly_lamp(\"lamp1\");\ncapture(0.01);\nlamps_off();\n";
        let (status, dry) = api.send("PUT", "/api/scripts/tiny.rhai", &operator, script);
        assert_eq!(status, 200, "{dry}");
        let (status, started) =
            api.send("POST", "/api/runs", &operator, r#"{"script": "tiny.rhai"}"#);
        assert_eq!(status, 201, "{started}");
        let run = started["run_id"].as_str().expect("run_id").to_string();
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        loop {
            let runs = api.get("/api/runs").json();
            let status = runs
                .as_array()
                .and_then(|a| a.iter().find(|r| r["run_id"] == run.as_str()))
                .map(|r| r["status"].as_str().unwrap_or("").to_string())
                .unwrap_or_default();
            if status != "running" && !status.is_empty() {
                assert_eq!(status, "done", "{runs}");
                break;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "run did not finish: {runs}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let cameras = 8;
        let list = api.get(&format!("/api/runs/{run}/frames"));
        assert_eq!(list.json()["total"], cameras, "{}", list.text());
        let frames = frames_of(&list);
        assert!(
            frames
                .iter()
                .all(|f| f["lamps_on"] == serde_json::json!(["lamp1"]))
        );
        let latest = api.get("/api/cameras/cam1/latest").json();
        assert_eq!(latest["run_id"], run.as_str());
        let thumb = api.get(latest["thumbnail_url"].as_str().expect("url"));
        assert_eq!(thumb.status, 200);
        assert_eq!(png8_size(&thumb.body), (256, 192));

        let after = api.get("/api/metrics").text();
        let delta = |name: &str, labels: &[&str]| {
            metric(&after, name, labels) - metric(&before, name, labels)
        };
        assert_eq!(
            delta("stagehand_frames_written_total", &[]),
            f64::from(cameras)
        );
        assert_eq!(delta("stagehand_runs_total", &["status=\"done\""]), 1.0);
        assert_eq!(delta("stagehand_steps_total", &["kind=\"capture\""]), 1.0);
        assert_eq!(delta("stagehand_steps_total", &["kind=\"home\""]), 1.0);
        assert_eq!(
            delta("stagehand_step_seconds_count", &["kind=\"capture\""]),
            1.0
        );
        assert!(delta("stagehand_step_seconds_sum", &["kind=\"capture\""]) > 0.0);
    })
    .await
    .expect("test body");
    daemon.shutdown().await;
}
