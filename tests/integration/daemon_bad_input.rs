//! Bad input against the daemon's HTTP API, driven by its own OpenAPI document so every route
//! is covered, whoever added it: requests without a token or with a wrong one (401), the
//! read-only token on a mutating route (403), unknown ids, path traversal in ids, malformed
//! JSON, wrong types, missing fields, oversized bodies and bad query strings. Every answer
//! must be a 4xx with a JSON `{error}` body (or a success where the input happens to be
//! valid), never a 5xx. Plus device ownership: a second opener of the daemon's real ports is
//! told where the daemon is.

use crate::common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::{Value, json};
use stagehand::client::Body;
use stagehand::daemon::{DaemonError, RunningDaemon};

type TestResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

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

/// One operation of the OpenAPI document.
#[derive(Debug, Clone)]
struct Op {
    method: String,
    path: String,
    path_params: Vec<String>,
    /// Query parameters with their (resolved) schemas.
    query: Vec<(String, Value)>,
    /// The JSON request body's (resolved) schema, if the operation takes JSON.
    json_body: Option<Value>,
    /// The operation takes a text body.
    text_body: bool,
    /// The operation needs no token (`security: [{}]`, e.g. `GET /api/health`).
    public: bool,
}

/// Resolves a `$ref` (one level at a time, recursively) in the document.
fn resolve(doc: &Value, schema: &Value) -> Value {
    if let Some(r) = schema.get("$ref").and_then(Value::as_str) {
        let target = r
            .trim_start_matches("#/")
            .split('/')
            .try_fold(doc, |v, k| v.get(k));
        return target.map(|t| resolve(doc, t)).unwrap_or(Value::Null);
    }
    schema.clone()
}

fn operations(doc: &Value) -> Vec<Op> {
    let mut ops = Vec::new();
    let Some(paths) = doc.get("paths").and_then(Value::as_object) else {
        return ops;
    };
    for (path, item) in paths {
        let Some(item) = item.as_object() else {
            continue;
        };
        for (method, op) in item {
            if !matches!(method.as_str(), "get" | "post" | "put" | "patch" | "delete") {
                continue;
            }
            let params = op
                .get("parameters")
                .and_then(Value::as_array)
                .cloned()
                .unwrap_or_default();
            let of = |place: &str| -> Vec<(String, Value)> {
                params
                    .iter()
                    .filter(|p| p.get("in").and_then(Value::as_str) == Some(place))
                    .filter_map(|p| {
                        let name = p.get("name")?.as_str()?.to_string();
                        let schema = resolve(doc, p.get("schema").unwrap_or(&Value::Null));
                        Some((name, schema))
                    })
                    .collect()
            };
            let content = op.pointer("/requestBody/content");
            let json_body = content
                .and_then(|c| c.get("application/json"))
                .map(|c| resolve(doc, c.get("schema").unwrap_or(&Value::Null)));
            let text_body = content.is_some_and(|c| c.get("text/plain").is_some());
            ops.push(Op {
                method: method.to_uppercase(),
                path: path.clone(),
                path_params: of("path").into_iter().map(|(n, _)| n).collect(),
                query: of("query"),
                json_body,
                text_body,
                public: op.get("security") == Some(&serde_json::json!([{}])),
            });
        }
    }
    ops
}

/// Ids of real things on the daemon, by the path segment before the parameter.
struct Ids {
    axis: String,
    lamp: String,
    camera: String,
}

impl Ids {
    /// A valid id for the parameter after `segment` where one exists, else an unknown one.
    fn valid(&self, segment: &str) -> String {
        match segment {
            "axes" => self.axis.clone(),
            "lamps" => self.lamp.clone(),
            "cameras" => self.camera.clone(),
            "scripts" => "quickstart".into(),
            // Queue items are numbers; none is queued.
            "queue" => "42".into(),
            _ => "no-such-id-42".into(),
        }
    }
}

/// Fills the path's `{param}`s: `pick(param, segment before it)`.
fn fill(path: &str, mut pick: impl FnMut(&str, &str) -> String) -> String {
    let segs: Vec<&str> = path.split('/').collect();
    segs.iter()
        .enumerate()
        .map(
            |(i, s)| match s.strip_prefix('{').and_then(|s| s.strip_suffix('}')) {
                Some(param) => pick(param, if i > 0 { segs[i - 1] } else { "" }),
                None => s.to_string(),
            },
        )
        .collect::<Vec<_>>()
        .join("/")
}

/// The JSON types a schema allows (`None`: anything).
fn types_of(schema: &Value) -> Option<Vec<String>> {
    match schema.get("type") {
        Some(Value::String(t)) => Some(vec![t.clone()]),
        Some(Value::Array(ts)) => Some(
            ts.iter()
                .filter_map(|t| t.as_str().map(str::to_string))
                .collect(),
        ),
        _ => {
            let alts = schema
                .get("oneOf")
                .or_else(|| schema.get("anyOf"))?
                .as_array()?;
            let mut all = Vec::new();
            for a in alts {
                all.extend(types_of(a)?);
            }
            Some(all)
        }
    }
}

/// A value of a type `schema` does not allow (an unknown string for enums), if there is one.
fn wrong_value(doc: &Value, schema: &Value) -> Option<Value> {
    let schema = resolve(doc, schema);
    if schema.get("enum").is_some() {
        return Some(json!("definitely-not-one-of-the-values"));
    }
    let allowed = types_of(&schema)?;
    let has = |t: &str| {
        allowed
            .iter()
            .any(|a| a == t || (t == "integer" && a == "number"))
    };
    [
        ("object", json!({"nested": [1, 2]})),
        ("array", json!([[1], {"a": 2}])),
        ("string", json!("not-a-number")),
        ("integer", json!(12345)),
        ("boolean", json!(true)),
    ]
    .into_iter()
    .find(|(t, _)| !has(t))
    .map(|(_, v)| v)
}

/// Path-traversal attempts for an id (raw and percent-encoded).
const TRAVERSALS: &[&str] = &[
    "..",
    "%2e%2e",
    "...",
    ".hidden",
    "..%2F..%2F..%2Fetc%2Fpasswd",
    "%2E%2E%2F%2E%2E%2Fdata%2Ftokens.json",
    "..%5C..%5Ctokens.json",
    "%2Fetc%2Fpasswd",
    "a%00b",
];

/// Parameters that name files (runs, scripts, frames, cameras' frames): traversal targets.
fn names_a_file(segment: &str, param: &str) -> bool {
    matches!(segment, "runs" | "scripts" | "frames" | "cameras") || param.contains("frame")
}

/// A body with every required field set to a plausible value, so that the ids in the path
/// are what the daemon checks.
fn plausible_body(doc: &Value, schema: &Value) -> Value {
    let schema = resolve(doc, schema);
    let mut body = serde_json::Map::new();
    let required = schema
        .get("required")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    for name in required.iter().filter_map(Value::as_str) {
        let prop = resolve(
            doc,
            schema
                .pointer(&format!("/properties/{name}"))
                .unwrap_or(&Value::Null),
        );
        let value = if let Some(first) = prop.get("enum").and_then(|e| e.get(0)) {
            first.clone()
        } else {
            match types_of(&prop)
                .unwrap_or_default()
                .first()
                .map(String::as_str)
            {
                Some("number" | "integer") => json!(0),
                Some("boolean") => json!(false),
                Some("array") => json!([]),
                Some("object") => json!({}),
                _ => json!("x"),
            }
        };
        body.insert(name.to_string(), value);
    }
    Value::Object(body)
}

fn cases_for(doc: &Value, ops: &[Op], ids: &Ids, op_token: &str, ro_token: &str) -> Vec<Case> {
    let mut cases = Vec::new();
    let case = |what: &str,
                op: &Op,
                path: String,
                token: Option<&str>,
                ctype: Option<&'static str>,
                body: Option<Vec<u8>>,
                expect: Expect| Case {
        what: what.to_string(),
        method: op.method.clone(),
        path,
        token: token.map(str::to_string),
        ctype,
        body,
        expect,
        presses_estop: false,
    };
    for op in ops {
        let valid_path = fill(&op.path, |_, seg| ids.valid(seg));
        let reads = op.method == "GET";
        // Auth: no token, a wrong token, the read-only token on a mutating route.
        let auth_expect = if op.public {
            Expect::Exactly(200)
        } else {
            Expect::Exactly(401)
        };
        cases.push(case(
            "no token",
            op,
            valid_path.clone(),
            None,
            None,
            None,
            auth_expect,
        ));
        cases.push(case(
            "wrong token",
            op,
            valid_path.clone(),
            Some(&"0".repeat(64)),
            None,
            None,
            auth_expect,
        ));
        cases.push(case(
            "truncated operator token",
            op,
            valid_path.clone(),
            Some(&op_token[..op_token.len() - 1]),
            None,
            None,
            auth_expect,
        ));
        if op.method == "POST" && op.path == stagehand::daemon::auth::ESTOP_PATH {
            // Anyone who may watch the rig may stop it.
            let mut c = case(
                "read-only token presses the e-stop",
                op,
                valid_path.clone(),
                Some(ro_token),
                None,
                None,
                Expect::Exactly(200),
            );
            c.presses_estop = true;
            cases.push(c);
        } else if !reads {
            cases.push(case(
                "read-only token on a mutating route",
                op,
                valid_path.clone(),
                Some(ro_token),
                None,
                None,
                Expect::Exactly(403),
            ));
        }
        // A plausible body for routes that need one, so the id is what is wrong.
        let (ctype, body): (Option<&'static str>, Option<Vec<u8>>) =
            if let Some(schema) = &op.json_body {
                (
                    Some("application/json"),
                    Some(plausible_body(doc, schema).to_string().into_bytes()),
                )
            } else if op.text_body {
                (Some("text/plain"), Some(b"// nothing\n".to_vec()))
            } else {
                (None, None)
            };
        // Unknown ids (`PUT` creates what it names).
        if !op.path_params.is_empty() && op.method != "PUT" {
            let unknown = fill(&op.path, |_, _| "no-such-id-42".into());
            cases.push(case(
                "unknown ids",
                op,
                unknown,
                Some(op_token),
                ctype,
                body.clone(),
                Expect::ClientError,
            ));
        }
        // Path traversal through each id.
        let segs: Vec<&str> = op.path.split('/').collect();
        for param in &op.path_params {
            let at = segs.iter().position(|s| *s == format!("{{{param}}}"));
            let segment = at.and_then(|i| i.checked_sub(1)).map_or("", |i| segs[i]);
            if !names_a_file(segment, param) {
                continue;
            }
            for t in TRAVERSALS {
                let path = fill(&op.path, |p, seg| {
                    if p == param {
                        (*t).to_string()
                    } else {
                        ids.valid(seg)
                    }
                });
                cases.push(case(
                    &format!("traversal in {param}"),
                    op,
                    path,
                    Some(op_token),
                    ctype,
                    body.clone(),
                    Expect::OneOf(&[400, 404]),
                ));
            }
        }
        // Bad query strings.
        for (name, schema) in &op.query {
            if name == "access_token" {
                continue;
            }
            let Some(bad) = wrong_value(doc, schema) else {
                continue;
            };
            let text = match bad {
                Value::String(s) => s,
                other => other.to_string(),
            };
            let mut enc = String::new();
            for b in text.bytes() {
                if b.is_ascii_alphanumeric() || b == b'-' {
                    enc.push(b as char);
                } else {
                    enc.push_str(&format!("%{b:02X}"));
                }
            }
            cases.push(case(
                &format!("wrong type in query `{name}`"),
                op,
                format!("{valid_path}?{name}={enc}"),
                Some(op_token),
                None,
                None,
                Expect::ClientError,
            ));
        }
        // Request bodies.
        if let Some(schema) = &op.json_body {
            let json_case = |what: &str, ctype: Option<&'static str>, body: Vec<u8>, expect| {
                case(
                    what,
                    op,
                    valid_path.clone(),
                    Some(op_token),
                    ctype,
                    Some(body),
                    expect,
                )
            };
            let j = Some("application/json");
            cases.push(json_case(
                "malformed JSON",
                j,
                b"{\"a\": ".to_vec(),
                Expect::ClientError,
            ));
            cases.push(json_case(
                "not UTF-8",
                j,
                vec![0xff, 0xfe, b'{', 0x80],
                Expect::ClientError,
            ));
            cases.push(json_case(
                "JSON array",
                j,
                b"[1, 2]".to_vec(),
                Expect::ClientError,
            ));
            cases.push(json_case(
                "JSON string",
                j,
                b"\"x\"".to_vec(),
                Expect::ClientError,
            ));
            cases.push(json_case(
                "deeply nested JSON",
                j,
                format!("{}{}", "[".repeat(5000), "]".repeat(5000)).into_bytes(),
                Expect::ClientError,
            ));
            cases.push(json_case(
                "no content type",
                None,
                b"{}".to_vec(),
                Expect::NotServerError,
            ));
            cases.push(json_case(
                "wrong content type",
                Some("text/plain"),
                b"{}".to_vec(),
                Expect::NotServerError,
            ));
            let schema = resolve(doc, schema);
            let required = schema
                .get("required")
                .and_then(Value::as_array)
                .is_some_and(|r| !r.is_empty());
            cases.push(json_case(
                "missing fields",
                j,
                b"{}".to_vec(),
                if required {
                    Expect::ClientError
                } else {
                    Expect::NotServerError
                },
            ));
            let props = schema
                .get("properties")
                .and_then(Value::as_object)
                .cloned()
                .unwrap_or_default();
            let wrong: serde_json::Map<String, Value> = props
                .iter()
                .filter_map(|(k, s)| Some((k.clone(), wrong_value(doc, s)?)))
                .collect();
            if !wrong.is_empty() {
                cases.push(json_case(
                    "wrong types",
                    j,
                    Value::Object(wrong).to_string().into_bytes(),
                    Expect::ClientError,
                ));
            }
            if schema.get("additionalProperties") == Some(&Value::Bool(false)) {
                cases.push(json_case(
                    "unknown field",
                    j,
                    b"{\"no_such_field\": 1}".to_vec(),
                    Expect::ClientError,
                ));
            }
            let big = format!("{{\"pad\": \"{}\"}}", "a".repeat((1 << 20) + 4096));
            cases.push(json_case(
                "oversized body",
                j,
                big.into_bytes(),
                Expect::OneOf(&[413]),
            ));
        }
        if op.text_body {
            cases.push(case(
                "oversized text body",
                op,
                fill(&op.path, |_, _| "bad-input-big".into()),
                Some(op_token),
                Some("text/plain"),
                Some(vec![b'/'; (1 << 20) + 4096]),
                Expect::OneOf(&[413]),
            ));
            cases.push(case(
                "text body not UTF-8",
                op,
                fill(&op.path, |_, _| "bad-input-test".into()),
                Some(op_token),
                Some("text/plain"),
                Some(vec![0xff, 0xfe, 0x80]),
                Expect::ClientError,
            ));
        }
    }
    cases
}

/// Hand-written cases the document cannot derive: scripts with errors, unknown scripts,
/// traversal through script names in bodies, unknown routes.
fn specific_cases(op_token: &str) -> Vec<Case> {
    let post = |what: &str, path: &str, body: Value, expect: Expect| Case {
        what: what.into(),
        method: "POST".into(),
        path: path.into(),
        token: Some(op_token.into()),
        ctype: Some("application/json"),
        body: Some(body.to_string().into_bytes()),
        expect,
        presses_estop: false,
    };
    vec![
        Case {
            what: "unknown route".into(),
            method: "GET".into(),
            path: "/api/no/such/route".into(),
            token: Some(op_token.into()),
            ctype: None,
            body: None,
            expect: Expect::Exactly(404),
            presses_estop: false,
        },
        Case {
            what: "unknown method".into(),
            method: "DELETE".into(),
            path: "/api/status".into(),
            token: Some(op_token.into()),
            ctype: None,
            body: None,
            expect: Expect::ClientError,
            presses_estop: false,
        },
        post(
            "run of an unknown script",
            "/api/runs",
            json!({"script": "no-such-script"}),
            Expect::Exactly(404),
        ),
        post(
            "run of a script outside the library",
            "/api/runs",
            json!({"script": "../../../etc/passwd"}),
            Expect::OneOf(&[400, 404]),
        ),
        post(
            "run with an unknown parameter",
            "/api/runs",
            json!({"script": "quickstart", "set": {"no_such_parameter": "1"}}),
            Expect::ClientError,
        ),
        post(
            "run with a parameter of the wrong type",
            "/api/runs",
            json!({"script": "quickstart", "set": {"turntable_deg": {"a": 1}}}),
            Expect::ClientError,
        ),
        post(
            "run with a negative seed",
            "/api/runs",
            json!({"script": "quickstart", "seed": -1}),
            Expect::ClientError,
        ),
        post(
            "validate a script with a syntax error",
            "/api/validate",
            json!({"text": "let x = ;"}),
            Expect::NotServerError,
        ),
        post(
            "validate a script that throws",
            "/api/validate",
            json!({"text": "throw \"boom\";"}),
            Expect::NotServerError,
        ),
        post(
            "validate a name outside the library",
            "/api/validate",
            json!({"name": "../escape", "text": "move_to(\"turntable\", 0.0);"}),
            Expect::NotServerError,
        ),
        post(
            "prompt answer that is not an answer",
            "/api/runs/no-such-run/prompt",
            json!({"answer": "maybe"}),
            Expect::ClientError,
        ),
    ]
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

/// The rig with its lamp board behind a (fake) real serial port: opening it takes the port's
/// lock, without touching the port until a lamp switches.
fn rig_with_a_real_port(
    dir: &Path,
) -> Result<(PathBuf, String), Box<dyn std::error::Error + Send + Sync>> {
    let port = dir.join("ttyFAKE-lamps").display().to_string();
    let text = std::fs::read_to_string(small_rig(dir))?;
    let from = "[[switch_bank]]\nid = \"lamps\"\nbackend = \"sim\"\n";
    if !text.contains(from) {
        return Err("the built-in light stage's lamp bank is not where this test expects".into());
    }
    let text = text.replacen(
        from,
        &format!(
            "[[switch_bank]]\nid = \"lamps\"\nbackend = \"relay-serial\"\nport = \"{port}\"\n"
        ),
        1,
    );
    let path = dir.join("real-port-rig.toml");
    std::fs::write(&path, text)?;
    Ok((path, port))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_opener_of_the_daemons_ports_is_told_to_use_remote() -> TestResult {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir()?;
    let (rig, port) = rig_with_a_real_port(tmp.path())?;
    let d = start(tmp.path(), &rig).await?;
    let url = format!("http://{}", d.addr);
    // The daemon records its URL once it listens (idempotent if `start` did already).
    stagehand::rig::port_lock::record_listen_addr(d.addr);

    // The CLI's `run` on the same rig is refused, naming the port and the daemon.
    let out_dir = tmp.path().join("runs");
    let script = common::root().join("sequences/quickstart.rhai");
    let (rig2, out2) = (rig.clone(), out_dir.clone());
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new(BIN)
            .arg("run")
            .arg("--rig")
            .arg(&rig2)
            .arg("--out")
            .arg(&out2)
            .arg("-y")
            .arg(&script)
            .output()
    })
    .await??;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(&port), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "the daemon at {url} owns this rig; use `stagehand run --remote {url} script.rhai`"
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("pid {}", std::process::id())),
        "{stderr}"
    );
    let made = std::fs::read_dir(&out_dir).map(|d| d.count()).unwrap_or(0);
    assert_eq!(
        made,
        0,
        "a refused run left a run directory in {}",
        out_dir.display()
    );

    // A second daemon on the same rig is refused too.
    let second = tmp.path().join("second");
    std::fs::create_dir_all(&second)?;
    match start(&second, &rig).await {
        Ok(other) => {
            other.shutdown().await;
            d.shutdown().await;
            return Err("a second daemon opened the first one's ports".into());
        }
        Err(e) => {
            let text = e.to_string();
            assert!(
                text.contains(&port) && text.contains("owns this rig"),
                "{text}"
            );
        }
    }
    d.shutdown().await;
    // The fake port's lock file is this test's own: leave the shared lock directory clean.
    let lock = stagehand::rig::port_lock::lock_file_for(
        &stagehand::rig::port_lock::lock_dir(),
        &stagehand::rig::port_lock::canonical_port(&port),
    );
    let _ = std::fs::remove_file(lock);
    Ok(())
}

/// Runs `stagehand ARGS` (blocking, in a worker thread) with `STAGEHAND_TOKEN` removed.
async fn cli(
    args: Vec<String>,
) -> Result<std::process::Output, Box<dyn std::error::Error + Send + Sync>> {
    Ok(tokio::task::spawn_blocking(move || {
        std::process::Command::new(BIN)
            .args(&args)
            .env_remove("STAGEHAND_TOKEN")
            .stdin(std::process::Stdio::null())
            .output()
    })
    .await??)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_remote_refuses_bad_input_and_runs_a_script_on_the_daemon() -> TestResult {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir()?;
    let rig = small_rig(tmp.path());
    let d = start(tmp.path(), &rig).await?;
    let url = format!("http://{}", d.addr);
    let token = d.state.tokens.operator.clone();
    let write = |name: &str, text: &str| -> std::io::Result<String> {
        let p = tmp.path().join(name);
        std::fs::write(&p, text)?;
        Ok(p.display().to_string())
    };
    let tiny = write(
        "tiny.rhai",
        "prompt(\"Check the sample\");\nonly_lamp(lamps()[0]);\nmove_to(\"turntable\", 3.0);\ncapture(0.01);\nlamps_off();\n",
    )?;
    let broken = write("broken.rhai", "let x = ;\n")?;
    let outside = write("outside.rhai", "move_to(\"turntable\", 99999.0);\n")?;
    let s = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let text = |o: &std::process::Output| {
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )
    };

    // No token, a wrong token, nothing listening, a script with errors, a plan with errors,
    // an unknown parameter: exit 2 with the daemon's message, nothing started.
    let cases: Vec<(Vec<String>, &str)> = vec![
        (s(&["run", "--remote", &url, &tiny]), "STAGEHAND_TOKEN"),
        (
            s(&["run", "--remote", &url, "--token", &"0".repeat(64), &tiny]),
            "401",
        ),
        (
            s(&[
                "run",
                "--remote",
                "http://127.0.0.1:9",
                "--token",
                &token,
                &tiny,
            ]),
            "cannot reach the daemon at http://127.0.0.1:9",
        ),
        (
            s(&["run", "--remote", &url, "--token", &token, &broken]),
            "1:9",
        ),
        (
            s(&["run", "--remote", &url, "--token", &token, &outside]),
            "soft limits",
        ),
        (
            s(&[
                "run", "--remote", &url, "--token", &token, "--set", "nope=1", &tiny,
            ]),
            "nope",
        ),
        (
            s(&[
                "run", "--remote", &url, "--token", &token, "--rig", "x.toml", &tiny,
            ]),
            "cannot be used with",
        ),
    ];
    for (args, needle) in cases {
        let o = cli(args.clone()).await?;
        let t = text(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {t}");
        assert!(t.contains(needle), "{args:?}: expected `{needle}` in {t}");
        assert!(!t.contains("panicked"), "{t}");
    }
    assert!(d.state.runs.snapshot().is_none(), "bad input started a run");

    // The real thing: uploaded, run on the daemon, prompt confirmed by -y, exit 0.
    let o = cli(s(&[
        "run", "--remote", &url, "--token", &token, "-y", &tiny,
    ]))
    .await?;
    let t = text(&o);
    assert_eq!(o.status.code(), Some(0), "{t}");
    assert!(t.contains("run done:"), "{t}");
    assert!(t.contains("Check the sample"), "{t}");
    assert!(t.contains("steps 5/5"), "{t}");
    d.shutdown().await;
    Ok(())
}
