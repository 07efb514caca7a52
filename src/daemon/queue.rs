//! The run queue, as Bluesky's queue server offers it: runs submitted ahead of time execute
//! one after another, in queue order, whenever the rig is idle. Queued runs can be listed,
//! removed and reordered. An e-stop, or a run that does not end `done` (failed or aborted),
//! pauses the queue: the next run starts only once an operator says so
//! (`POST /api/queue/start`), after looking at the rig.
//!
//! A worker task owns the starting: it waits until the queue is running, an item is queued,
//! no run is active and the e-stop is not latched, starts the first item like
//! `POST /api/runs` would, and follows the run to its end. The queue lives in memory: a
//! daemon restart empties it.

use std::collections::VecDeque;
use std::sync::{Mutex, MutexGuard};

use axum::http::StatusCode;
use serde::Serialize;
use tokio::sync::Notify;
use utoipa::ToSchema;

use super::error::ApiError;
use super::run_start::{self, StartRun};
use super::state::AppState;
use crate::daemon::events::EventKind;
use crate::storage::RunStatus;

/// Finished items `GET /api/queue` keeps.
pub const HISTORY: usize = 50;

/// A run waiting in the queue.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct QueueItem {
    /// The item's id (for `DELETE /api/queue/{item}` and moves); never reused.
    pub item_id: u64,
    /// What to start, as for `POST /api/runs`.
    pub request: StartRun,
    /// Wall-clock Unix time it was submitted.
    pub submitted_unix_s: f64,
    /// Why starting it failed last time (the queue then paused with it first).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// An item the queue started.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct StartedItem {
    /// The item's id.
    pub item_id: u64,
    /// Script name.
    pub script: String,
    /// The run it became.
    pub run_id: String,
    /// `running` while it runs, then how it ended: `done`, `failed` or `aborted`.
    #[schema(value_type = String)]
    pub status: RunStatus,
    /// The run's message when it did not end `done`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
}

/// The queue as `GET /api/queue` answers it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct QueueState {
    /// True when the queue starts its next run as soon as the rig is idle; false when paused.
    pub running: bool,
    /// Why the queue paused (an e-stop, a failed or aborted run, `POST /api/queue/stop`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paused_because: Option<String>,
    /// The run the queue started and that is still running.
    pub current: Option<StartedItem>,
    /// The runs waiting, in the order they will start.
    pub items: Vec<QueueItem>,
    /// The last runs the queue started that ended, newest last.
    pub history: Vec<StartedItem>,
}

struct Inner {
    items: VecDeque<QueueItem>,
    next_id: u64,
    paused: Option<String>,
    current: Option<StartedItem>,
    history: VecDeque<StartedItem>,
}

/// The daemon's run queue.
pub struct RunQueue {
    inner: Mutex<Inner>,
    /// Wakes the worker when the queue may have work.
    wake: Notify,
}

impl Default for RunQueue {
    fn default() -> Self {
        Self {
            inner: Mutex::new(Inner {
                items: VecDeque::new(),
                next_id: 1,
                paused: None,
                current: None,
                history: VecDeque::new(),
            }),
            wake: Notify::new(),
        }
    }
}

fn no_item(item_id: u64) -> ApiError {
    ApiError::not_found(format!("no queued item {item_id}"))
        .hint("`GET /api/queue` lists the queued items; started ones are no longer queued")
}

impl RunQueue {
    fn inner(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The queue now.
    pub fn state(&self) -> QueueState {
        let q = self.inner();
        QueueState {
            running: q.paused.is_none(),
            paused_because: q.paused.clone(),
            current: q.current.clone(),
            items: q.items.iter().cloned().collect(),
            history: q.history.iter().cloned().collect(),
        }
    }

    /// Appends a run to the queue.
    pub fn submit(&self, request: StartRun) -> QueueItem {
        let item = {
            let mut q = self.inner();
            let item = QueueItem {
                item_id: q.next_id,
                request,
                submitted_unix_s: crate::executor::wall_now(),
                error: None,
            };
            q.next_id += 1;
            q.items.push_back(item.clone());
            item
        };
        self.wake.notify_one();
        item
    }

    /// Removes a queued item.
    pub fn remove(&self, item_id: u64) -> Result<QueueItem, ApiError> {
        let mut q = self.inner();
        let at = q
            .items
            .iter()
            .position(|i| i.item_id == item_id)
            .ok_or_else(|| no_item(item_id))?;
        q.items.remove(at).ok_or_else(|| no_item(item_id))
    }

    /// Moves a queued item to `position` (0 starts next).
    pub fn move_to(&self, item_id: u64, position: usize) -> Result<(), ApiError> {
        let mut q = self.inner();
        let len = q.items.len();
        if position >= len {
            return Err(ApiError::unprocessable(format!(
                "position {position} is past the end of the queue ({len} items)"
            ))
            .hint(format!(
                "positions are 0 (next) to {}",
                len.saturating_sub(1)
            )));
        }
        let at = q
            .items
            .iter()
            .position(|i| i.item_id == item_id)
            .ok_or_else(|| no_item(item_id))?;
        if let Some(item) = q.items.remove(at) {
            q.items.insert(position, item);
        }
        Ok(())
    }

    /// Lets the queue start runs again.
    pub fn start(&self) {
        self.inner().paused = None;
        self.wake.notify_one();
    }

    /// Stops the queue from starting runs (the current one goes on).
    pub fn pause(&self, why: impl Into<String>) {
        let mut q = self.inner();
        if q.paused.is_none() {
            q.paused = Some(why.into());
        }
    }

    /// The next item to start, taken off the queue, if the queue runs.
    fn take_next(&self) -> Option<QueueItem> {
        let mut q = self.inner();
        if q.paused.is_some() {
            return None;
        }
        q.items.pop_front()
    }

    /// Puts an item that could not start back first.
    fn put_back(&self, item: QueueItem) {
        self.inner().items.push_front(item);
    }

    fn set_current(&self, item: Option<StartedItem>) {
        self.inner().current = item;
    }

    fn finished(&self, item: StartedItem) {
        let mut q = self.inner();
        q.current = None;
        if q.history.len() == HISTORY {
            q.history.pop_front();
        }
        q.history.push_back(item);
    }
}

/// Publishes a `queue` event: what changed (`action`: `submitted`, `removed`, `moved`,
/// `started`, `stopped`, `paused`, `run_started`, `run_ended`), a `message` for the event
/// log, and the whole queue after the change.
pub fn publish(app: &AppState, action: &str, message: String) {
    app.hub.publish(
        EventKind::Queue,
        serde_json::json!({"action": action, "message": message, "queue": app.queue.state()}),
    );
}

/// Starts the queue's worker on the current runtime; it ends when the daemon shuts down.
pub fn spawn_worker(app: AppState) {
    tokio::spawn(async move {
        tokio::select! {
            () = worker(&app) => {}
            () = app.hub.closed() => {}
        }
    });
}

async fn worker(app: &AppState) {
    let mut latch = app.estop.subscribe();
    loop {
        // Registered before looking, so a wake-up between the look and the wait is kept.
        let wake = app.queue.wake.notified();
        tokio::pin!(wake);
        wake.as_mut().enable();
        if app.estop.is_latched() {
            if app.queue.state().running {
                app.queue.pause("the e-stop was pressed");
                publish(
                    app,
                    "paused",
                    "the queue paused: the e-stop was pressed".into(),
                );
            }
            let reset = async { latch.wait_for(|l| !*l).await.is_ok() }.await;
            if !reset {
                return;
            }
            continue;
        }
        // (The guard `wait_for` returns is not Send: it must not live across an await.)
        let pressed = async { latch.clone().wait_for(|l| *l).await.map(|_| ()) };
        if app.runs.is_active() {
            // Someone else's run (`POST /api/runs`, a capture, a resume): wait for its end.
            tokio::select! {
                () = app.runs.wait_idle() => {}
                _ = pressed => {}
            }
            continue;
        }
        let Some(item) = app.queue.take_next() else {
            tokio::select! {
                () = &mut wake => {}
                _ = pressed => {}
            }
            continue;
        };
        run_item(app, item).await;
    }
}

/// Starts one item and follows its run to the end.
async fn run_item(app: &AppState, mut item: QueueItem) {
    let started = run_start::start_script_run(app, item.request.clone()).await;
    let (active, started) = match started {
        Ok(s) => s,
        Err(e) if e.status == StatusCode::CONFLICT && !app.estop.is_latched() => {
            // Someone started a run first: this one waits for its turn again.
            app.queue.put_back(item);
            return;
        }
        Err(e) => {
            tracing::warn!(
                item = item.item_id,
                "the queue could not start its run: {}",
                e.error
            );
            let why = format!(
                "queued item {} ({}) could not start: {}",
                item.item_id, item.request.script, e.error
            );
            item.error = Some(e.error);
            app.queue.put_back(item);
            app.queue.pause(why.clone());
            publish(app, "paused", format!("the queue paused: {why}"));
            app.hub.publish(
                EventKind::Warning,
                serde_json::json!({"message": why, "queue": true}),
            );
            return;
        }
    };
    let mut record = StartedItem {
        item_id: item.item_id,
        script: started.script.clone(),
        run_id: started.run_id.clone(),
        status: RunStatus::Running,
        message: None,
    };
    app.queue.set_current(Some(record.clone()));
    publish(
        app,
        "run_started",
        format!(
            "the queue started item {} ({}) as run {}",
            record.item_id, record.script, record.run_id
        ),
    );
    let outcome = active.wait_finished().await;
    let ended = format!(
        "run {} (queued item {}) ended {}",
        record.run_id, record.item_id, outcome.status
    );
    let paused = outcome.status != RunStatus::Done;
    if paused {
        let cause = if app.estop.is_latched() {
            "the e-stop was pressed: "
        } else {
            ""
        };
        app.queue.pause(format!("{cause}{ended}"));
    }
    record.status = outcome.status;
    record.message = outcome.message;
    app.queue.finished(record);
    if paused {
        publish(app, "paused", format!("the queue paused: {ended}"));
    } else {
        publish(app, "run_ended", ended);
    }
}

/// Checks a request before it is queued: the script exists, the values are of the right kind
/// and the dry run has no error (422 with every violation otherwise), so a queued run does not
/// fail at its start hours later.
pub async fn check_submission(app: &AppState, req: &StartRun) -> Result<(), ApiError> {
    let (source, set) = run_start::checked_request(app, req)?;
    let name = source.name.clone();
    let dry = super::scripts::dry_run_async(source, set, app.rig_source.clone()).await?;
    if dry.ok {
        return Ok(());
    }
    let mut items: Vec<super::error::ViolationItem> = dry
        .violations
        .iter()
        .filter(|v| v.severity == "error")
        .map(|v| super::error::ViolationItem {
            line: Some(v.line),
            col: Some(v.col),
            message: v.message.clone(),
        })
        .collect();
    if let Some(error) = &dry.error {
        items.push(super::error::ViolationItem {
            line: dry.error_line,
            col: dry.error_col,
            message: error.clone(),
        });
    }
    let stem = name.trim_end_matches(".rhai");
    Err(ApiError::unprocessable(format!(
        "{name} does not pass its dry run; not queued:\n{}",
        dry.report
    ))
    .hint(format!(
        "fix the script; `POST /api/scripts/{stem}/validate` shows the dry run"
    ))
    .violations(items))
}
