//! The daemon's live events (`GET /api/events`, Server-Sent Events), parsed by
//! `eventsource-stream` and decoded into the types the daemon publishes.
//!
//! Each SSE event's `data` is a [`HubEvent`] (`seq`, `kind`, `unix_s`, `data`), except the
//! `resync` that starts a stream (and replaces the events a slow reader missed), whose data is
//! the whole status (`GET /api/status`).

use std::pin::Pin;

use eventsource_stream::Eventsource;
use futures_util::{Stream, StreamExt};
use serde::Deserialize;
use serde::de::DeserializeOwned;

use super::{ClientError, EventKind, HubEvent, PromptAnswer, RunState, excerpt};
use crate::executor::Event;

/// One Server-Sent Event as it came.
#[derive(Debug, Clone, PartialEq)]
pub struct SseEvent {
    /// The `event:` name (`message` when absent).
    pub name: String,
    /// The `id:` (the hub's sequence number), when the event has one.
    pub id: Option<u64>,
    /// The `data:` lines joined with newlines.
    pub data: String,
}

/// The status a `resync` carries, as far as a client following runs needs it.
#[derive(Debug, Clone, Deserialize)]
pub struct Resync {
    /// True while the e-stop is latched.
    pub estop: bool,
    /// The active run, if any.
    pub run: Option<RunState>,
}

/// A `run` event: the executor's event of one run (its JSON is the [`Event`]'s with
/// `run_id` added).
#[derive(Debug, Clone, Deserialize)]
pub struct RunEvent {
    /// The run it belongs to.
    pub run_id: String,
    /// What happened.
    #[serde(flatten)]
    pub event: Event,
}

/// A `prompt` event: a run asks the operator, or a prompt was answered.
#[derive(Debug, Clone, Deserialize)]
pub struct PromptEvent {
    /// The run asking.
    pub run_id: String,
    /// The step of the prompt.
    pub step: usize,
    /// What the operator is asked to do (absent in an answer).
    #[serde(default)]
    pub message: Option<String>,
    /// How it was answered (absent while it waits).
    #[serde(default)]
    pub answered: Option<PromptAnswer>,
}

/// A `warning` event.
#[derive(Debug, Clone, Deserialize)]
pub struct WarningEvent {
    /// The run it concerns, if any.
    #[serde(default)]
    pub run_id: Option<String>,
    /// What the operator should know.
    pub message: String,
}

/// One decoded event of the daemon.
#[derive(Debug, Clone)]
pub enum DaemonEvent {
    /// The whole status: the stream's first event, or instead of events a slow reader missed.
    Resync(Box<Resync>),
    /// Progress of a run.
    Run(RunEvent),
    /// A prompt asked or answered.
    Prompt(PromptEvent),
    /// A warning.
    Warning(WarningEvent),
    /// Any other kind (`device`, `frame`, `estop`, `queue`, …), its data as JSON.
    Other(HubEvent),
}

/// Decodes one SSE event of `GET /api/events`.
pub fn decode(ev: &SseEvent) -> Result<DaemonEvent, ClientError> {
    fn data<T: DeserializeOwned>(ev: &SseEvent, v: serde_json::Value) -> Result<T, ClientError> {
        serde_json::from_value(v).map_err(|e| bad(ev, e))
    }
    if ev.name == "resync" {
        let r: Resync = serde_json::from_str(&ev.data).map_err(|e| bad(ev, e))?;
        return Ok(DaemonEvent::Resync(Box::new(r)));
    }
    let hub: HubEvent = serde_json::from_str(&ev.data).map_err(|e| bad(ev, e))?;
    Ok(match hub.kind {
        EventKind::Run => DaemonEvent::Run(data(ev, hub.data)?),
        EventKind::Prompt => DaemonEvent::Prompt(data(ev, hub.data)?),
        EventKind::Warning => DaemonEvent::Warning(data(ev, hub.data)?),
        _ => DaemonEvent::Other(hub),
    })
}

fn bad(ev: &SseEvent, source: serde_json::Error) -> ClientError {
    ClientError::Decode {
        endpoint: format!("GET /api/events (`{}` event)", ev.name),
        source,
        excerpt: excerpt(&ev.data),
    }
}

/// An error of the byte stream under the parser, whatever its type.
type TransportError = Box<dyn std::error::Error + Send + Sync>;

type Events = Pin<
    Box<
        dyn Stream<
                Item = Result<
                    eventsource_stream::Event,
                    eventsource_stream::EventStreamError<TransportError>,
                >,
            > + Send,
    >,
>;

/// A live `GET /api/events` stream.
pub struct EventStream {
    base: String,
    events: Events,
    last_id: Option<u64>,
}

impl std::fmt::Debug for EventStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EventStream")
            .field("base", &self.base)
            .field("last_id", &self.last_id)
            .finish_non_exhaustive()
    }
}

impl EventStream {
    pub(super) fn new(base: String, resp: reqwest::Response) -> Self {
        Self::from_bytes(base, resp.bytes_stream())
    }

    /// The events of an SSE body given as a stream of byte chunks (for a body read some
    /// other way, and tests).
    pub fn from_bytes<S, B, E>(base: String, bytes: S) -> Self
    where
        S: Stream<Item = Result<B, E>> + Send + 'static,
        B: AsRef<[u8]>,
        E: Into<TransportError>,
    {
        let events = bytes.map(|r| r.map_err(Into::into)).eventsource();
        Self {
            base,
            events: Box::pin(events),
            last_id: None,
        }
    }

    /// The `id` of the last event read: give it to [`super::Client::events`] when
    /// reconnecting to be replayed what was missed.
    pub fn last_event_id(&self) -> Option<u64> {
        self.last_id
    }

    /// The next event as it came; `None` when the daemon ended the stream.
    pub async fn next_raw(&mut self) -> Option<Result<SseEvent, ClientError>> {
        let ev = match self.events.next().await? {
            Ok(ev) => ev,
            Err(e) => {
                return Some(Err(ClientError::Stream {
                    base: self.base.clone(),
                    endpoint: "GET /api/events".into(),
                    reason: e.to_string(),
                }));
            }
        };
        let id = ev.id.trim().parse().ok();
        if id.is_some() {
            self.last_id = id;
        }
        Some(Ok(SseEvent {
            name: if ev.event.is_empty() {
                "message".into()
            } else {
                ev.event
            },
            id,
            data: ev.data,
        }))
    }

    /// The next event, decoded; `None` when the daemon ended the stream.
    pub async fn next(&mut self) -> Option<Result<DaemonEvent, ClientError>> {
        Some(self.next_raw().await?.and_then(|ev| decode(&ev)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream(chunks: &[&'static str]) -> EventStream {
        let chunks: Vec<Result<&'static str, std::io::Error>> =
            chunks.iter().map(|c| Ok(*c)).collect();
        EventStream::from_bytes("http://test".into(), futures_util::stream::iter(chunks))
    }

    #[tokio::test]
    async fn events_are_parsed_across_chunks_and_decoded() -> Result<(), ClientError> {
        let run = r#"{"seq":7,"kind":"run","unix_s":1.0,"data":{"event":"step_finished","step":2,"kind":"capture","frames":3,"rig_time_s":1.5,"total_steps":5,"eta_s":2.0,"run_id":"r1"}}"#;
        let (head, tail) = run.split_at(40);
        let mut s = stream(&[
            ": keep-alive\n\n",
            "event: resync\ndata: {\"estop\":false,\"run\":null,\"devices\":[]}\n\n",
            "event: run\nid: 7\ndata: ",
            head,
            tail,
            "\n\nevent: prompt\nid: 8\r\ndata: {\"seq\":8,\"kind\":\"prompt\",\"unix_s\":1.0,\"data\":{\"run_id\":\"r1\",\"step\":3,\"answered\":\"abort\"}}\r\n\r\n",
        ]);
        let Some(Ok(DaemonEvent::Resync(r))) = s.next().await else {
            panic!("no resync first");
        };
        assert!(r.run.is_none() && !r.estop);
        let Some(Ok(DaemonEvent::Run(r))) = s.next().await else {
            panic!("no run event");
        };
        assert_eq!(r.run_id, "r1");
        assert_eq!(
            r.event,
            Event::StepFinished {
                step: 2,
                kind: "capture",
                frames: 3,
                rig_time_s: 1.5,
                total_steps: 5,
                eta_s: 2.0
            }
        );
        assert_eq!(s.last_event_id(), Some(7));
        let Some(Ok(DaemonEvent::Prompt(p))) = s.next().await else {
            panic!("no prompt event");
        };
        assert_eq!((p.step, p.answered), (3, Some(PromptAnswer::Abort)));
        assert_eq!(s.last_event_id(), Some(8));
        assert!(s.next().await.is_none());
        Ok(())
    }

    #[tokio::test]
    async fn a_renamed_field_is_an_error_not_a_zero() {
        let mut s = stream(&[
            "event: run\ndata: {\"seq\":1,\"kind\":\"run\",\"unix_s\":1.0,\"data\":{\"event\":\"run_started\",\"total\":5,\"steps_to_do\":5,\"estimated_rig_time_s\":1.0,\"run_id\":\"r\"}}\n\n",
        ]);
        match s.next().await {
            Some(Err(e @ ClientError::Decode { .. })) => {
                assert!(e.to_string().contains("`run` event"), "{e}");
            }
            other => panic!("decoded a renamed field: {other:?}"),
        }
    }
}
