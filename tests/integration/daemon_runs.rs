//! Scripts and runs over the daemon's API, on a simulated light stage with tiny cameras in
//! real time: upload and dry runs, bad names, runs with prompts answered over the API, pause,
//! resume, abort and resume of a stored run, one run at a time, the single capture, and
//! quickstart from start to end.

use crate::common;
use common::small_daemon as daemon;

use std::path::Path;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use stagehand::daemon::RunningDaemon;

/// A short tour: a prompt, two captures (the second an HDR bracket) and a second prompt.
/// Steps: 0 prompt, 1 home, 2 lamps, 3 capture (2 raw), 4 prompt, 5 capture (2 raw + 1 HDR),
/// 6 lamps off: 7 steps, 5 frame files.
const TOUR: &str = r#"// tour.rhai: the test's own short script
prompt("Place the bumps sample", #{fixture: "bumps"});
home();
lamps_on(["lamp1"]);
capture(0.01, #{cameras: ["cam1", "cam2"]});
prompt("Check the sample");
capture([0.01, 0.02], #{cameras: ["cam1"]});
lamps_off();
"#;
const TOUR_STEPS: u64 = 7;
const TOUR_FRAMES: u64 = 5;

/// A blocking client for one daemon (use it inside `spawn_blocking`) with this file's helpers.
#[derive(Clone)]
struct Api {
    http: common::api::Api,
}

impl Api {
    fn new(d: &RunningDaemon, token: &str) -> Self {
        Self {
            http: common::api::Api::new(d, token),
        }
    }

    fn get(&self, path: &str) -> (u16, Value) {
        self.http.get(path)
    }

    fn post(&self, path: &str, body: Option<Value>) -> (u16, Value) {
        self.http.post(path, body)
    }

    fn put(&self, path: &str, body: &[u8]) -> (u16, Value) {
        self.http.put_bytes(path, body)
    }

    fn ok(&self, path: &str, body: Option<Value>) -> Value {
        let (status, v) = self.post(path, body);
        assert_eq!(status, 200, "POST {path}: {v}");
        v
    }

    /// The active run's state (`null` when idle).
    fn live(&self) -> Value {
        self.get("/api/status").1["run"].clone()
    }

    fn run(&self, id: &str) -> Value {
        let (status, v) = self.get(&format!("/api/runs/{id}"));
        assert_eq!(status, 200, "GET run {id}: {v}");
        v
    }

    fn start(&self, script: &str) -> String {
        let (status, v) = self.post("/api/runs", Some(json!({"script": script})));
        assert_eq!(status, 201, "start {script}: {v}");
        v["run_id"].as_str().expect("a run id").to_string()
    }

    /// Waits for the prompt of `step` and answers it.
    fn answer_prompt(&self, id: &str, step: u64, answer: &str) {
        common::eventually(45, &format!("the prompt of step {step}"), || {
            self.live()["prompt"]["step"] == step
        });
        assert_eq!(self.live()["state"], "prompt");
        let v = self.ok(
            &format!("/api/runs/{id}/prompt"),
            Some(json!({"answer": answer})),
        );
        assert_eq!(v["step"], step);
    }

    fn wait_status(&self, id: &str, status: &str) -> Value {
        common::eventually(45, &format!("run {id} {status}"), || {
            let r = self.run(id);
            r["status"] == status && !r["active"].as_bool().unwrap_or(true)
        });
        self.run(id)
    }
}

/// Frames and done steps in a run's SQLite index.
fn index_counts(data: &Path, run_id: &str) -> (u64, u64) {
    let db = data.join("runs").join(run_id).join("index.sqlite");
    let conn =
        rusqlite::Connection::open_with_flags(&db, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
            .expect("open the index");
    let frames: i64 = conn
        .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
        .expect("count frames");
    let done: i64 = conn
        .query_row(
            "SELECT COUNT(*) FROM steps WHERE status = 'done'",
            [],
            |r| r.get(0),
        )
        .expect("count steps");
    (frames as u64, done as u64)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scripts_upload_validate_and_refuse_bad_names() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::new(&d, &d.state.tokens.operator);
    let reader = Api::new(&d, &d.state.tokens.read_only);
    common::blocking(move || {
        let (status, list) = api.get("/api/scripts");
        assert_eq!(status, 200, "{list}");
        assert!(
            list.as_array()
                .expect("a list")
                .iter()
                .any(|s| s["name"] == "quickstart" && s["source"] == "builtin"),
            "{list}"
        );
        let r = api.http.get_reply("/api/scripts/quickstart.rhai");
        assert_eq!(r.status, 200);
        let text = r.body.as_str().expect("text").to_string();
        assert!(text.contains("quickstart.rhai"), "{text}");

        // A good upload: its dry run.
        let (status, dry) = api.put("/api/scripts/tour", TOUR.as_bytes());
        assert_eq!(status, 200, "{dry}");
        assert_eq!(dry["ok"], true, "{dry}");
        assert_eq!(dry["script"], "tour.rhai");
        assert_eq!(dry["steps"], TOUR_STEPS);
        assert_eq!(dry["estimate"]["frames"], TOUR_FRAMES, "{dry}");
        assert!(dry["estimate"]["rig_time_s"].as_f64().unwrap_or(0.0) > 0.0);
        let (_, list) = api.get("/api/scripts");
        assert!(
            list.as_array()
                .expect("a list")
                .iter()
                .any(|s| s["name"] == "tour" && s["source"] == "uploaded"),
            "{list}"
        );
        // Read-only tokens cannot upload.
        let (status, v) = reader.put("/api/scripts/other", TOUR.as_bytes());
        assert_eq!(status, 403, "{v}");

        // A plan error: at its line and column, 200 with ok = false.
        let limits = "home();\nlamps_off();\n  move_to(\"turntable\", 400);\ncapture(0.01);\n";
        let (status, dry) = api.put("/api/scripts/limits", limits.as_bytes());
        assert_eq!(status, 200, "{dry}");
        assert_eq!(dry["ok"], false, "{dry}");
        let v = dry["violations"]
            .as_array()
            .expect("violations")
            .iter()
            .find(|v| v["severity"] == "error")
            .cloned()
            .expect("an error");
        assert_eq!(
            (v["line"].as_u64(), v["col"].as_u64()),
            (Some(3), Some(3)),
            "{v}"
        );
        assert!(
            v["message"].as_str().unwrap_or("").contains("turntable"),
            "{v}"
        );
        // A script error: file:line:col.
        let broken = "home();\nlet x = ;\n";
        let (status, dry) = api.post(
            "/api/validate",
            Some(json!({"name": "broken", "text": broken})),
        );
        assert_eq!(status, 200, "{dry}");
        assert_eq!(dry["ok"], false);
        assert!(
            dry["error"]
                .as_str()
                .unwrap_or("")
                .starts_with("broken.rhai:2:"),
            "{dry}"
        );
        assert_eq!(dry["error_line"], 2);
        // Validate a stored script with parameters; unknown parameters are script errors.
        let (status, dry) = api.post(
            "/api/scripts/quickstart/validate",
            Some(json!({"set": {"lamp_count": 1, "turntable_deg": [0.0]}})),
        );
        assert_eq!(status, 200, "{dry}");
        assert_eq!(dry["ok"], true, "{dry}");
        let (status, dry) = api.post(
            "/api/scripts/quickstart/validate",
            Some(json!({"set": {"no_such": 1}})),
        );
        assert_eq!(status, 200, "{dry}");
        assert!(
            dry["error"].as_str().unwrap_or("").contains("no_such"),
            "{dry}"
        );
        let (status, _) = api.post("/api/scripts/quickstart/validate", None);
        assert_eq!(status, 200);

        // Starting a script with errors: 422 naming the line; unknown scripts: 404.
        let (status, e) = api.post("/api/runs", Some(json!({"script": "limits"})));
        assert_eq!(status, 422, "{e}");
        assert!(
            e["error"]
                .as_str()
                .unwrap_or("")
                .contains("limits.rhai:3:3"),
            "{e}"
        );
        let (status, e) = api.post("/api/runs", Some(json!({"script": "nope"})));
        assert_eq!(status, 404, "{e}");

        // Names cannot reach outside the script directories.
        for path in [
            "/api/scripts/..%2F..%2Fetc%2Fpasswd",
            "/api/scripts/.hidden",
            "/api/scripts/a%5Cb",
            "/api/scripts/..",
            "/api/scripts/a%00b",
            "/api/runs/..%2Ftokens.json",
            "/api/runs/.lock",
        ] {
            let (status, e) = api.get(path);
            assert_eq!(status, 400, "GET {path}: {e}");
            assert!(e["error"].is_string(), "{e}");
        }
        let (status, e) = api.put("/api/scripts/..%2Fescape", b"home();");
        assert_eq!(status, 400, "{e}");
        let (status, e) = api.post("/api/runs", Some(json!({"script": "../tokens"})));
        assert_eq!(status, 400, "{e}");
        // Built-in names are taken; sizes and encodings are checked.
        let (status, e) = api.put("/api/scripts/quickstart", b"home();");
        assert_eq!(status, 409, "{e}");
        let big = vec![b'/'; 300 << 10];
        let (status, e) = api.put("/api/scripts/big", &big);
        assert_eq!(status, 413, "{e}");
        let (status, e) = api.put("/api/scripts/latin1", &[b'h', 0xe9, 0xff, b'\n']);
        assert_eq!(status, 400, "{e}");
        assert!(e["error"].as_str().unwrap_or("").contains("UTF-8"), "{e}");
        let (status, _) = api.get("/api/scripts/big");
        assert_eq!(status, 404, "oversized uploads are not stored");
        let (status, e) = api.get("/api/runs/no-such-run");
        assert_eq!(status, 404, "{e}");
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn runs_with_prompts_pause_abort_resume_and_capture() {
    let _turn = crate::grbl_peer::alongside();
    let (d, dir) = daemon().await;
    let data = dir.path().join("data");
    let api = Api::new(&d, &d.state.tokens.operator);
    let state = d.state.clone();
    common::blocking(move || {
        let (status, dry) = api.put("/api/scripts/tour", TOUR.as_bytes());
        assert_eq!(status, 200, "{dry}");

        // Run to the end: prompts answered over the API, paused and resumed on the way.
        let (status, started) = api.post("/api/runs", Some(json!({"script": "tour"})));
        assert_eq!(status, 201, "{started}");
        assert_eq!(started["estimate"]["frames"], TOUR_FRAMES);
        let id = started["run_id"].as_str().expect("run id").to_string();
        // One run at a time; no capture or manual command meanwhile.
        let (status, e) = api.post("/api/runs", Some(json!({"script": "tour"})));
        assert_eq!(status, 409, "{e}");
        assert!(e["error"].as_str().unwrap_or("").contains(&id), "{e}");
        let (status, e) = api.post("/api/capture", Some(json!({"exposure_s": 0.01})));
        assert_eq!(status, 409, "{e}");
        api.answer_prompt(&id, 0, "continue");
        // Pause while the second prompt waits: the run stops before step 5.
        common::eventually(45, "the second prompt", || {
            api.live()["prompt"]["step"] == 4
        });
        let v = api.ok(&format!("/api/runs/{id}/pause"), None);
        assert_eq!(v["state"], "prompt", "a pending prompt shows first: {v}");
        let (status, e) = api.post(&format!("/api/runs/{id}/pause"), None);
        assert_eq!(status, 409, "already paused: {e}");
        api.answer_prompt(&id, 4, "continue");
        common::eventually(45, "paused after step 4", || {
            let l = api.live();
            l["state"] == "paused" && l["steps_done"] == 5
        });
        let recent = api.get("/api/events/recent").1;
        assert!(
            recent
                .as_array()
                .expect("events")
                .iter()
                .any(|e| e["kind"] == "run"
                    && e["data"]["event"] == "paused"
                    && e["data"]["run_id"] == id.as_str()),
            "a paused event"
        );
        std::thread::sleep(Duration::from_millis(300));
        assert_eq!(api.live()["steps_done"], 5, "nothing runs while paused");
        let v = api.ok(&format!("/api/runs/{id}/resume"), None);
        assert_eq!(v["state"], "running", "{v}");
        let run = api.wait_status(&id, "done");
        assert_eq!(run["steps_done"], TOUR_STEPS, "{run}");
        assert_eq!(run["steps_total"], TOUR_STEPS);
        assert_eq!(run["frames"], TOUR_FRAMES, "{run}");
        assert_eq!(run["manifest"]["script_name"], "tour.rhai");
        assert_eq!(index_counts(&data, &id), (TOUR_FRAMES, TOUR_STEPS));
        // The run's events on the hub, and the prompt answers.
        let recent = api.get("/api/events/recent").1;
        let events = recent.as_array().expect("events");
        let finished = events
            .iter()
            .filter(|e| e["kind"] == "run" && e["data"]["run_id"] == id.as_str())
            .filter(|e| e["data"]["event"] == "step_finished")
            .count();
        assert_eq!(finished as u64, TOUR_STEPS, "one step_finished per step");
        let frame_events = events
            .iter()
            .filter(|e| e["kind"] == "frame" && e["data"]["run_id"] == id.as_str())
            .count();
        assert_eq!(
            frame_events as u64, TOUR_FRAMES,
            "a frame event per durable frame"
        );
        assert!(events.iter().any(|e| e["kind"] == "prompt"
            && e["data"]["run_id"] == id.as_str()
            && e["data"]["answered"] == "continue"));
        assert!(api.live().is_null(), "no run is active");
        let (status, e) = api.post(&format!("/api/runs/{id}/resume"), None);
        assert_eq!(status, 409, "a done run: {e}");
        let (status, e) = api.post(&format!("/api/runs/{id}/abort"), None);
        assert_eq!(status, 409, "a done run: {e}");
        let (status, e) = api.post(
            &format!("/api/runs/{id}/prompt"),
            Some(json!({"answer": "continue"})),
        );
        assert_eq!(status, 409, "{e}");

        // Abort while a prompt waits: stopped, resumable, then resumed to the end.
        let id2 = api.start("tour");
        assert_ne!(id2, id);
        api.answer_prompt(&id2, 0, "continue");
        common::eventually(45, "the second prompt", || {
            api.live()["prompt"]["step"] == 4
        });
        let (status, e) = api.post(
            &format!("/api/runs/{id2}/prompt"),
            Some(json!({"answer": "maybe"})),
        );
        assert_eq!(status, 422, "{e}");
        let v = api.ok(&format!("/api/runs/{id2}/abort"), None);
        assert_eq!(v["state"], "stopping", "{v}");
        let run = api.wait_status(&id2, "aborted");
        assert_eq!(run["resumable"], true, "{run}");
        assert_eq!(run["frames"], 2, "the first capture is durable: {run}");
        let (status, e) = api.post(&format!("/api/runs/{id2}/pause"), None);
        assert_eq!(status, 409, "{e}");
        let v = api.ok(&format!("/api/runs/{id2}/resume"), None);
        assert_eq!(v["run_id"], id2.as_str());
        assert_eq!(v["steps_done"], 4, "{v}");
        api.answer_prompt(&id2, 4, "continue");
        let run = api.wait_status(&id2, "done");
        assert_eq!(run["frames"], TOUR_FRAMES, "no frame twice: {run}");
        assert_eq!(index_counts(&data, &id2), (TOUR_FRAMES, TOUR_STEPS));

        // Answering `abort` stops the run too.
        let id3 = api.start("tour");
        api.answer_prompt(&id3, 0, "abort");
        let run = api.wait_status(&id3, "aborted");
        assert_eq!(run["frames"], 0, "{run}");

        // The e-stop latch refuses runs and captures.
        state.estop.latch();
        let (status, e) = api.post("/api/runs", Some(json!({"script": "tour"})));
        assert_eq!(status, 409, "{e}");
        let (status, e) = api.post("/api/capture", Some(json!({"exposure_s": 0.01})));
        assert_eq!(status, 409, "{e}");
        let (status, e) = api.post(&format!("/api/runs/{id3}/resume"), None);
        assert_eq!(status, 409, "{e}");
        state.estop.reset();

        // A single capture: the rig as it is, one exposure, durable and indexed.
        let (status, e) = api.post(
            "/api/capture",
            Some(json!({"cameras": ["cam9"], "exposure_s": 0.01})),
        );
        assert_eq!(status, 404, "{e}");
        let (status, e) = api.post(
            "/api/capture",
            Some(json!({"cameras": ["cam1"], "exposure_s": 100.0})),
        );
        assert_eq!(status, 422, "{e}");
        let (status, cap) = api.post(
            "/api/capture",
            Some(json!({"cameras": ["cam1", "cam3"], "exposure_s": 0.01, "gain": 2.0})),
        );
        assert_eq!(status, 200, "{cap}");
        let cap_id = cap["run_id"].as_str().expect("run id").to_string();
        assert!(cap_id.starts_with("capture-"), "{cap_id}");
        assert_eq!(index_counts(&data, &cap_id).0, 2);
        let frames = cap["frames"].as_array().expect("frames");
        let mut cams: Vec<&str> = frames.iter().filter_map(|f| f["camera"].as_str()).collect();
        cams.sort_unstable();
        assert_eq!(cams, ["cam1", "cam3"], "{cap}");
        assert!(
            frames
                .iter()
                .all(|f| f["exposure_s"] == 0.01 && f["gain"] == 2.0)
        );
        // In place: at the turntable's position with the lamp on, and both left so.
        api.ok(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 40.0})),
        );
        api.ok("/api/lamps/lamp1", Some(json!({"on": true})));
        let (status, cap) = api.post(
            "/api/capture",
            Some(json!({"cameras": ["cam1"], "exposure_s": 0.01})),
        );
        assert_eq!(status, 200, "{cap}");
        let f = &cap["frames"][0];
        assert!(
            (f["axes_deg"]["turntable"].as_f64().unwrap_or(0.0) - 40.0).abs() < 0.01,
            "{f}"
        );
        assert!(f["lamps_on"].to_string().contains("lamp1"), "{f}");
        let devices = api.get("/api/status").1["devices"].clone();
        let turntable = devices["axes"]
            .as_array()
            .and_then(|a| a.iter().find(|a| a["id"] == "turntable"))
            .cloned()
            .unwrap_or_default();
        assert!(
            (turntable["position_deg"].as_f64().unwrap_or(0.0) - 40.0).abs() < 0.01,
            "not re-homed: {turntable}"
        );
        assert!(
            devices["lamps"]
                .as_array()
                .is_some_and(|l| l.iter().any(|l| l["id"] == "lamp1" && l["on"] == true)),
            "the lamp stays on: {devices}"
        );
        api.ok("/api/lamps/off", None);

        // The list: newest first, all of them.
        let (status, runs) = api.get("/api/runs");
        assert_eq!(status, 200);
        let runs = runs.as_array().expect("runs");
        assert_eq!(runs.len(), 5, "{runs:?}");
        assert_eq!(runs[0]["run_id"], cap["run_id"], "the newest first");
        assert_eq!(runs[1]["run_id"], cap_id.as_str());
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn quickstart_runs_to_the_end_and_broken_runs_are_listed() {
    let _turn = crate::grbl_peer::alongside();
    let (d, dir) = daemon().await;
    let data = dir.path().join("data");
    // A run directory without a manifest is listed as unreadable, not a server error.
    std::fs::create_dir_all(data.join("runs").join("broken-run")).expect("mkdir");
    let api = Api::new(&d, &d.state.tokens.operator);
    let started = Instant::now();
    let id = common::blocking(move || {
        let (status, v) = api.post(
            "/api/runs",
            Some(json!({"script": "quickstart", "seed": 7})),
        );
        assert_eq!(status, 422, "the daemon's seed is fixed: {v}");
        let (status, v) = api.post("/api/runs", Some(json!({"script": "quickstart"})));
        assert_eq!(status, 201, "{v}");
        let id = v["run_id"].as_str().expect("run id").to_string();
        let expected = v["estimate"]["frames"].as_u64().expect("frames");
        api.answer_prompt(&id, 0, "continue");
        let mut last = 0.0;
        common::eventually(45, "quickstart done", || {
            let l = api.live();
            if let Some(p) = l["progress"].as_f64() {
                assert!(p >= last, "progress never goes back");
                last = p;
            }
            l.is_null()
        });
        let run = api.wait_status(&id, "done");
        assert_eq!(run["frames"].as_u64(), Some(expected), "{run}");
        assert_eq!(index_counts(&data, &id).0, expected);
        let (_, runs) = api.get("/api/runs");
        let runs = runs.as_array().expect("runs");
        let broken = runs
            .iter()
            .find(|r| r["run_id"] == "broken-run")
            .expect("listed");
        assert_eq!(broken["status"], "unreadable");
        assert!(broken["error"].as_str().unwrap_or("").contains("manifest"));
        let (status, b) = api.get("/api/runs/broken-run");
        assert_eq!(status, 200, "{b}");
        assert_eq!(b["status"], "unreadable");
        let (status, e) = api.post("/api/runs/broken-run/resume", None);
        assert_eq!(status, 409, "{e}");
        id
    })
    .await;
    eprintln!(
        "quickstart {id} in the daemon: {:.1} s wall",
        started.elapsed().as_secs_f64()
    );
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scripts_delete_uploaded_only() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::new(&d, &d.state.tokens.operator);
    let reader = Api::new(&d, &d.state.tokens.read_only);
    common::blocking(move || {
        let delete = |who: &Api, name: &str| who.http.delete(&format!("/api/scripts/{name}"));
        let (status, dry) = api.put("/api/scripts/tour", TOUR.as_bytes());
        assert_eq!(status, 200, "{dry}");
        // Read-only tokens cannot delete; built-in scripts cannot be deleted.
        assert_eq!(delete(&reader, "tour").0, 403);
        let (status, v) = delete(&api, "quickstart");
        assert_eq!(status, 409, "{v}");
        let (status, v) = delete(&api, "tour.rhai");
        assert_eq!(status, 204, "{v}");
        let (_, list) = api.get("/api/scripts");
        assert!(
            !list
                .as_array()
                .expect("a list")
                .iter()
                .any(|s| s["name"] == "tour"),
            "{list}"
        );
        let (status, v) = delete(&api, "tour");
        assert_eq!(status, 404, "{v}");
        let (status, v) = delete(&api, "..%2Fetc");
        assert_eq!(status, 400, "{v}");
    })
    .await;
}
