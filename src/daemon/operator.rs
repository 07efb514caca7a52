//! Operator prompts answered over the API: the executor's [`Operator`] stores the pending
//! prompt, publishes a `prompt` event and waits until `POST /api/runs/{id}/prompt` answers
//! (or the run is aborted, which answers `abort`).

use std::future::Future;
use std::pin::Pin;
use std::sync::Mutex;

use serde::{Deserialize, Serialize};
use tokio::sync::oneshot;
use utoipa::ToSchema;

use super::state::AppState;
use crate::daemon::events::EventKind;
use crate::executor::{Answer, Operator};

/// A prompt waiting for the operator.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct PromptInfo {
    pub step: usize,
    pub message: String,
}

struct Pending {
    info: PromptInfo,
    reply: oneshot::Sender<Answer>,
}

/// The pending prompt of one run (at most one: the executor asks one at a time).
#[derive(Default)]
pub struct PromptSlot {
    pending: Mutex<Option<Pending>>,
}

impl PromptSlot {
    fn lock(&self) -> std::sync::MutexGuard<'_, Option<Pending>> {
        self.pending.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Stores a prompt and returns where its answer will arrive. A prompt still pending (it
    /// cannot be, the executor asks one at a time) is answered `abort`.
    fn ask(&self, info: PromptInfo) -> oneshot::Receiver<Answer> {
        let (reply, rx) = oneshot::channel();
        if let Some(old) = self.lock().replace(Pending { info, reply }) {
            let _ = old.reply.send(Answer::Abort);
        }
        rx
    }

    /// The prompt waiting for an answer, if any.
    pub fn pending(&self) -> Option<PromptInfo> {
        self.lock().as_ref().map(|p| p.info.clone())
    }

    /// Answers the pending prompt; returns it, or `None` if none is pending.
    pub fn answer(&self, answer: Answer) -> Option<PromptInfo> {
        let pending = self.lock().take()?;
        let _ = pending.reply.send(answer);
        Some(pending.info)
    }

    /// Drops the pending prompt of `step` without answering (its waiter went away).
    fn clear(&self, step: usize) {
        let mut slot = self.lock();
        if slot.as_ref().is_some_and(|p| p.info.step == step) {
            *slot = None;
        }
    }
}

/// The [`Operator`] of a run started over the API.
pub struct ApiOperator {
    app: AppState,
    run_id: String,
    slot: std::sync::Arc<PromptSlot>,
}

impl ApiOperator {
    pub fn new(app: AppState, run_id: String, slot: std::sync::Arc<PromptSlot>) -> Self {
        Self { app, run_id, slot }
    }
}

/// Clears the slot when the executor stops waiting (abort drops the confirm future).
struct ClearOnDrop<'a> {
    slot: &'a PromptSlot,
    step: usize,
}

impl Drop for ClearOnDrop<'_> {
    fn drop(&mut self) {
        self.slot.clear(self.step);
    }
}

impl Operator for ApiOperator {
    fn confirm<'a>(
        &'a self,
        step: usize,
        message: &'a str,
    ) -> Pin<Box<dyn Future<Output = Answer> + Send + 'a>> {
        Box::pin(async move {
            let info = PromptInfo {
                step,
                message: message.to_string(),
            };
            let rx = self.slot.ask(info);
            let _clear = ClearOnDrop {
                slot: &self.slot,
                step,
            };
            self.app.hub.publish(
                EventKind::Prompt,
                serde_json::json!({"run_id": self.run_id, "step": step, "message": message}),
            );
            tracing::info!(run = %self.run_id, step, "operator prompt: {message}");
            // A dropped sender (the slot was replaced or the run is going away) means abort.
            rx.await.unwrap_or(Answer::Abort)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn answers_reach_the_waiter_once() {
        let slot = PromptSlot::default();
        assert!(slot.answer(Answer::Continue).is_none());
        let rx = slot.ask(PromptInfo {
            step: 3,
            message: "swap".into(),
        });
        assert_eq!(slot.pending().map(|p| p.step), Some(3));
        assert_eq!(slot.answer(Answer::Continue).map(|p| p.step), Some(3));
        assert!(slot.pending().is_none());
        assert_eq!(rx.await.ok(), Some(Answer::Continue));
        assert!(slot.answer(Answer::Abort).is_none());
    }

    #[tokio::test]
    async fn a_replaced_prompt_is_aborted() {
        let slot = PromptSlot::default();
        let first = slot.ask(PromptInfo {
            step: 1,
            message: "a".into(),
        });
        let _second = slot.ask(PromptInfo {
            step: 2,
            message: "b".into(),
        });
        assert_eq!(first.await.ok(), Some(Answer::Abort));
        slot.clear(1);
        assert_eq!(slot.pending().map(|p| p.step), Some(2));
        slot.clear(2);
        assert!(slot.pending().is_none());
    }
}
