//! Run control (pause, resume, abort) and the operator who answers prompts.

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use tokio::sync::{broadcast, watch};

use super::events::Event;

/// What the run should do next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    Run,
    /// Stop at the next step boundary until resumed.
    Pause,
    /// Stop now and go to the safe state.
    Abort,
}

/// Cheap-to-clone remote control of one run.
#[derive(Clone)]
pub struct RunControl {
    tx: watch::Sender<Control>,
    /// Why the run paused itself (an interlock that opened), until it is resumed.
    reason: Arc<Mutex<Option<String>>>,
}

impl Default for RunControl {
    fn default() -> Self {
        Self::new()
    }
}

impl RunControl {
    pub fn new() -> Self {
        Self {
            tx: watch::channel(Control::Run).0,
            reason: Arc::default(),
        }
    }

    pub fn pause(&self) {
        self.set(Control::Pause);
    }

    /// Pauses for a reason the operator must act on (shown with the run's state).
    pub fn pause_because(&self, reason: String) {
        *self.reason.lock().unwrap_or_else(|p| p.into_inner()) = Some(reason);
        self.set(Control::Pause);
    }

    /// Why the run paused itself, while it is paused.
    pub fn pause_reason(&self) -> Option<String> {
        if self.current() != Control::Pause {
            return None;
        }
        self.reason
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    pub fn resume(&self) {
        *self.reason.lock().unwrap_or_else(|p| p.into_inner()) = None;
        self.set(Control::Run);
    }

    pub fn abort(&self) {
        self.set(Control::Abort);
    }

    fn set(&self, c: Control) {
        // Abort is final: a later pause or resume cannot undo it.
        self.tx.send_if_modified(|cur| {
            if *cur == Control::Abort || *cur == c {
                false
            } else {
                *cur = c;
                true
            }
        });
    }

    pub fn current(&self) -> Control {
        *self.tx.borrow()
    }

    /// At a step boundary: returns true to proceed, false if the run was aborted.
    pub(crate) async fn wait_to_proceed(
        &self,
        step: usize,
        events: &broadcast::Sender<Event>,
    ) -> bool {
        let mut rx = self.tx.subscribe();
        let mut paused = false;
        loop {
            let c = *rx.borrow_and_update();
            match c {
                Control::Run => {
                    if paused {
                        let _ = events.send(Event::Resumed { before_step: step });
                    }
                    return true;
                }
                Control::Abort => return false,
                Control::Pause => {
                    if !paused {
                        paused = true;
                        let _ = events.send(Event::Paused { before_step: step });
                    }
                    if rx.changed().await.is_err() {
                        return false;
                    }
                }
            }
        }
    }

    /// Resolves when the run is aborted.
    pub(crate) async fn aborted(&self) {
        let mut rx = self.tx.subscribe();
        // The sender lives in self, so `wait_for` only fails if it is dropped; treat as pending.
        if rx.wait_for(|c| *c == Control::Abort).await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// An operator's answer to a prompt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answer {
    Continue,
    Abort,
}

/// Whoever answers operator prompts (a terminal, the web page, a test).
pub trait Operator: Send + Sync {
    fn confirm<'a>(
        &'a self,
        step: usize,
        message: &'a str,
    ) -> Pin<Box<dyn Future<Output = Answer> + Send + 'a>>;
}

/// Confirms every prompt at once (`--yes`), logging the message.
pub struct AutoConfirm;

impl Operator for AutoConfirm {
    fn confirm<'a>(
        &'a self,
        step: usize,
        message: &'a str,
    ) -> Pin<Box<dyn Future<Output = Answer> + Send + 'a>> {
        tracing::info!("step {step}: prompt confirmed automatically: {message}");
        Box::pin(async { Answer::Continue })
    }
}
