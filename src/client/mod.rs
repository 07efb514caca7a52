//! A typed async client of the daemon's HTTP API (`stagehand serve`), used by
//! `stagehand run --remote`, the daemon load benchmark and the daemon tests.
//!
//! It decodes the answers into the types the daemon serialises ([`DryRun`], [`Started`],
//! [`RunState`], [`RunSummary`], the executor's [`crate::executor::Event`]), so a renamed or
//! missing field is a [`ClientError::Decode`] naming the endpoint, never a silent zero. Live
//! events come from [`Client::events`] (Server-Sent Events, see [`sse`]).
//!
//! Plain HTTP only: the daemon serves loopback or a lab LAN (use an SSH tunnel from further).

pub mod sse;

use std::collections::BTreeMap;
use std::time::Duration;

use reqwest::{Method, RequestBuilder, StatusCode};
use serde::Deserialize;
use serde::de::DeserializeOwned;

pub use crate::daemon::api::{PromptAnswer, RunSummary};
pub use crate::daemon::error::{ErrorBody, ViolationItem};
pub use crate::daemon::events::{EventKind, HubEvent};
pub use crate::daemon::operator::PromptInfo;
pub use crate::daemon::run_start::{StartRun, Started};
pub use crate::daemon::runs::{LiveState, RunState};
pub use crate::daemon::scripts::{BlockEstimate, DryRun, EstimateInfo, ViolationInfo};
pub use crate::daemon::stored_runs::StoredStatus;
pub use sse::{DaemonEvent, EventStream, PromptEvent, Resync, RunEvent, SseEvent, WarningEvent};

/// How long connecting may take before the daemon counts as unreachable.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// How long one request (not the event stream) may take in all.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(120);

/// Why a request to the daemon failed. Each names the endpoint and what to do.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The base URL is not one this client can use.
    #[error("{url}: {reason}")]
    BadUrl {
        /// The URL as given.
        url: String,
        /// What is wrong with it and what to use instead.
        reason: String,
    },
    /// Nothing answered (connection refused, timed out, broken).
    #[error(
        "cannot reach the daemon at {base} ({endpoint}): {source}; is `stagehand serve` running there? (check the URL and port)"
    )]
    Unreachable {
        /// The daemon's base URL.
        base: String,
        /// `METHOD /path` of the request.
        endpoint: String,
        /// What the HTTP client saw.
        #[source]
        source: reqwest::Error,
    },
    /// The daemon refused the request (4xx) and said why.
    #[error("{endpoint}: {}", refusal(*.status, .body))]
    Rejected {
        /// `METHOD /path` of the request.
        endpoint: String,
        /// The HTTP status (400..=499).
        status: u16,
        /// The daemon's error body: what went wrong and what to do.
        body: ErrorBody,
    },
    /// The daemon failed (5xx or another unexpected status).
    #[error("{endpoint}: the daemon failed ({status}): {body}; see the daemon's log")]
    Server {
        /// `METHOD /path` of the request.
        endpoint: String,
        /// The HTTP status.
        status: u16,
        /// The start of the answer.
        body: String,
    },
    /// The daemon answered something this client cannot decode.
    #[error(
        "{endpoint}: unexpected answer ({source}): {excerpt}; is the daemon the same stagehand version as this client?"
    )]
    Decode {
        /// `METHOD /path` of the request (or the SSE event's name).
        endpoint: String,
        /// What did not fit.
        #[source]
        source: serde_json::Error,
        /// The start of the answer.
        excerpt: String,
    },
    /// The event stream broke while it was read.
    #[error(
        "{endpoint}: the event stream of {base} broke: {reason}; reconnect (with the last event id to be replayed what was missed)"
    )]
    Stream {
        /// The daemon's base URL.
        base: String,
        /// `GET /api/events`.
        endpoint: String,
        /// What broke.
        reason: String,
    },
}

impl ClientError {
    /// The HTTP status the daemon answered, for [`ClientError::Rejected`] and
    /// [`ClientError::Server`].
    pub fn status(&self) -> Option<u16> {
        match self {
            ClientError::Rejected { status, .. } | ClientError::Server { status, .. } => {
                Some(*status)
            }
            _ => None,
        }
    }
}

/// The daemon's refusal as one text: status, error, hint and each violation.
fn refusal(status: u16, body: &ErrorBody) -> String {
    let mut text = format!("the daemon refused ({status}): {}", body.error);
    for v in &body.violations {
        match (v.line, v.col) {
            (Some(l), Some(c)) => text.push_str(&format!("\n  {l}:{c}: {}", v.message)),
            _ => text.push_str(&format!("\n  {}", v.message)),
        }
    }
    if let Some(h) = &body.hint {
        text.push_str(&format!("\n  hint: {h}"));
    }
    text
}

/// At most 300 characters of `text`, `…` when cut.
pub(crate) fn excerpt(text: &str) -> String {
    let t: String = text.chars().take(300).collect();
    if t.len() < text.len() {
        format!("{t}…")
    } else {
        t
    }
}

/// An answer as it came: status, headers and body (for callers that check statuses
/// themselves, such as the daemon's tests).
#[derive(Debug, Clone)]
pub struct RawReply {
    /// The HTTP status.
    pub status: u16,
    /// Header names (lower case) and values (`""` when not text).
    pub headers: Vec<(String, String)>,
    /// The body (empty for an event stream, which is not read).
    pub body: Vec<u8>,
}

impl RawReply {
    /// The body as text (invalid UTF-8 replaced).
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    /// The value of header `name` (lower case), `""` when absent.
    pub fn header(&self, name: &str) -> &str {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map_or("", |(_, v)| v.as_str())
    }
}

/// What a raw request sends.
#[derive(Debug, Clone)]
pub enum Body {
    /// No body.
    Empty,
    /// A JSON document.
    Json(serde_json::Value),
    /// Text as it is, with this content type.
    Text {
        /// The `Content-Type`.
        content_type: String,
        /// The body.
        text: String,
    },
    /// Bytes as they are, with no content type (give one in the headers, or none).
    Raw(Vec<u8>),
    /// Bytes as they are (not necessarily UTF-8), with this content type.
    Bytes {
        /// The `Content-Type`.
        content_type: String,
        /// The body.
        bytes: Vec<u8>,
    },
}

/// `GET /api/status` as far as this client reads it.
#[derive(Debug, Deserialize)]
struct StatusRun {
    run: Option<RunState>,
}

/// A client of one daemon with one token. Cheap to clone (connections are pooled and shared).
#[derive(Debug, Clone)]
pub struct Client {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Client {
    /// A client of the daemon at `base` (`http://host:port`, or `host:port`) using `token`
    /// (`None`: requests go without one, as for the public endpoints).
    pub fn new(base: &str, token: Option<&str>) -> Result<Client, ClientError> {
        let base = normalise_url(base)?;
        let http = reqwest::Client::builder()
            .connect_timeout(CONNECT_TIMEOUT)
            .no_proxy()
            .build()
            .map_err(|e| ClientError::BadUrl {
                url: base.clone(),
                reason: format!("cannot set up an HTTP client: {e}"),
            })?;
        Ok(Client {
            http,
            base,
            token: token.map(str::to_string),
        })
    }

    /// The daemon's base URL, e.g. `http://127.0.0.1:8080`.
    pub fn base(&self) -> &str {
        &self.base
    }

    /// The same daemon with another token (`None`: anonymous).
    pub fn with_token(&self, token: Option<&str>) -> Client {
        Client {
            token: token.map(str::to_string),
            ..self.clone()
        }
    }

    fn request(&self, method: Method, path: &str) -> RequestBuilder {
        let req = self.http.request(method, format!("{}{path}", self.base));
        match &self.token {
            Some(t) => req.bearer_auth(t),
            None => req,
        }
    }

    fn unreachable(&self, endpoint: &str, source: reqwest::Error) -> ClientError {
        ClientError::Unreachable {
            base: self.base.clone(),
            endpoint: endpoint.to_string(),
            source,
        }
    }

    /// Sends a request and reads its whole answer.
    async fn send(&self, endpoint: &str, req: RequestBuilder) -> Result<RawReply, ClientError> {
        let resp = req
            .timeout(REQUEST_TIMEOUT)
            .send()
            .await
            .map_err(|e| self.unreachable(endpoint, e))?;
        let status = resp.status().as_u16();
        let headers = resp
            .headers()
            .iter()
            .map(|(n, v)| (n.as_str().to_string(), v.to_str().unwrap_or("").to_string()))
            .collect();
        let stream = resp
            .headers()
            .get(reqwest::header::CONTENT_TYPE)
            .is_some_and(|v| v.as_bytes().starts_with(b"text/event-stream"));
        let body = if stream {
            Vec::new()
        } else {
            resp.bytes()
                .await
                .map_err(|e| self.unreachable(endpoint, e))?
                .to_vec()
        };
        Ok(RawReply {
            status,
            headers,
            body,
        })
    }

    /// Any request, answered as it came (statuses are not checked).
    pub async fn raw(
        &self,
        method: Method,
        path: &str,
        body: Body,
    ) -> Result<RawReply, ClientError> {
        self.raw_with(method, path, &[], body).await
    }

    /// Any request with extra headers (e.g. `If-None-Match`), answered as it came.
    pub async fn raw_with(
        &self,
        method: Method,
        path: &str,
        headers: &[(&str, &str)],
        body: Body,
    ) -> Result<RawReply, ClientError> {
        let endpoint = format!("{method} {path}");
        let mut req = self.request(method, path);
        for (name, value) in headers {
            req = req.header(*name, *value);
        }
        let req = match body {
            Body::Empty => req,
            Body::Json(v) => req.json(&v),
            Body::Text { content_type, text } => req
                .header(reqwest::header::CONTENT_TYPE, content_type)
                .body(text),
            Body::Raw(bytes) => req.body(bytes),
            Body::Bytes {
                content_type,
                bytes,
            } => req
                .header(reqwest::header::CONTENT_TYPE, content_type)
                .body(bytes),
        };
        self.send(&endpoint, req).await
    }

    /// `Ok` for a 2xx answer; a 4xx is [`ClientError::Rejected`], anything else
    /// [`ClientError::Server`].
    fn check(endpoint: &str, reply: RawReply) -> Result<RawReply, ClientError> {
        match reply.status {
            200..=299 => Ok(reply),
            status @ 400..=499 => {
                let body = serde_json::from_slice(&reply.body).unwrap_or_else(|_| ErrorBody {
                    error: excerpt(&reply.text()),
                    hint: None,
                    violations: Vec::new(),
                });
                Err(ClientError::Rejected {
                    endpoint: endpoint.to_string(),
                    status,
                    body,
                })
            }
            status => Err(ClientError::Server {
                endpoint: endpoint.to_string(),
                status,
                body: excerpt(&reply.text()),
            }),
        }
    }

    /// A request whose 2xx answer is JSON of type `T`.
    async fn call<T: DeserializeOwned>(
        &self,
        method: Method,
        path: &str,
        body: Body,
    ) -> Result<T, ClientError> {
        let endpoint = format!("{method} {path}");
        let reply = Self::check(&endpoint, self.raw(method, path, body).await?)?;
        decode(&endpoint, &reply.text())
    }

    /// `GET /api/status`: the active run, if any.
    pub async fn active_run(&self) -> Result<Option<RunState>, ClientError> {
        let s: StatusRun = self.call(Method::GET, "/api/status", Body::Empty).await?;
        Ok(s.run)
    }

    /// `GET /api/scripts/{name}`: the script's text; `None` when the library has no such
    /// script.
    pub async fn script(&self, name: &str) -> Result<Option<String>, ClientError> {
        let path = format!("/api/scripts/{name}");
        let reply = self.raw(Method::GET, &path, Body::Empty).await?;
        if reply.status == 404 {
            return Ok(None);
        }
        Ok(Some(Self::check(&format!("GET {path}"), reply)?.text()))
    }

    /// `PUT /api/scripts/{name}`: stores the script; its dry run (which may list errors:
    /// check [`DryRun::ok`]). 409 when a built-in script has that name.
    pub async fn put_script(&self, name: &str, text: &str) -> Result<DryRun, ClientError> {
        let body = Body::Text {
            content_type: "text/plain; charset=utf-8".into(),
            text: text.to_string(),
        };
        self.call(Method::PUT, &format!("/api/scripts/{name}"), body)
            .await
    }

    /// `POST /api/scripts/{name}/validate` with parameter values: the dry run.
    pub async fn validate(
        &self,
        name: &str,
        set: &BTreeMap<String, serde_json::Value>,
    ) -> Result<DryRun, ClientError> {
        let body = Body::Json(serde_json::json!({ "set": set }));
        self.call(Method::POST, &format!("/api/scripts/{name}/validate"), body)
            .await
    }

    /// `POST /api/runs`: starts a run of a library script.
    pub async fn start_run(&self, start: &StartRun) -> Result<Started, ClientError> {
        let body = serde_json::to_value(start).map_err(|e| ClientError::Decode {
            endpoint: "POST /api/runs".into(),
            source: e,
            excerpt: String::new(),
        })?;
        self.call(Method::POST, "/api/runs", Body::Json(body)).await
    }

    /// `GET /api/runs/{id}`: the run as stored (with its live status while active).
    pub async fn run(&self, run_id: &str) -> Result<RunSummary, ClientError> {
        self.call(Method::GET, &format!("/api/runs/{run_id}"), Body::Empty)
            .await
    }

    /// `POST /api/runs/{id}/abort`: aborts the active run to the safe state; its state.
    pub async fn abort(&self, run_id: &str) -> Result<RunState, ClientError> {
        self.call(
            Method::POST,
            &format!("/api/runs/{run_id}/abort"),
            Body::Empty,
        )
        .await
    }

    /// `POST /api/runs/{id}/prompt`: answers the run's pending prompt.
    pub async fn answer_prompt(
        &self,
        run_id: &str,
        answer: PromptAnswer,
    ) -> Result<PromptInfo, ClientError> {
        let body = Body::Json(serde_json::json!({ "answer": answer }));
        self.call(Method::POST, &format!("/api/runs/{run_id}/prompt"), body)
            .await
    }

    /// `GET /api/events`: the live event stream. With `last_event_id`, the daemon replays
    /// the events after it while it still holds them (else the stream starts with a
    /// `resync`). The stream has no overall timeout: it lasts as long as it is read.
    pub async fn events(&self, last_event_id: Option<u64>) -> Result<EventStream, ClientError> {
        let endpoint = "GET /api/events";
        let mut req = self
            .request(Method::GET, "/api/events")
            .header(reqwest::header::ACCEPT, "text/event-stream");
        if let Some(id) = last_event_id {
            req = req.header("Last-Event-ID", id.to_string());
        }
        let resp = req
            .send()
            .await
            .map_err(|e| self.unreachable(endpoint, e))?;
        if resp.status() != StatusCode::OK {
            let status = resp.status().as_u16();
            let body = resp.bytes().await.map(|b| b.to_vec()).unwrap_or_default();
            let reply = RawReply {
                status,
                headers: Vec::new(),
                body,
            };
            return Err(Self::check(endpoint, reply).err().unwrap_or_else(|| {
                ClientError::Server {
                    endpoint: endpoint.into(),
                    status,
                    body: "a success other than 200 for a stream".into(),
                }
            }));
        }
        Ok(EventStream::new(self.base.clone(), resp))
    }
}

/// Decodes a JSON answer of `endpoint`.
fn decode<T: DeserializeOwned>(endpoint: &str, body: &str) -> Result<T, ClientError> {
    serde_json::from_str(body).map_err(|e| ClientError::Decode {
        endpoint: endpoint.to_string(),
        source: e,
        excerpt: excerpt(body),
    })
}

/// The daemon's base URL: `http://` added when missing, no trailing slash.
pub fn normalise_url(url: &str) -> Result<String, ClientError> {
    let url = url.trim().trim_end_matches('/');
    let bad = |reason: &str| ClientError::BadUrl {
        url: url.to_string(),
        reason: reason.to_string(),
    };
    if url.is_empty() {
        return Err(bad("no URL: give the daemon's, e.g. http://127.0.0.1:8080"));
    }
    if url.starts_with("https://") {
        return Err(bad(
            "this client speaks plain HTTP (the daemon serves loopback or the lab LAN); use http:// or an SSH tunnel",
        ));
    }
    if url.starts_with("http://") {
        Ok(url.to_string())
    } else if url.contains("://") {
        Err(bad("only http:// URLs are supported"))
    } else {
        Ok(format!("http://{url}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_normalised() -> Result<(), ClientError> {
        assert_eq!(normalise_url("127.0.0.1:8080/")?, "http://127.0.0.1:8080");
        assert_eq!(normalise_url("http://lab:1")?, "http://lab:1");
        assert!(normalise_url("https://lab").is_err());
        assert!(normalise_url("ftp://lab").is_err());
        assert!(normalise_url(" ").is_err());
        Ok(())
    }

    #[test]
    fn refusals_say_what_to_do() {
        let e = ClientError::Rejected {
            endpoint: "POST /api/runs".into(),
            status: 409,
            body: ErrorBody {
                error: "a run is active".into(),
                hint: Some("abort it first".into()),
                violations: vec![ViolationItem {
                    line: None,
                    col: None,
                    message: "`nope` is not a parameter".into(),
                }],
            },
        };
        let text = e.to_string();
        for needle in ["POST /api/runs", "409", "abort it first", "nope"] {
            assert!(text.contains(needle), "{needle}: {text}");
        }
    }

    #[test]
    fn a_renamed_field_is_an_error_naming_the_endpoint() {
        let r = decode::<RunState>("GET /api/status", r#"{"run_id":"x","steps":3}"#);
        let Err(e) = r else {
            panic!("decoded a RunState without its fields");
        };
        assert!(e.to_string().contains("GET /api/status"), "{e}");
    }
}
