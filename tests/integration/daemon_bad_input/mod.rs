//! Bad input against the daemon's HTTP API, driven by its own OpenAPI document so every route
//! is covered, whoever added it: requests without a token or with a wrong one (401), the
//! read-only token on a mutating route (403), unknown ids, path traversal in ids, malformed
//! JSON, wrong types, missing fields, oversized bodies and bad query strings. Every answer
//! must be a 4xx with a JSON `{error}` body (or a success where the input happens to be
//! valid), never a 5xx. `cases.rs` derives the requests from the document; this file sends
//! them and judges the answers.

mod cases;

use crate::common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;
use stagehand::client::Body;
use stagehand::daemon::{DaemonError, RunningDaemon};

use cases::{Ids, cases_for, operations, specific_cases};

type TestResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

/// A small simulated light stage (cameras 64×48) as a rig file.
fn small_rig(dir: &Path) -> PathBuf {
    common::small_rig_file(dir, "lightstage", 64, 48)
}

async fn start(dir: &Path, rig: &Path) -> Result<RunningDaemon, DaemonError> {
    common::start_daemon(&dir.join("data"), Some(rig)).await
}

/// One answer: status, content type and body (not read for event streams).
#[derive(Debug)]
struct Resp {
    status: u16,
    ctype: String,
    body: String,
}

/// A blocking client for one daemon (call it outside the runtime's workers): requests go
/// through the daemon's router, except big bodies and paths with dot segments, which go byte
/// for byte over its socket (an HTTP client would resolve the dot segments, and a body over
/// the limit is refused while it is still being sent, which only a connection shows).
struct Http {
    api: common::api::Api,
}

impl Http {
    fn new(d: &RunningDaemon) -> Http {
        Http {
            api: common::api::Api::operator(d),
        }
    }

    fn send(
        &self,
        method: &str,
        path: &str,
        token: Option<&str>,
        ctype: Option<&str>,
        body: Option<&[u8]>,
    ) -> Result<Resp, String> {
        if body.is_some_and(|b| b.len() > 64 << 10) || common::api::has_dot_segment(path) {
            return self.send_big(method, path, token, ctype, body.unwrap_or(&[]));
        }
        let headers: Vec<(&str, &str)> = ctype.map(|c| ("Content-Type", c)).into_iter().collect();
        let body = body.map_or(Body::Empty, |b| Body::Raw(b.to_vec()));
        let r = self.api.send(method, path, token, &headers, body)?;
        Ok(Resp {
            status: r.status,
            ctype: r.header("content-type").to_string(),
            body: r.text(),
        })
    }
}

impl Http {
    /// Sends a big body over a raw connection and reads the answer even if the server stopped
    /// reading the body and closed the connection (it may refuse it after the limit: the
    /// client then gets a broken pipe, but the answer is already in its receive buffer).
    fn send_big(
        &self,
        method: &str,
        path: &str,
        token: Option<&str>,
        ctype: Option<&str>,
        body: &[u8],
    ) -> Result<Resp, String> {
        use std::io::{Read, Write};
        let what = |e: std::io::Error| format!("{method} {path}: {e}");
        let host = self.api.base.trim_start_matches("http://");
        let mut s = std::net::TcpStream::connect(host).map_err(what)?;
        s.set_read_timeout(Some(Duration::from_secs(20)))
            .map_err(what)?;
        let mut head = format!(
            "{method} {path} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {}\r\nConnection: close\r\n",
            body.len()
        );
        if let Some(t) = token {
            head.push_str(&format!("Authorization: Bearer {t}\r\n"));
        }
        if let Some(c) = ctype {
            head.push_str(&format!("Content-Type: {c}\r\n"));
        }
        head.push_str("\r\n");
        // Write errors are expected when the server refuses the body early.
        let _ = s
            .write_all(head.as_bytes())
            .and_then(|()| s.write_all(body));
        let mut raw = Vec::new();
        let mut buf = [0u8; 16 << 10];
        loop {
            match s.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => raw.extend_from_slice(&buf[..n]),
                // A reset after the answer arrived: keep what was read.
                Err(_) if !raw.is_empty() => break,
                Err(e) => return Err(what(e)),
            }
        }
        let text = String::from_utf8_lossy(&raw);
        let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
        let status = head
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("{method} {path}: no HTTP answer: {head:?}"))?;
        let ctype = head
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once(':')?;
                k.eq_ignore_ascii_case("content-type")
                    .then(|| v.trim().to_string())
            })
            .unwrap_or_default();
        Ok(Resp {
            status,
            ctype,
            body: body.to_string(),
        })
    }
}

/// What a case must answer.
#[derive(Debug, Clone, Copy)]
enum Expect {
    Exactly(u16),
    OneOf(&'static [u16]),
    /// Any 4xx.
    ClientError,
    /// Anything but a 5xx (the input may happen to be valid).
    NotServerError,
}

/// One request of the test matrix.
#[derive(Debug)]
struct Case {
    what: String,
    method: String,
    path: String,
    token: Option<String>,
    ctype: Option<&'static str>,
    body: Option<Vec<u8>>,
    expect: Expect,
    /// The request presses the e-stop on purpose (it is reset after it).
    presses_estop: bool,
}

/// True if the e-stop is latched.
fn estop_latched(http: &Http, token: &str) -> bool {
    http.send("GET", "/api/status", Some(token), None, None)
        .ok()
        .and_then(|r| serde_json::from_str::<Value>(&r.body).ok())
        .and_then(|v| v.get("estop").and_then(Value::as_bool))
        .unwrap_or(false)
}

/// Runs every case; returns the failures (empty when all pass) and the number run. Bad input
/// must not change the rig: a case after which the e-stop is latched is a failure too.
fn run_cases(http: &Http, cases: &[Case], token: &str) -> (Vec<String>, usize) {
    let mut failures = Vec::new();
    for c in cases {
        if estop_latched(http, token) {
            failures.push(format!(
                "[{}] {} {}: the e-stop was latched by the case before",
                c.what, c.method, c.path
            ));
            let _ = http.send("POST", "/api/estop/reset", Some(token), None, None);
        }
        let reset_after = c.presses_estop;
        let r = match http.send(
            &c.method,
            &c.path,
            c.token.as_deref(),
            c.ctype,
            c.body.as_deref(),
        ) {
            Ok(r) => r,
            Err(e) => {
                failures.push(format!("[{}] {e}", c.what));
                continue;
            }
        };
        let mut problems = Vec::new();
        if r.status >= 500 {
            problems.push("server error".to_string());
        }
        let ok = match c.expect {
            Expect::Exactly(s) => r.status == s,
            Expect::OneOf(s) => s.contains(&r.status),
            Expect::ClientError => (400..500).contains(&r.status),
            Expect::NotServerError => r.status < 500,
        };
        if !ok {
            problems.push(format!("expected {:?}", c.expect));
        }
        if (400..500).contains(&r.status) {
            let error = serde_json::from_str::<Value>(&r.body)
                .ok()
                .and_then(|v| v.get("error").and_then(Value::as_str).map(str::to_string));
            if !r.ctype.starts_with("application/json") || error.is_none_or(|e| e.is_empty()) {
                problems.push(format!("4xx without a JSON {{error}} body ({})", r.ctype));
            }
        }
        if !problems.is_empty() {
            let body: String = r.body.chars().take(200).collect();
            failures.push(format!(
                "[{}] {} {} → {} {}: {body}",
                c.what,
                c.method,
                c.path,
                r.status,
                problems.join(", ")
            ));
        }
        if reset_after {
            let _ = http.send("POST", "/api/estop/reset", Some(token), None, None);
        }
    }
    (failures, cases.len())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_route_answers_bad_input_with_a_4xx_and_a_message() -> TestResult {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir()?;
    let rig = small_rig(tmp.path());
    let d = start(tmp.path(), &rig).await?;
    let op_token = d.state.tokens.operator.clone();
    let ro_token = d.state.tokens.read_only.clone();
    let http = Http::new(&d);
    let data = tmp.path().join("data");
    let tokens_before = std::fs::read(data.join("tokens.json"))?;

    let outcome = tokio::task::spawn_blocking(
        move || -> Result<(Vec<String>, usize, Vec<String>), String> {
            let doc = http.send("GET", "/openapi.json", None, None, None)?;
            let doc: Value =
                serde_json::from_str(&doc.body).map_err(|e| format!("/openapi.json: {e}"))?;
            let ops = operations(&doc);
            if ops.len() < 5 {
                return Err(format!("only {} operations in /openapi.json", ops.len()));
            }
            let status = http.send("GET", "/api/status", Some(&op_token), None, None)?;
            let status: Value = serde_json::from_str(&status.body).map_err(|e| e.to_string())?;
            let first = |list: &str| {
                status
                    .pointer(&format!("/devices/{list}/0/id"))
                    .and_then(Value::as_str)
                    .unwrap_or("none")
                    .to_string()
            };
            let ids = Ids {
                axis: first("axes"),
                lamp: first("lamps"),
                camera: first("cameras"),
            };
            let mut cases = cases_for(&doc, &ops, &ids, &op_token, &ro_token);
            cases.extend(specific_cases(&op_token));
            let (failures, n) = run_cases(&http, &cases, &op_token);
            // Bad input started nothing and latched nothing.
            let status = http.send("GET", "/api/status", Some(&op_token), None, None)?;
            let status: Value = serde_json::from_str(&status.body).map_err(|e| e.to_string())?;
            let mut state = Vec::new();
            if !status.get("run").is_none_or(Value::is_null) {
                state.push(format!(
                    "a run is active after bad input: {}",
                    status["run"]
                ));
            }
            if status.get("estop") != Some(&Value::Bool(false)) {
                state.push("the e-stop is latched after bad input".into());
            }
            let mut routes: Vec<String> = ops
                .iter()
                .map(|o| format!("{} {}", o.method, o.path))
                .collect();
            routes.dedup();
            eprintln!("{n} requests over {} operations", routes.len());
            Ok((failures, n, state))
        },
    )
    .await??;
    let (failures, n, state) = outcome;

    // Nothing escaped the data directory through a traversal.
    let escaped: Vec<PathBuf> = ["escape.rhai", "passwd.rhai", "tokens.json.rhai"]
        .iter()
        .flat_map(|f| [tmp.path().join(f), data.join(f), data.join("runs").join(f)])
        .filter(|p| p.exists())
        .collect();
    let tokens_after = std::fs::read(data.join("tokens.json"))?;
    d.shutdown().await;
    assert_eq!(tokens_before, tokens_after, "tokens.json changed");
    assert!(
        escaped.is_empty(),
        "files written outside the library: {escaped:?}"
    );
    assert!(state.is_empty(), "{state:?}");
    assert!(
        failures.is_empty(),
        "{} of {n} requests answered wrongly:\n{}",
        failures.len(),
        failures.join("\n")
    );
    Ok(())
}
