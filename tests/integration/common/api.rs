//! A blocking JSON client for a daemon under test (call it inside `spawn_blocking` or a thread
//! of its own: each call waits on the test's runtime).
//!
//! Requests go through the daemon's axum router (`tower::ServiceExt::oneshot`), without a
//! socket: no handler reads the peer's address, so the router answers as the server would.
//! What needs the daemon's listener goes over its socket with `stagehand::client`, the typed
//! client: event streams ([`Api::sse`]) and targets that must reach the server byte for byte
//! ([`Api::get_exact`], and paths with dot segments, which an HTTP client would resolve).

use reqwest::Method;
use serde_json::Value;
use stagehand::client::{Body, Client, EventStream, RawReply};
use stagehand::daemon::RunningDaemon;
use tokio::runtime::Handle;
use tower::ServiceExt;

/// Status, headers and JSON body (or the text as a JSON string) of an answer.
pub struct Reply {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Value,
}

impl Reply {
    /// The value of header `name` (lower case), `""` when absent.
    pub fn header(&self, name: &str) -> &str {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
            .unwrap_or("")
    }
}

impl From<RawReply> for Reply {
    fn from(r: RawReply) -> Self {
        let body = serde_json::from_slice(&r.body).unwrap_or_else(|_| Value::String(r.text()));
        Reply {
            status: r.status,
            headers: r.headers,
            body,
        }
    }
}

/// One daemon and one token: requests through its router, streams over its socket.
#[derive(Clone)]
pub struct Api {
    /// `http://` and the daemon's socket address.
    pub base: String,
    pub token: String,
    /// The socket client (event streams), with [`Api::token`].
    client: Client,
    runtime: Handle,
    /// The daemon's router: every other request goes through it.
    router: axum::Router,
}

impl Api {
    /// A client of `d` with `token` (made inside the test's runtime).
    pub fn new(d: &RunningDaemon, token: &str) -> Self {
        let client = Client::new(&d.addr.to_string(), Some(token)).expect("a client");
        Self {
            base: client.base().to_string(),
            token: token.to_string(),
            client,
            runtime: Handle::current(),
            router: stagehand::daemon::router(d.state.clone()),
        }
    }

    /// A client with the operator token.
    pub fn operator(d: &RunningDaemon) -> Self {
        Self::new(d, &d.state.tokens.operator)
    }

    /// A client with the read-only token.
    pub fn read_only(d: &RunningDaemon) -> Self {
        Self::new(d, &d.state.tokens.read_only)
    }

    /// The same daemon with another token.
    pub fn with_token(&self, token: &str) -> Self {
        Self {
            token: token.to_string(),
            client: self.client.with_token(Some(token)),
            ..self.clone()
        }
    }

    /// `method path` through the router with `token` (none: no `Authorization` header), extra
    /// headers and a body, answered as it came (body bytes). An error only when no request
    /// can be made of the method or path.
    pub fn send(
        &self,
        method: &str,
        path: &str,
        token: Option<&str>,
        headers: &[(&str, &str)],
        body: Body,
    ) -> Result<RawReply, String> {
        let method = Method::from_bytes(method.as_bytes())
            .map_err(|e| format!("{method} {path}: not an HTTP method: {e}"))?;
        self.runtime.block_on(oneshot(
            self.router.clone(),
            method,
            path,
            token,
            headers,
            body,
        ))
    }

    /// `method path` with the token, extra headers and a body, answered as it came (body
    /// bytes).
    pub fn raw(&self, method: &str, path: &str, headers: &[(&str, &str)], body: Body) -> RawReply {
        self.send(method, path, Some(&self.token), headers, body)
            .expect("a request")
    }

    /// `method path` with the token (none when `anonymous`).
    fn call(&self, anonymous: bool, method: Method, path: &str, body: Body) -> Reply {
        let token = (!anonymous).then_some(self.token.as_str());
        self.send(method.as_str(), path, token, &[], body)
            .expect("a request")
            .into()
    }

    /// `GET path` with the token. A path with a dot segment (`/..`, `/%2e%2e`) goes byte for
    /// byte over the daemon's socket ([`Api::get_exact`]), as a client that does not resolve
    /// them would send it.
    pub fn get_reply(&self, path: &str) -> Reply {
        if has_dot_segment(path) {
            return self.exact_get(path);
        }
        self.call(false, Method::GET, path, Body::Empty)
    }

    /// `GET target` as written (no client-side resolution of `..` or `%2F`), over the daemon's
    /// socket on a connection that closes after the answer: the status and the whole answer as
    /// text.
    pub fn get_exact(&self, target: &str) -> (u16, String) {
        use std::io::{Read, Write};
        let host = self.base.trim_start_matches("http://");
        let mut s = std::net::TcpStream::connect(host).expect("connect");
        s.set_read_timeout(Some(std::time::Duration::from_secs(30)))
            .expect("timeout");
        write!(
            s,
            "GET {target} HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {}\r\nConnection: close\r\n\r\n",
            self.token
        )
        .expect("send");
        let mut raw = Vec::new();
        s.read_to_end(&mut raw).expect("read");
        let text = String::from_utf8_lossy(&raw).into_owned();
        let status = text
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .unwrap_or(0);
        (status, text)
    }

    /// [`Api::get_exact`] as a [`Reply`] (a body with a length, not chunked).
    fn exact_get(&self, target: &str) -> Reply {
        let (status, text) = self.get_exact(target);
        let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
        let headers = head
            .lines()
            .skip(1)
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        Reply {
            status,
            headers,
            body: serde_json::from_str(body).unwrap_or_else(|_| Value::String(body.to_string())),
        }
    }

    /// `GET path` without any token.
    pub fn get_anonymous(&self, path: &str) -> Reply {
        self.call(true, Method::GET, path, Body::Empty)
    }

    /// `GET path`: status and body.
    pub fn get(&self, path: &str) -> (u16, Value) {
        let r = self.get_reply(path);
        (r.status, r.body)
    }

    /// `POST path` with a raw JSON text body: status and body.
    pub fn post_text(&self, path: &str, body: &str) -> (u16, Value) {
        let body = Body::Text {
            content_type: "application/json".into(),
            text: body.to_string(),
        };
        let r = self.call(false, Method::POST, path, body);
        (r.status, r.body)
    }

    /// `POST path` with a JSON body (or none): status and body.
    pub fn post(&self, path: &str, body: Option<Value>) -> (u16, Value) {
        let body = body.map_or(Body::Empty, Body::Json);
        let r = self.call(false, Method::POST, path, body);
        (r.status, r.body)
    }

    /// `DELETE path`: status and body.
    pub fn delete(&self, path: &str) -> (u16, Value) {
        let r = self.call(false, Method::DELETE, path, Body::Empty);
        (r.status, r.body)
    }

    /// `POST path` that must answer `status`; its body.
    pub fn expect(&self, status: u16, path: &str, body: Option<Value>) -> Value {
        let (s, v) = self.post(path, body);
        assert_eq!(s, status, "POST {path}: {v}");
        v
    }

    /// `PUT path` with a text body: status and body.
    pub fn put_text(&self, path: &str, body: &str) -> (u16, Value) {
        self.put_bytes(path, body.as_bytes())
    }

    /// `PUT path` with a `text/plain` body that need not be UTF-8: status and body.
    pub fn put_bytes(&self, path: &str, body: &[u8]) -> (u16, Value) {
        let body = Body::Bytes {
            content_type: "text/plain".into(),
            bytes: body.to_vec(),
        };
        let r = self.call(false, Method::PUT, path, body);
        (r.status, r.body)
    }

    /// Opens `GET /api/events` over the daemon's socket, with `Last-Event-ID` when given.
    pub fn sse(&self, last_event_id: Option<u64>) -> Sse {
        let events = self
            .runtime
            .block_on(self.client.events(last_event_id))
            .expect("the daemon streams events");
        Sse {
            events,
            runtime: self.runtime.clone(),
        }
    }
}

/// One request through `router` without a socket, as the socket would carry it (bearer
/// token, extra headers, content type, body), answered with its status, headers and body.
async fn oneshot(
    router: axum::Router,
    method: Method,
    path: &str,
    token: Option<&str>,
    headers: &[(&str, &str)],
    body: Body,
) -> Result<RawReply, String> {
    let mut req = axum::http::Request::builder()
        .method(method.as_str())
        .uri(path);
    if let Some(token) = token {
        req = req.header("authorization", format!("Bearer {token}"));
    }
    for (name, value) in headers {
        req = req.header(*name, *value);
    }
    let (content_type, bytes) = match body {
        Body::Empty => (None, Vec::new()),
        Body::Raw(bytes) => (None, bytes),
        Body::Json(v) => (
            Some("application/json".to_string()),
            v.to_string().into_bytes(),
        ),
        Body::Text { content_type, text } => (Some(content_type), text.into_bytes()),
        Body::Bytes {
            content_type,
            bytes,
        } => (Some(content_type), bytes),
    };
    if let Some(ct) = content_type {
        req = req.header("content-type", ct);
    }
    let req = req
        .body(axum::body::Body::from(bytes))
        .map_err(|e| format!("{method} {path}: cannot build the request: {e}"))?;
    let resp = router.oneshot(req).await.expect("the router answers");
    let status = resp.status().as_u16();
    let headers = resp
        .headers()
        .iter()
        .map(|(k, v)| (k.as_str().to_string(), v.to_str().unwrap_or("").to_string()))
        .collect();
    let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .expect("the body")
        .to_vec();
    Ok(RawReply {
        status,
        headers,
        body,
    })
}

/// True when `path` has a `.` or `..` segment, plain or percent-encoded (an HTTP client
/// resolves those before sending).
pub fn has_dot_segment(path: &str) -> bool {
    path.split(['/', '?'])
        .map(|seg| seg.to_ascii_lowercase().replace("%2e", "."))
        .any(|seg| seg == "." || seg == "..")
}

/// One Server-Sent Event.
#[derive(Debug, Clone)]
pub struct SseEvent {
    /// The `event:` name.
    pub kind: String,
    /// The `id:`, when the event has one.
    pub id: Option<u64>,
    /// The `data:` as JSON.
    pub data: Value,
}

/// A live `GET /api/events` stream.
pub struct Sse {
    events: EventStream,
    runtime: Handle,
}

impl Sse {
    /// The next event; `None` when the stream ended.
    pub fn next_event(&mut self) -> Option<SseEvent> {
        let ev = self.runtime.block_on(self.events.next_raw())?.ok()?;
        let data = serde_json::from_str(&ev.data).unwrap_or(Value::String(ev.data));
        Some(SseEvent {
            kind: ev.name,
            id: ev.id,
            data,
        })
    }
}
