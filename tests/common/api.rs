//! A blocking JSON client for a daemon under test, over `stagehand::client` (call it inside
//! `spawn_blocking` or a thread of its own: each call waits on the test's runtime).

use reqwest::Method;
use serde_json::Value;
use stagehand::client::{Body, Client, EventStream, RawReply};
use stagehand::daemon::RunningDaemon;
use tokio::runtime::Handle;

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
        let body = serde_json::from_str(&r.body).unwrap_or(Value::String(r.body));
        Reply {
            status: r.status,
            headers: r.headers,
            body,
        }
    }
}

/// One daemon and one token.
#[derive(Clone)]
pub struct Api {
    pub base: String,
    pub token: String,
    client: Client,
    runtime: Handle,
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
        }
    }

    /// A client with the operator token.
    pub fn operator(d: &RunningDaemon) -> Self {
        Self::new(d, &d.state.tokens.operator)
    }

    fn call(&self, client: &Client, method: Method, path: &str, body: Body) -> Reply {
        self.runtime
            .block_on(client.raw(method, path, body))
            .expect("the daemon answers")
            .into()
    }

    /// `GET path` with the token.
    pub fn get_reply(&self, path: &str) -> Reply {
        self.call(&self.client, Method::GET, path, Body::Empty)
    }

    /// `GET path` without any token.
    pub fn get_anonymous(&self, path: &str) -> Reply {
        let anonymous = self.client.with_token(None);
        self.call(&anonymous, Method::GET, path, Body::Empty)
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
        let r = self.call(&self.client, Method::POST, path, body);
        (r.status, r.body)
    }

    /// `POST path` with a JSON body (or none): status and body.
    pub fn post(&self, path: &str, body: Option<Value>) -> (u16, Value) {
        let body = body.map_or(Body::Empty, Body::Json);
        let r = self.call(&self.client, Method::POST, path, body);
        (r.status, r.body)
    }

    /// `DELETE path`: status and body.
    pub fn delete(&self, path: &str) -> (u16, Value) {
        let r = self.call(&self.client, Method::DELETE, path, Body::Empty);
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
        let body = Body::Text {
            content_type: "text/plain".into(),
            text: body.to_string(),
        };
        let r = self.call(&self.client, Method::PUT, path, body);
        (r.status, r.body)
    }

    /// Opens `GET /api/events`, with `Last-Event-ID` when given.
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
