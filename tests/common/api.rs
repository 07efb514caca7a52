//! A blocking JSON client for a daemon under test (call it inside `spawn_blocking`).

use std::time::Duration;

use serde_json::Value;
use stagehand::daemon::RunningDaemon;

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

/// One daemon and one token.
#[derive(Clone)]
pub struct Api {
    pub base: String,
    pub token: String,
    agent: ureq::Agent,
}

impl Api {
    /// A client of `d` with `token`.
    pub fn new(d: &RunningDaemon, token: &str) -> Self {
        let config = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(60)))
            .build();
        Self {
            base: format!("http://{}", d.addr),
            token: token.to_string(),
            agent: ureq::Agent::new_with_config(config),
        }
    }

    /// A client with the operator token.
    pub fn operator(d: &RunningDaemon) -> Self {
        Self::new(d, &d.state.tokens.operator)
    }

    fn reply(r: Result<ureq::http::Response<ureq::Body>, ureq::Error>) -> Reply {
        let r = r.expect("the daemon answers");
        let status = r.status().as_u16();
        let headers = r
            .headers()
            .iter()
            .map(|(n, v)| (n.as_str().to_string(), v.to_str().unwrap_or("").to_string()))
            .collect();
        let text = r.into_body().read_to_string().expect("a body");
        let body = serde_json::from_str(&text).unwrap_or(Value::String(text));
        Reply {
            status,
            headers,
            body,
        }
    }

    /// `GET path` with the token.
    pub fn get_reply(&self, path: &str) -> Reply {
        Self::reply(
            self.agent
                .get(format!("{}{path}", self.base))
                .header("Authorization", format!("Bearer {}", self.token))
                .call(),
        )
    }

    /// `GET path` without any token.
    pub fn get_anonymous(&self, path: &str) -> Reply {
        Self::reply(self.agent.get(format!("{}{path}", self.base)).call())
    }

    /// `GET path`: status and body.
    pub fn get(&self, path: &str) -> (u16, Value) {
        let r = self.get_reply(path);
        (r.status, r.body)
    }

    /// `POST path` with a raw JSON text body: status and body.
    pub fn post_text(&self, path: &str, body: &str) -> (u16, Value) {
        let r = Self::reply(
            self.agent
                .post(format!("{}{path}", self.base))
                .header("Authorization", format!("Bearer {}", self.token))
                .header("Content-Type", "application/json")
                .send(body),
        );
        (r.status, r.body)
    }

    /// `POST path` with a JSON body (or none): status and body.
    pub fn post(&self, path: &str, body: Option<Value>) -> (u16, Value) {
        let req = self
            .agent
            .post(format!("{}{path}", self.base))
            .header("Authorization", format!("Bearer {}", self.token));
        let r = Self::reply(match body {
            Some(b) => req.send_json(b),
            None => req.send_empty(),
        });
        (r.status, r.body)
    }

    /// `DELETE path`: status and body.
    pub fn delete(&self, path: &str) -> (u16, Value) {
        let r = Self::reply(
            self.agent
                .delete(format!("{}{path}", self.base))
                .header("Authorization", format!("Bearer {}", self.token))
                .call(),
        );
        (r.status, r.body)
    }

    /// `POST path` that must answer `status`; its body.
    pub fn expect(&self, status: u16, path: &str, body: Option<Value>) -> Value {
        let (s, v) = self.post(path, body);
        assert_eq!(s, status, "POST {path}: {v}");
        v
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
    lines: std::io::Lines<std::io::BufReader<Box<dyn std::io::Read + Send>>>,
}

impl Sse {
    /// The next event; `None` when the stream ended.
    pub fn next_event(&mut self) -> Option<SseEvent> {
        let (mut kind, mut id, mut data) = (String::new(), None, String::new());
        loop {
            let line = self.lines.next()?.ok()?;
            if line.is_empty() {
                if kind.is_empty() && data.is_empty() {
                    continue; // a keep-alive comment's end
                }
                let data = serde_json::from_str(&data).unwrap_or(Value::String(data));
                return Some(SseEvent { kind, id, data });
            }
            if let Some(v) = line.strip_prefix("event:") {
                kind = v.trim().to_string();
            } else if let Some(v) = line.strip_prefix("id:") {
                id = v.trim().parse().ok();
            } else if let Some(v) = line.strip_prefix("data:") {
                data.push_str(v.trim_start());
            }
        }
    }
}

impl Api {
    /// Opens `GET /api/events`, with `Last-Event-ID` when given.
    pub fn sse(&self, last_event_id: Option<u64>) -> Sse {
        let mut req = self
            .agent
            .get(format!("{}/api/events", self.base))
            .header("Authorization", format!("Bearer {}", self.token));
        if let Some(id) = last_event_id {
            req = req.header("Last-Event-ID", id.to_string());
        }
        let r = req.call().expect("the daemon answers");
        assert_eq!(r.status().as_u16(), 200);
        let reader: Box<dyn std::io::Read + Send> = Box::new(r.into_body().into_reader());
        Sse {
            lines: std::io::BufRead::lines(std::io::BufReader::new(reader)),
        }
    }

    /// `PUT path` with a text body: status and body.
    pub fn put_text(&self, path: &str, body: &str) -> (u16, Value) {
        let r = Self::reply(
            self.agent
                .put(format!("{}{path}", self.base))
                .header("Authorization", format!("Bearer {}", self.token))
                .content_type("text/plain")
                .send(body),
        );
        (r.status, r.body)
    }
}
