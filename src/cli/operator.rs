//! Operator prompts on the terminal: the run waits until the operator presses Enter
//! (or types `abort`).

use std::future::Future;
use std::io::BufRead;
use std::pin::Pin;

use indicatif::ProgressBar;

use crate::executor::{Answer, Operator};

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
            let asked = tokio::task::spawn_blocking(move || {
                bar.suspend(|| {
                    eprintln!("\n── operator, step {step}: {message}");
                    eprintln!(
                        "   press Enter when done, or type `abort` and Enter to stop the run safely"
                    );
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
        })
    }
}
