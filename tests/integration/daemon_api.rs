//! The daemon's HTTP layer as an operator's day uses it: bodies that must be objects, run
//! listings, resuming with an ETA, messages worded for API clients, SSE replay and the final
//! event at shutdown, on the simulated light stage with tiny cameras in real time.

use crate::common;
use common::small_daemon as daemon;

use common::api::Api;
use serde_json::{Value, json};

/// A prompt first (the run waits there), then a capture on one camera.
const PROMPTED: &str = r#"// prompted.rhai
prompt("Place the sample");
home();
lamps_on(["lamp1"]);
capture(0.01, #{cameras: ["cam1"]});
lamps_off();
"#;

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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
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
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    // The event streams go over the daemon's socket, the other requests through its router.
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_needs_no_token_and_every_answer_has_security_headers() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        let h = api.get_anonymous("/api/health");
        assert_eq!(h.status, 200, "{}", h.body);
        assert_eq!(h.body["status"], "ok");
        assert_eq!(h.body["version"], env!("CARGO_PKG_VERSION"));
        assert!(h.body["uptime_s"].as_f64().expect("uptime") >= 0.0);
        let keys: Vec<&String> = h.body.as_object().expect("object").keys().collect();
        assert_eq!(keys.len(), 3, "health says nothing else: {}", h.body);
        assert!(!h.body.to_string().contains(&api.token));
        // Everything else under /api/ still needs a token.
        assert_eq!(api.get_anonymous("/api/status").status, 401);

        for path in [
            "/",
            "/app.js",
            "/style.css",
            "/api/status",
            "/api/health",
            "/api/nope",
        ] {
            let r = if path == "/api/health" {
                api.get_anonymous(path)
            } else {
                api.get_reply(path)
            };
            assert_eq!(r.header("x-frame-options"), "DENY", "{path}");
            assert_eq!(r.header("x-content-type-options"), "nosniff", "{path}");
            let csp = r.header("content-security-policy");
            assert!(csp.contains("default-src 'self'"), "{path}: {csp}");
            assert!(csp.contains("script-src 'self'"), "{path}: {csp}");
            assert!(!csp.contains("unsafe-eval"), "{path}: {csp}");
            assert!(csp.contains("frame-ancestors 'none'"), "{path}: {csp}");
        }
        let unauthorised = api.get_anonymous("/api/status");
        assert_eq!(unauthorised.header("x-frame-options"), "DENY");
        let docs = api.get_reply("/docs/");
        assert_eq!(docs.header("x-content-type-options"), "nosniff");
        // The dashboard runs under that policy: no inline script or style element.
        let (_, html) = api.get("/");
        let html = html.as_str().expect("html").to_string();
        assert!(!html.contains("<style"), "inline style element");
        for tag in html.split("<script").skip(1) {
            let open = &tag[..tag.find('>').expect("tag end")];
            assert!(open.contains("src="), "inline script: <script{open}>");
        }
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_script_that_fails_validation_answers_its_violations_as_a_list() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        // Line 3 moves out of the soft limits; line 4 captures with a camera the rig lacks.
        let bad = "// bad.rhai\nhome();\nmove_to(#{turntable: 1000.0});\ncapture(0.01);\n";
        let (s, v) = api.put_text("/api/scripts/bad", bad);
        assert_eq!(s, 200, "{v}");
        let (s, v) = api.post("/api/runs", Some(json!({"script": "bad"})));
        assert_eq!(s, 422, "{v}");
        let violations = v["violations"].as_array().expect("violations");
        assert!(!violations.is_empty(), "{v}");
        let limit = violations
            .iter()
            .find(|x| x["line"] == 3)
            .unwrap_or_else(|| panic!("a violation at line 3: {v}"));
        assert!(limit["col"].as_u64().expect("col") >= 1, "{limit}");
        assert!(
            limit["message"]
                .as_str()
                .expect("message")
                .contains("turntable")
        );

        // A script that does not compile: one violation at its place.
        let (s, _) = api.put_text("/api/scripts/broken", "home();\nmove_to(#{turntable: );\n");
        assert_eq!(s, 200);
        let (s, v) = api.post("/api/runs", Some(json!({"script": "broken"})));
        assert_eq!(s, 422, "{v}");
        assert_eq!(v["violations"][0]["line"], 2, "{v}");

        // A parameter of the wrong kind: a violation without a place in the script.
        let (s, v) = api.post(
            "/api/runs",
            Some(json!({"script": "quickstart", "set": {"lamp_count": {"a": 1}}})),
        );
        assert_eq!(s, 422, "{v}");
        assert_eq!(v["violations"][0]["line"], Value::Null, "{v}");
        assert!(
            v["violations"][0]["message"]
                .as_str()
                .expect("message")
                .contains("lamp_count")
        );
        // Other errors carry no list.
        let (s, v) = api.post("/api/runs", Some(json!({"script": "nope"})));
        assert_eq!(s, 404);
        assert!(v.get("violations").is_none(), "{v}");
    })
    .await;
    d.shutdown().await;
}

/// The position of axis `id` in the status.
fn axis(api: &Api, id: &str) -> Value {
    let (_, st) = api.get("/api/status");
    st["devices"]["axes"]
        .as_array()
        .and_then(|a| a.iter().find(|a| a["id"] == id))
        .cloned()
        .unwrap_or_else(|| panic!("no axis {id}: {st}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_axes_move_at_once_with_the_single_move_checks() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    let ro = Api::read_only(&d);
    common::blocking(move || {
        // Not homed: refused, nothing moves.
        let v = api.expect(
            409,
            "/api/axes/move",
            Some(json!({"targets": {"turntable": 90.0, "light_arc": 30.0}})),
        );
        assert!(v["hint"].as_str().expect("hint").contains("home"), "{v}");
        api.expect(200, "/api/axes/turntable/home", None);
        api.expect(200, "/api/axes/light_arc/home", None);
        // One target outside the limits, one unknown axis, none at all: nothing moves.
        let v = api.expect(
            422,
            "/api/axes/move",
            Some(json!({"targets": {"turntable": 90.0, "light_arc": 1000.0}})),
        );
        assert!(
            v["error"].as_str().expect("error").contains("light_arc"),
            "{v}"
        );
        api.expect(
            404,
            "/api/axes/move",
            Some(json!({"targets": {"turntable": 90.0, "elevator": 1.0}})),
        );
        api.expect(422, "/api/axes/move", Some(json!({"targets": {}})));
        api.expect(
            422,
            "/api/axes/move",
            Some(json!({"targets": {"turntable": "east"}})),
        );
        assert!(
            axis(&api, "turntable")["position_deg"]
                .as_f64()
                .expect("pos")
                .abs()
                < 1e-6
        );

        // Both at once: at some moment both are moving.
        let mover = api.clone();
        let moving = std::thread::spawn(move || {
            mover.post(
                "/api/axes/move",
                Some(json!({"targets": {"turntable": 120.0, "light_arc": 30.0}})),
            )
        });
        common::eventually(30, "both axes moving together", || {
            axis(&api, "turntable")["moving"] == true && axis(&api, "light_arc")["moving"] == true
        });
        let (s, v) = moving.join().expect("mover");
        assert_eq!(s, 200, "{v}");
        let arrived = v.as_array().expect("axes");
        assert_eq!(arrived.len(), 2, "{v}");
        for (a, want) in arrived.iter().zip([30.0, 120.0]) {
            let pos = a["position_deg"].as_f64().expect("position");
            assert!((pos - want).abs() < 0.01, "{a}");
            assert_eq!(a["moving"], false);
        }
        // The read-only token may not.
        let (s, _) = ro.post(
            "/api/axes/move",
            Some(json!({"targets": {"turntable": 1.0}})),
        );
        assert_eq!(s, 403);
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lamp_switches_while_an_axis_moves_but_the_axis_takes_one_command_at_a_time() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        api.expect(200, "/api/axes/turntable/home", None);
        // A move of several seconds in the background.
        let mover = api.clone();
        let long_move = std::thread::spawn(move || {
            mover.post(
                "/api/axes/turntable/move",
                Some(json!({"target_deg": 300.0})),
            )
        });
        common::eventually(10, "the turntable moves", || {
            axis(&api, "turntable")["moving"] == true
        });
        // Other devices answer during the move…
        let v = api.expect(200, "/api/lamps/lamp1", Some(json!({"on": true})));
        assert_eq!(v["on"], true);
        api.expect(200, "/api/lamps/off", None);
        api.expect(200, "/api/laser/arm", Some(json!({"confirm": true})));
        api.expect(200, "/api/axes/light_arc/home", None);
        // …while the turntable is still on its way: nothing waited for it.
        assert_eq!(
            axis(&api, "turntable")["moving"],
            true,
            "the move ended first"
        );
        // The same axis still takes one command at a time.
        let v = api.expect(409, "/api/axes/turntable/home", None);
        assert!(
            v["error"].as_str().expect("error").contains("in progress"),
            "{v}"
        );
        api.expect(200, "/api/axes/turntable/stop", None);
        let (s, v) = long_move.join().expect("mover");
        assert_eq!(s, 409, "the stopped move: {v}");
    })
    .await;
    d.shutdown().await;
}

/// A run that ends on its own: one capture.
const QUICK: &str = "// quick.rhai\nhome();\ncapture(0.01, #{cameras: [\"cam1\"]});\n";

/// The queue now.
fn queue(api: &Api) -> Value {
    let (s, q) = api.get("/api/queue");
    assert_eq!(s, 200, "{q}");
    q
}

/// The ids of the queued items, in order.
fn queued(api: &Api) -> Vec<u64> {
    queue(api)["items"]
        .as_array()
        .expect("items")
        .iter()
        .filter_map(|i| i["item_id"].as_u64())
        .collect()
}

/// Queues `script`; the item id.
fn submit(api: &Api, script: &str) -> u64 {
    let v = api.expect(201, "/api/queue", Some(json!({"script": script})));
    v["item_id"].as_u64().expect("item id")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_runs_start_in_order_and_can_be_reordered_removed_and_paused() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        assert_eq!(api.put_text("/api/scripts/prompted", PROMPTED).0, 200);
        assert_eq!(api.put_text("/api/scripts/quick", QUICK).0, 200);
        // Refused at submission: unknown script, a script that fails its dry run.
        api.expect(404, "/api/queue", Some(json!({"script": "nope"})));
        let bad = "home();\nmove_to(#{turntable: 1000.0});\n";
        assert_eq!(api.put_text("/api/scripts/bad", bad).0, 200);
        let v = api.expect(422, "/api/queue", Some(json!({"script": "bad"})));
        assert_eq!(v["violations"][0]["line"], 2, "{v}");

        // The first starts at once (the rig is idle) and waits at its prompt.
        let a = submit(&api, "prompted");
        let b = submit(&api, "quick");
        let c = submit(&api, "quick");
        wait_prompt(&api, 0);
        let q = queue(&api);
        assert_eq!(q["running"], true, "{q}");
        assert_eq!(q["current"]["item_id"], a, "{q}");
        let run_a = q["current"]["run_id"].as_str().expect("run id").to_string();
        assert_eq!(queued(&api), [b, c]);

        // Reorder and remove while it waits.
        let v = api.expect(
            200,
            &format!("/api/queue/{c}/move"),
            Some(json!({"position": 0})),
        );
        assert_eq!(v["items"][0]["item_id"], c, "{v}");
        api.expect(
            422,
            &format!("/api/queue/{c}/move"),
            Some(json!({"position": 2})),
        );
        api.expect(404, "/api/queue/999/move", Some(json!({"position": 0})));
        let (s, v) = api.delete(&format!("/api/queue/{b}"));
        assert_eq!(s, 200, "{v}");
        assert_eq!(v["item_id"], b);
        assert_eq!(api.delete(&format!("/api/queue/{b}")).0, 404);
        assert_eq!(api.delete("/api/queue/x").0, 400);
        assert_eq!(queued(&api), [c]);

        // A ends; C follows by itself and ends; the queue is empty.
        api.expect(
            200,
            &format!("/api/runs/{run_a}/prompt"),
            Some(json!({"answer": "continue"})),
        );
        common::eventually(60, "A and C done", || {
            queue(&api)["history"].as_array().map_or(0, Vec::len) == 2
        });
        let q = queue(&api);
        let history = q["history"].as_array().expect("history");
        assert_eq!(history[0]["item_id"], a);
        assert_eq!(history[1]["item_id"], c);
        assert!(history.iter().all(|h| h["status"] == "done"), "{q}");
        assert_eq!(q["current"], Value::Null);
        assert_eq!(queued(&api), Vec::<u64>::new());
        let run_c = history[1]["run_id"].as_str().expect("run id");
        assert_eq!(api.get(&format!("/api/runs/{run_c}")).1["status"], "done");

        // An e-stop during a queued run pauses the queue: the next one stays queued.
        let e = submit(&api, "prompted");
        wait_prompt(&api, 0);
        let f = submit(&api, "quick");
        api.expect(200, "/api/estop", None);
        common::eventually(30, "the queue paused with E's run ended", || {
            let q = queue(&api);
            q["running"] == false && q["current"].is_null()
        });
        let q = queue(&api);
        assert!(
            q["paused_because"]
                .as_str()
                .expect("why")
                .contains("e-stop"),
            "{q}"
        );
        let last = q["history"].as_array().and_then(|h| h.last()).cloned();
        let last = last.expect("E in the history");
        assert_eq!(last["item_id"], e);
        assert_eq!(last["status"], "aborted");
        assert_eq!(queued(&api), [f]);
        // Starting while latched is refused; after the reset the queue stays paused…
        api.expect(409, "/api/queue/start", None);
        api.expect(200, "/api/estop/reset", None);
        assert_eq!(queue(&api)["running"], false);
        assert_eq!(queued(&api), [f]);
        assert_eq!(api.get("/api/status").1["run"], Value::Null);
        // …until it is started: F runs.
        api.expect(200, "/api/queue/start", None);
        common::eventually(60, "F done", || {
            queue(&api)["history"]
                .as_array()
                .and_then(|h| h.last())
                .is_some_and(|h| h["item_id"] == f && h["status"] == "done")
        });
        assert_eq!(queue(&api)["running"], true);

        // Stopping holds the next run back.
        api.expect(200, "/api/queue/stop", None);
        let g = submit(&api, "quick");
        assert_eq!(queued(&api), [g]);
        assert_eq!(api.get("/api/status").1["run"], Value::Null);

        // Every change went out as a `queue` event with the queue after it.
        let (_, events) = api.get("/api/events/recent");
        let actions: Vec<&str> = events
            .as_array()
            .expect("events")
            .iter()
            .filter(|e| e["kind"] == "queue")
            .filter_map(|e| e["data"]["action"].as_str())
            .collect();
        for want in [
            "submitted",
            "moved",
            "removed",
            "run_started",
            "run_ended",
            "paused",
        ] {
            assert!(actions.contains(&want), "{want} in {actions:?}");
        }
        assert_eq!(actions.last(), Some(&"submitted"), "{actions:?}");
        let last = events
            .as_array()
            .and_then(|e| e.iter().rev().find(|e| e["kind"] == "queue"))
            .cloned()
            .expect("a queue event");
        assert_eq!(last["data"]["queue"]["items"][0]["item_id"], g, "{last}");
    })
    .await;
    d.shutdown().await;
}
