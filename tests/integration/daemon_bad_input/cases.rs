//! The requests of the bad-input matrix: every operation of the OpenAPI document with its
//! path, query and body parameters resolved, turned into cases (no or wrong token, the
//! read-only token, unknown ids, traversal through ids that name files, wrong types in query
//! strings and bodies, malformed and oversized bodies), plus hand-written cases the document
//! cannot derive.

use serde_json::{Value, json};

use super::{Case, Expect};

/// One operation of the OpenAPI document.
#[derive(Debug, Clone)]
pub(super) struct Op {
    pub(super) method: String,
    pub(super) path: String,
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

pub(super) fn operations(doc: &Value) -> Vec<Op> {
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
pub(super) struct Ids {
    pub(super) axis: String,
    pub(super) lamp: String,
    pub(super) camera: String,
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

pub(super) fn cases_for(
    doc: &Value,
    ops: &[Op],
    ids: &Ids,
    op_token: &str,
    ro_token: &str,
) -> Vec<Case> {
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
pub(super) fn specific_cases(op_token: &str) -> Vec<Case> {
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
