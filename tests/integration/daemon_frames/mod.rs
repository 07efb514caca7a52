//! Frames over the daemon's API: query a real run's frames by metadata, download them as
//! PNG / TIFF / EXR and compare the pixels, thumbnails, the latest frame per camera, path
//! traversal attempts, and the executor's Prometheus metrics.
//!
//! The dataset is made once per test binary by the CLI engine in-process (`dataset.rs`), then
//! every test starts its own daemon on that data directory. This file holds the client and the
//! helpers; each topic is a submodule.

mod dataset;
mod download;
mod metrics;
mod never_served;
mod query;

use crate::common;

use std::io::Cursor;

use serde_json::Value;
use stagehand::client::Body;
use stagehand::daemon::RunningDaemon;

use dataset::{Dataset, dataset, db};

async fn daemon(d: &Dataset) -> RunningDaemon {
    common::start_daemon(&d.data, None)
        .await
        .expect("daemon starts")
}

/// A blocking client (call it inside `spawn_blocking`): requests through the daemon's router,
/// raw targets over its socket.
#[derive(Clone)]
struct Api {
    http: common::api::Api,
}

/// Status, headers and body of an answer.
struct Answer {
    status: u16,
    content_type: String,
    disposition: String,
    etag: String,
    body: Vec<u8>,
}

impl Answer {
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

impl Api {
    fn new(d: &RunningDaemon) -> Self {
        // Reading frames needs only the read-only token.
        Self {
            http: common::api::Api::read_only(d),
        }
    }

    fn get_with(&self, path: &str, if_none_match: Option<&str>) -> Answer {
        let headers: Vec<(&str, &str)> = if_none_match
            .map(|tag| ("If-None-Match", tag))
            .into_iter()
            .collect();
        let r = self.http.raw("GET", path, &headers, Body::Empty);
        Answer {
            status: r.status,
            content_type: r.header("content-type").to_string(),
            disposition: r.header("content-disposition").to_string(),
            etag: r.header("etag").to_string(),
            body: r.body,
        }
    }

    fn get(&self, path: &str) -> Answer {
        self.get_with(path, None)
    }

    /// `method path` with `token`, a text body (PUT) or a JSON body (POST): status and JSON.
    fn send(&self, method: &str, path: &str, token: &str, body: &str) -> (u16, Value) {
        let (method, content_type) = match method {
            "PUT" => ("PUT", "text/plain"),
            _ => ("POST", "application/json"),
        };
        let body = Body::Text {
            content_type: content_type.into(),
            text: body.to_string(),
        };
        let r = self.http.with_token(token).raw(method, path, &[], body);
        (
            r.status,
            serde_json::from_slice(&r.body).unwrap_or(Value::Null),
        )
    }

    /// Sends `GET <raw target>` byte for byte over the daemon's socket (no client-side
    /// normalisation of `..` or `%2F`).
    fn raw_get(&self, target: &str) -> (u16, String) {
        self.http.get_exact(target)
    }
}

/// Runs `f` with a client of a fresh daemon on the dataset, then shuts the daemon down.
async fn with_api<T: Send + 'static>(f: impl FnOnce(&Dataset, Api) -> T + Send + 'static) -> T {
    let d = dataset();
    let daemon = daemon(d).await;
    let api = Api::new(&daemon);
    let out = tokio::task::spawn_blocking(move || f(d, api))
        .await
        .expect("test body");
    daemon.shutdown().await;
    out
}

fn frames_of(a: &Answer) -> Vec<Value> {
    a.json()["frames"].as_array().cloned().unwrap_or_default()
}

/// (frame id, path) of the first frame of `kind`.
fn first_of(d: &Dataset, kind: &str) -> (i64, String) {
    db(d)
        .query_row(
            "SELECT id, path FROM frames WHERE kind = ?1 ORDER BY id LIMIT 1",
            [kind],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .expect("frame")
}

fn png8_size(bytes: &[u8]) -> (u32, u32) {
    let reader = png::Decoder::new(Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let info = reader.info();
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "8-bit");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    (info.width, info.height)
}
