//! The event hub: everything the dashboard and API clients follow live (device changes, run
//! progress, new frames, prompts, warnings, e-stop) goes through one broadcast channel with a
//! sequence number, and the last events stay in a ring for the event log.
//!
//! Publishing never waits: a subscriber that falls behind loses events (the channel is
//! bounded) and the SSE stream then sends a `resync` event with the whole current state, so a
//! slow client can never slow the executor.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};
use tokio::sync::broadcast;
use utoipa::ToSchema;

/// How many events a subscriber may fall behind before it is resynchronised.
pub const CHANNEL_CAPACITY: usize = 1024;
/// How many events `GET /api/events/recent` keeps (and a reconnecting SSE client can be
/// replayed with `Last-Event-ID`).
pub const RECENT: usize = 200;

/// The kind of a published event, also its SSE event name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// Progress of a run (an executor event with its `run_id`).
    Run,
    /// A device's published status changed.
    Device,
    /// A frame became durable.
    Frame,
    /// A prompt was asked or answered.
    Prompt,
    /// Something the operator should know.
    Warning,
    /// The e-stop was latched or released.
    Estop,
    /// The run queue changed.
    Queue,
}

impl EventKind {
    /// The SSE event name (the serde spelling).
    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Run => "run",
            EventKind::Device => "device",
            EventKind::Frame => "frame",
            EventKind::Prompt => "prompt",
            EventKind::Warning => "warning",
            EventKind::Estop => "estop",
            EventKind::Queue => "queue",
        }
    }
}

/// One published event.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct HubEvent {
    /// Increasing number, also the SSE `id`.
    pub seq: u64,
    /// What the event is about (the SSE event name).
    pub kind: EventKind,
    /// Wall-clock Unix time in seconds.
    pub unix_s: f64,
    /// The event itself (its shape depends on `kind`; see the README's API section).
    #[schema(value_type = Object)]
    pub data: serde_json::Value,
}

/// The daemon's event hub.
pub struct EventHub {
    tx: broadcast::Sender<HubEvent>,
    /// Set when the daemon shuts down: live streams end so the server can stop.
    closing: tokio::sync::watch::Sender<bool>,
    seq: AtomicU64,
    recent: Mutex<VecDeque<HubEvent>>,
}

impl Default for EventHub {
    fn default() -> Self {
        Self::new()
    }
}

impl EventHub {
    /// A hub with no event yet. Sequence numbers continue from the wall clock in
    /// microseconds, so the ids of a restarted daemon are above those of the one before: a
    /// client's `Last-Event-ID` from before the restart asks for a resync, and a dashboard
    /// that skips ids it has seen does not skip the new daemon's events.
    pub fn new() -> Self {
        let start_us = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| u64::try_from(d.as_micros()).unwrap_or(0))
            .unwrap_or(0);
        Self::starting_after(start_us)
    }

    /// A hub whose first event has sequence number `seq + 1`.
    fn starting_after(seq: u64) -> Self {
        Self {
            tx: broadcast::channel(CHANNEL_CAPACITY).0,
            closing: tokio::sync::watch::channel(false).0,
            seq: AtomicU64::new(seq),
            recent: Mutex::new(VecDeque::with_capacity(RECENT)),
        }
    }

    /// Publishes an event; never blocks, whoever listens or not.
    pub fn publish(&self, kind: EventKind, data: impl Serialize) {
        let data = serde_json::to_value(data).unwrap_or_else(
            |e| serde_json::json!({"error": format!("event not serialisable: {e}")}),
        );
        // The ring lock also orders sequence numbers with what subscribers see.
        let mut recent = self.recent.lock().unwrap_or_else(|p| p.into_inner());
        let event = HubEvent {
            seq: self.seq.fetch_add(1, Ordering::Relaxed) + 1,
            kind,
            unix_s: crate::executor::wall_now(),
            data,
        };
        if recent.len() == RECENT {
            recent.pop_front();
        }
        recent.push_back(event.clone());
        let _ = self.tx.send(event);
        metrics::counter!("stagehand_events_published_total", "kind" => kind.as_str()).increment(1);
    }

    /// A receiver of every event published from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<HubEvent> {
        self.tx.subscribe()
    }

    /// A receiver of every event published from now on and, when the ring still holds every
    /// event after `after` (the SSE `Last-Event-ID` a reconnecting client sends), those
    /// events, oldest first: together exactly the events after `after`, none twice. `None`
    /// when some of them already left the ring (or `after` is from before a restart): the
    /// client must resynchronise instead.
    pub fn subscribe_after(
        &self,
        after: u64,
    ) -> (broadcast::Receiver<HubEvent>, Option<Vec<HubEvent>>) {
        // Publishing holds the ring lock while it sends: subscribing under it splits the
        // events exactly between the ring and the receiver.
        let recent = self.recent.lock().unwrap_or_else(|p| p.into_inner());
        let rx = self.tx.subscribe();
        let last = self.seq.load(Ordering::Relaxed);
        let oldest = recent.front().map_or(last + 1, |e| e.seq);
        let missed = (after <= last && oldest <= after + 1)
            .then(|| recent.iter().filter(|e| e.seq > after).cloned().collect());
        (rx, missed)
    }

    /// The last [`RECENT`] events, oldest first.
    pub fn recent(&self) -> Vec<HubEvent> {
        let recent = self.recent.lock().unwrap_or_else(|p| p.into_inner());
        recent.iter().cloned().collect()
    }

    /// Ends every live stream (daemon shutdown).
    pub fn close(&self) {
        self.closing.send_replace(true);
    }

    /// Resolves once [`EventHub::close`] was called.
    pub async fn closed(&self) {
        let mut rx = self.closing.subscribe();
        let _ = rx.wait_for(|closing| *closing).await;
    }

    /// Number of live subscribers (SSE clients and internal listeners).
    pub fn subscribers(&self) -> usize {
        self.tx.receiver_count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seqs(events: &[HubEvent]) -> Vec<u64> {
        events.iter().map(|e| e.seq).collect()
    }

    #[test]
    fn a_reconnecting_client_gets_exactly_the_events_it_missed_while_the_ring_holds_them() {
        let hub = EventHub::starting_after(1000);
        for i in 0..5 {
            hub.publish(EventKind::Device, i);
        }
        let (_, missed) = hub.subscribe_after(1002);
        assert_eq!(missed.map(|m| seqs(&m)), Some(vec![1003, 1004, 1005]));
        let (_, missed) = hub.subscribe_after(1005);
        assert_eq!(missed.map(|m| seqs(&m)), Some(vec![]));
        // From before this hub (a daemon restarted) or from the future: resync.
        assert!(hub.subscribe_after(10).1.is_none());
        assert!(hub.subscribe_after(1006).1.is_none());
        // Events that left the ring cannot be replayed.
        for i in 0..RECENT {
            hub.publish(EventKind::Device, i);
        }
        assert!(hub.subscribe_after(1002).1.is_none());
        let oldest = hub.recent()[0].seq;
        let (_, missed) = hub.subscribe_after(oldest - 1);
        assert_eq!(missed.map(|m| m.len()), Some(RECENT));
    }

    #[test]
    fn events_after_the_subscription_come_through_the_receiver_not_twice() {
        let hub = EventHub::starting_after(0);
        hub.publish(EventKind::Device, 1);
        let (mut rx, missed) = hub.subscribe_after(0);
        assert_eq!(missed.map(|m| seqs(&m)), Some(vec![1]));
        hub.publish(EventKind::Device, 2);
        assert_eq!(rx.try_recv().map(|e| e.seq).ok(), Some(2));
        assert!(rx.try_recv().is_err());
    }

    #[test]
    fn a_new_hub_numbers_its_events_after_the_clock() {
        let hub = EventHub::new();
        hub.publish(EventKind::Device, 1);
        // 2020-01-01 in microseconds: far above any count of events a daemon publishes.
        assert!(hub.recent()[0].seq > 1_577_836_800_000_000);
    }
}
