//! The daemon's HTTP layer as an operator's day uses it: bodies that must be objects, run
//! listings, resuming with an ETA, messages worded for API clients, SSE replay and the final
//! event at shutdown, on the simulated light stage with tiny cameras in real time.

mod common;

use common::api::Api;
use serde_json::{Value, json};
use stagehand::daemon::RunningDaemon;

/// A prompt first (the run waits there), then a capture on one camera.
const PROMPTED: &str = r#"// prompted.rhai
prompt("Place the sample");
home();
lamps_on(["lamp1"]);
capture(0.01, #{cameras: ["cam1"]});
lamps_off();
"#;

/// A daemon on the light stage with 32×24 cameras and the repository's sequences.
async fn daemon() -> (RunningDaemon, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("temp dir");
    let rig = common::small_rig_file(dir.path(), "lightstage", 32, 24);
    let d = common::start_daemon(&dir.path().join("data"), Some(&rig))
        .await
        .expect("daemon starts");
    (d, dir)
}

/// Uploads [`PROMPTED`] and starts it; the run id.
fn start_prompted(api: &Api) -> String {
    let (s, v) = api.put_text("/api/scripts/prompted", PROMPTED);
    assert_eq!(s, 200, "{v}");
    let v = api.expect(201, "/api/runs", Some(json!({"script": "prompted"})));
    v["run_id"].as_str().expect("run id").to_string()
}

/// Waits until the active run waits at the prompt of `step`.
fn wait_prompt(api: &Api, step: u64) {
    common::eventually(45, "the prompt", || {
        api.get("/api/status").1["run"]["prompt"]["step"] == step
    });
}

/// Waits until run `id` is no longer active and has `status`; its listing.
fn wait_ended(api: &Api, id: &str, status: &str) -> Value {
    common::eventually(45, &format!("run {id} {status}"), || {
        let (_, r) = api.get(&format!("/api/runs/{id}"));
        r["status"] == status && r["active"] == false
    });
    api.get(&format!("/api/runs/{id}")).1
}

/// Every POST route of the OpenAPI document that takes a body, with its path filled in.
fn post_routes_with_a_body(api: &Api) -> Vec<String> {
    let (s, doc) = api.get("/openapi.json");
    assert_eq!(s, 200);
    let paths = doc["paths"].as_object().expect("paths");
    let mut out = Vec::new();
    for (path, item) in paths {
        if item["post"]["requestBody"].is_null() {
            continue;
        }
        let filled = path
            .replace("/axes/{id}", "/axes/turntable")
            .replace("/lamps/{id}", "/lamps/lamp1")
            .replace("/runs/{id}", "/runs/20260101-000000-none")
            .replace("/scripts/{name}", "/scripts/quickstart")
            .replace("{item}", "1");
        assert!(!filled.contains('{'), "fill in the parameters of {path}");
        out.push(filled);
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn json_arrays_are_refused_where_objects_are_documented() {
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        let routes = post_routes_with_a_body(&api);
        for must in [
            "/api/laser/arm",
            "/api/interlock",
            "/api/axes/turntable/move",
        ] {
            assert!(routes.iter().any(|r| r == must), "{must} in {routes:?}");
        }
        api.expect(200, "/api/axes/turntable/home", None);
        for route in &routes {
            for body in ["[true]", "[1]", "[false]", "[]", "true", "90", "\"on\""] {
                let (s, v) = api.post_text(route, body);
                assert_eq!(s, 422, "POST {route} {body}: {v}");
                let error = v["error"].as_str().unwrap_or_default();
                assert!(error.contains("JSON object"), "POST {route} {body}: {v}");
            }
        }
        // Nothing happened: the laser is not armed, the door closed, the turntable at home.
        let (_, st) = api.get("/api/status");
        assert_eq!(st["devices"]["laser"]["armed"], false, "{st}");
        assert_eq!(st["devices"]["laser"]["interlock"], "closed", "{st}");
        let tt = st["devices"]["axes"]
            .as_array()
            .and_then(|a| a.iter().find(|a| a["id"] == "turntable"))
            .cloned()
            .expect("turntable");
        assert!(tt["position_deg"].as_f64().expect("position").abs() < 1e-6);
        assert_eq!(st["run"], Value::Null);
        // The documented objects still work.
        let v = api.expect(200, "/api/laser/arm", Some(json!({"confirm": true})));
        assert_eq!(v["armed"], true);
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_aborted_run_says_how_to_resume_over_the_api_and_resumes_with_an_eta() {
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        let id = start_prompted(&api);
        wait_prompt(&api, 0);
        api.expect(200, &format!("/api/runs/{id}/abort"), None);
        let run = wait_ended(&api, &id, "aborted");
        let resume = format!("/api/runs/{id}/resume");
        let message = run["message"].as_str().expect("a message").to_string();
        assert!(message.contains(&resume), "{message}");
        assert!(!message.contains("stagehand resume"), "{message}");
        let (_, events) = api.get("/api/events/recent");
        let finished: Vec<&Value> = events
            .as_array()
            .expect("events")
            .iter()
            .filter(|e| e["kind"] == "run" && e["data"]["event"] == "run_finished")
            .collect();
        assert!(!finished.is_empty(), "{events}");
        for e in finished.iter().chain(
            events
                .as_array()
                .expect("events")
                .iter()
                .filter(|e| e["kind"] == "warning")
                .collect::<Vec<_>>()
                .iter(),
        ) {
            let text = e["data"].to_string();
            assert!(!text.contains("stagehand resume"), "{text}");
        }

        // Resuming answers a real ETA: the steps left, as the plan estimates them.
        let v = api.expect(200, &resume, None);
        let eta = v["eta_s"].as_f64().expect("eta_s");
        assert!(eta > 0.0, "resume answered {v}");
        assert!(
            v["estimated_rig_time_s"].as_f64().expect("estimate") > 0.0,
            "{v}"
        );
        wait_prompt(&api, 0);
        api.expect(
            200,
            &format!("/api/runs/{id}/prompt"),
            Some(json!({"answer": "continue"})),
        );
        wait_ended(&api, &id, "done");
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn runs_are_listed_newest_first_with_start_end_duration_and_a_limit() {
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        let first = start_prompted(&api);
        wait_prompt(&api, 0);
        // While it runs: started, no end, a duration so far.
        let (_, runs) = api.get("/api/runs");
        let live = &runs[0];
        assert_eq!(live["run_id"], first.as_str());
        assert_eq!(live["status"], "prompt");
        assert_eq!(live["ended_unix_s"], Value::Null, "{live}");
        assert!(
            live["duration_s"].as_f64().expect("duration") >= 0.0,
            "{live}"
        );
        api.expect(
            200,
            &format!("/api/runs/{first}/prompt"),
            Some(json!({"answer": "continue"})),
        );
        wait_ended(&api, &first, "done");
        let second = api.expect(200, "/api/capture", Some(json!({"exposure_s": 0.01})))["run_id"]
            .as_str()
            .expect("run id")
            .to_string();

        let (s, all) = api.get("/api/runs");
        assert_eq!(s, 200);
        let ids: Vec<&str> = all
            .as_array()
            .expect("runs")
            .iter()
            .filter_map(|r| r["run_id"].as_str())
            .collect();
        assert_eq!(ids, [second.as_str(), first.as_str()], "newest first");
        for r in all.as_array().expect("runs") {
            assert_eq!(r["status"], "done", "{r}");
            let start = r["created_unix_s"].as_f64().expect("start");
            let end = r["ended_unix_s"].as_f64().expect("end");
            let duration = r["duration_s"].as_f64().expect("duration");
            assert!(end >= start, "{r}");
            assert!((duration - (end - start)).abs() < 1e-6, "{r}");
        }
        let (s, one) = api.get("/api/runs?limit=1");
        assert_eq!(s, 200, "{one}");
        let one = one.as_array().expect("runs");
        assert_eq!(one.len(), 1);
        assert_eq!(one[0]["run_id"], second.as_str());
        let (s, none) = api.get("/api/runs?limit=0");
        assert_eq!((s, none), (200, json!([])));
        let (s, v) = api.get("/api/runs?limit=many");
        assert_eq!(s, 400, "{v}");
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sse_replays_missed_events_and_shutdown_sends_the_runs_final_event() {
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    let (id, reader) = common::blocking(move || {
        // Some events with ids (device changes are published as the device watch sees them).
        let mut on = false;
        common::eventually(30, "three events", || {
            on = !on;
            api.expect(200, "/api/lamps/lamp1", Some(json!({"on": on})));
            api.get("/api/events/recent")
                .1
                .as_array()
                .map_or(0, Vec::len)
                >= 3
        });
        let (_, recent) = api.get("/api/events/recent");
        let recent = recent.as_array().expect("events").clone();
        let seqs: Vec<u64> = recent.iter().filter_map(|e| e["seq"].as_u64()).collect();
        assert!(seqs.windows(2).all(|w| w[1] > w[0]), "{seqs:?}");

        // Reconnecting after the third-last event: the last two are replayed, no resync.
        let after = seqs[seqs.len() - 3];
        let mut sse = api.sse(Some(after));
        for want in &recent[recent.len() - 2..] {
            let e = sse.next_event().expect("a replayed event");
            assert_eq!(e.id, want["seq"].as_u64(), "{e:?}");
            assert_eq!(e.kind, want["kind"].as_str().expect("kind"));
        }
        drop(sse);
        // An id the daemon never sent (another daemon's): a resync.
        let mut sse = api.sse(Some(u64::MAX / 2));
        assert_eq!(sse.next_event().expect("an event").kind, "resync");
        drop(sse);

        // A run waiting at a prompt when the daemon stops.
        let id = start_prompted(&api);
        wait_prompt(&api, 0);
        let mut sse = api.sse(None);
        assert_eq!(sse.next_event().expect("an event").kind, "resync");
        let reader = std::thread::spawn(move || {
            let mut all = Vec::new();
            while let Some(e) = sse.next_event() {
                all.push(e);
            }
            all
        });
        (id, reader)
    })
    .await;
    d.shutdown().await;
    let events = common::blocking(move || reader.join().expect("reader")).await;
    let last_run = events
        .iter()
        .rev()
        .find(|e| e.kind == "run")
        .unwrap_or_else(|| panic!("no run event before the stream ended: {events:?}"));
    assert_eq!(
        last_run.data["data"]["event"], "run_finished",
        "{last_run:?}"
    );
    assert_eq!(last_run.data["data"]["run_id"], id.as_str());
    assert_eq!(last_run.data["data"]["status"], "aborted", "{last_run:?}");
}
