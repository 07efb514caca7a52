//! The terminal progress bar: steps done, frames, rig time and ETA, fed by run events.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tokio::sync::broadcast;
use tokio::sync::broadcast::error::RecvError;

use crate::executor::Event;
use crate::units::hms;

/// A progress bar following one run's events.
pub struct Progress {
    bar: ProgressBar,
    task: tokio::task::JoinHandle<()>,
}

impl Progress {
    pub fn start(mut events: broadcast::Receiver<Event>) -> Progress {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr_with_hz(5));
        let style = ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} steps  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        let b = bar.clone();
        let task = tokio::spawn(async move {
            let mut frames = 0usize;
            loop {
                match events.recv().await {
                    Ok(Event::RunStarted {
                        total_steps,
                        steps_to_do,
                        ..
                    }) => {
                        b.set_length(total_steps as u64);
                        b.set_position((total_steps - steps_to_do) as u64);
                    }
                    Ok(Event::StepFinished {
                        step,
                        frames: n,
                        rig_time_s,
                        eta_s,
                        ..
                    }) => {
                        frames += n;
                        b.set_position(step as u64 + 1);
                        b.set_message(format!(
                            "{frames} raw frames  rig time {}  ETA {}",
                            hms(rig_time_s),
                            hms(eta_s)
                        ));
                    }
                    Ok(Event::Warning { message }) => b.println(format!("warning: {message}")),
                    Ok(Event::DeviceFault {
                        step,
                        message,
                        attempt,
                        ..
                    }) => b.println(format!(
                        "paused at step {step} (fault {attempt}): {message}; reconnecting and re-homing"
                    )),
                    Ok(Event::Recovered { step, device }) => {
                        b.println(format!("{device} recovered; running step {step} again"))
                    }
                    Ok(Event::RunFinished { .. }) => {
                        b.finish();
                        break;
                    }
                    Ok(_) | Err(RecvError::Lagged(_)) => {}
                    Err(RecvError::Closed) => break,
                }
            }
        });
        Progress { bar, task }
    }

    pub fn bar(&self) -> ProgressBar {
        self.bar.clone()
    }

    /// Waits for the bar to draw its last state.
    pub async fn finish(self) {
        if tokio::time::timeout(std::time::Duration::from_secs(1), self.task)
            .await
            .is_err()
        {
            self.bar.finish();
        }
    }
}
