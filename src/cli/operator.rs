//! Operator prompts on the terminal: the run waits until the operator presses Enter
//! (or types `abort`).

use std::future::Future;
use std::io::BufRead;
use std::pin::Pin;

use indicatif::ProgressBar;

use tokio::sync::broadcast;

use crate::executor::{Answer, Event, Operator, RunControl};

/// Asks on stderr, reads stdin.
pub struct TerminalOperator {
    bar: ProgressBar,
}

impl TerminalOperator {
    pub fn new(bar: ProgressBar) -> Self {
        Self { bar }
    }
}

impl Operator for TerminalOperator {
    fn confirm<'a>(
        &'a self,
        step: usize,
        message: &'a str,
    ) -> Pin<Box<dyn Future<Output = Answer> + Send + 'a>> {
        let bar = self.bar.clone();
        let message = message.to_string();
        Box::pin(async move {
            ask(
                bar,
                format!("operator, step {step}: {message}"),
                "press Enter when done",
            )
            .await
        })
    }
}

/// Shows `message` above the progress bar and waits for Enter (continue) or `abort` (or the
/// end of the input).
async fn ask(bar: ProgressBar, message: String, enter: &'static str) -> Answer {
    let asked = stagehand_devices::realtime::spawn_blocking(move || {
        bar.suspend(|| {
            eprintln!("\n── {message}");
            eprintln!("   {enter}, or type `abort` and Enter to stop the run safely");
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(0) | Err(_) => Answer::Abort,
                Ok(_) if line.trim().eq_ignore_ascii_case("abort") => Answer::Abort,
                Ok(_) => Answer::Continue,
            }
        })
    })
    .await;
    asked.unwrap_or(Answer::Abort)
}

/// When the run pauses itself (the interlock opened), asks the operator on the terminal to
/// resume (Enter) or abort; with `--yes` there is nobody to close the door, so the run is
/// aborted to the safe state, resumable with `stagehand resume`.
pub fn answer_pauses(
    mut events: broadcast::Receiver<Event>,
    control: RunControl,
    yes: bool,
    bar: ProgressBar,
) {
    tokio::spawn(async move {
        loop {
            let event = match events.recv().await {
                Ok(e) => e,
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            };
            if matches!(event, Event::RunFinished { .. }) {
                break;
            }
            if !matches!(event, Event::Paused { .. }) {
                continue;
            }
            let Some(reason) = control.pause_reason() else {
                continue;
            };
            if yes {
                bar.suspend(|| {
                    eprintln!("\n── {reason}");
                    eprintln!(
                        "   --yes: nobody can close the door, so the run stops safely; finish it with `stagehand resume RUN_DIR`"
                    );
                });
                control.abort();
                continue;
            }
            match ask(
                bar.clone(),
                format!("paused: {reason}"),
                "press Enter to resume",
            )
            .await
            {
                Answer::Continue => control.resume(),
                Answer::Abort => control.abort(),
            }
        }
    });
}
