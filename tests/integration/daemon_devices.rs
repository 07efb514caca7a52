//! Manual device control over the daemon's API, on the simulated light stage in real time:
//! axes, lamps, the laser and its interlock, the e-stop, and hold-to-jog over a WebSocket.

use crate::common;
use common::builtin_daemon as daemon;

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use stagehand::daemon::RunningDaemon;
use tokio_tungstenite::tungstenite::Message;

/// A blocking client for one daemon (call it inside `spawn_blocking`) with this file's
/// helpers.
#[derive(Clone)]
struct Api {
    http: common::api::Api,
}

impl Api {
    fn operator(d: &RunningDaemon) -> Self {
        Self {
            http: common::api::Api::operator(d),
        }
    }

    fn read_only(d: &RunningDaemon) -> Self {
        Self {
            http: common::api::Api::read_only(d),
        }
    }

    /// `POST path` with a JSON body (or none): status and body.
    fn post(&self, path: &str, body: Option<Value>) -> (u16, Value) {
        self.http.post(path, body)
    }

    fn get(&self, path: &str) -> (u16, Value) {
        self.http.get(path)
    }

    fn ok(&self, path: &str, body: Option<Value>) -> Value {
        let (status, v) = self.post(path, body);
        assert_eq!(status, 200, "POST {path}: {v}");
        v
    }

    fn axis(&self, id: &str) -> Value {
        let (_, s) = self.get("/api/status");
        s["devices"]["axes"]
            .as_array()
            .expect("axes")
            .iter()
            .find(|a| a["id"] == id)
            .cloned()
            .expect("the axis is in the status")
    }

    fn status(&self) -> Value {
        self.get("/api/status").1
    }
}

fn pos(v: &Value) -> f64 {
    v["position_deg"].as_f64().expect("position_deg")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn axes_move_jog_home_and_stop_with_positions_in_the_status() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    let ro = Api::read_only(&d);
    common::blocking(move || {
        // Moving before homing is refused with a hint to home.
        let (s, v) = api.post(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 10.0})),
        );
        assert_eq!(s, 409, "{v}");
        assert!(v["hint"].as_str().unwrap().contains("home"), "{v}");

        let v = api.ok("/api/axes/turntable/home", None);
        assert_eq!(v["homed"], true);
        assert!(pos(&v).abs() < 1e-6);

        let v = api.ok(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 10.0})),
        );
        assert!((pos(&v) - 10.0).abs() < 0.01, "{v}");
        assert_eq!(v["moving"], false);
        let v = api.ok("/api/axes/turntable/jog", Some(json!({"delta_deg": 5.0})));
        assert!((pos(&v) - 15.0).abs() < 0.01, "{v}");
        let v = api.ok("/api/axes/turntable/jog", Some(json!({"delta_deg": -20.0})));
        assert!((pos(&v) + 5.0).abs() < 0.01, "{v}");
        let a = api.axis("turntable");
        assert!((pos(&a) + 5.0).abs() < 0.01, "{a}");
        assert_eq!(a["homed"], true);
        assert_eq!(a["moving"], false);
        let v = api.ok("/api/axes/turntable/stop", None);
        assert!((pos(&v) + 5.0).abs() < 0.01, "{v}");

        // Soft limits: 422 naming them; the axis stays put.
        let (s, v) = api.post(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 1000.0})),
        );
        assert_eq!(s, 422, "{v}");
        let text = v.to_string();
        assert!(text.contains("-180") && text.contains("360"), "{v}");
        let (s, v) = api.post(
            "/api/axes/turntable/jog",
            Some(json!({"delta_deg": -500.0})),
        );
        assert_eq!(s, 422, "{v}");
        assert!((pos(&api.axis("turntable")) + 5.0).abs() < 0.01);

        // Bad input is a 4xx with a message.
        let (s, v) = api.post("/api/axes/turntable/move", Some(json!({"target": 1.0})));
        assert!((400..500).contains(&s), "{s} {v}");
        let (s, v) = api.post(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": "north"})),
        );
        assert!((400..500).contains(&s), "{s} {v}");

        // Unknown ids: 404 naming the known ones.
        let (s, v) = api.post("/api/axes/elevator/move", Some(json!({"target_deg": 1.0})));
        assert_eq!(s, 404, "{v}");
        assert!(v["error"].as_str().unwrap().contains("turntable"), "{v}");
        let (s, v) = api.post("/api/lamps/lamp99", Some(json!({"on": true})));
        assert_eq!(s, 404, "{v}");
        assert!(v["error"].as_str().unwrap().contains("lamp1"), "{v}");

        // Lamps.
        let v = api.ok("/api/lamps/lamp3", Some(json!({"on": true})));
        assert_eq!(v["on"], true);
        let v = api.ok("/api/lamps/off", None);
        assert!(
            v.as_array().unwrap().iter().all(|l| l["on"] == false),
            "{v}"
        );

        // The read-only token may look but not touch.
        let (s, v) = ro.post("/api/axes/turntable/home", None);
        assert_eq!(s, 403, "{v}");
        // …except the e-stop, which anyone who can watch the rig may press; only the
        // operator may reset it.
        let (s, v) = ro.post("/api/estop", None);
        assert_eq!(s, 200, "{v}");
        let (s, v) = ro.post("/api/estop/reset", None);
        assert_eq!(s, 403, "{v}");
        let v = api.ok("/api/estop/reset", None);
        assert_eq!(v["active"], false, "{v}");
        let (s, _) = ro.get("/api/interlock");
        assert_eq!(s, 200);

        // Every change went out as a `device` event.
        let (_, events) = api.get("/api/events/recent");
        let moved = events.as_array().unwrap().iter().any(|e| {
            e["kind"] == "device"
                && e["data"]["axes"].as_array().is_some_and(|a| {
                    a.iter()
                        .any(|a| a["id"] == "turntable" && a["homed"] == true)
                })
        });
        assert!(moved, "no device event: {events}");
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_laser_needs_arming_and_a_closed_interlock() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    common::blocking(move || {
        let (s, v) = api.post("/api/laser/on", None);
        assert_eq!(s, 409, "on without arming: {v}");
        assert!(v["hint"].as_str().unwrap().contains("arm"), "{v}");

        let (s, v) = api.post("/api/laser/arm", None);
        assert_eq!(s, 400, "{v}");
        assert!(v["hint"].as_str().unwrap().contains("confirm"), "{v}");
        let (s, _) = api.post("/api/laser/arm", Some(json!({"confirm": false})));
        assert_eq!(s, 400);
        let v = api.ok("/api/laser/arm", Some(json!({"confirm": true})));
        assert_eq!(v["armed"], true);
        assert_eq!(v["on"], false);
        assert_eq!(v["interlock_closed"], true);

        let (s, v) = api.post("/api/laser/on", Some(json!({"colour_nm": 532})));
        assert_eq!(s, 422, "532 nm is not fitted: {v}");

        // Door open: the laser refuses to emit.
        let v = api.ok("/api/interlock", Some(json!({"closed": false})));
        assert_eq!(v["closed"], false);
        assert_eq!(v["source"], "simulated");
        let (s, v) = api.post("/api/laser/on", None);
        assert_eq!(s, 409, "{v}");
        assert!(v["error"].as_str().unwrap().contains("interlock"), "{v}");
        assert!(v["error"].as_str().unwrap().contains("laser"), "{v}");
        assert_eq!(api.status()["devices"]["laser"]["interlock"], "open");

        // Door closed: it emits; opening the door switches it off at once.
        api.ok("/api/interlock", Some(json!({"closed": true})));
        let v = api.ok("/api/laser/on", Some(json!({})));
        assert_eq!(v["on"], true, "{v}");
        assert_eq!(v["interlock_closed"], true);
        api.ok("/api/interlock", Some(json!({"closed": false})));
        common::eventually(10, "the laser goes off when the door opens", || {
            let l = &api.status()["devices"]["laser"];
            l["on"] == false && l["interlock_closed"] == false
        });
        assert_eq!(api.status()["devices"]["laser"]["armed"], true);
        api.ok("/api/interlock", Some(json!({"closed": true})));
        let v = api.ok("/api/laser/disarm", None);
        assert_eq!(v["armed"], false);
    })
    .await;
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_estop_stops_a_long_move_switches_everything_off_and_latches() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    let elapsed_ms = common::blocking(move || {
        api.ok("/api/axes/turntable/home", None);
        api.ok("/api/lamps/lamp1", Some(json!({"on": true})));
        api.ok("/api/laser/arm", Some(json!({"confirm": true})));
        api.ok("/api/laser/on", None);

        // A move of about ten seconds, in the background.
        let mover = api.clone();
        let long_move = std::thread::spawn(move || {
            mover.post(
                "/api/axes/turntable/move",
                Some(json!({"target_deg": 300.0})),
            )
        });
        common::eventually(10, "the turntable moves", || {
            api.axis("turntable")["moving"] == true
        });
        std::thread::sleep(Duration::from_millis(300));

        let report = api.ok("/api/estop", None);
        assert_eq!(report["active"], true, "{report}");
        assert!(report["errors"].as_array().unwrap().is_empty(), "{report}");
        let snapshot = &report["devices"];
        assert!(
            snapshot["lamps"]
                .as_array()
                .unwrap()
                .iter()
                .all(|l| l["on"] == false),
            "the e-stop's own snapshot shows every lamp off: {snapshot}"
        );
        assert_eq!(snapshot["laser"]["on"], false, "{snapshot}");
        assert!(
            snapshot["axes"]
                .as_array()
                .unwrap()
                .iter()
                .all(|a| a["homed"] == false),
            "stopped abruptly, every axis must be homed again: {snapshot}"
        );
        let elapsed_ms = report["elapsed_ms"].as_f64().unwrap();

        let (s, v) = long_move.join().expect("the mover thread");
        assert_eq!(s, 409, "the interrupted move: {v}");
        assert!(v["error"].as_str().unwrap().contains("e-stop"), "{v}");
        let st = api.status();
        assert_eq!(st["estop"], true);
        let tt = api.axis("turntable");
        assert_eq!(tt["moving"], false, "{tt}");
        assert!(pos(&tt) > 0.0 && pos(&tt) < 299.0, "stopped short: {tt}");
        let devices = &st["devices"];
        assert!(
            devices["lamps"]
                .as_array()
                .unwrap()
                .iter()
                .all(|l| l["on"] == false),
            "{devices}"
        );
        assert_eq!(devices["laser"]["on"], false);
        assert_eq!(devices["laser"]["armed"], false);

        // The latch refuses motion and emission, but not stopping.
        let (s, v) = api.post(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 10.0})),
        );
        assert_eq!(s, 409, "{v}");
        assert!(v["hint"].as_str().unwrap().contains("reset"), "{v}");
        let (s, _) = api.post("/api/lamps/lamp2", Some(json!({"on": true})));
        assert_eq!(s, 409);
        let (s, _) = api.post("/api/laser/arm", Some(json!({"confirm": true})));
        assert_eq!(s, 409);
        api.ok("/api/axes/turntable/stop", None);
        api.ok("/api/lamps/off", None);

        let (_, events) = api.get("/api/events/recent");
        assert!(
            events
                .as_array()
                .unwrap()
                .iter()
                .any(|e| e["kind"] == "estop" && e["data"]["active"] == true),
            "{events}"
        );

        let v = api.ok("/api/estop/reset", None);
        assert_eq!(v["active"], false);
        assert_eq!(api.axis("turntable")["homed"], false);
        let (s, v) = api.post(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 10.0})),
        );
        assert_eq!(s, 409, "not homed after the e-stop: {v}");
        api.ok("/api/axes/turntable/home", None);
        let v = api.ok(
            "/api/axes/turntable/move",
            Some(json!({"target_deg": 10.0})),
        );
        assert!((pos(&v) - 10.0).abs() < 0.01, "{v}");

        let (_, metrics) = api.get("/api/metrics");
        assert!(metrics.to_string().contains("stagehand_estop_seconds"));
        elapsed_ms
    })
    .await;
    eprintln!("e-stop: devices safe in {elapsed_ms:.2} ms");
    d.shutdown().await;
}

/// A capture arms its cameras before its pacing wait; the e-stop disarms them itself, without
/// waiting for the aborted run's own end (here there is no run at all).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_estop_disarms_every_camera() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let world = d.state.rig.world.clone().expect("the simulated rig");
    for c in d.state.rig.cameras.values() {
        c.set_armed(true).await.expect("arm");
    }
    assert_eq!(world.armed_cameras(), d.state.rig.cameras.len());
    assert_eq!(world.armed_cameras(), 8);
    let api = Api::operator(&d);
    common::blocking(move || {
        let report = api.ok("/api/estop", None);
        assert!(report["errors"].as_array().unwrap().is_empty(), "{report}");
        common::eventually(10, "every camera disarmed", || world.armed_cameras() == 0);
        api.ok("/api/estop/reset", None);
    })
    .await;
    d.shutdown().await;
}

/// Reads messages until one satisfies `pred` (or the guard deadline passes).
async fn until<S>(ws: &mut S, what: &str, pred: impl Fn(&Value) -> bool) -> Value
where
    S: futures_util::Stream<Item = Result<Message, tokio_tungstenite::tungstenite::Error>> + Unpin,
{
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let msg = tokio::time::timeout_at(deadline, ws.next())
            .await
            .unwrap_or_else(|_| panic!("no message: {what}"))
            .expect("the socket stays open")
            .expect("a message");
        if let Message::Text(t) = msg {
            let v: Value = serde_json::from_str(t.as_str()).expect("JSON");
            if pred(&v) {
                return v;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hold_to_jog_stops_when_the_client_goes_quiet() {
    let _turn = crate::grbl_peer::alongside();
    let (d, _dir) = daemon().await;
    let api = Api::operator(&d);
    let http = api.clone();
    common::blocking(move || http.ok("/api/axes/turntable/home", None)).await;
    // The WebSocket needs the daemon's listener (an upgraded connection); the HTTP requests
    // around it go through the router.
    let url = |token: &str| format!("ws://{}/api/ws/jog?access_token={token}", d.addr);

    // A read-only token may not jog.
    match tokio_tungstenite::connect_async(url(&d.state.tokens.read_only)).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => assert_eq!(r.status(), 403),
        other => panic!("read-only jog: {:?}", other.map(|_| ())),
    }

    let (mut ws, _) = tokio_tungstenite::connect_async(url(&d.state.tokens.operator))
        .await
        .expect("the operator may jog");
    // Refusals come back as messages; the socket stays usable.
    ws.send(Message::text(
        json!({"axis": "nope", "direction": 1}).to_string(),
    ))
    .await
    .unwrap();
    let v = until(&mut ws, "unknown axis refused", |v| {
        v.get("error").is_some()
    })
    .await;
    assert!(v["error"].as_str().unwrap().contains("turntable"), "{v}");

    // Held with keepalives, the axis moves; then the client goes quiet.
    ws.send(Message::text(
        json!({"axis": "turntable", "direction": 1}).to_string(),
    ))
    .await
    .unwrap();
    for _ in 0..4 {
        tokio::time::sleep(Duration::from_millis(200)).await;
        ws.send(Message::text(json!({"hold": true}).to_string()))
            .await
            .unwrap();
    }
    let moving = until(&mut ws, "position updates", |v| v["moving"] == true).await;
    assert_eq!(moving["axis"], "turntable");
    let stopped = until(&mut ws, "the dead-man stop", |v| v.get("stopped").is_some()).await;
    assert_eq!(stopped["stopped"], "deadman", "{stopped}");
    let p = pos(&stopped);
    assert!(
        p > 1.0 && p < 300.0,
        "moved some way, not to the limit: {stopped}"
    );
    let a = common::blocking(move || api.axis("turntable")).await;
    assert_eq!(a["moving"], false, "{a}");
    assert!((pos(&a) - p).abs() < 0.01, "{a} vs {stopped}");

    // A crawl (speed < 1) moves too, and the e-stop ends it.
    ws.send(Message::text(
        json!({"axis": "turntable", "direction": 1, "speed": 0.2}).to_string(),
    ))
    .await
    .unwrap();
    until(&mut ws, "crawling", |v| v["moving"] == true).await;
    let http = Api::operator(&d);
    common::blocking(move || http.ok("/api/estop", None)).await;
    ws.send(Message::text(json!({"hold": true}).to_string()))
        .await
        .unwrap();
    let stopped = until(&mut ws, "the e-stop", |v| v.get("stopped").is_some()).await;
    assert_eq!(stopped["stopped"], "estop", "{stopped}");
    ws.send(Message::text(
        json!({"axis": "turntable", "direction": 1}).to_string(),
    ))
    .await
    .unwrap();
    let v = until(&mut ws, "refused while latched", |v| {
        v.get("error").is_some()
    })
    .await;
    assert!(v["error"].as_str().unwrap().contains("e-stop"), "{v}");
    let http = Api::operator(&d);
    common::blocking(move || {
        http.ok("/api/estop/reset", None);
        // The e-stop forgot the home (the stepper may have lost steps).
        assert_eq!(http.axis("turntable")["homed"], false);
        http.ok("/api/axes/turntable/home", None);
    })
    .await;

    // An explicit stop, then closing the socket mid-jog, stop the axis too.
    ws.send(Message::text(
        json!({"axis": "turntable", "direction": -1}).to_string(),
    ))
    .await
    .unwrap();
    until(&mut ws, "moving back", |v| v["moving"] == true).await;
    ws.send(Message::text(json!({"stop": true}).to_string()))
        .await
        .unwrap();
    let stopped = until(&mut ws, "the stop", |v| v.get("stopped").is_some()).await;
    assert_eq!(stopped["stopped"], "stop", "{stopped}");
    ws.send(Message::text(
        json!({"axis": "turntable", "direction": 1}).to_string(),
    ))
    .await
    .unwrap();
    until(&mut ws, "moving again", |v| v["moving"] == true).await;
    drop(ws);
    let api = Api::operator(&d);
    common::blocking(move || {
        common::eventually(10, "closing the socket stops the axis", || {
            let a = api.axis("turntable");
            a["moving"] == false
        });
        // The manual lock was released: an HTTP move works.
        let v = api.ok("/api/axes/turntable/move", Some(json!({"target_deg": 5.0})));
        assert!((pos(&v) - 5.0).abs() < 0.01, "{v}");
    })
    .await;
    d.shutdown().await;
}
